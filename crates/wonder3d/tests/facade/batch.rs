//! `wonder3d::batch` on real view sets: jobs in parallel give the bytes of one at a time,
//! failures stay with their item, resume reruns only what is missing or damaged, timeouts
//! and shards.

use std::path::{Path, PathBuf};
use std::time::Duration;

use wonder3d::batch::{Batch, BatchOptions, BatchSummary, Manifest, Shard};
use wonder3d::{Mesh, Preset, ViewRig};

/// Renders spot (ortho and persp) and bob (ortho) at 64² into `dir`; returns their folder names.
fn render_views(dir: &Path) -> Vec<&'static str> {
    let spot = wonder3d::demo::bundled_spot().unwrap();
    let mut bob = wonder3d::load_mesh(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/bob_tri.obj")).unwrap();
    bob.normalize_unit_cube();
    let sets: [(&str, &Mesh, ViewRig); 3] = [
        ("spot_ortho", &spot, ViewRig::wonder3d_ortho()),
        ("spot_persp", &spot, ViewRig::wonder3d_persp()),
        ("bob", &bob, ViewRig::wonder3d_ortho()),
    ];
    for (name, mesh, rig) in &sets {
        wonder3d::raster::render_oracle_views(mesh, rig, 64).unwrap().save(dir.join(name)).unwrap();
    }
    sets.map(|(name, _, _)| name).to_vec()
}

fn options(out: PathBuf) -> BatchOptions {
    BatchOptions::new(out).with_preset(Preset::Fast).with_texture_size(256)
}

fn run(options: BatchOptions, manifest: &Manifest) -> BatchSummary {
    let report = options.report_path();
    let summary = Batch::new(options).run(manifest, &|_| {}).unwrap();
    // Shown when an assertion below fails.
    eprintln!("{}", std::fs::read_to_string(report).unwrap());
    summary
}

fn report_lines(path: &Path) -> Vec<serde_json::Value> {
    std::fs::read_to_string(path).unwrap().lines().map(|l| serde_json::from_str(l).unwrap()).collect()
}

#[test]
fn jobs_in_parallel_write_the_bytes_of_one_at_a_time() {
    let dir = tempfile::tempdir().unwrap();
    let names = render_views(dir.path());
    let manifest = Manifest::parse(&names.join("\n"), dir.path(), "items").unwrap();
    let one = run(options(dir.path().join("one")), &manifest);
    let three = run(options(dir.path().join("three")).with_jobs(3), &manifest);
    assert_eq!((one.ok, three.ok, three.jobs), (3, 3, 3));
    // The meshes are the same bytes (the reports differ only in their timings).
    for name in names {
        let a = std::fs::read(dir.path().join("one").join(name).join("mesh.glb")).unwrap();
        let b = std::fs::read(dir.path().join("three").join(name).join("mesh.glb")).unwrap();
        assert!(a == b, "{name}/mesh.glb differs between --jobs 1 and --jobs 3");
    }
}

#[test]
fn a_failing_item_is_recorded_and_resume_reruns_only_what_is_not_done() {
    let dir = tempfile::tempdir().unwrap();
    render_views(dir.path());
    // A view folder whose normal map was cut short after rendering (cameras.json records
    // its size and hash), and a folder that does not exist.
    let normal = dir.path().join("bob/normal_front.png");
    let bytes = std::fs::read(&normal).unwrap();
    std::fs::write(&normal, &bytes[..bytes.len() / 2]).unwrap();
    let text = "spot_ortho\nbob\n{\"input\": \"gone\", \"kind\": \"views\"}\n";
    let manifest = Manifest::parse(text, dir.path(), "items").unwrap();
    let out = dir.path().join("out");
    let first = run(options(out.clone()), &manifest);
    assert_eq!((first.ok, first.failed, first.skipped), (1, 2, 0));
    let report = report_lines(&out.join("reports/all.jsonl"));
    assert_eq!(report.len(), 3);
    let bob = report.iter().find(|r| r["id"] == "bob").unwrap();
    assert_eq!(bob["status"], "failed");
    assert!(bob["error"].as_str().unwrap().contains("normal_front.png"), "{bob}");
    assert!(!out.join("bob").exists() && !out.join("gone").exists());
    assert!(out.join("spot_ortho/mesh.glb").is_file() && out.join("spot_ortho/report.json").is_file());

    // Without --resume, earlier results are refused before any work.
    let err = Batch::new(options(out.clone())).run(&manifest, &|_| {}).unwrap_err().to_string();
    assert!(err.contains("--resume"), "{err}");
    // So are 0 fits of generated views, whatever the items are.
    let zero = options(out.clone()).with_resume(true).with_generated_view_starts(0);
    let err = Batch::new(zero).run(&manifest, &|_| {}).unwrap_err().to_string();
    assert!(err.contains("generated_view_starts"), "{err}");

    // Repair bob, damage spot's finished mesh: resume reruns both, skips nothing valid.
    std::fs::write(&normal, &bytes).unwrap();
    let glb = out.join("spot_ortho/mesh.glb");
    let mut damaged = std::fs::read(&glb).unwrap();
    damaged.truncate(damaged.len() - 7);
    std::fs::write(&glb, &damaged).unwrap();
    let second = run(options(out.clone()).with_resume(true), &manifest);
    assert_eq!((second.ok, second.failed, second.skipped), (2, 1, 0));
    // A third run finds both done.
    let third = run(options(out.clone()).with_resume(true), &manifest);
    assert_eq!((third.ok, third.failed, third.skipped), (0, 1, 2));
    let statuses: Vec<_> = report_lines(&out.join("reports/all.jsonl")).iter().map(|r| r["status"].clone()).collect();
    assert_eq!(statuses.len(), 9);
    assert!(out.join("reports/all.summary.json").is_file());
    // No staging folder is left behind.
    let leftovers: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

#[test]
fn an_item_past_its_timeout_is_stopped_and_the_batch_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    render_views(dir.path());
    let manifest = Manifest::parse("spot_ortho\nbob\n", dir.path(), "items").unwrap();
    let out = dir.path().join("out");
    let summary = run(options(out.clone()).with_timeout(Some(Duration::from_millis(1))), &manifest);
    assert_eq!((summary.ok, summary.timed_out), (0, 2));
    let report = report_lines(&out.join("reports/all.jsonl"));
    assert!(report.iter().all(|r| r["status"] == "timed_out" && r["error"].as_str().unwrap().contains("timeout")));
    let entries: Vec<_> = std::fs::read_dir(&out).unwrap().flatten().map(|e| e.file_name()).collect();
    assert_eq!(entries, vec![std::ffi::OsString::from("reports")]);
}

#[test]
fn shards_split_the_manifest_into_one_folder() {
    let dir = tempfile::tempdir().unwrap();
    let names = render_views(dir.path());
    let manifest = Manifest::parse(&names.join("\n"), dir.path(), "items").unwrap();
    let out = dir.path().join("out");
    let a = run(options(out.clone()).with_shard(Shard::new(0, 2).unwrap()), &manifest);
    let b = run(options(out.clone()).with_shard(Shard::new(1, 2).unwrap()), &manifest);
    assert_eq!((a.items, b.items, a.ok + b.ok), (2, 1, 3));
    for name in names {
        assert!(out.join(name).join("mesh.glb").is_file(), "{name}");
    }
    let first = report_lines(&out.join("reports/shard-0000-of-0002.jsonl"));
    let second = report_lines(&out.join("reports/shard-0001-of-0002.jsonl"));
    assert_eq!((first.len(), second.len()), (2, 1));
    assert!(first.iter().chain(&second).all(|r| r["status"] == "ok"));
}
