//! Damaged folders: view sets (their images, EXR headers, non-finite pixels, the file list),
//! `cameras.json`, model directories (configs, safetensors headers and values), training
//! sets, and batch manifests.

use std::path::{Path, PathBuf};

use serde_json::{Value, json};

use super::case::{Case, Setup};
use super::ctx::{Ctx, args, deep_json, edit_json, get, put, relist, replace_arg, s, with_flag};
use super::inputs::{
    cut, exr_with_chunk_count, exr_with_window, junk, safetensors_edit, safetensors_first_key, safetensors_poison,
};

/// Which commands may accept a damaged view folder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Pass {
    /// None: every command must refuse it, naming a token.
    Never,
    /// Those that do not need colour (`reconstruct`, `batch --no-texture`): the damage is in a
    /// colour image.
    WithoutColour,
    /// All: the damage is harmless (a file no view uses).
    Always,
}

/// A damaged view folder: what reading it must name, and which commands may accept it.
struct ViewFolder {
    /// Folder name in `bad/`.
    name: String,
    /// Path as an argument.
    path: String,
    /// Tokens: the damaged file or field.
    tokens: Vec<String>,
    /// Which commands may accept it.
    pass: Pass,
    /// Part of the `--quick` subset.
    quick: bool,
}

/// A view image with one pixel set to `value` in every channel but alpha (written with the
/// library, so the file is a valid EXR).
fn exr_with_pixel(path: &Path, value: f32) -> Result<(), String> {
    let mut img = wonder3d::Image::read_exr(path).map_err(|e| e.to_string())?;
    let (w, h) = (img.width(), img.height());
    let px = img.pixel_mut(w / 2, h / 2);
    let n = px.len();
    for c in px.iter_mut().take(n.saturating_sub(1).max(1)) {
        *c = value;
    }
    img.write_exr(path).map_err(|e| e.to_string())
}

/// A grey PNG of the given size and value.
fn grey_png(path: &Path, w: u32, h: u32, v: f32) -> Result<(), String> {
    wonder3d::Image::filled(w, h, 1, v).and_then(|i| i.write_png(path)).map_err(|e| e.to_string())
}

/// Removes the file list of a view folder and its front normal PNG, so that
/// `normal_front.exr` is the front normal's only source (a folder from before the list).
fn unlisted_exr_only(d: &Path) -> Result<(), String> {
    edit_json(&d.join("cameras.json"), |j| {
        if let Some(o) = j.as_object_mut() {
            o.remove("files");
        }
    })?;
    let png = d.join("normal_front.png");
    std::fs::remove_file(&png).map_err(|e| format!("{}: {e}", png.display()))
}

/// `batch` of the manifest `{case}/items.txt` without texturing (the cheapest valid batch).
fn batch_args() -> Vec<String> {
    args(&["batch", "{case}/items.txt", "--out", "{case}/b", "--preset", "fast", "--no-texture", "--quiet"])
}

/// The damaged view folders.
fn view_folders(ctx: &Ctx) -> Vec<ViewFolder> {
    let mut v = Vec::new();
    let views = ctx.seeds.views.clone();
    let mut add = |name: &str, tokens: &[&str], pass: Pass, quick: bool, edit: &dyn Fn(&Path) -> Result<(), String>| {
        let path = ctx.bad_dir(name, &views, edit);
        let tokens = tokens.iter().map(|t| t.to_string()).collect();
        v.push(ViewFolder { name: name.into(), path, tokens, pass, quick });
    };
    let rm = |p: &Path| std::fs::remove_file(p).map_err(|e| format!("{}: {e}", p.display()));
    add("views-no-cameras", &["cameras.json"], Pass::Never, false, &|d| rm(&d.join("cameras.json")));
    add("views-empty-folder", &["cameras.json"], Pass::Never, false, &|d| {
        std::fs::remove_dir_all(d).and_then(|()| std::fs::create_dir(d)).map_err(|e| e.to_string())
    });
    add("views-normal-exr-empty", &["normal_front.exr"], Pass::Never, false, &|d| {
        put(&d.join("normal_front.exr"), b"")?;
        relist(d)
    });
    add("views-normal-exr-cut", &["normal_front.exr"], Pass::Never, false, &|d| {
        let p = d.join("normal_front.exr");
        put(&p, &cut(&get(&p)?, 1, 2))?;
        relist(d)
    });
    add("views-normal-exr-60000", &["normal_front.exr"], Pass::Never, true, &|d| {
        let p = d.join("normal_front.exr");
        put(&p, &exr_with_window(&get(&p)?, 60000))?;
        relist(d)
    });
    add("views-normal-exr-chunks-2e31", &["normal_front.exr"], Pass::Never, false, &|d| {
        let p = d.join("normal_front.exr");
        put(&p, &exr_with_chunk_count(&get(&p)?, i32::MAX))?;
        relist(d)
    });
    add("views-normal-exr-nan", &["normal_front", "views[0].normal"], Pass::Never, true, &|d| {
        exr_with_pixel(&d.join("normal_front.exr"), f32::NAN)?;
        relist(d)
    });
    add("views-normal-exr-inf", &["normal_front", "views[0].normal"], Pass::Never, false, &|d| {
        exr_with_pixel(&d.join("normal_front.exr"), f32::INFINITY)?;
        relist(d)
    });
    add("views-depth-exr-cut", &["depth_front.exr"], Pass::Never, false, &|d| {
        let p = d.join("depth_front.exr");
        put(&p, &cut(&get(&p)?, 1, 3))?;
        relist(d)
    });
    add("views-depth-exr-nan", &["depth_front", "views[0].depth"], Pass::Never, false, &|d| {
        exr_with_pixel(&d.join("depth_front.exr"), f32::NAN)?;
        relist(d)
    });
    add("views-mask-cut", &["mask_front.png"], Pass::Never, false, &|d| {
        let p = d.join("mask_front.png");
        put(&p, &cut(&get(&p)?, 1, 2))?;
        relist(d)
    });
    add("views-mask-16x16", &["mask_front", "views[0].mask"], Pass::Never, false, &|d| {
        grey_png(&d.join("mask_front.png"), 16, 16, 1.0)?;
        relist(d)
    });
    add(
        "views-masks-empty",
        &["mask_front", "views[0].mask", "empty mask", "mask is empty"],
        Pass::Never,
        false,
        &|d| {
            for view in ["front", "front_right", "right", "back", "left", "front_left"] {
                grey_png(&d.join(format!("mask_{view}.png")), 32, 32, 0.0)?;
            }
            relist(d)
        },
    );
    add("views-colour-cut", &["colour_front.png"], Pass::WithoutColour, false, &|d| {
        let p = d.join("colour_front.png");
        put(&p, &cut(&get(&p)?, 1, 2))?;
        relist(d)
    });
    add("views-colour-60000", &["colour_front.png"], Pass::WithoutColour, false, &|d| {
        let p = d.join("colour_front.png");
        put(&p, &super::inputs::png_with_size(&get(&p)?, 60000, 60000))?;
        relist(d)
    });
    add("views-normal-png-cut", &["normal_front.png"], Pass::Never, false, &|d| {
        rm(&d.join("normal_front.exr"))?;
        let p = d.join("normal_front.png");
        put(&p, &cut(&get(&p)?, 1, 2))?;
        edit_json(&d.join("cameras.json"), |j| {
            if let Some(f) = j["files"].as_object_mut() {
                f.remove("normal_front.exr");
            }
        })?;
        relist(d)
    });
    add("views-stale-list", &["normal_front"], Pass::Never, false, &|d| {
        let p = d.join("normal_front.exr");
        exr_with_pixel(&p, 0.5)
    });
    add("views-stray-file", &["normal_extra"], Pass::Always, false, &|d| {
        std::fs::copy(d.join("normal_front.png"), d.join("normal_extra.png")).map(|_| ()).map_err(|e| e.to_string())
    });
    add("views-unlisted-cut", &["normal_front.exr"], Pass::Never, false, &|d| {
        edit_json(&d.join("cameras.json"), |j| {
            if let Some(o) = j.as_object_mut() {
                o.remove("files");
            }
        })?;
        let p = d.join("normal_front.exr");
        put(&p, &cut(&get(&p)?, 1, 2))
    });
    add("views-unlisted-devzero", &["normal_front.exr"], Pass::Never, false, &|d| {
        unlisted_exr_only(d)?;
        let p = d.join("normal_front.exr");
        rm(&p)?;
        std::os::unix::fs::symlink("/dev/zero", &p).map_err(|e| e.to_string())
    });
    add("views-unlisted-fifo", &["normal_front.exr"], Pass::Never, false, &|d| {
        unlisted_exr_only(d)?;
        let p = d.join("normal_front.exr");
        rm(&p)?;
        let ok = std::process::Command::new("mkfifo").arg(&p).status().map_err(|e| e.to_string())?.success();
        if ok { Ok(()) } else { Err("mkfifo failed".into()) }
    });
    add("views-normal-is-folder", &["normal_front.exr"], Pass::Never, false, &|d| {
        unlisted_exr_only(d)?;
        let p = d.join("normal_front.exr");
        rm(&p)?;
        std::fs::create_dir(&p).map_err(|e| e.to_string())
    });
    v
}

/// The cases of the damaged view folders: `reconstruct`, `texture`, `refine` and `batch`.
pub(crate) fn view_cases(ctx: &Ctx, out: &mut Vec<Case>) {
    let views = s(&ctx.seeds.views);
    for (i, f) in view_folders(ctx).into_iter().enumerate() {
        let tokens: Vec<&str> = f.tokens.iter().map(String::as_str).collect();
        // Which commands may accept the folder: the others must name a token.
        let expect = |c: Case, needs_colour: bool| match f.pass {
            Pass::Always => c.either(),
            Pass::WithoutColour if !needs_colour => c.either(),
            _ => c,
        };
        let recon = Case::new("reconstruct", &f.name, replace_arg(&ctx.base("reconstruct"), &views, &f.path), &tokens);
        out.push(expect(recon.masking(&f.path), false).quick_if(f.quick));
        let texture = Case::new("texture", &f.name, replace_arg(&ctx.base("texture"), &views, &f.path), &tokens);
        out.push(expect(texture.masking(&f.path), true));
        if i % 3 == 0 || f.quick {
            let refine = replace_arg(&ctx.base("refine"), &views, &f.path);
            let case = Case::new("refine", &format!("views-{}", f.name), refine, &tokens).masking(&f.path);
            out.push(expect(case.timeout(60), true));
            let manifest = format!("{}\n", f.path);
            let case = Case::new("batch", &f.name, batch_args(), &tokens)
                .masking(&f.path)
                .with(Setup::Write("items.txt".into(), manifest.into_bytes()))
                .timeout(60);
            out.push(expect(case, false));
        }
    }
}

/// Sets `views[*].camera` fields of a `cameras.json` document with `edit`.
fn each_camera(j: &mut Value, edit: impl Fn(&mut Value)) {
    if let Some(views) = j["views"].as_array_mut() {
        for v in views {
            edit(&mut v["camera"]);
        }
    }
}

/// The damaged `cameras.json` files (in copies of the view folder) and their tokens.
fn cameras(ctx: &Ctx) -> Vec<(String, String, Vec<&'static str>, bool)> {
    let mut v = Vec::new();
    let views = ctx.seeds.views.clone();
    let mut text = |name: &str, tokens: Vec<&'static str>, quick: bool, make: &dyn Fn(&[u8]) -> Vec<u8>| {
        let path = ctx.bad_dir(name, &views, |d| {
            let p = d.join("cameras.json");
            put(&p, &make(&get(&p)?))
        });
        v.push((name.to_string(), path, tokens, quick));
    };
    text("cam-empty", vec!["cameras.json"], false, &|_| Vec::new());
    text("cam-cut", vec!["cameras.json"], false, &|b| cut(b, 1, 2));
    text("cam-junk", vec!["cameras.json"], false, &|_| junk(500, 7));
    text("cam-nan-token", vec!["cameras.json"], true, &|b| {
        String::from_utf8_lossy(b).replacen("\"half_height\": 0.75", "\"half_height\": NaN", 1).into_bytes()
    });
    text("cam-1e309", vec!["half_height"], false, &|b| {
        String::from_utf8_lossy(b).replacen("\"half_height\": 0.75", "\"half_height\": 1e309", 1).into_bytes()
    });
    text("cam-deep", vec!["cameras.json"], false, &|_| deep_json(100_000));
    text("cam-deep-views", vec!["cameras.json", "views"], false, &|b| {
        let mut j: Value = serde_json::from_slice(b).unwrap_or(Value::Null);
        j["views"] = json!("PLACEHOLDER");
        let deep = String::from_utf8_lossy(&deep_json(50_000)).into_owned();
        j.to_string().replace("\"PLACEHOLDER\"", &deep).into_bytes()
    });
    let mut edit = |name: &str, tokens: Vec<&'static str>, quick: bool, e: &dyn Fn(&mut Value)| {
        let path = ctx.bad_dir(name, &views, |d| edit_json(&d.join("cameras.json"), e));
        v.push((name.to_string(), path, tokens, quick));
    };
    edit("cam-half-height-0", vec!["half_height"], false, &|j| {
        each_camera(j, |c| c["projection"]["half_height"] = 0.into())
    });
    edit("cam-half-height-neg", vec!["half_height"], false, &|j| {
        each_camera(j, |c| c["projection"]["half_height"] = (-0.75).into())
    });
    // The projection is a tagged enum: serde reports the path down to it (and the line and
    // column of the value), not into it.
    edit("cam-half-height-string", vec!["half_height", "camera.projection"], false, &|j| {
        j["views"][0]["camera"]["projection"]["half_height"] = "big".into()
    });
    edit("cam-half-height-1e30", vec!["half_height"], false, &|j| {
        each_camera(j, |c| c["projection"]["half_height"] = 1e30.into())
    });
    edit("cam-eye-at-target", vec!["camera.target", "camera.eye"], false, &|j| {
        j["views"][0]["camera"]["eye"] = json!([0.0, 0.0, 0.0])
    });
    edit("cam-up-along-view", vec!["camera.up"], false, &|j| j["views"][0]["camera"]["up"] = json!([0.0, 0.0, 1.0]));
    edit("cam-up-zero", vec!["camera.up"], false, &|j| j["views"][0]["camera"]["up"] = json!([0.0, 0.0, 0.0]));
    edit("cam-eye-2d", vec!["camera.eye"], false, &|j| j["views"][0]["camera"]["eye"] = json!([0.0, 1.64]));
    edit("cam-eye-1e300", vec!["camera.eye", "views[0].camera"], false, &|j| {
        j["views"][0]["camera"]["eye"] = json!([0.0, 0.0, 1e300])
    });
    edit("cam-views-empty", vec!["views"], false, &|j| j["views"] = json!([]));
    edit("cam-views-missing", vec!["views"], false, &|j| {
        if let Some(o) = j.as_object_mut() {
            o.remove("views");
        }
    });
    edit("cam-views-1000", vec!["views[1].name", "views:"], false, &|j| {
        let first = j["views"][0].clone();
        j["views"] = Value::Array(vec![first; 1000]);
    });
    edit("cam-duplicate-name", vec!["views[1].name"], false, &|j| j["views"][1]["name"] = "front".into());
    edit("cam-name-traversal", vec!["views[0].name"], false, &|j| j["views"][0]["name"] = "../../../etc/x".into());
    edit("cam-name-empty", vec!["views[0].name"], false, &|j| j["views"][0]["name"] = "".into());
    edit("cam-projection-fisheye", vec!["projection", "fisheye"], false, &|j| {
        j["views"][0]["camera"]["projection"]["type"] = "fisheye".into()
    });
    edit("cam-files-number", vec!["files"], false, &|j| j["files"] = 5.into());
    edit("cam-files-bytes-1e18", vec!["files.normal_front", "normal_front.exr"], false, &|j| {
        j["files"]["normal_front.exr"]["bytes"] = 1_000_000_000_000_000_000u64.into()
    });
    v
}

/// The cases of the damaged `cameras.json` files: `reconstruct` (all), `texture`, `refine`
/// and `batch` (some).
pub(crate) fn camera_cases(ctx: &Ctx, out: &mut Vec<Case>) {
    let views = s(&ctx.seeds.views);
    for (i, (name, path, tokens, quick)) in cameras(ctx).into_iter().enumerate() {
        let recon = replace_arg(&ctx.base("reconstruct"), &views, &path);
        out.push(Case::new("reconstruct", &name, recon, &tokens).masking(&path).quick_if(quick));
        if i % 2 == 0 {
            let texture = replace_arg(&ctx.base("texture"), &views, &path);
            out.push(Case::new("texture", &name, texture, &tokens).masking(&path));
        }
        if i % 5 == 0 {
            let refine = replace_arg(&ctx.base("refine"), &views, &path);
            out.push(Case::new("refine", &name, refine, &tokens).masking(&path).timeout(60));
            out.push(
                Case::new("batch", &name, batch_args(), &tokens)
                    .masking(&path)
                    .with(Setup::Write("items.txt".into(), format!("{path}\n").into_bytes()))
                    .timeout(60),
            );
        }
    }
}

/// A damaged model directory: name, path, tokens, quick.
type Weights = (String, String, Vec<String>, bool);

/// Makes damaged copies of model directories.
struct WeightsMaker<'a> {
    /// Where they are written.
    ctx: &'a Ctx,
    /// The tiny checkpoint (the default source).
    tiny: PathBuf,
    /// The directories made.
    out: Vec<Weights>,
}

impl WeightsMaker<'_> {
    /// A copy of `from` changed by `edit`.
    fn add(
        &mut self,
        name: &str,
        from: &Path,
        tokens: &[&str],
        quick: bool,
        edit: impl FnOnce(&Path) -> Result<(), String>,
    ) {
        let path = self.ctx.bad_dir(name, from, edit);
        self.out.push((name.into(), path, tokens.iter().map(|t| t.to_string()).collect(), quick));
    }

    /// A copy of the tiny checkpoint with the JSON file `file` edited.
    fn json(&mut self, name: &str, file: &str, tokens: &[&str], edit: impl FnOnce(&mut Value)) {
        let from = self.tiny.clone();
        self.add(name, &from, tokens, false, |d| edit_json(&d.join(file), edit));
    }

    /// A copy of the tiny checkpoint with the file `file` replaced by `make` of its bytes.
    fn bytes(
        &mut self,
        name: &str,
        file: &str,
        tokens: &[&str],
        quick: bool,
        make: impl FnOnce(&[u8]) -> Option<Vec<u8>>,
    ) {
        let from = self.tiny.clone();
        self.add(name, &from, tokens, quick, |d| {
            let p = d.join(file);
            let bytes = make(&get(&p)?).ok_or_else(|| format!("{}: cannot damage as planned", p.display()))?;
            put(&p, &bytes)
        });
    }
}

/// The damaged model directories (copies of the tiny checkpoint, two of the small model).
fn weights(ctx: &Ctx) -> Vec<Weights> {
    let (tiny, small) = (ctx.seeds.tiny.clone(), ctx.seeds.small.clone());
    let mut w = WeightsMaker { ctx, tiny: tiny.clone(), out: Vec::new() };
    let unet = "unet/diffusion_pytorch_model.safetensors";
    let vae = "vae/diffusion_pytorch_model.safetensors";
    let clip = "image_encoder/model.safetensors";
    let (uc, cc, sc) = ("unet/config.json", "image_encoder/config.json", "scheduler/scheduler_config.json");
    // The first tensor of each weights file (known once the seeds exist; a listing-only run's
    // tokens say "first tensor").
    let key = |from: &Path, file: &str| {
        ctx.read(&from.join(file)).ok().and_then(|b| safetensors_first_key(&b)).unwrap_or_else(|| "first tensor".into())
    };
    let (unet_key, vae_key, clip_key, small_key) =
        (key(&tiny, unet), key(&tiny, vae), key(&tiny, clip), key(&small, unet));
    let rm_dir = |p: &Path| std::fs::remove_dir_all(p).map_err(|e| format!("{}: {e}", p.display()));
    w.add("w-no-unet", &tiny, &["unet"], false, |d| rm_dir(&d.join("unet")));
    w.add("w-empty", &tiny, &["unet", "model_index.json"], false, |d| {
        rm_dir(d).and_then(|()| std::fs::create_dir(d).map_err(|e| e.to_string()))
    });
    w.bytes("w-unet-config-empty", uc, &[uc], false, |_| Some(Vec::new()));
    w.bytes("w-unet-config-cut", uc, &[uc], false, |b| Some(cut(b, 1, 2)));
    w.bytes("w-unet-config-deep", uc, &[uc], false, |_| Some(deep_json(100_000)));
    w.add("w-layers-string", &tiny, &["layers_per_block"], true, |d| {
        edit_json(&d.join(uc), |j| j["layers_per_block"] = "two".into())
    });
    w.json("w-layers-1e12", uc, &["layers_per_block"], |j| j["layers_per_block"] = 1e12.into());
    w.json("w-layers-2e32", uc, &["layers_per_block"], |j| j["layers_per_block"] = 4_294_967_296u64.into());
    w.json("w-channels-1e9", uc, &["block_out_channels"], |j| {
        j["block_out_channels"] = json!([1_000_000_000, 1_000_000_000])
    });
    w.json("w-channels-empty", uc, &["block_out_channels"], |j| j["block_out_channels"] = json!([]));
    w.json("w-in-channels-neg", uc, &["in_channels"], |j| j["in_channels"] = (-8).into());
    w.json("w-sample-size-0", uc, &["sample_size"], |j| j["sample_size"] = 0.into());
    w.json("w-views-1e6", uc, &["num_views"], |j| j["num_views"] = 1_000_000.into());
    w.json("w-clip-hidden-string", cc, &["hidden_size"], |j| j["hidden_size"] = "big".into());
    w.json("w-clip-image-1e6", cc, &["image_size"], |j| j["image_size"] = 1_000_000.into());
    w.json("w-vae-latent-nan", "vae/config.json", &["scaling_factor"], |j| j["scaling_factor"] = "NaN".into());
    w.json("w-timesteps-neg", sc, &["num_train_timesteps"], |j| j["num_train_timesteps"] = (-5).into());
    w.json("w-timesteps-1e12", sc, &["num_train_timesteps"], |j| {
        j["num_train_timesteps"] = 1_000_000_000_000u64.into()
    });
    w.json("w-beta-schedule", sc, &["beta_schedule"], |j| j["beta_schedule"] = "zigzag".into());
    let file = "diffusion_pytorch_model.safetensors";
    w.bytes("w-unet-st-empty", unet, &[file], false, |_| Some(Vec::new()));
    w.bytes("w-unet-st-cut", unet, &[file], false, |b| Some(cut(b, 1, 2)));
    let header_length = |b: &[u8], n: u64| {
        let mut b = b.to_vec();
        b[..8].copy_from_slice(&n.to_le_bytes());
        Some(b)
    };
    w.bytes("w-unet-st-header-2e63", unet, &[file, "header"], true, |b| header_length(b, 1 << 63));
    w.bytes("w-unet-st-header-max", unet, &[file, "header"], false, |b| header_length(b, u64::MAX));
    w.bytes("w-unet-st-header-junk", unet, &[file, "header"], false, |b| {
        let n = u64::from_le_bytes(b.get(..8)?.try_into().ok()?) as usize;
        let mut b = b.to_vec();
        b.get_mut(8..8 + n)?.copy_from_slice(&junk(n, 8));
        Some(b)
    });
    let k = unet_key.clone();
    w.bytes("w-unet-st-offsets", unet, &[&unet_key], false, |b| {
        safetensors_edit(b, |h| h[&k]["data_offsets"] = json!([0, 1_000_000_000_000u64]))
    });
    w.bytes("w-unet-st-shape", unet, &[&unet_key], false, |b| {
        safetensors_edit(b, |h| h[&k]["shape"] = json!([1_000_000_000, 1_000_000_000]))
    });
    w.bytes("w-unet-st-dtype", unet, &[&unet_key], false, |b| safetensors_edit(b, |h| h[&k]["dtype"] = "Q7".into()));
    // Without its entry the next tensor's data starts where no tensor ends: the error can only
    // name the header and the tensor where the gap shows.
    w.bytes("w-unet-st-missing", unet, &[&unet_key, "header"], false, |b| {
        safetensors_edit(b, |h| {
            if let Some(o) = h.as_object_mut() {
                o.remove(&k);
            }
        })
    });
    w.bytes("w-unet-nan", unet, &[&unet_key], true, |b| safetensors_poison(b, Some(&k), false));
    w.bytes("w-unet-inf", unet, &[&unet_key], false, |b| safetensors_poison(b, Some(&k), true));
    w.bytes("w-vae-nan", vae, &[&vae_key], false, |b| safetensors_poison(b, Some(&vae_key), false));
    w.bytes("w-clip-inf", clip, &[&clip_key], false, |b| safetensors_poison(b, Some(&clip_key), true));
    w.bytes("w-vae-st-cut", vae, &["vae", file], false, |b| Some(cut(b, 2, 3)));
    w.add("w-unet-st-folder", &tiny, &[file], false, |d| {
        let p = d.join(unet);
        std::fs::remove_file(&p).and_then(|()| std::fs::create_dir(&p)).map_err(|e| e.to_string())
    });
    w.add("w-unet-st-devzero", &tiny, &[file], false, |d| {
        let p = d.join(unet);
        std::fs::remove_file(&p).and_then(|()| std::os::unix::fs::symlink("/dev/zero", &p)).map_err(|e| e.to_string())
    });
    w.add("w-small-nan", &small, &[&small_key], false, |d| {
        let p = d.join(unet);
        let bytes = safetensors_poison(&get(&p)?, Some(&small_key), false).ok_or("cannot poison the small model")?;
        put(&p, &bytes)
    });
    w.add("w-small-config-cut", &small, &[uc], false, |d| {
        let p = d.join(uc);
        put(&p, &cut(&get(&p)?, 1, 2))
    });
    w.out
}

/// The cases of the damaged model directories: `generate` (all), `run`, `train --init`,
/// `batch --weights` and `demo --from-image --weights` (some).
pub(crate) fn weight_cases(ctx: &Ctx, out: &mut Vec<Case>) {
    let tiny = s(&ctx.seeds.tiny);
    for (i, (name, path, tokens, quick)) in weights(ctx).into_iter().enumerate() {
        let mut tokens: Vec<&str> = tokens.iter().map(String::as_str).collect();
        if tokens.is_empty() {
            tokens.push(&name);
        }
        // Tokens are looked for outside the folder's own path (its name is the case's).
        let case =
            |command: &'static str, what: &str, a: Vec<String>| Case::new(command, what, a, &tokens).masking(&path);
        let generate = replace_arg(&ctx.base("generate"), &tiny, &path);
        out.push(case("generate", &name, generate).quick_if(quick));
        let small = name.starts_with("w-small");
        if i % 4 == 0 || quick {
            out.push(case("run", &name, replace_arg(&ctx.base("run"), &tiny, &path)).timeout(60));
        }
        if (i % 3 == 0 || quick) && !small {
            let train = replace_arg(&ctx.base("train"), &tiny, &path);
            out.push(case("train", &format!("init-{name}"), train).timeout(60));
        }
        if i % 7 == 0 || quick {
            let batch = [
                &args(&["batch", "{case}/items.txt", "--out", "{case}/b", "--weights"])[..],
                std::slice::from_ref(&path),
                &args(&["--steps", "1", "--preset", "fast", "--no-texture", "--starts", "1", "--quiet"])[..],
            ]
            .concat();
            let manifest = format!("{}\n", s(&ctx.seeds.disc_png));
            out.push(
                case("batch", &format!("weights-{name}"), batch)
                    .with(Setup::Write("items.txt".into(), manifest.into_bytes()))
                    .timeout(60),
            );
            let demo = [
                &ctx.base("demo")[..],
                &args(&["--from-image", "--steps", "1", "--starts", "1", "--draws", "1", "--weights"])[..],
                std::slice::from_ref(&path),
            ]
            .concat();
            out.push(case("demo", &format!("weights-{name}"), demo).timeout(90));
        }
    }
}

/// The damaged training sets (copies of the seed set) and their tokens.
fn datasets(ctx: &Ctx) -> Vec<(String, String, Vec<&'static str>, bool)> {
    let mut v = Vec::new();
    let data = ctx.seeds.dataset.clone();
    let sample = "cube_000";
    let mut add = |name: &str, tokens: Vec<&'static str>, quick: bool, edit: &dyn Fn(&Path) -> Result<(), String>| {
        let path = ctx.bad_dir(name, &data, edit);
        v.push((name.to_string(), path, tokens, quick));
    };
    let json = |d: &Path| d.join("dataset.json");
    add("ds-no-json", vec!["dataset.json"], true, &|d| std::fs::remove_file(json(d)).map_err(|e| e.to_string()));
    add("ds-json-empty", vec!["dataset.json"], false, &|d| put(&json(d), b""));
    add("ds-json-cut", vec!["dataset.json"], false, &|d| put(&json(d), &cut(&get(&json(d))?, 1, 2)));
    add("ds-json-deep", vec!["dataset.json"], false, &|d| put(&json(d), &deep_json(100_000)));
    add("ds-size-string", vec!["size"], false, &|d| edit_json(&json(d), |j| j["size"] = "big".into()));
    add("ds-size-64", vec!["size", "64", "32"], false, &|d| edit_json(&json(d), |j| j["size"] = 64.into()));
    add("ds-size-2e32", vec!["size"], false, &|d| edit_json(&json(d), |j| j["size"] = 4_294_967_296u64.into()));
    add("ds-version-99", vec!["version"], false, &|d| edit_json(&json(d), |j| j["version"] = 99.into()));
    add("ds-samples-empty", vec!["samples"], false, &|d| edit_json(&json(d), |j| j["samples"] = json!([])));
    add("ds-views-wrong", vec!["views"], false, &|d| edit_json(&json(d), |j| j["views"] = json!(["front", "up"])));
    add("ds-id-traversal", vec!["id", "samples[0]", "../"], false, &|d| {
        edit_json(&json(d), |j| j["samples"][0]["id"] = "../../../../etc".into())
    });
    add("ds-background-string", vec!["background"], false, &|d| {
        edit_json(&json(d), |j| j["samples"][0]["background"] = "plaid".into())
    });
    add("ds-sample-missing", vec![sample], false, &|d| {
        std::fs::remove_dir_all(d.join(sample)).map_err(|e| e.to_string())
    });
    add("ds-sample-exr-cut", vec!["normal_front.exr"], false, &|d| {
        let p = d.join(sample).join("normal_front.exr");
        put(&p, &cut(&get(&p)?, 1, 2))?;
        relist(&d.join(sample))
    });
    add("ds-sample-nan", vec!["normal_front", "views[0].normal", sample], false, &|d| {
        exr_with_pixel(&d.join(sample).join("normal_front.exr"), f32::NAN)?;
        relist(&d.join(sample))
    });
    add("ds-sample-masks-empty", vec!["mask", sample], false, &|d| {
        for view in ["front", "front_right", "right", "back", "left", "front_left"] {
            grey_png(&d.join(sample).join(format!("mask_{view}.png")), 32, 32, 0.0)?;
        }
        relist(&d.join(sample))
    });
    v
}

/// The cases of the damaged training sets (`train --data`), and `train`'s and `dataset`'s
/// own hostile command lines.
pub(crate) fn dataset_cases(ctx: &Ctx, out: &mut Vec<Case>) {
    let data = s(&ctx.seeds.dataset);
    for (name, path, tokens, quick) in datasets(ctx) {
        let train = replace_arg(&ctx.base("train"), &data, &path);
        let case = Case::new("train", &format!("data-{name}"), train, &tokens).masking(&path);
        out.push(case.quick_if(quick).timeout(60));
    }
    let train = ctx.base("train");
    let t = |what: &str, a: Vec<String>, tokens: &[&str]| Case::new("train", what, a, tokens).timeout(60);
    out.push(t("resume-without-run", [&train[..], &args(&["--resume"])].concat(), &["--resume", "checkpoint"]));
    out.push(t("stage-1-on-joint-checkpoint", with_flag(&train, "--stage", "1"), &["--stage"]));
    out.push(t(
        "small-model-on-32px-data",
        replace_arg(&train, &s(&ctx.seeds.tiny), &s(&ctx.seeds.small)),
        &["size", "--data"],
    ));
    let short = with_flag(&with_flag(&train, "--steps", "5"), "--warmup", "10");
    let cool = [&short[..], &args(&["--lr-schedule", "linear"])].concat();
    out.push(t("cool-down-inside-warmup", cool, &["--warmup", "--lr-schedule", "lr_schedule"]));
    out.push(t("wgpu-without-feature", [&train[..], &args(&["--device", "wgpu"])].concat(), &["wgpu"]));
    out.push(
        t(
            "objects-per-batch-over-samples",
            with_flag(&train, "--objects-per-batch", "8"),
            &["--objects-per-batch", "samples"],
        )
        .either(),
    );
    out.push(t("data-is-init", replace_arg(&train, &data, &s(&ctx.seeds.tiny)), &["dataset.json", "--data"]));
    out.push(t("init-is-data", replace_arg(&train, &s(&ctx.seeds.tiny), &data), &["unet", "--init"]));
    // dataset: two meshes with one stem, one mesh twice.
    let dataset = ctx.base("dataset");
    let cube = s(&ctx.seeds.cube_obj);
    let twice = [&dataset[..2], std::slice::from_ref(&cube), &dataset[2..]].concat();
    out.push(Case::new("dataset", "same-mesh-twice", twice, &["cube"]));
    let stems = [&dataset[..1], &args(&["{case}/a/m.obj", "{case}/b/m.obj"]), &dataset[2..]].concat();
    out.push(
        Case::new("dataset", "one-stem-two-meshes", stems, &["m.obj", "stem"])
            .with(Setup::Copy(ctx.seeds.cube_obj.clone(), "a/m.obj".into()))
            .with(Setup::Copy(ctx.seeds.torus.clone(), "b/m.obj".into())),
    );
    let no_mesh = dataset.iter().filter(|a| **a != cube).cloned().collect::<Vec<_>>();
    out.push(Case::new("dataset", "no-mesh", no_mesh, &["MESHES", "<MESHES>"]));
}

/// `batch`'s own hostile manifests (written into the case folder beside the view folder they
/// name).
pub(crate) fn manifest_cases(ctx: &Ctx, out: &mut Vec<Case>) {
    let views = ctx.seeds.views.clone();
    let batch =
        args(&["batch", "{case}/items.txt", "--out", "{case}/b", "--preset", "fast", "--no-texture", "--quiet"]);
    let case = |what: &str, manifest: &[u8], tokens: &[&str]| {
        Case::new("batch", what, batch.clone(), tokens)
            .with(Setup::Copy(views.clone(), "views".into()))
            .with(Setup::Write("items.txt".into(), manifest.to_vec()))
            .timeout(60)
    };
    out.push(case("manifest-empty", b"", &["items.txt"]));
    out.push(case("manifest-comments-only", b"# nothing here\n\n", &["items.txt"]));
    out.push(case("manifest-missing-path", b"views\nnot-there\n", &["not-there"]).quick_if(true));
    out.push(case("manifest-nul", b"views\nvi\0ews\n", &["line 2"]).quick_if(true));
    out.push(case("manifest-invalid-utf8", b"views\n\xff\xfe\n", &["line 2", "UTF-8"]));
    out.push(case("manifest-json-input-number", b"{\"input\": 5}\n", &["input", "line 1"]));
    out.push(case("manifest-json-cut", b"{\"input\": \"views\"\n", &["line 1"]));
    out.push(
        case("manifest-json-unknown-key", b"{\"input\": \"views\", \"frobnicate\": 1}\n", &["frobnicate"]).either(),
    );
    out.push(case("manifest-duplicate", b"views\nviews\n", &["line 2", "id"]));
    out.push(case("manifest-id-traversal", b"{\"input\": \"views\", \"id\": \"../../escape\"}\n", &["id", "line 1"]));
    out.push(case("manifest-id-slash", b"{\"input\": \"views\", \"id\": \"a/b\"}\n", &["id", "line 1"]));
    out.push(case("manifest-id-empty", b"{\"input\": \"views\", \"id\": \"\"}\n", &["id", "line 1"]));
    out.push(case("manifest-preset-ultra", b"{\"input\": \"views\", \"preset\": \"ultra\"}\n", &["preset", "line 1"]));
    out.push(case("manifest-seed-negative", b"{\"input\": \"views\", \"seed\": -1}\n", &["seed", "line 1"]));
    out.push(case("manifest-seed-1e30", b"{\"input\": \"views\", \"seed\": 1e30}\n", &["seed", "line 1"]));
    out.push(
        case("manifest-image-without-weights", b"views\nphoto.png\n", &["--weights", "photo.png"])
            .with(Setup::Copy(ctx.seeds.disc_png.clone(), "photo.png".into())),
    );
    out.push(case("manifest-deep-json", &[&b"{\"input\": "[..], &deep_json(50_000), b"}\n"].concat(), &["line 1"]));
    let long = [&b"views\n"[..], &vec![b'x'; 1 << 20], b"\n"].concat();
    out.push(case("manifest-1mb-line", &long, &["line 2"]));
    out.push(case("manifest-item-is-file", b"items.txt\n", &["items.txt", "line 1"]));
    out.push(case("manifest-item-devzero", b"/dev/zero\n", &["/dev/zero", "line 1"]));
    // A text file and /dev/zero as image items, with a model: refused by name, not read.
    let with_weights =
        [&batch[..], &args(&["--weights", &s(&ctx.seeds.tiny), "--steps", "1", "--starts", "1"])[..]].concat();
    let weighted = |what: &str, manifest: &[u8], tokens: &[&str]| {
        Case::new("batch", what, with_weights.clone(), tokens)
            .with(Setup::Copy(views.clone(), "views".into()))
            .with(Setup::Write("items.txt".into(), manifest.to_vec()))
            .with(Setup::Write("notes.png".into(), b"a text file named like an image\n".to_vec()))
            .timeout(60)
    };
    out.push(weighted("manifest-item-text-as-image-with-weights", b"notes.png\n", &["notes.png"]));
    out.push(weighted("manifest-item-devzero-with-weights", b"/dev/zero\n", &["/dev/zero"]));
    out.push(case("manifest-item-absolute-missing", b"/nonexistent/hostile/views\n", &["/nonexistent/hostile/views"]));
    // A model folder that does not exist, though only view folders are listed (so it is
    // never loaded): still a wrong flag, named.
    let missing_model = [&batch[..], &args(&["--weights", "{case}/no-model"])[..]].concat();
    out.push(
        Case::new("batch", "weights-missing-view-items-only", missing_model, &["--weights", "no-model"])
            .with(Setup::Copy(views.clone(), "views".into()))
            .with(Setup::Write("items.txt".into(), b"views\n".to_vec()))
            .timeout(60),
    );
    let resume = [&batch[..], &args(&["--resume"])].concat();
    out.push(
        Case::new("batch", "resume-into-foreign-folder", resume, &["--out", "--resume", "b"])
            .with(Setup::Copy(views.clone(), "views".into()))
            .with(Setup::Write("items.txt".into(), b"views\n".to_vec()))
            .with(Setup::Write("b/notes.txt".into(), b"someone else's folder\n".to_vec()))
            .either()
            .timeout(60),
    );
}
