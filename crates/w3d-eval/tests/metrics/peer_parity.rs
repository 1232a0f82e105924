//! Parity with the peer tools, from the committed `fixtures/peer_metrics.json` (made once
//! by `fixtures/make_fixtures.py`): Chamfer and F-score within 5 % (or 0.0005 absolute) of
//! point-cloud-utils, volume IoU within 0.01 of mesh2sdf, PSNR / SSIM within 1e-3 of
//! scikit-image. Also the self-distance floor and bad-input errors. No Python needed.

use std::path::{Path, PathBuf};

use glam::{Mat3, Vec3};
use serde_json::Value;
use w3d_core::{Image, Mesh, load_mesh};
use w3d_eval::{EvalOptions, Grid, MeshMetrics, SurfaceComparison, evaluate, psnr, sample_surface, ssim, volume_iou};

fn crate_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn shared_mesh(name: &str) -> PathBuf {
    crate_dir().join("../../../shared/data/meshes").join(name)
}

/// A bare name is a shared test mesh; `fixtures/...` is relative to this crate.
fn mesh_path(name: &str) -> PathBuf {
    if name.starts_with("fixtures/") { crate_dir().join(name) } else { shared_mesh(name) }
}

fn fixtures() -> Value {
    let text = std::fs::read_to_string(crate_dir().join("fixtures/peer_metrics.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

fn num(v: &Value, key: &str) -> f64 {
    v[key].as_f64().unwrap_or_else(|| panic!("fixture key {key} in {v}"))
}

/// The prediction of a fixture entry, transformed exactly as the script describes.
fn prediction(entry: &Value) -> Mesh {
    let mut pred = load_mesh(mesh_path(entry["pred_mesh"].as_str().unwrap())).unwrap();
    if entry["pred_normalize"].as_bool().unwrap() {
        pred.normalize_unit_cube();
    }
    let scale = num(entry, "pred_scale") as f32;
    let rotation = Mat3::from_rotation_y((num(entry, "pred_rotate_y_deg") as f32).to_radians());
    let t: Vec<f32> = entry["pred_translate"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap() as f32).collect();
    pred.map_positions(|p| rotation * (p * scale) + Vec3::new(t[0], t[1], t[2])).unwrap();
    pred
}

fn close(ours: f64, peer: f64, rel: f64, abs: f64) -> bool {
    (ours - peer).abs() <= abs.max(rel * peer.abs())
}

/// Our numbers for one fixture pair and the keys they answer. `evaluate` computes every
/// field; the 128³ IoU (the slowest part) is checked end to end on `FULL_PAIRS` only, the
/// other pairs get the same surface metrics and the 64³ IoU from the building blocks
/// `evaluate` uses, with the same seeds.
const FULL_PAIRS: [&str; 2] = ["spot_shift_0.01", "armadillo_decimated"];

fn ours(entry: &Value) -> Vec<(&'static str, f64)> {
    let mut gt = load_mesh(mesh_path(entry["gt_mesh"].as_str().unwrap())).unwrap();
    let pred = prediction(entry);
    let closed = !entry["iou_64"].is_null();
    if FULL_PAIRS.contains(&entry["name"].as_str().unwrap()) {
        let m: MeshMetrics = evaluate(&pred, &gt, &EvalOptions::default()).unwrap();
        return vec![
            ("chamfer", m.chamfer),
            ("fscore_0.01", m.fscore_001),
            ("fscore_0.02", m.fscore_002),
            ("precision_0.01", m.precision_001),
            ("recall_0.01", m.recall_001),
            ("normal_consistency", m.normal_consistency),
            ("iou_64", m.iou_64),
            ("iou_128", m.iou_128),
        ];
    }
    gt.normalize_unit_cube();
    let options = EvalOptions::default();
    let a = sample_surface(&pred, options.samples, options.seed).unwrap();
    let b = sample_surface(&gt, options.samples, options.seed + 1).unwrap();
    let c = SurfaceComparison::new(&a, &b).unwrap();
    let (f1, f2) = (c.fscore(0.01).unwrap(), c.fscore(0.02).unwrap());
    let mut values = vec![
        ("chamfer", c.chamfer()),
        ("fscore_0.01", f1.fscore),
        ("fscore_0.02", f2.fscore),
        ("precision_0.01", f1.precision),
        ("recall_0.01", f1.recall),
        ("normal_consistency", c.normal_consistency),
    ];
    if closed {
        values.push(("iou_64", volume_iou(&pred, &gt, &Grid::syncdreamer64()).unwrap()));
    }
    values
}

#[test]
fn mesh_metrics_match_point_cloud_utils_and_mesh2sdf() {
    let fixtures = fixtures();
    let pairs = fixtures["mesh_pairs"].as_array().unwrap();
    assert!(pairs.len() >= 6);
    let mut failures = Vec::new();
    let mut checked = 0;
    for entry in pairs {
        let name = entry["name"].as_str().unwrap();
        for (key, value) in ours(entry) {
            let peer = num(entry, key);
            let (rel, abs) = match key {
                "chamfer" | "fscore_0.01" | "fscore_0.02" | "precision_0.01" | "recall_0.01" => (0.05, 0.0005),
                "normal_consistency" => (0.0, 0.005),
                _ => (0.0, 0.01), // IoU
            };
            let ok = close(value, peer, rel, abs);
            println!("{name:24} {key:20} ours {value:.5}  peer {peer:.5}  {}", if ok { "ok" } else { "FAIL" });
            if !ok {
                failures.push(format!("{name} {key}: ours {value}, peer {peer}"));
            }
            checked += 1;
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
    assert!(checked >= 6 * 7, "only {checked} values compared");
}

#[test]
fn image_metrics_match_scikit_image() {
    let fixtures = fixtures();
    let pairs = fixtures["image_pairs"].as_array().unwrap();
    assert!(pairs.len() >= 3);
    for entry in pairs {
        let a = Image::read_png(crate_dir().join(entry["a"].as_str().unwrap())).unwrap();
        let b = Image::read_png(crate_dir().join(entry["b"].as_str().unwrap())).unwrap();
        let (p, s) = (psnr(&a, &b).unwrap(), ssim(&a, &b).unwrap());
        println!("{}: psnr {p:.6} (peer {}), ssim {s:.6} (peer {})", entry["name"], entry["psnr"], entry["ssim"]);
        assert!((p - num(entry, "psnr")).abs() < 1e-3, "{}: psnr {p}", entry["name"]);
        assert!((s - num(entry, "ssim")).abs() < 1e-3, "{}: ssim {s}", entry["name"]);
    }
}

/// Two independent samplings of the same mesh: the Chamfer floor at 100k samples.
#[test]
fn self_distance_floor_at_100k_samples() {
    for name in ["spot.obj", "armadillo.obj"] {
        let mut mesh = load_mesh(shared_mesh(name)).unwrap();
        mesh.normalize_unit_cube();
        let a = sample_surface(&mesh, 100_000, 11).unwrap();
        let b = sample_surface(&mesh, 100_000, 12).unwrap();
        let c = SurfaceComparison::new(&a, &b).unwrap();
        let (cd, f) = (c.chamfer(), c.fscore(0.01).unwrap().fscore);
        println!("{name}: self CD {cd:.5}, F@0.01 {f:.4}");
        assert!(cd <= 0.0025 && cd > 0.0005, "{name}: self CD {cd}");
        assert!(f > 0.999, "{name}: self F@0.01 {f}");
    }
}

#[test]
fn evaluate_normalises_serialises_and_rejects_bad_options() {
    let spot = load_mesh(shared_mesh("spot.obj")).unwrap();
    let options = EvalOptions::default().with_samples(2_000).with_seed(5).with_normalize_pred(false);
    let mut unit = spot.clone();
    unit.normalize_unit_cube();
    let a = evaluate(&unit, &spot, &options).unwrap();
    assert_eq!((a.iou_64, a.iou_128), (1.0, 1.0));
    // A prediction 3× larger and moved: far off as it is, at the floor once normalised.
    let mut big = spot.clone();
    big.map_positions(|p| p * 3.0 + Vec3::new(1.0, -2.0, 0.5)).unwrap();
    let raw = evaluate(&big, &spot, &options).unwrap();
    let normalised = evaluate(&big, &spot, &options.with_normalize_pred(true)).unwrap();
    assert_eq!((normalised.samples, normalised.seed), (2_000, 5));
    assert!(raw.chamfer > 1.0 && raw.iou_64 < 0.2, "raw chamfer {}, iou {}", raw.chamfer, raw.iou_64);
    assert!((normalised.chamfer - a.chamfer).abs() < 1e-4, "{} vs {}", normalised.chamfer, a.chamfer);
    assert!(normalised.iou_64 > 0.999);
    let e = evaluate(&spot, &spot, &options.with_samples(0)).unwrap_err().to_string();
    assert!(e.contains("options.samples"), "{e}");
    assert_json_keys(&a);
}

/// The JSON keys are part of the interface (`wonder3d eval --json`, benchmark files).
fn assert_json_keys(m: &MeshMetrics) {
    let json = serde_json::to_value(m).unwrap();
    let mut keys: Vec<&str> = json.as_object().unwrap().keys().map(String::as_str).collect();
    keys.sort_unstable();
    let expected = [
        "chamfer",
        "chamfer_gt_to_pred",
        "chamfer_pred_to_gt",
        "fscore_0.01",
        "fscore_0.02",
        "iou_128",
        "iou_64",
        "normal_consistency",
        "precision_0.01",
        "precision_0.02",
        "recall_0.01",
        "recall_0.02",
        "samples",
        "seed",
    ];
    assert_eq!(keys, expected);
    assert_eq!(json["samples"], m.samples);
}

#[test]
fn mismatched_images_are_clear_errors() {
    let a = Image::read_png(crate_dir().join("fixtures/images/a.png")).unwrap();
    let d = Image::read_png(crate_dir().join("fixtures/images/d.png")).unwrap();
    let small = Image::filled(32, 48, 3, 1.0).unwrap();
    for err in [psnr(&d, &small).unwrap_err(), ssim(&a, &small).unwrap_err()] {
        let text = err.to_string();
        assert!(text.contains("image b") && text.contains("64×48"), "{text}");
    }
    assert!(Path::new(&crate_dir().join("fixtures/images/a.png")).exists());
}
