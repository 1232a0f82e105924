//! Continuous remeshing (Palfinger 2022, "Continuous Remeshing for Inverse Rendering") for
//! wonder3d-rs: a per-vertex Adam-like optimizer of vertex positions whose step size is
//! relative to a per-vertex target edge length, and remesh operations (edge collapse,
//! split, flip, pack) that run after every step and carry all per-vertex state along.
//! Two steps that are not in the reference make every remesh leave a clean surface: interior
//! valence-3 vertices that block collapses are removed, and flipped or zero-area faces left
//! by the motion are untangled by moving their vertices towards their 1-ring means
//! ([`RemeshOptions::remove_valence3`], [`RemeshOptions::fold_relaxation_rounds`]; both can
//! be turned off).
//!
//! Meshes are plain arrays: `Vec<[f32; 3]>` positions and `Vec<[u32; 3]>` triangles,
//! counter-clockwise seen from outside; lengths are in mesh units (the unit cube
//! `[-0.5, 0.5]³` for normalised meshes). [`MeshOptimizer`] is the usual entry point;
//! [`ops`] exposes the individual operations on explicit face masks, [`EdgeTable`] the
//! edge connectivity, [`check_manifold`] the invariants, [`icosphere`] a start mesh.
//! [`simplify`] is the other direction: quadric edge collapse down to a distance
//! tolerance, for meshes that carry more triangles than their shape needs.
//!
//! ```
//! use w3d_remesh::{MeshOptimizer, RemeshOptions, icosphere};
//!
//! // Shrink a sphere of radius 0.5 towards radius 0.3: loss = Σ (|x| − 0.3)².
//! let sphere = icosphere(2, 0.5)?;
//! let mut opt = MeshOptimizer::from_mesh(&sphere, RemeshOptions::default())?;
//! for _ in 0..60 {
//!     let grad: Vec<[f32; 3]> = opt
//!         .positions()
//!         .iter()
//!         .map(|p| {
//!             let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
//!             p.map(|c| 2.0 * (r - 0.3) * c / r)
//!         })
//!         .collect();
//!     opt.step(&grad)?;
//!     opt.remesh();
//! }
//! let mesh = opt.to_mesh()?;
//! assert!(mesh.topology().is_watertight());
//! let mean_radius: f32 = mesh.positions().iter().map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()).sum::<f32>()
//!     / mesh.vertex_count() as f32;
//! assert!((mean_radius - 0.3).abs() < 0.01, "{mean_radius}");
//! # Ok::<(), w3d_core::Error>(())
//! ```

mod edges;
pub mod ops;
mod optimizer;
mod options;
mod rows;
mod shapes;
mod simplify;
mod topology;

pub use edges::{EdgeTable, NONE};
pub use ops::{RemeshParams, RemeshStats};
pub use optimizer::{CurvatureHint, MeshOptimizer, vertex_curvatures};
pub use options::RemeshOptions;
pub use rows::VertexRows;
pub use shapes::{geodesic_sphere, icosphere};
pub use simplify::{Simplified, SimplifyOptions, SimplifyReport, simplify, simplify_keeping};
pub use topology::{ManifoldSummary, check_manifold};
