//! `wonder3d train`: a stage run on the tiny model, resumed, its checkpoint generating views;
//! bad input refused before the model loads.

use crate::common::{tiny_weights, wonder3d};

fn stderr(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// `wonder3d dataset` of the bundled spot at the tiny model's 32² into `dir/data`.
fn spot_dataset(dir: &std::path::Path, samples: &str) -> std::path::PathBuf {
    let data = dir.join("data");
    let spot = concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets/spot.obj");
    let out =
        wonder3d(&["dataset", spot, "--out", data.to_str().unwrap(), "--samples", samples, "--size", "32", "--quiet"]);
    assert!(out.status.success(), "{}", stderr(&out));
    data
}

#[test]
fn a_stage_runs_resumes_and_its_checkpoint_generates() {
    let dir = tempfile::tempdir().unwrap();
    let data = spot_dataset(dir.path(), "2");
    let run = dir.path().join("run");
    // A tiny stage-3 run into `out` to `steps`, with `extra` arguments.
    let train_into = |out: &std::path::Path, steps: &str, extra: &[&str]| {
        let mut args = vec![
            "train",
            "--stage",
            "3",
            "--data",
            data.to_str().unwrap(),
            "--init",
            &tiny_weights(),
            "--out",
            out.to_str().unwrap(),
            "--steps",
            steps,
            "--lr",
            "1e-3",
            "--warmup",
            "1",
            "--checkpoint-every",
            "2",
            "--quiet",
        ]
        .into_iter()
        .map(String::from)
        .collect::<Vec<_>>();
        args.extend(extra.iter().map(|a| a.to_string()));
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        wonder3d(&args)
    };
    let train = |steps: &str, resume: bool| train_into(&run, steps, if resume { &["--resume"] } else { &[] });
    let first = train("2", false);
    assert!(first.status.success(), "{}", stderr(&first));
    let again = train("4", false);
    assert!(!again.status.success() && stderr(&again).contains("--resume"), "{}", stderr(&again));
    let resumed = train("4", true);
    assert!(resumed.status.success(), "{}", stderr(&resumed));
    let log = std::fs::read_to_string(run.join("train_log.jsonl")).unwrap();
    assert_eq!(log.lines().count(), 4, "{log}");
    let views = dir.path().join("views");
    let input = data.join("spot_000").join("colour_front.png");
    let generated = wonder3d(&[
        "generate",
        input.to_str().unwrap(),
        "--weights",
        run.join("checkpoint").to_str().unwrap(),
        "--out",
        views.to_str().unwrap(),
        "--steps",
        "2",
        "--quiet",
    ]);
    assert!(generated.status.success(), "{}", stderr(&generated));
    assert!(views.join("normal_front.png").is_file());
    // A cool-down: after the warm-up the learning rate falls linearly to 0 at --steps.
    let cool = dir.path().join("cool");
    let out = train_into(&cool, "3", &["--lr-schedule", "linear"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let log = std::fs::read_to_string(cool.join("train_log.jsonl")).unwrap();
    let lrs: Vec<f64> =
        log.lines().map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["lr"].as_f64().unwrap()).collect();
    assert_eq!(lrs.len(), 3, "{log}");
    assert!(lrs.iter().zip([0.0, 1e-3, 5e-4]).all(|(a, b)| (a - b).abs() < 1e-12), "{lrs:?}");
}

#[test]
fn train_refuses_bad_input_before_loading_the_model() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nothing");
    let out = wonder3d(&[
        "train",
        "--stage",
        "2",
        "--data",
        missing.to_str().unwrap(),
        "--init",
        &tiny_weights(),
        "--out",
        dir.path().join("run").to_str().unwrap(),
    ]);
    assert!(!out.status.success() && stderr(&out).contains("dataset.json"), "{}", stderr(&out));
    let out = wonder3d(&["train", "--stage", "4", "--data", "x", "--init", "y", "--out", "z"]);
    assert!(!out.status.success() && stderr(&out).contains("--stage"), "{}", stderr(&out));
    let out = wonder3d(&["train", "--stage", "1", "--data", "x", "--init", "y", "--out", "z", "--lr", "0"]);
    assert!(!out.status.success() && stderr(&out).contains("learning rate"), "{}", stderr(&out));
    // A cool-down that would end inside the warm-up is named, and no run folder is left.
    let data = spot_dataset(dir.path(), "1");
    let run = dir.path().join("run");
    let (data, run) = (data.to_str().unwrap(), run.to_str().unwrap());
    let args = ["--steps", "5", "--warmup", "10", "--lr-schedule", "linear", "--quiet"];
    let mut all = vec!["train", "--stage", "3", "--data", data, "--init"];
    let weights = tiny_weights();
    all.extend([weights.as_str(), "--out", run]);
    all.extend(args);
    let out = wonder3d(&all);
    assert!(!out.status.success() && stderr(&out).contains("lr_schedule"), "{}", stderr(&out));
    assert!(!dir.path().join("run").exists(), "a refused run left its folder");
    // An earlier stage on a checkpoint that already has the cross-domain attention names the
    // flag and the checkpoint (it used to name an internal field, `batch.domains`).
    for stage in ["1", "2"] {
        let out = wonder3d(&["train", "--stage", stage, "--data", data, "--init", &weights, "--out", run, "--quiet"]);
        let err = stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{err}");
        assert!(err.contains("--stage") && err.contains("wonder3d_tiny") && !err.contains("batch."), "{err}");
    }
    assert!(!dir.path().join("run").exists(), "a refused run left its folder");
}

/// `--device wgpu` in a build without the `wgpu` feature names the feature before the model
/// loads, and leaves no run behind.
#[test]
#[cfg(not(feature = "wgpu"))]
fn training_on_a_gpu_needs_the_wgpu_build() {
    let dir = tempfile::tempdir().unwrap();
    let data = spot_dataset(dir.path(), "1");
    let run = dir.path().join("run");
    let missing = dir.path().join("no-model");
    for (init, device, expected) in
        [(missing.to_str().unwrap().to_string(), "wgpu", "`wgpu` feature"), (tiny_weights(), "tpu", "cpu, wgpu")]
    {
        let out = wonder3d(&[
            "train",
            "--stage",
            "3",
            "--data",
            data.to_str().unwrap(),
            "--init",
            &init,
            "--out",
            run.to_str().unwrap(),
            "--device",
            device,
            "--quiet",
        ]);
        let err = stderr(&out);
        assert!(!out.status.success() && err.contains(expected) && !err.contains("no-model"), "{err}");
        assert!(!run.exists(), "nothing is written");
    }
}
