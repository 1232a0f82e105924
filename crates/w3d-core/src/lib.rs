//! Core types of wonder3d-rs: [`Mesh`], [`Camera`], the view rigs ([`ViewRig`]), per-view
//! images ([`ViewSet`], [`Image`]), mesh and image file IO, and the one [`Error`] type.
//!
//! Cargo features:
//! - `io` (default): mesh files (OBJ, PLY, glTF / GLB: the `io` module, `load_mesh`,
//!   `save_mesh`), images (`Image::read` for PNG / JPEG / WebP, `Image::read_png`,
//!   `Image::write_exr`, …), view-set
//!   folders (`ViewSet::save` / `ViewSet::load`), rig JSON (`ViewRig::save_json` /
//!   `ViewRig::load_json`) and atomic writes (`io::write_atomic`). Implies `serde`.
//! - `serde`: `Serialize` / `Deserialize` for [`Camera`], [`Projection`], [`RigView`] and
//!   [`ViewRig`].
//!
//! An engine that only needs the in-memory types (to run mesh extraction, say) depends on
//! `w3d-core` with `default-features = false` and pulls no file-format parser.
//!
//! Everything here is plain data: slices of `[f32; 3]` positions and `[u32; 3]`
//! counter-clockwise triangles, `[H][W][C]` row-major float images, and `glam` vectors for
//! small math. The canonical frame is right-handed and y-up, with the input (front)
//! camera on +z looking along −z (see `docs/architecture.md`, "Conventions").
//!
//! ```
//! use w3d_core::{Mesh, ViewRig};
//!
//! // A unit right tetrahedron, normalised into the unit cube.
//! let positions = vec![[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]];
//! let triangles = vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
//! let mut mesh = Mesh::new(positions, triangles)?;
//! mesh.normalize_unit_cube();
//! let topology = mesh.topology();
//! assert!(topology.is_watertight());
//! assert_eq!(topology.genus(), Some(0));
//!
//! // Where does the front camera of the Wonder3D rig see the first corner?
//! let rig = ViewRig::wonder3d_ortho();
//! let front = &rig.views[0].camera;
//! let pixel = front.project(mesh.positions()[0].into(), 256, 256);
//! assert!(pixel.x < 128.0 && pixel.y > 128.0); // lower left of the image centre
//! # Ok::<(), w3d_core::Error>(())
//! ```

// Layers, bottom-up: each group imports only from itself and the groups above it.
// The error type; the options structs' setter macro.
mod error;
mod setters;

// Plain helpers: file reads and atomic writes, the EXR size limit, welding by position.
#[cfg(feature = "io")]
mod exr_limits;
#[cfg(feature = "io")]
mod files;
mod weld;

// Cameras, images and normals on plain arrays; the training-set format's fixed names.
pub mod camera;
pub mod dataset;
pub mod image;
pub mod normals;

// The mesh type and view rigs.
pub mod mesh;
pub mod rig;

// Queries and collections over meshes, images and rigs; mesh file formats.
mod intersect;
#[cfg(feature = "io")]
pub mod io;
pub mod viewset;

pub use camera::{Camera, Projection, Ray};
pub use error::{Error, Result};
pub use image::{Image, ReadLimits};
pub use intersect::{self_intersections, self_intersections_involving};
#[cfg(feature = "io")]
pub use io::{load_mesh, save_mesh};
pub use mesh::{Mesh, Normalization, Topology};
pub use rig::{RigView, ViewRig};
pub use viewset::{ViewImages, ViewSet};

/// Re-exported so users of the public API get the same `glam` version.
pub use glam;
