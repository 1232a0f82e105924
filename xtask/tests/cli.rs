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
