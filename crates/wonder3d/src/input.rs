//! Inputs: reading a photo or an RGBA image from a file and preparing it for the model
//! (background removal when there is no alpha, the authors' framing) with the `w3d-photo`
//! crate; reading a mesh that must have a surface.

use std::path::Path;

use w3d_core::{Error, Image, Mesh, Result};
use w3d_photo::{PrepareOptions, Prepared};

/// Reads an image file (PNG, JPEG or WebP, recognised from its bytes; EXIF orientation
/// applied) and prepares it for the model with [`w3d_photo::prepare`]: its own alpha when it
/// has a meaningful one, else automatic background removal (refused, with the reasons,
/// below `options.min_confidence`), then cropped, scaled and centred unless
/// `options.crop` is off. Errors name the file.
pub fn prepare_image(path: impl AsRef<Path>, options: &PrepareOptions) -> Result<Prepared> {
    let path = path.as_ref();
    let image = Image::read(path)?;
    w3d_photo::prepare(&image, options).map_err(|e| e.in_file(path))
}

/// The mesh at `path`, refused unless it has a surface: a mesh whose triangles all have zero
/// area renders as empty views and has no distance to anything. `role` names it in the error
/// (`PRED`, `MESH`, `--enhancer oracle:`, `mesh`), so a command reading several meshes says
/// which one is at fault.
pub fn load_mesh_with_surface(path: impl AsRef<Path>, role: &str) -> Result<Mesh> {
    let path = path.as_ref();
    let mesh = w3d_core::load_mesh(path)?;
    check_surface(&mesh, &format!("{role} {}", path.display()))?;
    Ok(mesh)
}

/// Fails, naming `what`, unless `mesh` has a surface (a positive, finite total area): the
/// check of [`load_mesh_with_surface`] for a mesh already in memory.
pub fn check_surface(mesh: &Mesh, what: &str) -> Result<()> {
    if mesh.surface_area().partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return Err(Error::invalid(what, "a mesh with a surface (its triangles all have zero area)"));
    }
    Ok(())
}
