//! `wonder3d render` writes a loadable oracle view set; `wonder3d eval` reports the
//! documented JSON keys and near-zero distances for a mesh against itself.

use std::path::PathBuf;
use std::process::Command;

use w3d_core::{ViewRig, ViewSet};

fn assets() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets")
}

fn wonder3d(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_wonder3d")).args(args).output().unwrap()
}

#[test]
fn render_writes_a_view_set_that_loads_back() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("spot");
    let spot = assets().join("spot.obj");
    let run = wonder3d(&[
        "render",
        spot.to_str().unwrap(),
        "--rig",
        "wonder3d-persp",
        "--size",
        "64",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let (views, rig) = ViewSet::load(&out).unwrap();
    assert_eq!(rig, ViewRig::wonder3d_persp());
    assert_eq!((views.width(), views.height()), (64, 64));
    for v in &views.views {
        let covered = v.mask.data().iter().filter(|&&m| m > 0.5).count();
        assert!(covered > 200, "{}: only {covered} foreground pixels", v.name);
        assert!(v.colour.is_some() && v.depth.is_some(), "{}", v.name);
        // Foreground normals are unit vectors.
        for (n, &m) in v.normal.data().chunks_exact(3).zip(v.mask.data()) {
            if m == 1.0 {
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                assert!((len - 1.0).abs() < 1e-3, "{}: |n| = {len}", v.name);
            }
        }
    }
}

#[test]
fn render_rejects_an_unknown_rig() {
    let dir = tempfile::tempdir().unwrap();
    let spot = assets().join("spot.obj");
    let run = wonder3d(&["render", spot.to_str().unwrap(), "--rig", "fisheye", "--out", dir.path().to_str().unwrap()]);
    assert!(!run.status.success());
    assert!(String::from_utf8_lossy(&run.stderr).contains("wonder3d-ortho"));
}

#[test]
fn eval_of_a_mesh_against_itself_is_at_the_sampling_floor() {
    let torus = assets().join("torus.obj");
    let t = torus.to_str().unwrap();
    let run = wonder3d(&["eval", t, t, "--json", "--normalize-pred", "--samples", "20000"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let json: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    for key in ["chamfer", "fscore_0.01", "fscore_0.02", "iou_64", "iou_128", "normal_consistency"] {
        assert!(json[key].is_number(), "missing {key}: {json}");
    }
    assert!(json["chamfer"].as_f64().unwrap() < 0.006, "{json}");
    assert!(json["iou_64"].as_f64().unwrap() > 0.99, "{json}");
}
