//! Cascaded mesh extraction for wonder3d-rs (Wonder3D++ §"mesh extraction"): the pieces
//! that turn six normal maps and masks into a mesh. So far: [`integrate_normals`]
//! (normal map → depth map, the first step of the geometric initialisation) and
//! [`vertex_normals`] / [`vertex_normals_backward`] (the exact gradient that lets a
//! normal loss move vertices). Frames and units follow `w3d-core`: canonical y-up world
//! frame, depth along each camera's viewing axis in world units.
//!
//! ```
//! use w3d_recon::{vertex_normals, vertex_normals_backward};
//!
//! // A tetrahedron; pull every vertex normal towards +y and get position gradients.
//! let positions = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
//! let triangles = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
//! let normals = vertex_normals(&positions, &triangles)?;
//! assert!((normals[3][2] - 0.0).abs() > 0.1); // the apex normal leans towards +z
//! let grad = vertex_normals_backward(&positions, &triangles, &[[0.0, -1.0, 0.0]; 4])?;
//! assert_eq!(grad.len(), 4);
//! # Ok::<(), w3d_core::Error>(())
//! ```

mod coarse;
mod init;
mod integrate;
mod normals;
mod pipeline;

pub use coarse::{CoarseOptions, CoarseReport, reconstruct_coarse, silhouette_sphere};
pub use init::{InitChoice, InitOptions, InitReport, initial_mesh};
pub use pipeline::{Preset, Progress, ReconOptions, ReconReport, Stage, StageTiming, reconstruct};

pub use integrate::{IntegrateOptions, integrate_normals, integrate_normals_anchored};
pub use normals::{vertex_normals, vertex_normals_backward};
