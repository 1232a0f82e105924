//! Cascaded mesh extraction for wonder3d-rs (Wonder3D++ §"mesh extraction"): six normal
//! maps and masks in, a closed mesh out. [`reconstruct`] runs the stages in order:
//!
//! 1. [`initial_mesh`]: front and back normal maps integrated to depth
//!    ([`integrate_normals_anchored`], silhouettes anchored where their rays enter the
//!    visual hull), the concave check, a dense-grid screened Poisson surface carved by the
//!    visual hull, marching tetrahedra and simplification — or a silhouette-sized sphere
//!    when a view is concave;
//! 2. [`reconstruct_coarse`]: differentiable rendering through `w3d-raster` with the
//!    geometry-aware normal loss and the mask loss, gradients through the rasteriser's
//!    backward passes and [`vertex_normals_backward`], continuous remeshing (`w3d-remesh`)
//!    after every step, and density bounded below by the views' pixel footprint — run a
//!    second time from the [`visual_hull_mesh`] when the Poisson start misses a silhouette
//!    (a handle pointing at the camera), keeping the hull result only when its loss is
//!    clearly lower ([`InitOptions::hull_alternative_margin`]);
//! 3. [`untangle`]: small local moves (separation, then smoothing) until no triangles cross
//!    (the coarse stage runs again with another remesher seed in the rare case it cannot);
//! 4. [`polish`]: the coarse loss again on the vertices untangling moved, at fixed
//!    topology, with every move that would make triangles cross undone.
//!
//! Stages 2–4 can run several times from the same start mesh with other remesher seeds
//! ([`ReconOptions::starts`]), keeping the fit with the lowest final view loss: on views that
//! disagree (generated ones) a single fit is a chaotic draw from a wide spread.
//!
//! [`refine_mesh`] is the refinement stage that follows: the same fit, from the finished
//! mesh, against sharper views (Wonder3D++'s enhanced 512² views), with the same clean-up.
//!
//! Frames and units follow `w3d-core`: the canonical y-up world frame of the rig, lengths in
//! unit-cube units. Accuracy and speed per preset are in `docs/accuracy.md`.
//!
//! ```
//! use w3d_core::ViewRig;
//! use w3d_recon::{Preset, ReconOptions, reconstruct};
//!
//! // Oracle views of a sphere, then a quick reconstruction.
//! let truth = w3d_remesh::icosphere(4, 0.35)?;
//! let rig = ViewRig::wonder3d_ortho();
//! let views = w3d_raster::render_oracle_views(&truth, &rig, 64)?;
//! // Options are `#[non_exhaustive]`: start from a preset (or `Default`) and chain setters.
//! let options = ReconOptions::preset(Preset::Fast).with_coarse_steps(20);
//! let (mesh, report) = reconstruct(&views, &options, &mut |_| {})?;
//! assert!(mesh.topology().is_watertight());
//! let radius = mesh.positions().iter().map(|p| glam::Vec3::from(*p).length()).sum::<f32>()
//!     / mesh.vertex_count() as f32;
//! assert!((radius - 0.35).abs() < 0.03, "mean radius {radius}");
//! println!("{} triangles in {:.2} s ({})", report.triangles, report.seconds, report.init.reason);
//! # Ok::<(), w3d_core::Error>(())
//! ```

mod agreement;
mod coarse;
mod init;
mod integrate;
mod normals;
mod pipeline;
mod polish;
mod refine;
mod untangle;

pub use agreement::{ViewAgreement, disagreeing_view, view_agreement};
pub use coarse::{
    CoarseOptions, CoarseReport, VIEW_CURVATURE_STENCIL, VIEW_REWEIGHT_EVERY, reconstruct_coarse, silhouette_sphere,
    view_loss,
};
pub use init::{InitChoice, InitOptions, InitReport, initial_mesh, visual_hull_mesh};
pub use pipeline::{
    COARSE_RESEEDS, CRUMPLED_MIN_PAIRS, CRUMPLED_PAIRS_PER_TRIANGLE, HOPELESS_VIEW_LOSS, Preset, Progress,
    ReconOptions, ReconReport, Stage, StageTiming, reconstruct,
};

pub use polish::{PolishReport, polish};
pub use refine::{RefineOptions, RefineReport, SIMPLIFY_RETRIES, refine_mesh, simplify_without_crossings};
pub use untangle::{UntangleReport, untangle, untangle_positions};

pub use integrate::{IntegrateOptions, integrate_normals, integrate_normals_anchored};
pub use normals::{vertex_normals, vertex_normals_backward};
