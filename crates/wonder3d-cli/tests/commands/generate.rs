//! `wonder3d generate` on the tiny Wonder3D checkpoint of w3d-diffusion's fixtures writes a
//! view-set folder that `wonder3d reconstruct` reads; `wonder3d run` chains the three stages;
//! bad input gets clear errors.
#![cfg(feature = "diffusion")]

use crate::common;

use common::{tiny_weights, wonder3d, write_input};
use wonder3d::Image;

#[test]
fn generate_writes_a_view_set_reconstruct_reads() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("disc.png");
    write_input(&input);
    let views = dir.path().join("views");
    let run = wonder3d(&[
        "generate",
        input.to_str().unwrap(),
        "--weights",
        &tiny_weights(),
        "--out",
        views.to_str().unwrap(),
        "--steps",
        "3",
        "--camera",
        "persp",
        "--seed",
        "5",
        "--quiet",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    for view in ["front", "front_right", "right", "back", "left", "front_left"] {
        for kind in ["normal", "colour", "mask"] {
            assert!(views.join(format!("{kind}_{view}.png")).is_file(), "{kind}_{view}.png missing");
        }
    }
    assert!(views.join("input.png").is_file());
    assert!(views.join("views.png").is_file(), "the contact sheet");
    // What `reconstruct` reads (`run_chains_generate_reconstruct_and_texture` reconstructs).
    let set = wonder3d::ViewSet::load(&views).unwrap();
    assert_eq!((set.rig().name.as_str(), set.width(), set.height()), ("wonder3d_persp", 32, 32));
    assert!(set.views().iter().all(|v| v.colour.is_some()));
}

#[test]
fn run_chains_generate_reconstruct_and_texture() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("disc.png");
    write_input(&input);
    let glb = dir.path().join("disc.glb");
    let run = wonder3d(&[
        "run",
        input.to_str().unwrap(),
        "--weights",
        &tiny_weights(),
        "--out",
        glb.to_str().unwrap(),
        "--steps",
        "2",
        "--preset",
        "fast",
        "--texture-size",
        "512",
        "--quiet",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    // A random-weight model's views: no surface explains them, so one fit of the default 4
    // runs (`ReconOptions::hopeless_view_loss`), and the summary says why.
    let summary = String::from_utf8_lossy(&run.stdout);
    assert!(summary.contains("(1 fit of 4: the views disagree"), "{summary}");
    let mesh = wonder3d::load_mesh(&glb).unwrap();
    assert!(mesh.triangle_count() > 0 && mesh.texture().is_some());
}

#[test]
fn generate_names_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("views");
    let rgb = dir.path().join("rgb.png");
    Image::filled(16, 16, 3, 0.5).unwrap().write_png(&rgb).unwrap();
    let run =
        wonder3d(&["generate", rgb.to_str().unwrap(), "--weights", &tiny_weights(), "--out", out.to_str().unwrap()]);
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("RGBA"), "{err}");
    let rgba = dir.path().join("rgba.png");
    write_input(&rgba);
    let missing = dir.path().join("no-model");
    let run = wonder3d(&[
        "generate",
        rgba.to_str().unwrap(),
        "--weights",
        missing.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("no-model"), "{err}");
    let run = wonder3d(&[
        "generate",
        rgba.to_str().unwrap(),
        "--weights",
        &tiny_weights(),
        "--out",
        out.to_str().unwrap(),
        "--camera",
        "fisheye",
    ]);
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("ortho, persp"), "{err}");
    // An input inside the folder that the views replace as a whole is refused before any work
    // (it would be deleted with the folder's old contents).
    let views = dir.path().join("rendered");
    let spot = concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets/spot.obj");
    let run = wonder3d(&["render", spot, "--size", "32", "--out", views.to_str().unwrap()]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let before = std::fs::read(views.join("cameras.json")).unwrap();
    let input = views.join("colour_front.png");
    let (i, v, w) = (input.to_str().unwrap(), views.to_str().unwrap(), tiny_weights());
    let glb = dir.path().join("m.glb");
    for args in [
        vec!["generate", i, "--weights", &w, "--out", v],
        vec!["run", i, "--weights", &w, "--out", glb.to_str().unwrap(), "--views", v],
    ] {
        let run = wonder3d(&args);
        assert_eq!(run.status.code(), Some(1), "{args:?}");
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(err.contains("IMAGE input") && err.contains("colour_front.png"), "{args:?}: {err}");
    }
    assert!(std::fs::read(views.join("cameras.json")).unwrap() == before, "the views are untouched");
    assert!(!glb.exists());
}

#[test]
fn generate_accepts_an_rgb_photo() {
    // No alpha: a shaded disc on a light grey backdrop; the background is removed first.
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (64u32, 48u32);
    let mut photo = Image::filled(w, h, 3, 0.85).unwrap();
    for y in 0..h {
        for x in 0..w {
            let (dx, dy) = (x as f32 - 32.0, y as f32 - 24.0);
            if dx * dx + dy * dy < 14.0 * 14.0 {
                photo.pixel_mut(x, y).copy_from_slice(&[0.2 + x as f32 / 128.0, 0.3, 0.7]);
            }
        }
    }
    let input = dir.path().join("photo.png");
    photo.write_png(&input).unwrap();
    let views = dir.path().join("views");
    let run = wonder3d(&[
        "generate",
        input.to_str().unwrap(),
        "--weights",
        &tiny_weights(),
        "--out",
        views.to_str().unwrap(),
        "--steps",
        "2",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("mask from segmented"), "{err}");
    assert!(views.join("input.png").is_file());
}

#[test]
fn demo_from_image_goes_from_a_photo_to_a_scored_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let run = wonder3d(&[
        "demo",
        "--from-image",
        "--weights",
        &tiny_weights(),
        "--steps",
        "2",
        "--draws",
        "2",
        "--out",
        out.to_str().unwrap(),
        "--preset",
        "fast",
        "--size",
        "128",
        "--texture-size",
        "256",
        // The default is 4 fits; one is enough on the tiny model's noise views.
        "--starts",
        "1",
        "--quiet",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let report: serde_json::Value = common::read_json(&out.join("report.json"));
    let losses = report["pipeline"]["reconstruction"]["start_losses"].as_array().unwrap();
    assert_eq!(losses.len(), 1, "--starts 1 reconstructs once");
    // The tiny checkpoint's views are noise: the report is checked for its content, not scores.
    let agreement = &report["generated_views"];
    let angle = agreement["normal_angle_deg"].as_f64().unwrap();
    assert!((0.0..=180.0).contains(&angle) && agreement["pixels"].as_u64().unwrap() > 100, "{report}");
    assert_eq!(report["pipeline"]["generation"]["steps"].as_u64(), Some(2), "{report}");
    assert_eq!(report["pipeline"]["generation"]["draws"].as_u64(), Some(2), "{report}");
    // A model given with --weights is sampled as the authors do where the flags are left out.
    assert_eq!(report["pipeline"]["generation"]["guidance"].as_f64(), Some(2.0), "{report}");
    assert!(out.join("spot.glb").is_file() && out.join("views.png").is_file());
    // A missing model directory is named, and --weights needs --from-image.
    let missing = dir.path().join("no-model");
    let run =
        wonder3d(&["demo", "--from-image", "--weights", missing.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success() && err.contains("no-model"), "{err}");
    let run = wonder3d(&["demo", "--weights", &tiny_weights(), "--out", out.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success() && err.contains("--from-image"), "{err}");
}

/// A build without the `wgpu` feature names the feature and its docs for `--device wgpu`
/// before reading the weights or writing anything; an unknown device lists the choices.
#[test]
#[cfg(not(feature = "wgpu"))]
fn a_gpu_device_needs_the_wgpu_build() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("disc.png");
    write_input(&input);
    let out = dir.path().join("views");
    let missing = dir.path().join("no-model");
    for (weights, device, expected) in [
        (missing.to_str().unwrap().to_string(), "wgpu", "`wgpu` feature"),
        (tiny_weights(), "wgpu", "docs/gpu.md"),
        (tiny_weights(), "tpu", "cpu, wgpu"),
    ] {
        let run = wonder3d(&[
            "generate",
            input.to_str().unwrap(),
            "--weights",
            &weights,
            "--out",
            out.to_str().unwrap(),
            "--device",
            device,
            "--quiet",
        ]);
        assert!(!run.status.success());
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(err.contains(expected) && !err.contains("no-model"), "{err}");
        assert!(!out.exists(), "nothing is written");
    }
}
