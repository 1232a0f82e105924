//! **wonder3d**: one photo of an object in, a textured, watertight 3D mesh out — a Rust
//! reimplementation of Wonder3D++. This facade re-exports the workspace's crates under one
//! name; depend on a single `w3d-*` crate instead when you need only one stage (for
//! example [`core`] for meshes, cameras and IO).
//!
//! ```
//! use wonder3d::{ViewRig, load_mesh};
//!
//! let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets/spot.obj");
//! let mut spot = load_mesh(path)?;
//! spot.normalize_unit_cube();
//! let rig = ViewRig::wonder3d_ortho();
//! assert_eq!(rig.views.iter().map(|v| v.name.as_str()).collect::<Vec<_>>(),
//!            ["front", "front_right", "right", "back", "left", "front_left"]);
//! assert!(spot.texture().is_some());
//! # Ok::<(), wonder3d::Error>(())
//! ```

/// Meshes, cameras, view rigs, images, view sets and file IO (the `w3d-core` crate).
pub use w3d_core as core;
pub use w3d_core::{
    Camera, Error, Image, Mesh, Projection, Result, RigView, ViewImages, ViewRig, ViewSet, load_mesh, save_mesh,
};
/// The Wonder3D++ multi-view diffusion model on Burn: the multi-view cross-domain UNet, VAE,
/// CLIP image encoder, DDIM sampling and inversion, and `MultiViewPipeline` (image → 6 views
/// × {normal, colour} → `ViewSet`) (the `w3d-diffusion` crate; feature `diffusion`, default).
#[cfg(feature = "diffusion")]
pub use w3d_diffusion as diffusion;
/// Evaluation metrics: Chamfer, F-score, volume IoU, normal consistency, PSNR / SSIM
/// (the `w3d-eval` crate).
pub use w3d_eval as eval;
/// The differentiable CPU rasteriser and render helpers (the `w3d-raster` crate).
pub use w3d_raster as raster;
/// Mesh extraction from normal maps: normal integration, coarse reconstruction (the
/// `w3d-recon` crate).
pub use w3d_recon as recon;
/// Continuous remeshing: the mesh optimiser and remesh operations (the `w3d-remesh` crate).
pub use w3d_remesh as remesh;
/// Texturing: vertex-colour fusion, UV atlas, baking and dilation (the `w3d-texture`
/// crate).
pub use w3d_texture as texture;
