//! `cargo xtask <command>`: project automation that needs more than cargo.
//!
//! - `cargo xtask deny`: runs `cargo deny check licenses bans sources` (advisories need a
//!   network), installing cargo-deny 0.20.2 into `target/tools` first if it is not on `PATH`.
//! - `cargo xtask validate-glb FILE...`: runs the Khronos glTF validator (npm package
//!   `gltf-validator`, installed into `target/tools/node` on first use; needs `node` and
//!   `npm`) and fails if any file has an error.

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
    /// Validate GLB / glTF files with the Khronos glTF validator (installed on demand).
    ValidateGlb {
        /// Files to validate.
        #[arg(required = true)]
        files: Vec<PathBuf>,
    },
}

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("xtask lives in the workspace").to_path_buf()
}

fn run(cmd: &mut Command) -> Result<(), String> {
    let status = cmd.status().map_err(|e| format!("cannot start {cmd:?}: {e}"))?;
    if status.success() { Ok(()) } else { Err(format!("{cmd:?} failed with {status}")) }
}

/// `cargo-deny` from `PATH`, if it runs.
fn cargo_deny_on_path() -> Option<PathBuf> {
    let ok = Command::new("cargo-deny").arg("--version").output().is_ok_and(|o| o.status.success());
    ok.then(|| PathBuf::from("cargo-deny"))
}

fn deny() -> Result<(), String> {
    let root = workspace_root();
    let tools = root.join("target").join("tools");
    let bin = cargo_deny_on_path().unwrap_or_else(|| tools.join("bin").join("cargo-deny"));
    if bin.is_absolute() && !bin.is_file() {
        eprintln!("installing cargo-deny 0.20.2 into {}", tools.display());
        run(Command::new("cargo")
            .args(["install", "--locked", "--version", "0.20.2", "--root"])
            .arg(&tools)
            .arg("cargo-deny"))?;
    }
    run(Command::new(&bin).current_dir(&root).args([
        "deny",
        "check",
        "--hide-inclusion-graph",
        "licenses",
        "bans",
        "sources",
    ]))
}

/// The pinned validator release and the script that runs it on each file.
const GLTF_VALIDATOR: &str = "gltf-validator@2.0.0-dev.3.10";
const VALIDATE_SCRIPT: &str = r#"import validator from 'gltf-validator';
import fs from 'fs';
let failed = false;
for (const f of process.argv.slice(2)) {
  const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(f)));
  const i = report.issues;
  console.log(`${f}: ${i.numErrors} errors, ${i.numWarnings} warnings, ${i.numInfos} infos`);
  for (const m of i.messages.filter((m) => m.severity <= 1)) console.log(`  ${m.code}: ${m.message} ${m.pointer ?? ''}`);
  if (i.numErrors > 0) failed = true;
}
process.exit(failed ? 1 : 0);
"#;

fn validate_glb(files: &[PathBuf]) -> Result<(), String> {
    let dir = workspace_root().join("target").join("tools").join("node");
    if !dir.join("node_modules").join("gltf-validator").is_dir() {
        std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        eprintln!("installing {GLTF_VALIDATOR} into {}", dir.display());
        run(Command::new("npm").args(["install", "--silent", "--no-save", "--prefix"]).arg(&dir).arg(GLTF_VALIDATOR))?;
    }
    let script = dir.join("validate.mjs");
    std::fs::write(&script, VALIDATE_SCRIPT).map_err(|e| format!("{}: {e}", script.display()))?;
    let files: Vec<PathBuf> = files.iter().map(|f| std::path::absolute(f).unwrap_or_else(|_| f.clone())).collect();
    run(Command::new("node").current_dir(&dir).arg(&script).args(&files))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Task::Deny => deny(),
        Task::ValidateGlb { files } => validate_glb(&files),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xtask: {e}");
            ExitCode::FAILURE
        }
    }
}
