//! `wonder3d batch`: view folders and images (with the tiny model, loaded once) in one run,
//! a failing item recorded while the others finish, checks before any work, resume.

use crate::common;

use std::path::{Path, PathBuf};

use common::wonder3d;

fn spot() -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets/spot.obj").to_str().unwrap().to_string()
}

fn render(out: &Path) {
    let run = wonder3d(&["render", &spot(), "--size", "64", "--out", out.to_str().unwrap()]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn a_batch_of_view_folders_records_failures_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    render(&dir.path().join("spot"));
    let manifest = dir.path().join("items.txt");
    std::fs::write(&manifest, "# two items\nspot\n{\"input\": \"missing\", \"kind\": \"views\"}\n").unwrap();
    let out = dir.path().join("out");
    let args = |extra: &[&str]| {
        let mut a = vec!["batch", manifest.to_str().unwrap(), "--out", out.to_str().unwrap()];
        a.extend_from_slice(&["--preset", "fast", "--texture-size", "256", "--quiet"]);
        a.extend_from_slice(extra);
        a.into_iter().map(String::from).collect::<Vec<_>>()
    };
    let run = |extra: &[&str]| {
        let a = args(extra);
        wonder3d(&a.iter().map(String::as_str).collect::<Vec<_>>())
    };
    let first = run(&[]);
    assert_eq!(first.status.code(), Some(1), "{}", text(&first.stderr));
    assert!(text(&first.stdout).contains("1 ok, 1 failed"), "{}", text(&first.stdout));
    assert!(text(&first.stderr).contains("missing (line 3)"), "{}", text(&first.stderr));
    assert!(out.join("spot/mesh.glb").is_file());
    let report = std::fs::read_to_string(out.join("reports/all.jsonl")).unwrap();
    assert_eq!(report.lines().count(), 2);

    // Earlier results need --resume; resume skips what is done.
    let again = run(&[]);
    assert!(text(&again.stderr).contains("--resume"), "{}", text(&again.stderr));
    std::fs::write(&manifest, "spot\n").unwrap();
    let resumed = run(&["--resume"]);
    assert!(resumed.status.success(), "{}", text(&resumed.stderr));
    assert!(text(&resumed.stdout).contains("0 ok, 0 failed, 0 timed out, 1 skipped"), "{}", text(&resumed.stdout));
}

#[test]
fn batch_checks_everything_before_work() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = dir.path().join("items.txt");
    let out = dir.path().join("out");
    let o = out.to_str().unwrap();
    // An image item without a model, a missing input, a NUL byte, a bad JSON line, a
    // duplicate id, a bad shard.
    std::fs::write(dir.path().join("photo.jpg"), b"not decoded before the model check").unwrap();
    std::fs::write(&manifest, "photo.jpg\n").unwrap();
    let run = wonder3d(&["batch", manifest.to_str().unwrap(), "--out", o]);
    assert!(text(&run.stderr).contains("--weights"), "{}", text(&run.stderr));
    std::fs::write(&manifest, "photo.jpg\nno-such-photo.jpg\n").unwrap();
    let run = wonder3d(&["batch", manifest.to_str().unwrap(), "--out", o]);
    let err = text(&run.stderr);
    assert!(
        err.contains("line 2") && err.contains("no-such-photo.jpg does not exist") && !err.contains("--weights"),
        "{err}"
    );
    std::fs::write(&manifest, b"photo.jpg\nph\0to.jpg\n").unwrap();
    let run = wonder3d(&["batch", manifest.to_str().unwrap(), "--out", o]);
    let err = text(&run.stderr);
    assert!(err.contains("line 2") && err.contains("NUL") && !err.contains('\0'), "{err}");
    std::fs::write(&manifest, "a.png\n{\"input\": \"b.png\", \"steps\": \"many\"}\n").unwrap();
    let run = wonder3d(&["batch", manifest.to_str().unwrap(), "--out", o]);
    assert!(text(&run.stderr).contains("line 2"), "{}", text(&run.stderr));
    std::fs::write(&manifest, "x/a.png\nx_a.png\n").unwrap();
    let run = wonder3d(&["batch", manifest.to_str().unwrap(), "--out", o]);
    assert!(text(&run.stderr).contains("line 1"), "{}", text(&run.stderr));
    let run = wonder3d(&["batch", manifest.to_str().unwrap(), "--out", o, "--shard", "2/2"]);
    assert!(text(&run.stderr).contains("I/N"), "{}", text(&run.stderr));
    std::fs::write(&manifest, "a.png\n").unwrap();
    // Missing parents of --out are created when the batch runs; a file in their way is named.
    let run = wonder3d(&["batch", manifest.to_str().unwrap(), "--out", manifest.join("out").to_str().unwrap()]);
    let err = text(&run.stderr);
    assert!(err.contains("items.txt is a file"), "{err}");
    assert!(!out.exists());
}

#[cfg(feature = "diffusion")]
#[test]
fn images_share_one_model_and_take_their_own_seed() {
    let dir = tempfile::tempdir().unwrap();
    common::write_input(&dir.path().join("disc.png"));
    let manifest = dir.path().join("items.txt");
    std::fs::write(&manifest, "disc.png\n{\"input\": \"disc.png\", \"id\": \"disc-7\", \"seed\": 7}\n").unwrap();
    let out = dir.path().join("out");
    let weights = common::tiny_weights();
    let run = wonder3d(&[
        "batch",
        manifest.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--weights",
        &weights,
        "--steps",
        "2",
        "--preset",
        "fast",
        "--no-texture",
        "--keep-views",
        "--jobs",
        "2",
        "--starts",
        "1",
        "--quiet",
    ]);
    assert!(run.status.success(), "{}", text(&run.stderr));
    for (id, seed) in [("disc", 42), ("disc-7", 7)] {
        let report: serde_json::Value = common::read_json(&out.join(id).join("report.json"));
        assert_eq!(report["generation"]["seed"], seed);
        assert_eq!(report["reconstruction"]["start_losses"].as_array().map(Vec::len), Some(1), "--starts 1");
        assert_eq!(report["generation"]["steps"], 2);
        assert!(out.join(id).join("views/cameras.json").is_file());
        assert!(out.join(id).join("views/input.png").is_file());
        assert!(wonder3d::load_mesh(out.join(id).join("mesh.glb")).unwrap().texture().is_none());
    }
    // Other seeds, other views.
    let a = std::fs::read(out.join("disc/views/normal_front.png")).unwrap();
    let b = std::fs::read(out.join("disc-7/views/normal_front.png")).unwrap();
    assert_ne!(a, b);
}
