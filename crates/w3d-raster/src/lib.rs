//! A differentiable CPU rasteriser for wonder3d-rs, replacing nvdiffrast: [`rasterize`]
//! (front-most triangle, perspective-correct barycentrics and depth per pixel),
//! [`interpolate`], [`antialias`] (analytic silhouette anti-aliasing, the source of
//! silhouette gradients) and [`texture`] (bilinear sampling), each with an explicit
//! backward pass on plain data, plus render helpers that draw normal / mask / depth /
//! colour images of a [`w3d_core::Mesh`] through a whole [`w3d_core::ViewRig`].
//!
//! Conventions: positions are world coordinates of the canonical frame (`docs/architecture.md`, "Conventions");
//! images are row-major `[H][W][C]` with the origin top-left and pixel centres at `+0.5`,
//! exactly as [`w3d_core::Camera::project`]; depth is the distance along the camera's
//! viewing axis in world units. Backward functions take the loss gradient of their output
//! and return gradients of their inputs (`Vec<[f32; 3]>` per vertex for positions,
//! accumulated in f64). Work runs on the rayon pool; results do not depend on the
//! number of threads.
//!
//! ```
//! use w3d_core::{Camera, Projection, glam::Vec3};
//! use w3d_raster::{EdgeTopology, antialias, antialias_backward, rasterize};
//!
//! // A triangle seen by an orthographic camera on +z.
//! let positions = [[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]];
//! let triangles = [[0, 1, 2]];
//! let camera = Camera::look_at(Vec3::Z * 2.0, Vec3::ZERO, Vec3::Y, Projection::Orthographic { half_height: 1.0 })?;
//! let raster = rasterize(&positions, &triangles, &camera, 32, 32)?;
//! assert_eq!(raster.triangle_at(16, 16), Some(0));
//! assert!((raster.depth[16 * 32 + 16] - 2.0).abs() < 1e-6);
//!
//! // Anti-alias the coverage mask and pull a "grow the mask" loss back to the vertices.
//! let mask = raster.coverage();
//! let topology = EdgeTopology::new(&positions, &triangles)?;
//! let aa = antialias(&mask, 1, &raster, &positions, &triangles, &topology)?;
//! let grad_out = vec![-1.0; mask.len()]; // d(−Σ mask)/d mask
//! let grad = antialias_backward(&aa, &mask, 1, &raster, &positions, &triangles, &grad_out)?;
//! // Descending the gradient moves the apex up: the triangle grows.
//! assert!(grad.positions[2][1] < 0.0);
//! # Ok::<(), w3d_core::Error>(())
//! ```

// Layers, bottom-up: each group imports only from itself and the groups above it.
// Test helpers.
#[cfg(test)]
mod tests_util;

// One camera's world → clip → pixel mapping.
mod project;

// Rasterisation: triangle ids, barycentrics and depth per pixel.
mod raster;

// Operations on a raster: attribute interpolation, silhouette anti-aliasing, texture sampling.
mod antialias;
mod interpolate;
mod texture;

// Render helpers over whole rigs.
mod render;

// Gradient checks across the operations.
#[cfg(test)]
mod gradient_checks;

pub use antialias::{AntialiasGrad, Antialiased, EdgeTopology, NO_VERTEX, antialias, antialias_backward};
pub use interpolate::{InterpolateGrad, interpolate, interpolate_backward};
pub use project::NEAR_DEPTH;
pub use raster::{NO_TRIANGLE, Raster, rasterize, rasterize_backward, rasterize_views};
pub use render::{
    MAX_VIEW_SIZE, NormalMode, rasterize_rig, render_colours, render_depth, render_mask, render_normals,
    render_oracle_views,
};
pub use texture::{TextureGrad, WrapMode, texture, texture_backward};
