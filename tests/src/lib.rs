//! Shared helpers of the end-to-end tests: where the test data lives.

use std::path::PathBuf;

/// The workspace root.
pub fn workspace_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// `../shared/data/meshes` beside the workspace (the project's real test meshes).
pub fn shared_meshes() -> PathBuf {
    workspace_root().join("..").join("shared").join("data").join("meshes")
}

/// The bundled `assets/` folder.
pub fn assets() -> PathBuf {
    workspace_root().join("assets")
}

/// The mesh files of `../shared/data/meshes` (OBJ and PLY), sorted by name.
pub fn shared_mesh_files() -> Vec<PathBuf> {
    let dir = shared_meshes();
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e} (the tests need ../shared beside the repository)", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("obj" | "ply")))
        .collect();
    files.sort();
    files
}
