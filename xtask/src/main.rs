//! `cargo xtask <command>`: project automation that needs more than cargo.
//!
//! - `cargo xtask deny`: installs `cargo-deny` (pinned, into `target/tools`) and runs
//!   `cargo deny check licenses bans sources` (advisories need a network).

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(about = "wonder3d-rs project automation")]
struct Cli {
    #[command(subcommand)]
    command: Task,
}

#[derive(Subcommand)]
enum Task {
    /// Check licences, duplicate crates and sources with cargo-deny (installed on demand).
    Deny,
}

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("xtask lives in the workspace").to_path_buf()
}

fn run(cmd: &mut Command) -> Result<(), String> {
    let status = cmd.status().map_err(|e| format!("cannot start {cmd:?}: {e}"))?;
    if status.success() { Ok(()) } else { Err(format!("{cmd:?} failed with {status}")) }
}

fn deny() -> Result<(), String> {
    let root = workspace_root();
    let tools = root.join("target").join("tools");
    let bin = tools.join("bin").join("cargo-deny");
    if !bin.is_file() {
        eprintln!("installing cargo-deny 0.20.2 into {}", tools.display());
        run(Command::new("cargo").args(["install", "--locked", "--version", "0.20.2", "--root"]).arg(&tools).arg("cargo-deny"))?;
    }
    run(Command::new(&bin).current_dir(&root).args(["deny", "check", "licenses", "bans", "sources"]))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Task::Deny => deny(),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xtask: {e}");
            ExitCode::FAILURE
        }
    }
}
