//! Helpers shared by the integration tests (`tests/files.rs`).
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use w3d_core::Error;

/// `../shared/data/meshes` beside the repository.
pub fn shared_meshes() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/meshes")
}

/// The repository's `assets/`.
pub fn assets() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../assets")
}

/// Every mesh file (OBJ, PLY) of the shared test data, sorted.
pub fn shared_mesh_files() -> Vec<PathBuf> {
    let dir = shared_meshes();
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e} (tests need ../shared beside the repository)", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("obj" | "ply")))
        .collect();
    files.sort();
    files
}

/// Writes `bytes` to `dir/name` and returns the path.
pub fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, bytes).unwrap();
    p
}

/// The error's message, after checking that it names `path`.
pub fn message_for(err: Error, path: &Path) -> String {
    let msg = err.to_string();
    assert!(msg.contains(&path.display().to_string()), "error should name {}: {msg}", path.display());
    msg
}
