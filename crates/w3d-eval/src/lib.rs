//! Evaluation metrics for wonder3d-rs, following the SyncDreamer / Wonder3D protocol:
//! Chamfer distance, F-score, normal consistency and volume IoU between a predicted and a
//! ground-truth [`Mesh`], and PSNR / SSIM between images.
//!
//! Geometry is compared in the canonical frame (y up, see `docs/architecture.md`, "Conventions"): the ground
//! truth is normalised into the unit cube `[-0.5, 0.5]³`, the prediction is used as it is
//! (optionally normalised too), and every distance is in those unit-cube units. Surface
//! metrics come from seeded, area-weighted samples ([`sample_surface`]) matched with k-d
//! trees ([`SurfaceComparison`]); volume IoU decides "inside" with hierarchical generalised
//! winding numbers ([`WindingNumber`]), so open or non-manifold predictions are handled.
//! [`surface_chamfer`] measures the samples to the other mesh's *surface* exactly (a
//! bounding-volume hierarchy, [`MeshDistance`]) instead of to its samples: it has no
//! sampling floor (a mesh against itself scores 0, not ~0.002), for telling apart meshes
//! whose error is 0.001–0.003.
//! SyncDreamer's own Chamfer variant, on the surface seen by its 16 depth views only, is
//! [`visible_surface_chamfer`]; [`align_icp_scale`] fits a similarity (ICP with scale) as a
//! diagnostic of how much of an error is pose and scale. Generated views are scored against
//! the true ones with [`view_agreement`] (normal angle inside the true mask, mask IoU), and
//! [`with_normal_noise`] perturbs views for robustness measurements.
//!
//! ```
//! use w3d_core::Mesh;
//! use w3d_eval::{evaluate, EvalOptions};
//!
//! // A tetrahedron against the same tetrahedron, slightly scaled.
//! let tet = |s: f32| {
//!     let p = vec![[0.0, 0.0, 0.0], [s, 0.0, 0.0], [0.0, s, 0.0], [0.0, 0.0, s]];
//!     Mesh::new(p, vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
//! };
//! let gt = tet(2.0)?; // normalised into the unit cube by `evaluate`
//! let mut pred = tet(1.0)?;
//! pred.map_positions(|p| p * 1.02 - 0.5)?; // the unit-cube tetrahedron, 2 % larger
//! let metrics = evaluate(&pred, &gt, &EvalOptions::default().with_samples(20_000))?;
//! assert!(metrics.chamfer < 0.01);
//! assert!(metrics.iou_64 > 0.8 && metrics.normal_consistency > 0.9);
//! let json = serde_json::to_string(&metrics).unwrap();
//! assert!(json.contains("\"fscore_0.01\""));
//! # Ok::<(), w3d_core::Error>(())
//! ```

mod distance;
mod icp;
mod image_metrics;
mod perturb;
mod sampling;
mod surface_distance;
mod views;
mod visible;
mod volume;
mod winding;

pub use distance::{FScore, SurfaceComparison};
pub use icp::{IcpOptions, Similarity, align_icp_scale};
pub use image_metrics::{NovelViewFidelity, composite_over_white, novel_view_fidelity, psnr, ssim};
pub use perturb::with_normal_noise;
pub use sampling::{MAX_SAMPLES, SurfaceSamples, sample_surface};
pub use surface_distance::{MeshDistance, SurfaceChamfer, closest_point_on_triangle, surface_chamfer};
pub use views::{ViewAgreement, view_agreement};
pub use visible::{VisibleChamfer, VisibleOptions, visible_points, visible_surface_chamfer, voxel_down_sample};
pub use volume::{Grid, occupancy, occupancy_iou, volume_iou};
pub use winding::WindingNumber;

use w3d_core::{Error, Mesh, Result};

/// Options of [`evaluate`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct EvalOptions {
    /// Surface samples per mesh for Chamfer, F-score and normal consistency (default
    /// 100 000: the self-distance floor is about 0.002 there, against 0.004–0.007 at 10k).
    pub samples: usize,
    /// Seed of the surface sampling; the prediction uses `seed`, the ground truth `seed + 1`.
    pub seed: u64,
    /// Also normalise the prediction into the unit cube (for predictions of unknown scale,
    /// such as reconstructions from photos). Default `false`: the prediction must already be
    /// in the canonical unit-cube frame.
    pub normalize_pred: bool,
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions { samples: 100_000, seed: 0, normalize_pred: false }
    }
}

/// Chainable setters, one per field: `EvalOptions::default().with_…(…)` (the struct is
/// `#[non_exhaustive]`, so code outside this crate cannot use struct-literal syntax).
impl EvalOptions {
    w3d_core::setters! {
        with_samples(samples: usize);
        with_seed(seed: u64);
        with_normalize_pred(normalize_pred: bool);
    }
}

/// Every geometry metric of one prediction against one ground truth, in unit-cube units.
/// Serialises to JSON with stable keys (`chamfer`, `fscore_0.01`, `iou_64`, …).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct MeshMetrics {
    /// Chamfer distance `(mean d_pred→gt + mean d_gt→pred) / 2`, Euclidean, not squared.
    pub chamfer: f64,
    /// Mean distance from predicted samples to the ground truth (accuracy).
    pub chamfer_pred_to_gt: f64,
    /// Mean distance from ground-truth samples to the prediction (completeness).
    pub chamfer_gt_to_pred: f64,
    /// F-score at τ = 0.01.
    #[cfg_attr(feature = "serde", serde(rename = "fscore_0.01"))]
    pub fscore_001: f64,
    /// Precision at τ = 0.01.
    #[cfg_attr(feature = "serde", serde(rename = "precision_0.01"))]
    pub precision_001: f64,
    /// Recall at τ = 0.01.
    #[cfg_attr(feature = "serde", serde(rename = "recall_0.01"))]
    pub recall_001: f64,
    /// F-score at τ = 0.02.
    #[cfg_attr(feature = "serde", serde(rename = "fscore_0.02"))]
    pub fscore_002: f64,
    /// Precision at τ = 0.02.
    #[cfg_attr(feature = "serde", serde(rename = "precision_0.02"))]
    pub precision_002: f64,
    /// Recall at τ = 0.02.
    #[cfg_attr(feature = "serde", serde(rename = "recall_0.02"))]
    pub recall_002: f64,
    /// Volume IoU on the SyncDreamer 64³ lattice over `[−1, 1]³` ([`Grid::syncdreamer64`]).
    pub iou_64: f64,
    /// Volume IoU on 128³ voxel centres over the union of both bounding boxes.
    pub iou_128: f64,
    /// Mean `|cos|` between the normals of nearest-neighbour sample pairs, both ways.
    pub normal_consistency: f64,
    /// Surface samples per mesh.
    pub samples: usize,
    /// Sampling seed.
    pub seed: u64,
}

/// Compares `pred` with `gt`: normalises `gt` into the unit cube (and `pred` too when
/// `options.normalize_pred`), samples both surfaces, and computes every [`MeshMetrics`]
/// field. Errors on a zero sample count, a zero-area mesh, or a pair whose volumes are
/// both empty on a grid.
pub fn evaluate(pred: &Mesh, gt: &Mesh, options: &EvalOptions) -> Result<MeshMetrics> {
    if options.samples == 0 || options.samples > sampling::MAX_SAMPLES {
        return Err(Error::invalid(
            "options.samples",
            format!("1 to {} surface samples, got {}", sampling::MAX_SAMPLES, options.samples),
        ));
    }
    let mut gt = gt.clone();
    gt.normalize_unit_cube();
    let mut pred_normalised;
    let pred = if options.normalize_pred {
        pred_normalised = pred.clone();
        pred_normalised.normalize_unit_cube();
        &pred_normalised
    } else {
        pred
    };
    let pred_samples = sample_surface(pred, options.samples, options.seed)?;
    let gt_samples = sample_surface(&gt, options.samples, options.seed.wrapping_add(1))?;
    let surface = SurfaceComparison::new(&pred_samples, &gt_samples)?;
    let (f1, f2) = (surface.fscore(0.01)?, surface.fscore(0.02)?);
    let ((plo, phi), (glo, ghi)) = (pred.bbox(), gt.bbox());
    let union = Grid::voxel_centres(plo.min(glo), phi.max(ghi), 128)?;
    Ok(MeshMetrics {
        chamfer: surface.chamfer(),
        chamfer_pred_to_gt: surface.mean_pred_to_gt(),
        chamfer_gt_to_pred: surface.mean_gt_to_pred(),
        fscore_001: f1.fscore,
        precision_001: f1.precision,
        recall_001: f1.recall,
        fscore_002: f2.fscore,
        precision_002: f2.precision,
        recall_002: f2.recall,
        iou_64: volume_iou(pred, &gt, &Grid::syncdreamer64())?,
        iou_128: volume_iou(pred, &gt, &union)?,
        normal_consistency: surface.normal_consistency,
        samples: options.samples,
        seed: options.seed,
    })
}
