//! The hostile-user findings of issue #23 against the command line: every case ends quickly
//! with a clear error (or does the right thing) and loses nothing.

use crate::common::{s, wonder3d};
use std::path::{Path, PathBuf};

use std::time::{Duration, Instant};

use wonder3d::{Mesh, ViewSet, load_mesh, save_mesh};

/// Runs a command that must fail within `seconds`, returning its stderr.
fn fails_within(seconds: u64, args: &[&str]) -> String {
    let start = Instant::now();
    let out = wonder3d(args);
    assert!(start.elapsed() < Duration::from_secs(seconds), "{args:?} took {:?}", start.elapsed());
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "{args:?} succeeded: {err}");
    // A clear error, not an abort on allocation (134) or a panic (101).
    assert!(matches!(out.status.code(), Some(1 | 2)), "{args:?}: {:?} {err}", out.status);
    err
}

fn asset(name: &str) -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets").join(name).to_str().unwrap().to_string()
}

/// Oracle views of the torus at 32² in `dir`.
fn render_torus(dir: &Path) {
    let run = wonder3d(&["render", &asset("torus.obj"), "--size", "32", "--out", s(dir)]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
}

#[test]
fn info_on_a_ply_claiming_10e18_rows_fails_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("junk.ply");
    let text = "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                property float z\nelement junk 1000000000000000000\nend_header\n";
    let mut bytes = text.as_bytes().to_vec();
    bytes.extend([0u8; 36]);
    std::fs::write(&p, bytes).unwrap();
    let err = fails_within(5, &["info", s(&p)]);
    assert!(err.contains("junk.ply") && err.contains("element junk"), "{err}");
}

#[test]
fn reconstruct_refuses_absurd_cameras_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let views = dir.path().join("views");
    render_torus(&views);
    let cameras = views.join("cameras.json");
    let original = crate::common::read_json(&cameras);
    for half_height in [100.0, 1e30] {
        let mut json = original.clone();
        for v in json["views"].as_array_mut().unwrap() {
            v["camera"]["projection"]["half_height"] = half_height.into();
        }
        std::fs::write(&cameras, json.to_string()).unwrap();
        let out = dir.path().join("x.glb");
        let err = fails_within(10, &["reconstruct", s(&views), "--out", s(&out), "--quiet"]);
        assert!(err.contains("cameras.json") && err.contains("half_height"), "{err}");
        assert!(!out.exists());
    }
}

#[test]
fn sizes_that_cannot_fit_in_memory_are_refused_by_the_parser() {
    let dir = tempfile::tempdir().unwrap();
    let torus = asset("torus.obj");
    let err = fails_within(5, &["eval", &torus, &torus, "--samples", "100000000000"]);
    assert!(err.contains("--samples") && err.contains("1 to 10000000"), "{err}");
    let out = dir.path().join("v");
    let err = fails_within(5, &["render", &torus, "--size", "16384", "--out", s(&out)]);
    assert!(err.contains("--size") && err.contains("1 to 4096"), "{err}");
    assert!(!out.exists());
    let err = fails_within(5, &["texture", &torus, s(dir.path()), "--size", "0", "--out", "t.glb"]);
    assert!(err.contains("from 8 to 8192 texels") && !err.contains("dilation"), "{err}");
    // Options that only the bake would refuse are checked before the demo's reconstruction.
    let err = fails_within(3, &["demo", "--out", s(&dir.path().join("demo")), "--texture-size", "8", "--quiet"]);
    assert!(err.contains("padding"), "{err}");
}

/// Every numeric option's parser, through the binary: in-range values pass it (the command
/// then fails on its missing input, exit code 1), out-of-range, negative, non-finite and
/// malformed values are refused with the option's range (clap's exit code 2).
#[test]
fn numeric_options_accept_their_range_and_refuse_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let missing = s(&dir.path().join("missing.obj")).to_string();
    let out = s(&dir.path().join("out")).to_string();
    let glb = s(&dir.path().join("out.glb")).to_string();
    let m = missing.as_str();
    let command = |option: &str| -> Vec<&str> {
        match option {
            "--seed" | "--samples" => vec!["eval", m, m],
            "--size" => vec!["render", m, "--out", &out],
            "--steps" | "--guidance" | "--eta" | "--draws" => vec!["generate", m, "--weights", m, "--out", &out],
            "--min-snr-gamma" => vec!["train", "--stage", "2", "--data", m, "--init", m, "--out", &out],
            "--starts" => vec!["reconstruct", m, "--out", &glb],
            _ => vec!["texture", m, m, "--out", &glb],
        }
    };
    let accepted = [
        ("--seed", "0"),
        ("--seed", "18446744073709551615"),
        ("--samples", "20000"),
        ("--size", "4096"),
        ("--steps", "50"),
        ("--guidance", "2"),
        ("--guidance", "1e1"),
        ("--eta", "0"),
        ("--draws", "64"),
        ("--starts", "64"),
        ("--min-snr-gamma", "5"),
        ("--min-snr-gamma", "none"),
        ("--padding", "0"),
        ("--exponent", "4"),
    ];
    for (option, value) in accepted {
        let mut args = command(option);
        args.extend([option, value]);
        let run = wonder3d(&args);
        let err = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains("missing.obj"), "{args:?}: {err}");
    }
    let refused: [(&str, &[&str], &str); 12] = [
        ("--seed", &["-1", "18446744073709551616", "1.5", "", "x"], "from 0 to 18446744073709551615"),
        ("--size", &["16384", "0", "-3"], "from 1 to 4096 pixels"),
        ("--samples", &["100000000000", "0"], "from 1 to 10000000 surface samples"),
        ("--steps", &["0", "-5", "1001"], "from 1 to 1000 steps"),
        ("--guidance", &["NaN", "nan", "inf", "-inf", "-1", "1e30", "two"], "a guidance scale from 0 to 100"),
        ("--eta", &["1.5", "NaN"], "an eta from 0 to 1"),
        ("--draws", &["0", "65", "-1", "2.5"], "from 1 to 64 draws"),
        ("--starts", &["0", "65", "-1", "2.5"], "from 1 to 64 fits"),
        ("--min-snr-gamma", &["0", "-1", "NaN", "inf", "five"], "a Min-SNR gamma"),
        ("--exponent", &["inf", "-2"], "an exponent from 0 to 64"),
        ("--padding", &["-1", "1025"], "from 0 to 1024 texels"),
        ("--dilation", &["0.5"], "from 0 to 1024 texels"),
    ];
    for (option, values, range) in refused {
        for value in values {
            let mut args = command(option);
            args.extend([option, value]);
            let err = fails_within(5, &args);
            assert!(err.contains(option) && err.contains(range) && !err.contains("tip"), "{args:?}: {err}");
        }
    }
    let err = fails_within(5, &["texture", m, m, "--out", &glb, "--size", "7"]);
    assert!(err.contains("from 8 to 8192 texels"), "{err}");
    assert!(!dir.path().join("out").exists() && !dir.path().join("out.glb").exists());
}

#[test]
fn negative_and_non_finite_numbers_get_a_range_error() {
    let torus = asset("torus.obj");
    let err = fails_within(5, &["eval", &torus, &torus, "--seed", "-1"]);
    assert!(err.contains("from 0 to 18446744073709551615") && !err.contains("tip"), "{err}");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("views");
    // Parsed (and refused) before any work, in builds with and without the model.
    let err = fails_within(5, &["generate", &torus, "--weights", "w", "--out", s(&out), "--guidance", "NaN"]);
    assert!(err.contains("guidance scale from 0 to 100"), "{err}");
    let err = fails_within(5, &["generate", &torus, "--weights", "w", "--out", s(&out), "--eta", "-0.5"]);
    assert!(err.contains("an eta from 0 to 1"), "{err}");
    assert!(!out.exists());
    let err = fails_within(5, &["texture", &torus, s(dir.path()), "--exponent", "inf", "--out", "t.glb"]);
    assert!(err.contains("exponent"), "{err}");
}

/// The newer commands' numeric options take negative values as values: the option's range is
/// named, not clap's "unexpected argument '-1'" with its `-- -1` tip.
#[test]
fn negative_numbers_of_the_newer_commands_get_a_range_error() {
    let dir = tempfile::tempdir().unwrap();
    let (missing, out_dir, out_glb) = (dir.path().join("missing"), dir.path().join("out"), dir.path().join("out.glb"));
    let (m, out, glb) = (s(&missing), s(&out_dir), s(&out_glb));
    let cases: [(&[&str], &str, &str); 6] = [
        (&["batch", m, "--out", out, "--shard", "-1/2"], "--shard", "-1/2"),
        (&["batch", m, "--out", out, "--jobs", "-1"], "--jobs", "from 1 to 256"),
        (&["train", "--stage", "3", "--data", m, "--init", m, "--out", out, "--steps", "-1"], "--steps", "-1"),
        (
            &["train", "--stage", "3", "--data", m, "--init", m, "--out", out, "--lr", "-1e-4"],
            "--lr",
            "a learning rate",
        ),
        (
            &["refine", m, m, "--enhancer", "identity", "--out", glb, "--iterations", "-1"],
            "--iterations",
            "from 0 to 10",
        ),
        (&["train", "--stage", "-2", "--data", m, "--init", m, "--out", out], "--stage", "-2"),
    ];
    for (args, option, expect) in cases {
        let err = fails_within(5, args);
        assert!(
            err.contains(option)
                && err.contains(expect)
                && !err.contains("unexpected argument")
                && !err.contains("tip"),
            "{args:?}: {err}"
        );
    }
    assert!(!dir.path().join("out").exists() && !dir.path().join("out.glb").exists());
}

/// A mesh whose triangles have no area is named, with its role, by every command that reads
/// two inputs (it used to be "mesh surface area: expected a positive area", whichever it was).
#[test]
fn a_mesh_without_area_is_named_with_its_role() {
    let dir = tempfile::tempdir().unwrap();
    let flat = dir.path().join("flat.obj");
    std::fs::write(&flat, "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n").unwrap();
    let torus = asset("torus.obj");
    let f = s(&flat);
    let err = fails_within(5, &["eval", f, &torus]);
    assert!(err.contains("PRED") && err.contains("flat.obj") && err.contains("zero area"), "{err}");
    let err = fails_within(5, &["eval", &torus, f]);
    assert!(err.contains("GT") && err.contains("flat.obj"), "{err}");
    let views = dir.path().join("views");
    render_torus(&views);
    let out = dir.path().join("t.glb");
    let err = fails_within(5, &["texture", f, s(&views), "--out", s(&out)]);
    assert!(err.contains("MESH") && err.contains("flat.obj") && err.contains("zero area"), "{err}");
    assert!(!out.exists());
}

#[test]
fn outputs_are_checked_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let views = dir.path().join("views");
    render_torus(&views);
    let v = s(&views);
    let err = fails_within(3, &["reconstruct", v, "--out", "/nonexistent/x.glb"]);
    assert!(err.contains("/nonexistent"), "{err}");
    let err = fails_within(3, &["reconstruct", v, "--out", s(&dir.path().join("x.stl"))]);
    assert!(err.contains(".glb, .obj or .ply"), "{err}");
    let mesh = dir.path().join("x.glb");
    let report = dir.path().join("missing/report.json");
    let err = fails_within(3, &["reconstruct", v, "--out", s(&mesh), "--report", s(&report)]);
    assert!(err.contains("missing"), "{err}");
    // A report on the mesh, or on the texture an .obj writes beside it: the report is JSON.
    let err = fails_within(3, &["reconstruct", v, "--out", s(&mesh), "--report", s(&mesh)]);
    assert!(err.contains("--report") && err.contains(".json file name"), "{err}");
    let obj = dir.path().join("y.obj");
    let err = fails_within(3, &["reconstruct", v, "--out", s(&obj), "--report", s(&dir.path().join("y.png"))]);
    assert!(err.contains("--report") && err.contains(".json file name"), "{err}");
    assert!(!mesh.exists() && !obj.exists());
    // render: into a file, or a folder of other files, is refused before rendering.
    let file = dir.path().join("file.txt");
    std::fs::write(&file, "mine").unwrap();
    let err = fails_within(3, &["render", &asset("torus.obj"), "--out", s(&file)]);
    assert!(err.contains("it is a file"), "{err}");
    let err = fails_within(3, &["render", &asset("torus.obj"), "--out", s(dir.path())]);
    assert!(err.contains("view-set files"), "{err}");
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "mine");
}

#[test]
fn texture_onto_a_folder_named_like_the_obj_keeps_the_side_files() {
    let dir = tempfile::tempdir().unwrap();
    let views = dir.path().join("views");
    render_torus(&views);
    let f = dir.path().join("f");
    std::fs::create_dir_all(f.join("tex.obj")).unwrap();
    std::fs::write(f.join("tex.png"), "old png").unwrap();
    std::fs::write(f.join("tex.mtl"), "old mtl").unwrap();
    let args = ["texture", &asset("torus.obj"), s(&views), "--normalize", "--size", "64", "--out"];
    let err = fails_within(5, &[&args[..], &[s(&f.join("tex.obj"))]].concat());
    assert!(err.contains("tex.obj") && err.contains("folder"), "{err}");
    assert_eq!(std::fs::read_to_string(f.join("tex.png")).unwrap(), "old png");
    assert_eq!(std::fs::read_to_string(f.join("tex.mtl")).unwrap(), "old mtl");
    // A good name writes the three files together.
    let run = wonder3d(&[&args[..], &[s(&f.join("good.obj")), "--quiet"]].concat());
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let textured = load_mesh(f.join("good.obj")).unwrap();
    assert_eq!(textured.texture().unwrap().width(), 64);
}

#[test]
fn render_replaces_a_view_folder_whole_and_reconstruct_refuses_a_mixed_one() {
    let dir = tempfile::tempdir().unwrap();
    let views = dir.path().join("views");
    render_torus(&views);
    // Rendering another object over it replaces every file (no torus file is left).
    let run = wonder3d(&["render", &asset("spot.obj"), "--size", "32", "--rig", "wonder3d-persp", "--out", s(&views)]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let spot = ViewSet::load(&views).unwrap();
    assert_eq!(spot.rig().name, "wonder3d_persp");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1, "no staging folder is left");
    // A folder mixing two renders (what a failed write into an old folder left) is refused.
    let torus = dir.path().join("torus");
    render_torus(&torus);
    std::fs::copy(torus.join("normal_back.png"), views.join("normal_back.png")).unwrap();
    std::fs::copy(torus.join("normal_back.exr"), views.join("normal_back.exr")).unwrap();
    let out = dir.path().join("x.glb");
    let err = fails_within(5, &["reconstruct", s(&views), "--out", s(&out), "--quiet"]);
    assert!(err.contains("normal_back") && err.contains("different renders"), "{err}");
    assert!(!out.exists());
}

#[test]
fn inward_wound_meshes_are_rendered_outward() {
    let dir = tempfile::tempdir().unwrap();
    let mut inward: Mesh = load_mesh(asset("torus.obj")).unwrap();
    inward.flip_winding();
    assert!(inward.signed_volume() < 0.0);
    let inward_path = dir.path().join("inward.ply");
    save_mesh(&inward_path, &inward).unwrap();
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    render_torus(&a);
    let run = wonder3d(&["render", s(&inward_path), "--size", "32", "--out", s(&b)]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let note = String::from_utf8_lossy(&run.stderr);
    assert!(note.contains("wound inward") && note.contains("inward.ply"), "{note}");
    let (a, b) = (ViewSet::load(&a).unwrap(), ViewSet::load(&b).unwrap());
    for (va, vb) in a.views().iter().zip(b.views()) {
        let worst = va.normal.data().iter().zip(vb.normal.data()).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max);
        assert!(worst < 1e-3, "{}: normals differ by {worst}", va.name);
    }
    // info reports the orientation as stored; eval scores the inward mesh like the outward one.
    let torus = asset("torus.obj");
    let run = wonder3d(&["eval", s(&inward_path), &torus, "--json", "--normalize-pred", "--samples", "5000"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let json: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert!(json["iou_64"].as_f64().unwrap() > 0.99, "{json}");
}

#[test]
fn degenerate_triangles_are_reported_not_called_watertight() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("point.obj");
    std::fs::write(&p, "v 0.5 0.5 0.5\nv 0.5 0.5 0.5\nv 0.5 0.5 0.5\nf 1 2 3\n").unwrap();
    let run = wonder3d(&["info", s(&p), "--json"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let json: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(json["degenerate_triangles"], 1, "{json}");
    assert_eq!(json["watertight"], false, "{json}");
    assert!(json["genus"].is_null(), "{json}");
    let run = wonder3d(&["info", s(&p)]);
    let text = String::from_utf8_lossy(&run.stdout);
    assert!(text.contains("degenerate    1") && text.contains("watertight    no"), "{text}");
    // Its views are empty; reconstruction names the first empty view instead of "mask".
    let views = dir.path().join("views");
    let run = wonder3d(&["render", s(&p), "--size", "16", "--out", s(&views)]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let err = fails_within(5, &["reconstruct", s(&views), "--out", s(&dir.path().join("x.glb")), "--quiet"]);
    assert!(err.contains("views[0].mask (front)") && err.contains("empty mask"), "{err}");
}

/// `render` and `dataset` write into an output folder that is a mount point (a container
/// volume), which cannot be renamed: the run is switched in through a staging folder inside
/// it, a second run replaces the first whole, and nothing is left beside or inside it but
/// the run. Runs where the test may mount a tmpfs (root, as CI runs).
#[test]
fn outputs_onto_a_mount_point_replace_the_run_inside_it() {
    let root = tempfile::tempdir().unwrap();
    let (views, data) = (root.path().join("views"), root.path().join("data"));
    std::fs::create_dir(&views).unwrap();
    std::fs::create_dir(&data).unwrap();
    let Some(_views_mount) = crate::common::Mounted::tmpfs(&views) else {
        eprintln!("skipped: this process may not mount a tmpfs");
        return;
    };
    let _data_mount = crate::common::Mounted::tmpfs(&data).unwrap();
    let names = |dir: &Path| {
        let mut names: Vec<String> =
            std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        names.sort();
        names
    };
    let spot = asset("spot.obj");
    for size in ["40", "48"] {
        let run = wonder3d(&["render", &spot, "--size", size, "--out", s(&views)]);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        let set = ViewSet::load(&views).unwrap();
        assert_eq!(set.width().to_string(), size);
        assert!(names(&views).iter().all(|n| !n.starts_with('.')), "{:?}", names(&views));
    }
    assert!(wonder3d::core::io::is_mount_point(&views));
    for seed in ["1", "2"] {
        let args = ["dataset", &spot, "--out", s(&data), "--samples", "2", "--size", "32", "--seed", seed, "--quiet"];
        let run = wonder3d(&args);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        let listed = names(&data);
        assert_eq!(listed.len(), 3, "two samples and dataset.json: {listed:?}");
        assert!(listed.contains(&"dataset.json".to_string()));
    }
    assert_eq!(names(root.path()), ["data", "views"], "nothing beside the mounts");
}

/// No command writes over what it reads: a report named like a file of the input view
/// folder (`reconstruct`, `texture`, `refine`), a dataset written over its own meshes, a
/// batch whose item folders or report folder hold an input or the manifest. Each is refused
/// before any work, naming the flag or line and the path, and the input is left as it was.
#[test]
fn outputs_never_overwrite_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let views = dir.path().join("views");
    render_torus(&views);
    let cameras = views.join("cameras.json");
    let before = std::fs::read(&cameras).unwrap();
    let torus = asset("torus.obj");
    let out = dir.path().join("out.glb");
    let err = fails_within(5, &["reconstruct", s(&views), "--out", s(&out), "--report", s(&cameras)]);
    assert!(err.contains("--report") && err.contains("VIEWS") && err.contains("cameras.json"), "{err}");
    let err = fails_within(5, &["texture", &torus, s(&views), "--out", s(&views.join("mask_front.png"))]);
    assert!(err.contains("mask_front.png"), "{err}");
    let obj = views.join("normal_front.obj");
    let err = fails_within(5, &["texture", &torus, s(&views), "--out", s(&obj)]);
    assert!(err.contains("--out") && err.contains("normal_front.png"), "an .obj writes its .png beside it: {err}");
    let err = fails_within(
        5,
        &["refine", &torus, s(&views), "--enhancer", "identity", "--out", s(&out), "--report", s(&cameras)],
    );
    assert!(err.contains("--report") && err.contains("VIEWS"), "{err}");
    assert_eq!(std::fs::read(&cameras).unwrap(), before, "the input is untouched");

    // A dataset over its own mesh: the folder would be replaced as a whole, the mesh with it
    // (`check_dataset_dir` accepts only an earlier dataset, which holds no meshes).
    let data = dir.path().join("data");
    std::fs::create_dir(&data).unwrap();
    let mesh = data.join("torus.obj");
    std::fs::copy(&torus, &mesh).unwrap();
    let err = fails_within(5, &["dataset", s(&mesh), "--out", s(&data), "--samples", "1", "--size", "32"]);
    assert!(err.contains("output folder") && err.contains("torus.obj"), "{err}");
    assert!(mesh.is_file());

    // A batch item whose input lies in the folder an item of the batch writes (`OUT/ID`).
    let results = dir.path().join("results");
    std::fs::create_dir(&results).unwrap();
    let kept = results.join("views");
    render_torus(&kept);
    let manifest = dir.path().join("items.txt");
    // (Views an earlier batch kept, run again under the id they were kept for.)
    std::fs::write(&manifest, format!("{{\"input\": \"{}\", \"id\": \"views\"}}\n", kept.display())).unwrap();
    let err = fails_within(5, &["batch", s(&manifest), "--out", s(&results)]);
    assert!(err.contains("manifest line 1 input") && err.contains("replaced as a whole"), "{err}");
    assert!(kept.join("cameras.json").is_file());
    // The manifest inside the report folder, which every run appends to.
    let reports = results.join("reports");
    std::fs::create_dir(&reports).unwrap();
    let inside = reports.join("items.txt");
    std::fs::write(&inside, format!("{}\n", views.display())).unwrap();
    let err = fails_within(5, &["batch", s(&inside), "--out", s(&results)]);
    assert!(err.contains("MANIFEST") && err.contains("reports"), "{err}");
}
