//! `wonder3d render` writes a loadable oracle view set; `wonder3d eval` reports the
//! documented JSON keys and near-zero distances for a mesh against itself.

use crate::common::wonder3d;
use std::path::PathBuf;

use wonder3d::{ViewRig, ViewSet};

fn assets() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets")
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
    let views = ViewSet::load(&out).unwrap();
    assert_eq!(views.rig(), &ViewRig::wonder3d_persp());
    assert_eq!((views.width(), views.height()), (64, 64));
    for v in views.views() {
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

/// `render --out a/b/c` creates the missing `a/b` (as `mkdir -p`; scripts expect it), and the
/// view set lands whole in `c`.
#[test]
fn render_creates_missing_parent_folders() {
    let dir = tempfile::tempdir().unwrap();
    let torus = assets().join("torus.obj");
    let out = dir.path().join("a/b/views");
    let run = wonder3d(&["render", torus.to_str().unwrap(), "--size", "32", "--out", out.to_str().unwrap()]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(wonder3d::ViewSet::load(&out).is_ok());
    let names: Vec<_> = std::fs::read_dir(dir.path().join("a/b")).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names, ["views"], "no staging folder left beside the views");
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

#[test]
fn texture_bakes_rendered_views_into_a_glb_and_an_obj() {
    let dir = tempfile::tempdir().unwrap();
    let views = dir.path().join("views");
    let spot = assets().join("spot.obj");
    let spot = spot.to_str().unwrap();
    let run = wonder3d(&["render", spot, "--size", "64", "--out", views.to_str().unwrap()]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let glb = dir.path().join("spot.glb");
    let args = ["texture", spot, views.to_str().unwrap(), "--normalize", "--size", "128", "--out"];
    let run = wonder3d(&[&args[..], &[glb.to_str().unwrap()]].concat());
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(stdout.contains("charts") && stdout.contains("6 views"), "{stdout}");
    let mesh = wonder3d::load_mesh(&glb).unwrap();
    assert_eq!(mesh.texture().unwrap().width(), 128);
    assert!(mesh.uvs().is_some());
    let obj = dir.path().join("spot_vc.obj");
    let run = wonder3d(&[&args[..], &[obj.to_str().unwrap(), "--vertex-colours"]].concat());
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let mesh = wonder3d::load_mesh(&obj).unwrap();
    assert!(mesh.colours().is_some() && mesh.texture().is_none());
    // Bad input names the problem.
    let run = wonder3d(&["texture", spot, dir.path().to_str().unwrap(), "--out", glb.to_str().unwrap()]);
    assert!(!run.status.success());
    assert!(String::from_utf8_lossy(&run.stderr).contains("cameras.json"));
}
