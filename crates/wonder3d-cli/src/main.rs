//! `wonder3d`: the command-line face of wonder3d-rs.
//!
//! ```text
//! wonder3d info assets/spot.obj          # counts, bbox, watertight, components, genus
//! wonder3d info assets/spot.obj --json   # the same as one JSON object
//! ```

mod info;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "wonder3d", version, about = "One photo in, a textured watertight 3D mesh out (Wonder3D++ in Rust).")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print a mesh's counts, bounding box and topology (merged by position).
    Info(info::InfoArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Info(args) => info::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
