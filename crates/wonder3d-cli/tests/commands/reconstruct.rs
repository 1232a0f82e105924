//! `wonder3d render` → `wonder3d reconstruct` → `wonder3d refine` → `wonder3d eval`: the
//! command-line hand-over on small views, the report files, and clear errors for bad input.

use crate::common::wonder3d;
use std::path::PathBuf;

fn spot() -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets/spot.obj").to_str().unwrap().to_string()
}

#[test]
fn reconstruct_reads_rendered_views_and_writes_a_mesh_and_report() {
    let dir = tempfile::tempdir().unwrap();
    let views = dir.path().join("views");
    let mesh = dir.path().join("spot.glb");
    let report = dir.path().join("report.json");
    let run = wonder3d(&["render", &spot(), "--size", "96", "--out", views.to_str().unwrap()]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let run = wonder3d(&[
        "reconstruct",
        views.to_str().unwrap(),
        "--out",
        mesh.to_str().unwrap(),
        "--preset",
        "fast",
        "--report",
        report.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let json = crate::common::read_json(&report);
    assert_eq!(json["init"]["choice"], "poisson", "{json}");
    assert_eq!(
        json["coarse"]["losses"].as_array().unwrap().len(),
        wonder3d::ReconOptions::preset(wonder3d::Preset::Fast).coarse.steps
    );
    assert!(json["triangles"].as_u64().unwrap() > 500);
    let run = wonder3d(&["eval", mesh.to_str().unwrap(), &spot(), "--json", "--samples", "20000"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let metrics: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    let chamfer = metrics["chamfer"].as_f64().unwrap();
    assert!(chamfer < 0.03, "fast preset at 96²: chamfer {chamfer}");
}

#[test]
fn reconstruct_names_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.glb");
    let missing = dir.path().join("no-such-views");
    let run = wonder3d(&["reconstruct", missing.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("no-such-views"), "{err}");
    let run =
        wonder3d(&["reconstruct", dir.path().to_str().unwrap(), "--out", out.to_str().unwrap(), "--preset", "best"]);
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("fast, default, quality"), "{err}");
    assert!(!out.exists());
}

#[test]
fn demo_writes_glb_contact_sheet_and_report() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let run = wonder3d(&[
        "demo",
        "--out",
        out.to_str().unwrap(),
        "--preset",
        "fast",
        "--size",
        "128",
        "--texture-size",
        "256",
        "--quiet",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let report = crate::common::read_json(&out.join("report.json"));
    let chamfer = report["geometry"]["chamfer"].as_f64().unwrap();
    let psnr = report["texture_psnr_input_views"].as_f64().unwrap();
    assert!(chamfer < 0.015, "{report}");
    assert!(psnr > 20.0, "{report}");
    let textured = wonder3d::load_mesh(out.join("spot.glb")).unwrap();
    assert!(textured.texture().is_some() && textured.uvs().is_some());
    assert_eq!(textured.triangle_count() as u64, report["pipeline"]["triangles"].as_u64().unwrap());
    let sheet = wonder3d::Image::read_png(out.join("views.png")).unwrap();
    // 6 views by 4 rows (input / result × colour / normal), plus the label margin and line.
    assert!(sheet.width() > 6 * 128 && sheet.width() < 7 * 128, "{}", sheet.width());
    assert!(sheet.height() > 4 * 128 && sheet.height() < 5 * 128, "{}", sheet.height());
}

#[test]
fn refine_with_the_oracle_sharpens_a_coarse_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let views = dir.path().join("views");
    let coarse = dir.path().join("coarse.ply");
    let refined = dir.path().join("refined.glb");
    let report = dir.path().join("refine.json");
    let run = wonder3d(&["render", &spot(), "--size", "64", "--out", views.to_str().unwrap()]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let run = wonder3d(&["reconstruct", views.to_str().unwrap(), "--out", coarse.to_str().unwrap(), "--quiet"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let oracle = format!("oracle:{}", spot());
    let run = wonder3d(&[
        "refine",
        coarse.to_str().unwrap(),
        views.to_str().unwrap(),
        "--enhancer",
        &oracle,
        "--iterations",
        "1",
        "--size",
        "192",
        "--texture-size",
        "256",
        "--out",
        refined.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let json = crate::common::read_json(&report);
    assert_eq!(json["enhancer"], "oracle", "{json}");
    assert_eq!(json["iterations"].as_array().unwrap().len(), 1, "{json}");
    // The default refinement simplifies the fitted mesh, and the report says by how much.
    let simplified = &json["iterations"][0]["mesh"]["simplify"];
    let (before, after) =
        (simplified["triangles_before"].as_u64().unwrap(), simplified["triangles_after"].as_u64().unwrap());
    assert!(after < before && json["triangles"].as_u64() == Some(after), "{json}");
    let mesh = wonder3d::load_mesh(&refined).unwrap();
    assert!(mesh.texture().is_some(), "the refined GLB carries its texture");
    let chamfer = |path: &std::path::Path| {
        let run = wonder3d(&["eval", path.to_str().unwrap(), &spot(), "--json", "--samples", "20000"]);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        let metrics: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
        metrics["chamfer"].as_f64().unwrap()
    };
    let (before, after) = (chamfer(&coarse), chamfer(&refined));
    assert!(after < before, "the oracle at 192² sharpens the 64² reconstruction: chamfer {before} -> {after}");
    assert_eq!(json["iterations"][0]["mesh"]["kept_input"], false, "{json}");

    // Views that show nothing new: the fit agrees no better with them, the coarse mesh comes
    // back and the summary says why.
    let (v, c, o) = (views.to_str().unwrap(), coarse.to_str().unwrap(), refined.to_str().unwrap());
    let run = wonder3d(&["refine", c, v, "--enhancer", "identity", "--iterations", "1", "--size", "128", "--out", o]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(stdout.contains("iteration 1 kept its input mesh"), "{stdout}");
    let (kept, input) = (wonder3d::load_mesh(&refined).unwrap(), wonder3d::load_mesh(&coarse).unwrap());
    assert_eq!(kept.triangle_count(), input.triangle_count());
}

#[test]
fn refine_names_what_is_wrong_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let views = dir.path().join("views");
    let run = wonder3d(&["render", &spot(), "--size", "32", "--out", views.to_str().unwrap()]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let out = dir.path().join("x.glb");
    let (v, o) = (views.to_str().unwrap(), out.to_str().unwrap());
    // An enhancer directory that does not exist, and one missing a file: the missing file is
    // named with the docs section on the layout, before any weight is read.
    let run = wonder3d(&["refine", &spot(), v, "--enhancer", "no-such-enhancer", "--out", o]);
    assert_eq!(run.status.code(), Some(1));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("no-such-enhancer") && err.contains("docs/weights.md"), "{err}");
    let partial = dir.path().join("enhancer");
    std::fs::create_dir_all(partial.join("unet")).unwrap();
    std::fs::write(partial.join("unet").join("config.json"), "{}").unwrap();
    let run = wonder3d(&["refine", &spot(), v, "--enhancer", partial.to_str().unwrap(), "--out", o]);
    assert_eq!(run.status.code(), Some(1));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("diffusion_pytorch_model.safetensors") && err.contains("docs/weights.md"), "{err}");
    assert!(!out.exists());
    let run = wonder3d(&["refine", &spot(), v, "--enhancer", "oracle:", "--out", o]);
    assert_eq!(run.status.code(), Some(2));
    let run = wonder3d(&["refine", &spot(), v, "--enhancer", "identity", "--iterations", "11", "--out", o]);
    assert_eq!(run.status.code(), Some(2));
    for bad in ["-0.001", "nan", "0.5", "of"] {
        let run = wonder3d(&["refine", &spot(), v, "--enhancer", "identity", "--simplify", bad, "--out", o]);
        assert_eq!(run.status.code(), Some(2), "--simplify {bad}");
        assert!(String::from_utf8_lossy(&run.stderr).contains("--simplify"), "--simplify {bad}");
    }
    // A missing oracle mesh and a missing view folder are named.
    let missing = dir.path().join("no-such-mesh.obj");
    let run = wonder3d(&["refine", &spot(), v, "--enhancer", &format!("oracle:{}", missing.display()), "--out", o]);
    assert_eq!(run.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&run.stderr).contains("no-such-mesh.obj"));
    let run = wonder3d(&["refine", &spot(), "no-such-views", "--enhancer", "identity", "--out", o]);
    assert_eq!(run.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&run.stderr).contains("no-such-views"));
    // An output on an input is refused before it could overwrite it.
    let copy = dir.path().join("copy.obj");
    std::fs::copy(spot(), &copy).unwrap();
    let before = std::fs::read(&copy).unwrap();
    let (c, oracle_copy) = (copy.to_str().unwrap(), format!("oracle:{}", copy.display()));
    for (args, input) in [
        (vec!["refine", c, v, "--enhancer", "identity", "--out", c], "MESH input"),
        (vec!["refine", &spot(), v, "--enhancer", &oracle_copy, "--out", c], "--enhancer oracle: input"),
        (vec!["texture", c, v, "--out", c], "MESH input"),
    ] {
        let run = wonder3d(&args);
        assert_eq!(run.status.code(), Some(1), "{args:?}");
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(err.contains("--out") && err.contains(input), "{args:?}: {err}");
    }
    assert!(std::fs::read(&copy).unwrap() == before, "the input mesh is untouched");
    // An open MESH, and an oracle mesh without area, are named before any work.
    let open = dir.path().join("open.obj");
    std::fs::write(&open, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let run = wonder3d(&["refine", open.to_str().unwrap(), v, "--enhancer", "identity", "--out", o]);
    assert_eq!(run.status.code(), Some(1));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("open.obj") && err.contains("a closed mesh"), "{err}");
    let flat = dir.path().join("flat.obj");
    std::fs::write(&flat, "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 3 4\n").unwrap();
    let oracle = format!("oracle:{}", flat.display());
    let run = wonder3d(&["refine", &spot(), v, "--enhancer", &oracle, "--out", o]);
    assert_eq!(run.status.code(), Some(1));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("--enhancer oracle:") && err.contains("flat.obj") && err.contains("zero area"), "{err}");
    assert!(!out.exists());
    // An output that cannot be written fails before the work.
    let nowhere = dir.path().join("missing-folder").join("x.glb");
    let run = wonder3d(&["refine", &spot(), v, "--enhancer", "identity", "--out", nowhere.to_str().unwrap()]);
    assert_eq!(run.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&run.stderr).contains("missing-folder"));
    assert!(!out.exists());
}

/// `reconstruct --enhancer DIR`: `--refine 0` writes exactly the coarse mesh, `--refine N`
/// without an enhancer and an enhancer directory missing a file fail before any work, and a
/// refinement with the tiny random-weight enhancer writes a textured mesh.
#[test]
fn reconstruct_refines_with_an_enhancer_and_refine_0_keeps_the_coarse_mesh() {
    let dir = tempfile::tempdir().unwrap();
    let views = dir.path().join("views");
    let run = wonder3d(&["render", &spot(), "--size", "64", "--out", views.to_str().unwrap()]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let enhancer = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../w3d-diffusion/tests/fixtures/enhancer");
    let (v, e) = (views.to_str().unwrap(), enhancer.to_str().unwrap());
    let out = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let plain = out("plain.ply");
    let run = wonder3d(&["reconstruct", v, "--out", &plain, "--preset", "fast", "--quiet"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let zero = out("zero.ply");
    let run =
        wonder3d(&["reconstruct", v, "--out", &zero, "--preset", "fast", "--enhancer", e, "--refine", "0", "--quiet"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert_eq!(std::fs::read(&plain).unwrap(), std::fs::read(&zero).unwrap(), "--refine 0 must be today's output");

    let failed = out("failed.glb");
    let run = wonder3d(&["reconstruct", v, "--out", &failed, "--refine", "1"]);
    assert_eq!(run.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&run.stderr).contains("--enhancer"));
    let run = wonder3d(&["reconstruct", v, "--out", &failed, "--enhancer", &out("no-such-enhancer")]);
    assert_eq!(run.status.code(), Some(1));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("no-such-enhancer") && err.contains("docs/weights.md"), "{err}");
    assert!(!std::path::Path::new(&failed).exists());

    let refined = out("refined.glb");
    let run = wonder3d(&[
        "reconstruct",
        v,
        "--out",
        &refined,
        "--preset",
        "fast",
        "--enhancer",
        e,
        "--refine",
        "1",
        "--refine-size",
        "32",
        "--texture-size",
        "512",
        "--quiet",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(String::from_utf8_lossy(&run.stdout).contains("refined with the diffusion enhancer: 1 iteration(s)"));
    let mesh = wonder3d::load_mesh(&refined).unwrap();
    assert!(mesh.texture().is_some());
}
