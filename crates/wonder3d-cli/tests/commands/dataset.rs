//! `wonder3d dataset`: a training set whose samples reconstruct, `--camera` fixing the rig,
//! and bad input refused before any rendering with nothing written.

use crate::common;

use std::path::{Path, PathBuf};

use common::wonder3d;
use wonder3d::{ViewRig, ViewSet};

fn asset(name: &str) -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets").join(name).to_str().unwrap().to_string()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn stderr(run: &std::process::Output) -> String {
    String::from_utf8_lossy(&run.stderr).into_owned()
}

fn names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    names
}

#[test]
fn dataset_writes_samples_that_load_and_reconstruct() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("train");
    let (spot, torus) = (asset("spot.obj"), asset("torus.obj"));
    let args = ["dataset", &spot, &torus, "--out", s(&out), "--samples", "2", "--size", "64", "--seed", "3", "--quiet"];
    let run = wonder3d(&args);
    assert!(run.status.success(), "{}", stderr(&run));
    assert!(String::from_utf8_lossy(&run.stdout).contains("wrote 4 samples of 2 meshes"));
    let json: serde_json::Value = common::read_json(&out.join("dataset.json"));
    assert_eq!((json["format"].as_str(), json["version"].as_u64()), (Some("wonder3d-rs dataset"), Some(2)));
    assert_eq!((json["size"].as_u64(), json["seed"].as_u64()), (Some(64), Some(3)));
    let samples = json["samples"].as_array().unwrap();
    let ids: Vec<&str> = samples.iter().map(|s| s["id"].as_str().unwrap()).collect();
    assert_eq!(ids, ["spot_000", "spot_001", "torus_000", "torus_001"]);
    assert_eq!(samples[0]["source"].as_str(), Some(spot.as_str()));
    assert_eq!(
        (samples[0]["colouring"].as_str(), samples[2]["colouring"].as_str()),
        (Some("mesh"), Some("procedural"))
    );
    assert_eq!(names(&out), ["dataset.json", "spot_000", "spot_001", "torus_000", "torus_001"]);
    for id in ids {
        ViewSet::load(out.join(id)).unwrap();
    }
    // The same command again replaces the dataset with the same bytes.
    let before = std::fs::read(out.join("torus_001/normal_front.exr")).unwrap();
    let run = wonder3d(&args);
    assert!(run.status.success(), "{}", stderr(&run));
    assert_eq!(std::fs::read(out.join("torus_001/normal_front.exr")).unwrap(), before);
    assert_eq!(names(dir.path()), ["train"]);
    // A sample folder is a view set that reconstructs.
    let mesh = dir.path().join("torus.glb");
    let run = wonder3d(&["reconstruct", s(&out.join("torus_000")), "--out", s(&mesh), "--preset", "fast"]);
    assert!(run.status.success(), "{}", stderr(&run));
    assert!(mesh.is_file());
}

#[test]
fn dataset_camera_ortho_fixes_the_rig() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("train");
    let run = wonder3d(&[
        "dataset",
        &asset("torus.obj"),
        "--out",
        s(&out),
        "--samples",
        "6",
        "--size",
        "16",
        "--camera",
        "ortho",
    ]);
    assert!(run.status.success(), "{}", stderr(&run));
    let json: serde_json::Value = common::read_json(&out.join("dataset.json"));
    for sample in json["samples"].as_array().unwrap() {
        assert_eq!(sample["camera"], "ortho");
        let views = ViewSet::load(out.join(sample["id"].as_str().unwrap())).unwrap();
        assert_eq!(views.rig(), &ViewRig::wonder3d_ortho());
    }
}

#[test]
fn dataset_refuses_bad_input_before_any_rendering() {
    let dir = tempfile::tempdir().unwrap();
    let torus = asset("torus.obj");
    let out = dir.path().join("train");
    let fails = |args: &[&str]| {
        let run = wonder3d(args);
        assert!(!run.status.success(), "{args:?} succeeded");
        stderr(&run)
    };
    let missing = dir.path().join("missing.obj");
    let err = fails(&["dataset", &torus, s(&missing), "--out", s(&out)]);
    assert!(err.contains("missing.obj"), "{err}");
    let corrupt = dir.path().join("corrupt.obj");
    std::fs::write(&corrupt, "v 0 0 0\nv 1 0 0\nf 1 2 7\n").unwrap();
    let err = fails(&["dataset", &torus, s(&corrupt), "--out", s(&out)]);
    assert!(err.contains("corrupt.obj"), "{err}");
    // A mesh whose triangles have no area would give samples with empty masks.
    let flat = dir.path().join("flat.obj");
    std::fs::write(&flat, "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n").unwrap();
    let err = fails(&["dataset", &torus, s(&flat), "--out", s(&out)]);
    assert!(err.contains("flat.obj") && err.contains("zero area"), "{err}");
    let err = fails(&["dataset", &torus, "--out", s(&out), "--size", "8"]);
    assert!(err.contains("16 to 2048 pixels"), "{err}");
    let err = fails(&["dataset", &torus, "--out", s(&out), "--samples", "0"]);
    assert!(err.contains("1 to 10000 samples"), "{err}");
    let err = fails(&["dataset", &torus, "--out", s(&out), "--camera", "fisheye"]);
    assert!(err.contains("both"), "{err}");
    let err = fails(&["dataset", "--out", s(&out)]);
    assert!(err.contains("MESHES"), "{err}");
    // Outputs: a file, a folder of other files, a file in the way of missing parents.
    let file = dir.path().join("file.txt");
    std::fs::write(&file, "mine").unwrap();
    let err = fails(&["dataset", &torus, "--out", s(&file)]);
    assert!(err.contains("it is a file"), "{err}");
    let err = fails(&["dataset", &torus, "--out", s(dir.path())]);
    assert!(err.contains("earlier dataset"), "{err}");
    let err = fails(&["dataset", &torus, "--out", s(&file.join("train"))]);
    assert!(err.contains("file.txt is a file"), "{err}");
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "mine");
    assert_eq!(names(dir.path()), ["corrupt.obj", "file.txt", "flat.obj"]);
}
