//! Meshes shared by the reconstruction tests, normalised to the unit cube without attributes.

use w3d_core::{Mesh, load_mesh};

/// The repository's spot (`assets/spot.obj`).
pub fn spot() -> Mesh {
    normalised(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets/spot.obj"))
}

/// A mesh of `../shared/data/meshes` beside the repository.
pub fn shared_mesh(name: &str) -> Mesh {
    normalised(&format!("{}/../../../shared/data/meshes/{name}", env!("CARGO_MANIFEST_DIR")))
}

fn normalised(path: &str) -> Mesh {
    let mut mesh = load_mesh(path).unwrap().without_attributes();
    mesh.normalize_unit_cube();
    mesh
}
