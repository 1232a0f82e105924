//! Mesh file IO (OBJ + MTL, PLY, glTF / GLB) and atomic writes.
//!
//! [`load_mesh`] and [`save_mesh`] pick the format from the file extension. Every write
//! goes to a temporary file beside the destination and is renamed into place, so a
//! failed write never leaves a half-written file.

mod gltf_io;
mod obj;
mod ply;

use std::path::Path;

pub use crate::exr_limits::{MAX_EXR_PIXELS, check_exr_size};
pub use crate::files::{
    file_in_the_way, fnv1a64, is_mount_point, replaceable_folder, write_atomic, write_atomic_all, write_dir_atomic,
};
pub use gltf_io::{read_glb_bytes, read_gltf, write_glb};
pub use obj::{read_obj, write_obj};
pub use ply::{read_ply, write_ply};

use crate::error::{Error, Result};
use crate::mesh::Mesh;

/// Reads a mesh from an `.obj`, `.ply`, `.glb` or `.gltf` file.
pub fn load_mesh(path: impl AsRef<Path>) -> Result<Mesh> {
    let path = path.as_ref();
    match extension(path).as_str() {
        "obj" => read_obj(path),
        "ply" => read_ply(path),
        "glb" | "gltf" => read_gltf(path),
        other => Err(Error::format(path, "file extension", format!("one of .obj, .ply, .glb, .gltf, got {other:?}"))),
    }
}

/// Writes a mesh to an `.obj` (+ `.mtl` and `.png` when textured), `.ply` or `.glb` file.
pub fn save_mesh(path: impl AsRef<Path>, mesh: &Mesh) -> Result<()> {
    let path = path.as_ref();
    match extension(path).as_str() {
        "obj" => write_obj(path, mesh),
        "ply" => write_ply(path, mesh),
        "glb" => write_glb(path, mesh),
        other => {
            Err(Error::format(path, "file extension", format!("one of .obj, .ply, .glb for writing, got {other:?}")))
        }
    }
}

fn extension(path: &Path) -> String {
    path.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase()
}
