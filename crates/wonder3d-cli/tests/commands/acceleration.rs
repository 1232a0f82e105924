//! The training-free acceleration flags (`--guidance-interval`, `--cache-interval`,
//! `--cache-depth`, `--products`, `--token-merge`) of `generate`, `run`, `batch`, `demo
//! --from-image` and `refine`: bad values are refused naming the flag before any weights load,
//! good ones reach the sampling loop and the reports name them.
#![cfg(feature = "diffusion")]

use std::path::{Path, PathBuf};

use crate::common::{self, s, wonder3d, write_input};

/// The small model shipped in `assets/model-small` (generates 64² views in about a second).
fn small_model() -> String {
    concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets/model-small").to_string()
}

/// The tiny random-weight enhancer of w3d-diffusion's fixtures.
fn tiny_enhancer() -> String {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../w3d-diffusion/tests/fixtures/enhancer");
    dir.to_str().unwrap().to_string()
}

/// The bad values of the issue, the flag each must name and a piece of what it expects.
const BAD: [(&str, &str, &str); 8] = [
    ("--cache-interval", "0", "from 1 to 50"),
    ("--cache-interval", "51", "from 1 to 50"),
    ("--guidance-interval", "1.2,0.3", "from 0 to 1"),
    ("--guidance-interval", "0.7,0.1", "LO ≤ HI"),
    ("--guidance-interval", "0.5", "LO,HI"),
    ("--token-merge", "0.95", "from 0 to 0.9"),
    ("--products", "fp8", "auto, f32, bf16"),
    ("--cache-depth", "-1", "from 0 to 63"),
];

#[test]
fn bad_acceleration_values_are_refused_naming_the_flag_before_any_weights_load() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("disc.png");
    write_input(&input);
    // A model directory that does not exist: an error naming it would mean the weights were
    // looked for before the flag was checked.
    let missing = dir.path().join("no-model");
    let manifest = dir.path().join("items.txt");
    std::fs::write(&manifest, "disc.png\n").unwrap();
    let (i, m, out) = (s(&input), s(&missing), dir.path().join("out"));
    let glb = dir.path().join("x.glb");
    let commands: [Vec<&str>; 5] = [
        vec!["generate", i, "--weights", m, "--out", s(&out)],
        vec!["run", i, "--weights", m, "--out", s(&glb)],
        vec!["batch", s(&manifest), "--weights", m, "--out", s(&out)],
        vec!["demo", "--from-image", "--weights", m, "--out", s(&out)],
        vec!["refine", i, i, "--enhancer", m, "--out", s(&glb)],
    ];
    for command in &commands {
        for (flag, value, expected) in BAD {
            let mut args = command.clone();
            let joined = format!("{flag}={value}");
            args.push(&joined);
            let run = wonder3d(&args);
            let err = String::from_utf8_lossy(&run.stderr);
            assert_eq!(run.status.code(), Some(2), "{args:?}: {err}");
            assert!(err.contains(flag) && err.contains(expected), "{args:?}: {err}");
            assert!(!err.contains("no-model"), "{args:?}: the flag comes before the weights: {err}");
        }
    }
    assert!(!out.exists() && !glb.exists(), "nothing is written");
}

#[test]
fn a_cache_depth_beyond_the_model_is_named_before_sampling() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("disc.png");
    write_input(&input);
    let out = dir.path().join("views");
    // The small model's UNet has 6 skips (0 to 5).
    let run = wonder3d(&[
        "generate",
        s(&input),
        "--weights",
        &small_model(),
        "--out",
        s(&out),
        "--cache-interval",
        "2",
        "--cache-depth",
        "6",
        "--quiet",
    ]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(1), "{err}");
    assert!(err.contains("--cache-depth") && err.contains("0 to 5") && err.contains("found 6"), "{err}");
    assert!(!out.exists(), "nothing is written");
    // Without caching the depth is unused, and accepted.
    let run = wonder3d(&[
        "generate",
        s(&input),
        "--weights",
        &small_model(),
        "--out",
        s(&out),
        "--steps",
        "2",
        "--cache-depth",
        "6",
        "--products",
        "f32",
        "--quiet",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(!String::from_utf8_lossy(&run.stdout).contains("acceleration"), "none is not named");
}

/// The front normal view of a view-set folder.
fn front_normal(views: &Path) -> Vec<u8> {
    std::fs::read(views.join("normal_front.png")).unwrap()
}

#[test]
fn generate_and_run_sample_with_the_accelerations_and_name_them() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("disc.png");
    write_input(&input);
    let model = small_model();
    let generate = |out: &Path, extra: &[&str]| {
        let mut args = vec!["generate", s(&input), "--weights", &model, "--out", s(out), "--steps", "4", "--quiet"];
        args.extend_from_slice(extra);
        let run = wonder3d(&args);
        assert!(run.status.success(), "{extra:?}: {}", String::from_utf8_lossy(&run.stderr));
        (String::from_utf8_lossy(&run.stdout).into_owned(), String::from_utf8_lossy(&run.stderr).into_owned())
    };
    let reference = dir.path().join("reference");
    let (summary, _) = generate(&reference, &["--products", "f32"]);
    assert!(!summary.contains("acceleration"), "{summary}");
    // The default products: bf16 where the CPU has them, silently f32 elsewhere.
    let default = dir.path().join("default");
    let (summary, err) = generate(&default, &[]);
    assert!(!err.contains("bf16"), "{err}");
    let bf16 = wonder3d::diffusion::compute::Products::Bf16.supported();
    assert_eq!(summary.contains("(acceleration: bf16 products)"), bf16, "{summary}");
    let cached = dir.path().join("cached");
    let (summary, _) =
        generate(&cached, &["--cache-interval", "2", "--guidance-interval", "0.1,0.7", "--products", "f32"]);
    assert!(summary.contains("(acceleration: guidance in [0.1, 0.7], DeepCache every 2 from skip 1)"), "{summary}");
    assert_ne!(front_normal(&cached), front_normal(&reference), "the accelerations change the sampling");

    // bf16 products: where this CPU lacks them, one line on stderr says so and the products
    // stay f32 (the summary does not claim them).
    let merged = dir.path().join("merged");
    let (summary, err) = generate(&merged, &["--token-merge", "0.5", "--products", "bf16"]);
    let notes: Vec<&str> = err.lines().filter(|l| l.contains("bf16")).collect();
    if wonder3d::diffusion::compute::Products::Bf16.supported() {
        assert!(notes.is_empty(), "{err}");
        assert!(summary.contains("(acceleration: token merging 0.5, bf16 products)"), "{summary}");
    } else {
        assert_eq!(notes.len(), 1, "exactly one line: {err}");
        assert!(notes[0].starts_with("note: ") && notes[0].contains("stay f32"), "{err}");
        assert!(summary.contains("(acceleration: token merging 0.5)"), "{summary}");
    }
    // Token merging changes no bit of the small model (its first level has no attention):
    // the views differ from the reference exactly where bf16 ran.
    assert_eq!(front_normal(&merged) != front_normal(&reference), bf16, "bf16 products change the sampling");

    // `run` records them in its report.
    let glb = dir.path().join("disc.glb");
    let report = dir.path().join("report.json");
    let run = wonder3d(&[
        "run",
        s(&input),
        "--weights",
        &model,
        "--out",
        s(&glb),
        "--report",
        s(&report),
        "--steps",
        "4",
        "--cache-interval",
        "2",
        "--guidance-interval",
        "0.1,0.7",
        "--products",
        "f32",
        "--preset",
        "fast",
        "--starts",
        "1",
        "--texture-size",
        "512",
        "--quiet",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let json = common::read_json(&report);
    assert_eq!(json["generation"]["acceleration"], "guidance in [0.1, 0.7], DeepCache every 2 from skip 1", "{json}");
    let summary = String::from_utf8_lossy(&run.stdout);
    assert!(summary.contains("generation (acceleration: guidance in [0.1, 0.7]"), "{summary}");
}

#[test]
fn refine_passes_the_accelerations_to_the_diffusion_enhancer_only() {
    let dir = tempfile::tempdir().unwrap();
    let spot = concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets/spot.obj");
    let views = dir.path().join("views");
    let run = wonder3d(&["render", spot, "--size", "64", "--out", s(&views)]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let coarse = dir.path().join("coarse.ply");
    let run = wonder3d(&["reconstruct", s(&views), "--out", s(&coarse), "--preset", "fast", "--quiet"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let out = dir.path().join("refined.glb");
    let report = dir.path().join("refine.json");
    let enhancer = tiny_enhancer();
    let refine = |enhancer: &str, iterations: &str, depth: &str| {
        wonder3d(&[
            "refine",
            s(&coarse),
            s(&views),
            "--enhancer",
            enhancer,
            "--out",
            s(&out),
            "--report",
            s(&report),
            "--iterations",
            iterations,
            "--size",
            "32",
            "--texture-size",
            "512",
            "--cache-interval",
            "2",
            "--cache-depth",
            depth,
            "--products",
            "f32",
            "--quiet",
        ])
    };
    // The tiny enhancer's UNet has 4 skips: a deeper start reaches its sampling loop, which
    // refuses it, and the error names the flag.
    let run = refine(&enhancer, "1", "11");
    let err = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(1), "{err}");
    assert!(err.starts_with("error: --cache-depth:") && err.contains("found 11"), "{err}");
    assert!(!out.exists());
    // With the identity enhancer the same flags are accepted and change nothing.
    let run = refine("identity", "1", "11");
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let json = common::read_json(&report);
    assert_eq!((json["enhancer"].as_str(), json["acceleration"].as_str()), (Some("identity"), Some("none")), "{json}");
    assert!(!String::from_utf8_lossy(&run.stdout).contains("acceleration"));
    // The diffusion enhancer's report names its settings, as it names the enhancer (with 0
    // iterations nothing is enhanced: the cheap way to see them reach the report).
    let run = refine(&enhancer, "0", "1");
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let json = common::read_json(&report);
    assert_eq!(
        (json["enhancer"].as_str(), json["acceleration"].as_str()),
        (Some("diffusion"), Some("DeepCache every 2 from skip 1")),
        "{json}"
    );
}
