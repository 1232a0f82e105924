//! `cargo xtask slurm-check` submits the Slurm script of `docs/scale.md` as the page shows it,
//! changed only where this machine must differ. The check itself needs root and Slurm (CI
//! runs it); this test needs neither: it fails as soon as the page's script no longer has
//! the lines the check changes, so a documentation edit cannot quietly break the check.

use std::process::Command;

#[test]
fn the_documented_slurm_script_still_has_the_lines_the_check_changes() {
    let out = Command::new(env!("CARGO_BIN_EXE_xtask"))
        .args(["slurm-check", "--script-only"])
        .output()
        .expect("the xtask binary runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}{stdout}", String::from_utf8_lossy(&out.stderr));
    let script = &stdout[stdout.find("#!/bin/bash").expect("the script is printed")..];
    for local in
        ["#SBATCH --array=0-2", "--cpus-per-task=1", "--resume", "#SBATCH --requeue", "target/release/wonder3d batch"]
    {
        assert!(script.contains(local), "`{local}` missing from:\n{script}");
    }
    assert!(!script.contains("/shared/"), "a documented path left in:\n{script}");
}
