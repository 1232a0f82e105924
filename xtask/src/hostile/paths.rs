//! Paths: every path argument of every subcommand given a missing path, a folder where a file
//! belongs (or a file where a folder belongs), `/dev/zero`, a FIFO, an empty file and an empty
//! string; every output aliased with an input or another output, or unwritable; and the
//! hostile-looking inputs that are valid and must succeed.

use super::case::{COMMANDS, Case, Setup};
use super::ctx::{Ctx, MOUNT_POINTS, args, replace_arg, s, with_flag, without_flag};

/// What a path argument must be.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    /// A file with this extension.
    File(&'static str),
    /// A folder.
    Folder,
}

/// A path argument: (subcommand, argument name, the command line, the argument's value in it
/// to replace, what it must be, a prefix for the replacement such as `oracle:`).
type PathArgument = (&'static str, &'static str, Vec<String>, String, Role, &'static str);

/// Every path argument.
fn path_arguments(ctx: &Ctx) -> Vec<PathArgument> {
    use Role::*;
    let sd = &ctx.seeds;
    let (cube, views, disc, tiny) = (s(&sd.cube_obj), s(&sd.views), s(&sd.disc_png), s(&sd.tiny));
    let refine = ctx.base("refine");
    let oracle = with_flag(&refine, "--enhancer", &format!("oracle:{cube}"));
    let eval = ctx.base("eval");
    let gt = [&eval[..1], &[s(&sd.torus)], &eval[2..]].concat();
    let demo = [&ctx.base("demo")[..], &args(&["--from-image", "--steps", "1", "--weights", &tiny])[..]].concat();
    let recon_enhancer = [&ctx.base("reconstruct")[..], &args(&["--enhancer", "ENHANCER"])[..]].concat();
    let run_enhancer = [&ctx.base("run")[..], &args(&["--enhancer", "ENHANCER"])[..]].concat();
    let images = replace_arg(&ctx.base("batch"), &s(&sd.manifest), &s(&sd.manifest_image));
    let batch_weights = [&images[..], &args(&["--weights", &tiny, "--steps", "1", "--starts", "1"])[..]].concat();
    vec![
        ("info", "MESH", ctx.base("info"), cube.clone(), File("obj"), ""),
        ("render", "MESH", ctx.base("render"), cube.clone(), File("obj"), ""),
        ("eval", "PRED", eval.clone(), cube.clone(), File("obj"), ""),
        ("eval", "GT", gt, cube.clone(), File("obj"), ""),
        ("reconstruct", "VIEWS", ctx.base("reconstruct"), views.clone(), Folder, ""),
        ("reconstruct", "--enhancer", recon_enhancer, "ENHANCER".into(), Folder, ""),
        ("texture", "MESH", ctx.base("texture"), cube.clone(), File("obj"), ""),
        ("texture", "VIEWS", ctx.base("texture"), views.clone(), Folder, ""),
        ("refine", "MESH", refine.clone(), cube.clone(), File("obj"), ""),
        ("refine", "VIEWS", refine.clone(), views.clone(), Folder, ""),
        ("refine", "--enhancer", refine, "identity".into(), Folder, ""),
        ("refine", "oracle", oracle, format!("oracle:{cube}"), File("obj"), "oracle:"),
        ("demo", "--weights", demo, tiny.clone(), Folder, ""),
        ("prepare", "IMAGE", ctx.base("prepare"), disc.clone(), File("png"), ""),
        ("generate", "IMAGE", ctx.base("generate"), disc.clone(), File("png"), ""),
        ("generate", "--weights", ctx.base("generate"), tiny.clone(), Folder, ""),
        ("run", "IMAGE", ctx.base("run"), disc.clone(), File("png"), ""),
        ("run", "--weights", ctx.base("run"), tiny.clone(), Folder, ""),
        ("run", "--enhancer", run_enhancer, "ENHANCER".into(), Folder, ""),
        ("batch", "MANIFEST", ctx.base("batch"), s(&sd.manifest), File("txt"), ""),
        ("batch", "--weights", batch_weights, tiny.clone(), Folder, ""),
        ("dataset", "MESHES", ctx.base("dataset"), cube, File("obj"), ""),
        ("train", "--data", ctx.base("train"), s(&sd.dataset), Folder, ""),
        ("train", "--init", ctx.base("train"), tiny, Folder, ""),
    ]
}

/// The cases of every path argument with a missing path, the wrong kind of file, `/dev/zero`,
/// a FIFO, an empty file and an empty string.
pub(crate) fn path_cases(ctx: &Ctx, out: &mut Vec<Case>) {
    for (i, (command, arg, base, value, role, prefix)) in path_arguments(ctx).into_iter().enumerate() {
        let ext = match role {
            Role::File(e) => format!(".{e}"),
            Role::Folder => String::new(),
        };
        let what = |w: &str| format!("path-{}-{w}", arg.trim_start_matches("--").to_lowercase());
        let at = |name: &str| format!("{prefix}{{case}}/{name}");
        let timeout = if matches!(command, "run" | "demo" | "refine") { 60 } else { 20 };
        let mk = |w: &str, name: &str, setup: Option<Setup>, quick: bool| {
            let file = format!("{name}{ext}");
            let mut c = Case::new(command, &what(w), replace_arg(&base, &value, &at(&file)), &[&file])
                .quick_if(quick)
                .timeout(timeout);
            if let Some(setup) = setup {
                c = c.with(setup);
            }
            c
        };
        out.push(mk("missing", "h-missing", None, false));
        let empty = format!("h-empty{ext}");
        out.push(match role {
            Role::File(_) => mk("folder", "h-folder", Some(Setup::Dir(format!("h-folder{ext}"))), false),
            Role::Folder => mk("file", "h-file", Some(Setup::Write("h-file".into(), b"a file\n".to_vec())), false),
        });
        // Nothing but an error is right here, and it needs no work: a short limit.
        let zero = Setup::Symlink("/dev/zero".into(), format!("h-zero{ext}"));
        out.push(mk("devzero", "h-zero", Some(zero), i % 6 == 1).timeout(10));
        out.push(mk("fifo", "h-fifo", Some(Setup::Fifo(format!("h-fifo{ext}"))), i % 6 == 4).timeout(10));
        out.push(match role {
            Role::File(_) => mk("empty", "h-empty", Some(Setup::Write(empty.clone(), Vec::new())), false),
            Role::Folder => mk("empty", "h-empty", Some(Setup::Dir(empty.clone())), false),
        });
        // A symbolic link to itself, a file path with a trailing slash, a name past NAME_MAX.
        let looped = format!("h-loop{ext}");
        let link = Setup::Symlink(looped.clone().into(), looped.clone());
        out.push(mk("symlink-loop", "h-loop", Some(link), false));
        if let Role::File(_) = role {
            let slash = replace_arg(&base, &value, &at(&format!("h-slash{ext}/")));
            let setup = Setup::Write(format!("h-slash{ext}"), b"x".to_vec());
            out.push(Case::new(command, &what("trailing-slash"), slash, &["h-slash"]).with(setup).timeout(timeout));
        }
        let long = format!("{}{ext}", "h".repeat(300));
        out.push(
            Case::new(command, &what("name-too-long"), replace_arg(&base, &value, &at(&long)), &[&long])
                .timeout(timeout),
        );
        let blank = replace_arg(&base, &value, prefix);
        let tokens = [arg, "\"\"", "empty"];
        out.push(Case::new(command, &what("empty-string"), blank, &tokens).timeout(timeout));
    }
    // /dev/zero itself (no extension) as a mesh and as an image.
    let info = ctx.base("info");
    out.push(Case::new(
        "info",
        "mesh-dev-zero",
        replace_arg(&info, &s(&ctx.seeds.cube_obj), "/dev/zero"),
        &["/dev/zero"],
    ));
    let prepare = ctx.base("prepare");
    let dev = replace_arg(&prepare, &s(&ctx.seeds.disc_png), "/dev/zero");
    out.push(Case::new("prepare", "image-dev-zero", dev, &["/dev/zero"]));
    let urandom = replace_arg(&prepare, &s(&ctx.seeds.disc_png), "/dev/urandom");
    out.push(Case::new("prepare", "image-dev-urandom", urandom, &["/dev/urandom"]));
}

/// Every output flag: (subcommand, flag, the command line, whether it is a folder).
fn outputs(ctx: &Ctx) -> Vec<(&'static str, &'static str, Vec<String>, bool)> {
    let report = |c: &str| [&ctx.base(c)[..], &args(&["--report", "{case}/report.json"])[..]].concat();
    let mask = [&ctx.base("prepare")[..], &args(&["--mask-out", "{case}/mask.png"])[..]].concat();
    let views = [&ctx.base("run")[..], &args(&["--views", "{case}/views"])[..]].concat();
    vec![
        ("render", "--out", ctx.base("render"), true),
        ("reconstruct", "--out", ctx.base("reconstruct"), false),
        ("reconstruct", "--report", report("reconstruct"), false),
        ("texture", "--out", ctx.base("texture"), false),
        ("refine", "--out", ctx.base("refine"), false),
        ("refine", "--report", report("refine"), false),
        ("demo", "--out", ctx.base("demo"), true),
        ("prepare", "--out", ctx.base("prepare"), false),
        ("prepare", "--mask-out", mask, false),
        ("generate", "--out", ctx.base("generate"), true),
        ("run", "--out", ctx.base("run"), false),
        ("run", "--views", views, true),
        ("run", "--report", report("run"), false),
        ("batch", "--out", ctx.base("batch"), true),
        ("dataset", "--out", ctx.base("dataset"), true),
        ("train", "--out", ctx.base("train"), true),
    ]
}

/// The extension an output file of `command`'s `flag` takes.
fn output_ext(command: &str, flag: &str) -> &'static str {
    match (command, flag) {
        (_, "--report") => "json",
        ("prepare", _) => "png",
        _ => "glb",
    }
}

/// The cases of unwritable outputs: under a regular file, in `/proc`, on a read-only bind
/// mount, an existing folder for a file (a file for a folder).
pub(crate) fn unwritable_cases(ctx: &Ctx, out: &mut Vec<Case>) {
    let file = s(&ctx.seeds.file);
    for (i, (command, flag, base, folder)) in outputs(ctx).into_iter().enumerate() {
        let name = if folder { "out".to_string() } else { format!("out.{}", output_ext(command, flag)) };
        let timeout = if matches!(command, "run" | "demo" | "refine") { 90 } else { 30 };
        let what = |w: &str| format!("{}-{w}", flag.trim_start_matches("--"));
        let case = |w: &str, path: String, tokens: &[&str]| {
            Case::new(command, &what(w), with_flag(&base, flag, &path), tokens).timeout(timeout)
        };
        out.push(case("under-a-file", format!("{file}/sub/{name}"), &["file.txt"]).quick_if(i % 5 == 0));
        out.push(case("in-proc", format!("/proc/w3d-hostile/{name}"), &["/proc/w3d-hostile"]));
        out.push(case("empty-string", String::new(), &[flag]));
        if let Some(m) = &ctx.mounts {
            out.push(case("read-only-mount", format!("{}/{name}", s(&m.readonly)), &["readonly"]));
        }
        out.push(if folder {
            case("is-a-file", "{case}/taken".into(), &["taken"]).with(Setup::Write("taken".into(), b"mine\n".to_vec()))
        } else {
            case("is-a-folder", format!("{{case}}/{name}"), &[&name]).with(Setup::Dir(name.clone()))
        });
        if !folder && flag == "--out" {
            out.push(case("wrong-extension", "{case}/out.stl".into(), &["out.stl", ".stl"]));
        }
    }
}

/// The cases of outputs aliased with an input or another output (in copies inside the case
/// folder, which must be left unchanged). An error must name the flag or the aliased path.
pub(crate) fn alias_cases(ctx: &Ctx, out: &mut Vec<Case>) {
    let sd = &ctx.seeds;
    let (cube, views, disc, tiny, data) = (s(&sd.cube_obj), s(&sd.views), s(&sd.disc_png), s(&sd.tiny), s(&sd.dataset));
    let copy = |from: &std::path::Path, to: &str| Setup::Copy(from.to_path_buf(), to.into());
    // `base` with `flag` set to `path`; the error must name the flag or the path.
    let alias = |command: &'static str, what: &str, base: &[String], flag: &str, path: &str| {
        Case::new(command, what, with_flag(base, flag, path), &[flag, path])
    };
    // prepare
    let p = replace_arg(&ctx.base("prepare"), &disc, "{case}/in.png");
    let img = || copy(&sd.disc_png, "in.png");
    let both = [&p[..], &args(&["--mask-out", "{case}/p.png"])[..]].concat();
    out.push(alias("prepare", "out-is-mask-out", &both, "--mask-out", "{case}/p.png").with(img()).quick_if(true));
    out.push(alias("prepare", "out-is-image", &p, "--out", "{case}/in.png").with(img()));
    out.push(alias("prepare", "out-is-image-dotted", &p, "--out", "{case}/./in.png").with(img()));
    let link = Setup::Symlink("in.png".into(), "link.png".into());
    out.push(alias("prepare", "out-is-link-to-image", &p, "--out", "{case}/link.png").with(img()).with(link));
    out.push(alias("prepare", "mask-out-is-image", &p, "--mask-out", "{case}/in.png").with(img()));
    // render
    let r = replace_arg(&ctx.base("render"), &cube, "{case}/m/cube.obj");
    let mesh = || copy(&sd.cube_obj, "m/cube.obj");
    out.push(alias("render", "out-holds-mesh", &r, "--out", "{case}/m").with(mesh()));
    out.push(alias("render", "out-is-mesh", &r, "--out", "{case}/m/cube.obj").with(mesh()));
    let other = Setup::Write("other/notes.txt".into(), b"mine\n".to_vec());
    out.push(alias("render", "out-holds-other-files", &r, "--out", "{case}/other").with(mesh()).with(other));
    // reconstruct
    let rc = replace_arg(&ctx.base("reconstruct"), &views, "{case}/views");
    let v = || copy(&sd.views, "views");
    let report = |what: &str, base: &[String], path: &str| alias("reconstruct", what, base, "--report", path).with(v());
    out.push(report("report-is-cameras-json", &rc, "{case}/views/cameras.json"));
    out.push(report("report-is-out", &rc, "{case}/r.glb"));
    out.push(report("report-is-side-png", &with_flag(&rc, "--out", "{case}/r.obj"), "{case}/r.png"));
    out.push(alias("reconstruct", "out-inside-views", &rc, "--out", "{case}/views/r.glb").with(v()).either());
    // texture
    let tx = replace_arg(&replace_arg(&ctx.base("texture"), &cube, "{case}/cube.glb"), &views, "{case}/views");
    let glb = || copy(&sd.cube_glb, "cube.glb");
    out.push(alias("texture", "out-is-mesh", &tx, "--out", "{case}/cube.glb").with(glb()).with(v()));
    // An OBJ output's texture is written beside it as <stem>.png: here a view's colour image.
    let side = alias("texture", "obj-side-png-is-a-view", &tx, "--out", "{case}/views/colour_front.obj");
    out.push(side.with(glb()).with(v()).either());
    // refine
    let rf = replace_arg(&replace_arg(&ctx.base("refine"), &cube, "{case}/cube.obj"), &views, "{case}/views");
    let rf_case = |what: &str, base: &[String], flag: &str, path: &str| {
        alias("refine", what, base, flag, path).with(copy(&sd.cube_obj, "cube.obj")).with(v()).timeout(60)
    };
    out.push(rf_case("out-is-mesh", &rf, "--out", "{case}/cube.obj"));
    out.push(rf_case("report-is-mesh", &rf, "--report", "{case}/cube.obj"));
    out.push(rf_case("report-is-out", &rf, "--report", "{case}/f.glb"));
    let oracle = with_flag(&rf, "--enhancer", "oracle:{case}/truth.obj");
    out.push(rf_case("out-is-oracle", &oracle, "--out", "{case}/truth.obj").with(copy(&sd.cube_obj, "truth.obj")));
    // generate
    let g = replace_arg(&ctx.base("generate"), &disc, "{case}/in/disc.png");
    let img = || copy(&sd.disc_png, "in/disc.png");
    out.push(alias("generate", "out-holds-image", &g, "--out", "{case}/in").with(img()));
    out.push(alias("generate", "out-is-image", &g, "--out", "{case}/in/disc.png").with(img()));
    let gw = replace_arg(&g, &tiny, "{case}/w");
    out.push(alias("generate", "out-is-weights", &gw, "--out", "{case}/w").with(img()).with(copy(&sd.tiny, "w")));
    // run
    let rn = replace_arg(&ctx.base("run"), &disc, "{case}/in/disc.png");
    let rn_case = |what: &str, base: &[String], flag: &str, path: &str| {
        alias("run", what, base, flag, path).with(img()).timeout(60)
    };
    // The folder is named, but the advice must be about --views, not --out.
    out.push(rn_case("views-hold-image", &rn, "--views", "{case}/in").forbid(&["another --out"]));
    out.push(rn_case("report-is-image", &rn, "--report", "{case}/in/disc.png"));
    out.push(rn_case("report-is-out", &rn, "--report", "{case}/r.glb"));
    out.push(rn_case("report-is-side-mtl", &with_flag(&rn, "--out", "{case}/r.obj"), "--report", "{case}/r.mtl"));
    let views_v = with_flag(&rn, "--views", "{case}/v");
    out.push(rn_case("out-inside-views", &views_v, "--out", "{case}/v/m.glb"));
    // batch
    let b = [&args(&["batch", "{case}/items.txt"])[..], &without_flag(&ctx.base("batch"), "--out")[2..]].concat();
    let b_case = |what: &str, base: &[String], path: &str| {
        alias("batch", what, base, "--out", path)
            .with(copy(&sd.views, "views"))
            .with(Setup::Write("items.txt".into(), b"views\n".to_vec()))
            .timeout(60)
    };
    out.push(b_case("out-is-manifest-folder", &b, "{case}"));
    out.push(b_case("out-is-manifest-folder-resume", &[&b[..], &args(&["--resume"])[..]].concat(), "{case}"));
    out.push(b_case("out-is-manifest", &b, "{case}/items.txt"));
    out.push(b_case("out-is-item", &b, "{case}/views"));
    // dataset
    let d = replace_arg(&ctx.base("dataset"), &cube, "{case}/m/cube.obj");
    out.push(alias("dataset", "out-holds-mesh", &d, "--out", "{case}/m").with(mesh()));
    out.push(alias("dataset", "out-is-mesh", &d, "--out", "{case}/m/cube.obj").with(mesh()));
    // train
    let t = replace_arg(&replace_arg(&ctx.base("train"), &tiny, "{case}/w"), &data, "{case}/data");
    let t_case = |what: &str, path: &str| {
        alias("train", what, &t, "--out", path).with(copy(&sd.tiny, "w")).with(copy(&sd.dataset, "data")).timeout(60)
    };
    out.push(t_case("out-is-init", "{case}/w"));
    out.push(t_case("out-is-data", "{case}/data"));
    out.push(t_case("out-inside-data", "{case}/data/run").either());
    // demo
    let taken = Setup::Write("taken".into(), b"mine\n".to_vec());
    out.push(alias("demo", "out-is-a-file-of-mine", &ctx.base("demo"), "--out", "{case}/taken").with(taken));
}

/// Hostile-looking inputs that are valid: every command's base line, odd but legal paths,
/// extreme legal values, outputs replacing earlier outputs, mount points.
pub(crate) fn valid_cases(ctx: &Ctx, out: &mut Vec<Case>) {
    let sd = &ctx.seeds;
    let cheap = ["info", "render", "eval", "reconstruct", "texture", "prepare", "generate", "dataset", "train"];
    for command in COMMANDS {
        let timeout = if matches!(command, "run" | "demo" | "refine" | "reconstruct" | "batch") { 90 } else { 30 };
        out.push(
            Case::new(command, "valid-base", ctx.base(command), &[])
                .succeeds()
                .timeout(timeout)
                .quick_if(cheap.contains(&command)),
        );
    }
    let cube = s(&sd.cube_obj);
    for (what, seed) in [
        ("ply-ascii", &sd.cube_ply_ascii),
        ("ply-binary", &sd.cube_ply),
        ("glb", &sd.cube_glb),
        ("gltf", &sd.cube_gltf),
    ] {
        out.push(
            Case::new("info", &format!("valid-{what}"), replace_arg(&ctx.base("info"), &cube, &s(seed)), &[])
                .succeeds(),
        );
        out.push(
            Case::new("render", &format!("valid-{what}"), replace_arg(&ctx.base("render"), &cube, &s(seed)), &[])
                .succeeds(),
        );
    }
    let odd = "{case}/ü ñ space [x] $HOME.obj";
    out.push(
        Case::new("info", "valid-odd-file-name", replace_arg(&ctx.base("info"), &cube, odd), &[])
            .succeeds()
            .with(Setup::Copy(sd.cube_obj.clone(), "ü ñ space [x] $HOME.obj".into())),
    );
    out.push(
        Case::new("render", "valid-odd-out-name", with_flag(&ctx.base("render"), "--out", "{case}/ü ñ -dash"), &[])
            .succeeds(),
    );
    out.push(
        Case::new("info", "valid-upper-case-extension", replace_arg(&ctx.base("info"), &cube, "{case}/CUBE.OBJ"), &[])
            .succeeds()
            .with(Setup::Copy(sd.cube_obj.clone(), "CUBE.OBJ".into())),
    );
    out.push(
        Case::new("info", "valid-symlinked-mesh", replace_arg(&ctx.base("info"), &cube, "{case}/link.obj"), &[])
            .succeeds()
            .with(Setup::Symlink(sd.cube_obj.clone(), "link.obj".into())),
    );
    out.push(Case::new("render", "valid-size-1", with_flag(&ctx.base("render"), "--size", "1"), &[]).succeeds());
    out.push(Case::new("eval", "valid-samples-1", with_flag(&ctx.base("eval"), "--samples", "1"), &[]).succeeds());
    out.push(
        Case::new("eval", "valid-seed-max", with_flag(&ctx.base("eval"), "--seed", "18446744073709551615"), &[])
            .succeeds(),
    );
    out.push(
        Case::new("render", "valid-replaces-earlier-views", with_flag(&ctx.base("render"), "--out", "{case}/v"), &[])
            .succeeds()
            .replaces()
            .with(Setup::Copy(sd.views.clone(), "v".into())),
    );
    out.push(
        Case::new("dataset", "valid-replaces-earlier-dataset", ctx.base("dataset"), &[])
            .succeeds()
            .replaces()
            .with(Setup::Copy(sd.dataset.clone(), "ds".into())),
    );
    let disc = s(&sd.disc_png);
    for (what, img) in [("webp", &sd.disc_webp), ("16bit-png", &sd.disc16_png)] {
        out.push(
            Case::new("prepare", &format!("valid-{what}"), replace_arg(&ctx.base("prepare"), &disc, &s(img)), &[])
                .succeeds(),
        );
        out.push(
            Case::new("generate", &format!("valid-{what}"), replace_arg(&ctx.base("generate"), &disc, &s(img)), &[])
                .succeeds(),
        );
    }
    let photo = with_flag(&replace_arg(&ctx.base("prepare"), &disc, &s(&sd.photo_jpg)), "--min-confidence", "0");
    out.push(Case::new("prepare", "valid-jpeg-photo", photo, &[]).succeeds());
    out.push(
        Case::new("prepare", "valid-no-crop", [&ctx.base("prepare")[..], &args(&["--no-crop"])].concat(), &[])
            .succeeds(),
    );
    out.push(
        Case::new(
            "generate",
            "valid-small-model",
            replace_arg(&ctx.base("generate"), &s(&sd.tiny), &s(&sd.small)),
            &[],
        )
        .succeeds(),
    );
    out.push(
        Case::new("batch", "valid-resume-fresh", [&ctx.base("batch")[..], &args(&["--resume"])].concat(), &[])
            .succeeds()
            .timeout(60),
    );
    out.push(
        Case::new("batch", "valid-shard-1-of-1", [&ctx.base("batch")[..], &args(&["--shard", "0/1"])].concat(), &[])
            .succeeds()
            .timeout(60),
    );
    out.push(
        Case::new(
            "train",
            "valid-ema-and-linear",
            [
                &ctx.base("train")[..],
                &args(&["--ema-decay", "0.5", "--lr-schedule", "linear", "--min-snr-gamma", "none"]),
            ]
            .concat(),
            &[],
        )
        .succeeds()
        .timeout(60),
    );
    // Outputs onto mount points (container or Kubernetes volumes) must work (issue #63).
    if let Some(m) = &ctx.mounts {
        for name in MOUNT_POINTS {
            let point = s(&m.points.join(name));
            let timeout = if name == "batch" { 60 } else { 30 };
            out.push(
                Case::new(name, "valid-out-is-a-mount-point", with_flag(&ctx.base(name), "--out", &point), &[])
                    .succeeds()
                    .timeout(timeout),
            );
        }
    }
    // Missing parents of folder outputs are created.
    out.push(
        Case::new("render", "valid-out-missing-parents", with_flag(&ctx.base("render"), "--out", "{case}/a/b/c"), &[])
            .succeeds(),
    );
    out.push(
        Case::new(
            "dataset",
            "valid-out-missing-parents",
            with_flag(&ctx.base("dataset"), "--out", "{case}/a/b/c"),
            &[],
        )
        .succeeds(),
    );
}
