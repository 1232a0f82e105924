//! Runnable examples for wonder3d-rs live in `examples/examples/`; run one with
//! `cargo run --release -p wonder3d-examples --example mesh_stats -- assets/spot.obj`.
//!
//! This library only holds helpers the examples share.

use std::path::PathBuf;

/// The repository's `assets/` folder (bundled demo meshes).
pub fn assets_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join("assets")
}
