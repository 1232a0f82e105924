//! The `cargo xtask` command line: the commands CI and the docs rely on exist, and a
//! mistyped one fails with clap's message instead of doing something else. (This file also
//! makes `cargo test --workspace` build the xtask binary, which `.ci/run` then uses.)

use std::process::Command;

fn xtask(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_xtask")).args(args).output().expect("the xtask binary runs")
}

#[test]
fn help_lists_the_commands_ci_uses() {
    let out = xtask(&["--help"]);
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout);
    for command in ["deny", "validate-glb", "load-glb", "bench", "chart", "fixtures", "package", "build-parity"] {
        assert!(help.contains(command), "`{command}` missing from:\n{help}");
    }
}

#[test]
fn an_unknown_command_is_an_error() {
    let out = xtask(&["frobnicate"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("frobnicate"));
}

/// A schedule of the small model's recipe that cannot run is refused before the run folder is
/// made, and the small model's scoring names the objects it knows when asked for another.
#[test]
fn bad_recipe_and_scoring_flags_are_refused_before_any_work() {
    let dir = std::env::temp_dir().join(format!("xtask-cli-{}", std::process::id()));
    let out = dir.join("run");
    let out_s = out.to_str().unwrap();
    for steps in ["800,4000", "800,0,1000", "1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1,1"] {
        let run = xtask(&["train-small", "--out", out_s, "--phase-steps", steps]);
        let err = String::from_utf8_lossy(&run.stderr);
        assert!(
            !run.status.success() && err.contains("--phase-steps") && err.contains("three stages"),
            "{steps}: {err}"
        );
        assert!(!out.exists(), "{steps}: the run folder was made");
    }
    let run = xtask(&["eval-small", "--out", out_s, "--objects", "spot,teapot"]);
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success() && err.contains("teapot") && err.contains("koala_low_resolution"), "{err}");
    assert!(!out.exists(), "eval-small made its output folder");
    let _ = std::fs::remove_dir_all(&dir);
}
