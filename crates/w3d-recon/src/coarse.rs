//! Coarse reconstruction: fit a closed mesh to the normal maps and masks of a view set by
//! differentiable rendering and continuous remeshing.
//!
//! Every step renders the current mesh through the rig (vertex normals interpolated, plus
//! a constant coverage channel, anti-aliased so the silhouette is differentiable) and
//! pulls the vertices down the gradient of
//!
//! * the **geometry-aware normal loss**: per target-foreground pixel, weight
//!   `|cos(view direction, target normal)|`, set to zero below `grazing_epsilon` (normals
//!   seen edge-on are the least reliable), times the squared difference between rendered
//!   and target normal;
//! * the **mask loss**: squared difference between rendered coverage and target mask;
//!
//! through `antialias`, `interpolate` and `rasterize` (w3d-raster) and through the vertex
//! normals themselves ([`crate::vertex_normals_backward`]). The Laplacian regulariser and
//! the step itself belong to the continuous-remeshing optimiser (w3d-remesh), which also
//! remeshes after every step.
//!
//! Measured on oracle views (wonder3d-ortho rig) from a [`silhouette_sphere`] start, on
//! the 2-core machine while other builds ran: spot at 256², 200 steps, edge lengths
//! (0.012, 0.1): Chamfer 0.0051, F@0.02 0.965, IoU 0.982, 36k triangles, 33 s; at 128²,
//! 150 steps: Chamfer 0.011, 8 s. A sphere start keeps genus 0, so the torus is not
//! recovered (Chamfer 0.09), and thin parts (plane wings) come out poorly (IoU 0.54):
//! both need the normal-integration initialisation.

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use w3d_core::{Camera, Error, Mesh, Projection, Result, ViewRig, ViewSet};
use w3d_raster::{
    EdgeTopology, antialias, antialias_backward, interpolate, interpolate_backward, rasterize_backward, rasterize_rig,
};
use w3d_remesh::{CurvatureHint, MeshOptimizer, RemeshOptions};

use crate::normals::{vertex_normals, vertex_normals_backward};

/// Options of [`reconstruct_coarse`]. Lengths are in world (unit-cube) units.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct CoarseOptions {
    /// Optimisation steps (one render, one step, one remesh each).
    pub steps: usize,
    /// Learning rate of the remeshing optimiser at the first step.
    pub lr: f32,
    /// Multiplicative learning-rate decay per step.
    pub lr_decay: f32,
    /// Smallest and largest target edge length.
    pub edge_len_lims: (f32, f32),
    /// Density control: the target edge length at a point never goes below this many
    /// pixels of the finest view that sees it (the image-space pixel footprint), so the mesh
    /// carries no detail the views cannot show; 0 turns the bound off.
    pub min_edge_pixels: f32,
    /// Weight of the Laplacian regulariser inside the remeshing optimiser's update.
    pub laplacian_weight: f32,
    /// Weight of the normal loss.
    pub normal_weight: f32,
    /// Weight of the mask loss.
    pub mask_weight: f32,
    /// Pixels whose target normal makes `|cos| <` this with the viewing direction are
    /// ignored by the normal loss.
    pub grazing_epsilon: f32,
    /// Seed of the remesher's random choices.
    pub seed: u64,
    /// Run the remesher's repairs after every step (fold relaxation, valence-3 removal, and
    /// passes that collapse edges below the lower limit; see `w3d_remesh::RemeshOptions`).
    /// Off by default: they pull vertices and drop detail while the mesh still moves
    /// towards the views (measured below, in [`reconstruct_coarse`]). [`crate::reconstruct`]
    /// turns them on for its reruns (after the first) when [`crate::untangle`] cannot remove
    /// the crossings of a crumpled coarse mesh: with them the remesher leaves far fewer
    /// crumples of sub-floor triangles. Measured (default preset, 256², `front_right` replaced by
    /// another object's view; crossing pairs without → with): armadillo 1702 → 0, fandisk
    /// 7301 → 0; the fandisk scaled to 95 % of the frame 10 214 → 139, which untangle.
    pub remesh_repairs: bool,
    /// Pixels the target masks are eroded by (a `(2e+1)²` square) for the normal loss only:
    /// the normals of views that a generative model sharpened are least reliable along the
    /// silhouette, so the refinement stage ([`crate::refine_mesh`]) leaves a band of 2 pixels
    /// out of the normal loss, as the reference does. The mask loss uses the masks as they are.
    pub normal_mask_erosion: u32,
    /// Not in the reference: a shape-following bound on the remesher's target edge lengths
    /// (`w3d_remesh::RemeshOptions::curvature_tolerance`, world units): edges where the
    /// mesh is curved are cut short enough that their chords stay within about this of the
    /// surface. `None` (the default) leaves the sizing to the speed controller alone, as in
    /// the coarse stage, whose sphere start says nothing about the object's curvature; the
    /// refinement ([`crate::RefineOptions::curvature_tolerance`]) sets it.
    pub curvature_tolerance: Option<f32>,
    /// With a [`curvature_tolerance`](Self::curvature_tolerance): read the curvature a
    /// vertex is sized by from the target normal maps where they show it, instead of from
    /// the mesh (off by default here, on in the refinement;
    /// [`crate::RefineOptions::curvature_from_views`] has the measurements). The mesh being fitted is wrong where the sizing matters most: it shows
    /// noise as curvature on smooth parts (short edges that keep the noise) and has not yet
    /// grown the detail the views show (long edges that cannot hold it). The views'
    /// curvature is the angle between target normals [`VIEW_CURVATURE_STENCIL`] pixels
    /// either side of a pixel (fewer where the mask ends sooner), per pixel of distance, the
    /// larger of the two image axes, foreshortening undone, divided by the pixel's size in
    /// world units at the vertex; averaged over the pixels where the current mesh's
    /// triangles around the vertex are visible (the renders of the fit say which surface a
    /// pixel shows), then the largest over the views. It replaces the mesh's curvature,
    /// except near a silhouette, where the views show least of the surface's turn and it
    /// only bounds the mesh's from below. Pixels seen at a grazing angle (`|cos| < 0.5`) or
    /// outside the masks count for nothing; a vertex no view shows keeps the mesh's
    /// curvature.
    pub curvature_from_views: bool,
    /// Start every vertex's target edge length at the mean length of its edges in the start
    /// mesh (clamped to `edge_len_lims`) instead of at the upper limit (`false` by default).
    /// For a start mesh that already fits the views (the refinement): starting at the upper
    /// limit, the first remesh collapses every shorter edge at once, and a thin part one or
    /// two edges across (the plane's wings) is lost before the fit can hold it.
    pub start_at_mesh_edge_lengths: bool,
    /// Outlier views: from a quarter of the steps on, every [`VIEW_REWEIGHT_EVERY`] steps,
    /// a view whose loss is above this many times the median view loss has its loss weighted
    /// by `(k · median / loss)²` (1 otherwise). Generated views disagree, and a view the
    /// others contradict (another object, a face drawn on the back) would otherwise pull the
    /// surface towards a shape no closed mesh explains. `None` weighs every view 1.
    pub outlier_view_loss: Option<f32>,
}

/// Steps between two estimates of the view weights ([`CoarseOptions::outlier_view_loss`]).
pub const VIEW_REWEIGHT_EVERY: usize = 10;

impl Default for CoarseOptions {
    fn default() -> Self {
        CoarseOptions {
            steps: 200,
            lr: 0.2,
            lr_decay: 0.995,
            edge_len_lims: (0.015, 0.1),
            min_edge_pixels: 2.0,
            laplacian_weight: 0.05,
            normal_weight: 1.0,
            mask_weight: 1.0,
            grazing_epsilon: 0.1,
            seed: 0,
            remesh_repairs: false,
            normal_mask_erosion: 0,
            curvature_tolerance: None,
            curvature_from_views: false,
            start_at_mesh_edge_lengths: false,
            outlier_view_loss: None,
        }
    }
}

/// Chainable setters, one per field: `CoarseOptions::default().with_…(…)` (the struct is
/// `#[non_exhaustive]`, so code outside this crate cannot use struct-literal syntax).
impl CoarseOptions {
    w3d_core::setters! {
        with_steps(steps: usize);
        with_lr(lr: f32);
        with_lr_decay(lr_decay: f32);
        with_edge_len_lims(edge_len_lims: (f32, f32));
        with_min_edge_pixels(min_edge_pixels: f32);
        with_laplacian_weight(laplacian_weight: f32);
        with_normal_weight(normal_weight: f32);
        with_mask_weight(mask_weight: f32);
        with_grazing_epsilon(grazing_epsilon: f32);
        with_seed(seed: u64);
        with_remesh_repairs(remesh_repairs: bool);
        with_normal_mask_erosion(normal_mask_erosion: u32);
        with_curvature_tolerance(curvature_tolerance: Option<f32>);
        with_curvature_from_views(curvature_from_views: bool);
        with_start_at_mesh_edge_lengths(start_at_mesh_edge_lengths: bool);
        with_outlier_view_loss(outlier_view_loss: Option<f32>);
    }
}

/// What [`reconstruct_coarse`] did.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct CoarseReport {
    /// Total loss before each step.
    pub losses: Vec<f32>,
    /// Triangle count after each remesh.
    pub triangle_counts: Vec<usize>,
    /// The weight of each view's loss at the end, in rig order (all 1 without
    /// [`CoarseOptions::outlier_view_loss`]).
    pub view_weights: Vec<f32>,
    /// Wall-clock seconds of the whole optimisation.
    pub seconds: f64,
}

/// An icosphere centred at the origin whose radius is half the largest silhouette extent
/// seen in any view (orthographic rigs: the mask bounding box in world units), a start
/// mesh that encloses roughly the same region as the object.
pub fn silhouette_sphere(views: &ViewSet, subdivisions: u32) -> Result<Mesh> {
    let (w, h) = (views.width(), views.height());
    let mut extent = 0.0f32;
    for (rv, v) in views.iter() {
        let (mut lo, mut hi) = ((u32::MAX, u32::MAX), (0u32, 0u32));
        for y in 0..h {
            for x in 0..w {
                if v.mask.pixel(x, y)[0] >= 0.5 {
                    lo = (lo.0.min(x), lo.1.min(y));
                    hi = (hi.0.max(x), hi.1.max(y));
                }
            }
        }
        if lo.0 == u32::MAX {
            return Err(Error::invalid(format!("views[{}].mask", rv.name), "a non-empty silhouette"));
        }
        let cam = &rv.camera;
        let depth = cam.depth(Vec3::ZERO);
        let a = cam.unproject(lo.0 as f32, lo.1 as f32, depth, w, h);
        let b = cam.unproject(hi.0 as f32 + 1.0, hi.1 as f32 + 1.0, depth, w, h);
        let d = cam.to_camera(b) - cam.to_camera(a);
        extent = extent.max(d.x.abs()).max(d.y.abs());
    }
    w3d_remesh::icosphere(subdivisions, 0.5 * extent)
}

/// The world-space height spanned by the image of the camera that sees `p` at the finest
/// scale (orthographic: `2·half_height`; perspective: `2·depth·tan(fov/2)`).
fn finest_view_span(cameras: &[Camera], p: glam::Vec3) -> f32 {
    cameras.iter().map(|c| image_span(c, p)).fold(f32::INFINITY, f32::min)
}

/// Fits `init` (a closed mesh in the rig's world frame) to the normal maps and masks of
/// `views` (through their rig) and returns the fitted mesh with a report. `progress` is called after every
/// step with `(steps done, steps in all, loss before the step)`.
pub fn reconstruct_coarse(
    views: &ViewSet,
    init: &Mesh,
    options: &CoarseOptions,
    progress: &mut dyn FnMut(usize, usize, f32),
) -> Result<(Mesh, CoarseReport)> {
    let start = Instant::now();
    let size = views.width();
    if views.height() != size {
        return Err(Error::invalid("views", format!("square images, got {}×{}", size, views.height())));
    }
    // The reference remesh passes only: the remesher's repairs (fold relaxation, valence-3
    // removal, floor passes) pull vertices and drop detail while the mesh is still moving
    // towards the views. Measured (ortho, default preset, armadillo / cow / plane / horse):
    // CD 0.0035 / 0.0035 / 0.0044 / 0.0030 without them, 0.0069 / 0.0091 / 0.0364 / 0.0158
    // with all three; `untangle` removes the crossings they would have prevented.
    // (`CoarseOptions::remesh_repairs` keeps the default repairs, for the last resort.)
    let remesh = if options.remesh_repairs {
        RemeshOptions::default()
    } else {
        RemeshOptions::default().with_edge_floor_passes(0).with_fold_relaxation_rounds(0).with_remove_valence3(false)
    };
    let remesh = remesh
        .with_lr(options.lr)
        .with_edge_len_lims(options.edge_len_lims)
        .with_laplacian_weight(options.laplacian_weight)
        .with_seed(options.seed);
    let remesh = remesh.with_curvature_tolerance(options.curvature_tolerance);
    let mut opt = MeshOptimizer::from_mesh(&init.clone().without_attributes(), remesh)?;
    if options.start_at_mesh_edge_lengths {
        opt.set_target_edge_lengths(&mean_edge_lengths(init, options.edge_len_lims))?;
    }
    if options.min_edge_pixels > 0.0 {
        let cameras: Vec<Camera> = views.rig().cameras().copied().collect();
        let scale = options.min_edge_pixels / size as f32;
        opt.set_min_edge_length_field(move |p| scale * finest_view_span(&cameras, glam::Vec3::from(p)));
    }
    let mut fit = ViewFit::new(views, options)?;
    let mut report =
        CoarseReport { losses: Vec::new(), triangle_counts: Vec::new(), view_weights: Vec::new(), seconds: 0.0 };
    let mut lr = options.lr;
    for step in 0..options.steps {
        let FitEvaluation { loss, gradient: grad_positions, curvature, view_losses } =
            fit.loss_gradient_and_curvature(opt.positions(), opt.triangles())?;
        if let Some(k) = options.outlier_view_loss
            && step >= options.steps / 4
            && (step - options.steps / 4).is_multiple_of(VIEW_REWEIGHT_EVERY)
        {
            fit.view_weights = outlier_weights(&view_losses, k);
        }
        report.losses.push(loss);
        if !loss.is_finite() {
            return Err(Error::invalid("views", format!("finite normal and mask values (the loss became {loss})")));
        }
        if let Some(curvature) = curvature {
            opt.set_curvature_hint(curvature)?;
        }
        opt.step(&grad_positions)?;
        opt.remesh();
        report.triangle_counts.push(opt.triangle_count());
        lr *= options.lr_decay;
        let mut o = *opt.options();
        o.lr = lr;
        opt.set_options(o)?;
        progress(report.losses.len(), options.steps, loss);
    }
    report.view_weights = fit.view_weights.clone();
    report.seconds = start.elapsed().as_secs_f64();
    Ok((opt.to_mesh()?, report))
}

/// The view weights of [`CoarseOptions::outlier_view_loss`] `k` for the unweighted per-view
/// losses `losses`: 1, or `(k · median / loss)²` for a loss above `k` times the median.
fn outlier_weights(losses: &[f32], k: f32) -> Vec<f32> {
    let mut sorted = losses.to_vec();
    sorted.sort_by(f32::total_cmp);
    let median = sorted[sorted.len() / 2];
    losses.iter().map(|&l| if l > k * median && l > 0.0 { ((k * median) / l).powi(2) } else { 1.0 }).collect()
}

/// The coarse stage's loss (normal and mask terms with `options`' weights, summed over the
/// views) of `mesh` against `views`: how far its renders are from the views. Near 0 for
/// the mesh the views were rendered from (about 0.0005 or less on the oracle meshes); the
/// mesh must be manifold.
pub fn view_loss(views: &ViewSet, mesh: &Mesh, options: &CoarseOptions) -> Result<f32> {
    Ok(ViewFit::new(views, options)?.loss_and_gradient(mesh.positions(), mesh.triangles())?.0)
}

/// The coarse stage's loss against one view set: per view, the target normals, mask and
/// geometry-aware weights, precomputed once.
pub(crate) struct ViewFit<'a> {
    rig: &'a ViewRig,
    size: u32,
    normal_weight: f32,
    mask_weight: f32,
    /// Per view: target normals (3 per pixel), mask, normal-loss weight.
    targets: Vec<(Vec<f32>, Vec<f32>, Vec<f32>)>,
    /// Per view, with [`CoarseOptions::curvature_from_views`] and a curvature tolerance: the
    /// target normals' angular change per pixel.
    view_curvature: Option<Vec<NormalChange>>,
    /// Per view: the weight of its loss ([`CoarseOptions::outlier_view_loss`]; 1 by default).
    pub(crate) view_weights: Vec<f32>,
}

impl<'a> ViewFit<'a> {
    /// Precomputes the targets of `views` (square images).
    pub(crate) fn new(views: &'a ViewSet, options: &CoarseOptions) -> Result<Self> {
        let size = views.width();
        if views.height() != size {
            return Err(Error::invalid("views", format!("square images, got {}×{}", size, views.height())));
        }
        let targets: Vec<(Vec<f32>, Vec<f32>, Vec<f32>)> = views
            .iter()
            .map(|(rv, v)| {
                let inside = eroded_mask(v.mask.data(), size as usize, options.normal_mask_erosion as usize);
                let weight = v
                    .normal
                    .data()
                    .chunks_exact(3)
                    .zip(inside)
                    .map(|(n, inside)| {
                        let cos = (Vec3::new(n[0], n[1], n[2]).dot(-rv.camera.forward())).abs();
                        if inside && cos >= options.grazing_epsilon { cos } else { 0.0 }
                    })
                    .collect();
                (v.normal.data().to_vec(), v.mask.data().to_vec(), weight)
            })
            .collect();
        let view_curvature = (options.curvature_from_views && options.curvature_tolerance.is_some()).then(|| {
            views
                .iter()
                .map(|(rv, v)| normal_change_per_pixel(v.normal.data(), v.mask.data(), size as usize, &rv.camera))
                .collect()
        });
        Ok(ViewFit {
            rig: views.rig(),
            size,
            normal_weight: options.normal_weight,
            mask_weight: options.mask_weight,
            view_weights: vec![1.0; targets.len()],
            targets,
            view_curvature,
        })
    }

    /// The total loss of the mesh `positions` / `triangles` over all views and its gradient
    /// with respect to every vertex position (through the rendered normals and the
    /// anti-aliased silhouette).
    pub(crate) fn loss_and_gradient(
        &self,
        positions: &[[f32; 3]],
        triangles: &[[u32; 3]],
    ) -> Result<(f32, Vec<[f32; 3]>)> {
        let eval = self.loss_gradient_and_curvature(positions, triangles)?;
        Ok((eval.loss, eval.gradient))
    }

    /// [`ViewFit::loss_and_gradient`] and, with [`CoarseOptions::curvature_from_views`], the
    /// curvature the views show at every vertex (1 / world units; NaN where no view shows
    /// it), from the same renders.
    pub(crate) fn loss_gradient_and_curvature(
        &self,
        positions: &[[f32; 3]],
        triangles: &[[u32; 3]],
    ) -> Result<FitEvaluation> {
        let mesh = Mesh::new(positions.to_vec(), triangles.to_vec())?;
        let normals = vertex_normals(positions, triangles)?;
        let attributes: Vec<f32> = normals.iter().flat_map(|n| [n[0], n[1], n[2], 1.0]).collect();
        let topology = EdgeTopology::new(positions, triangles)?;
        let rasters = rasterize_rig(&mesh, self.rig, self.size)?;
        let pixels = (self.size * self.size) as f32;
        let per_view: Vec<(f32, Vec<[f32; 3]>, Vec<f32>)> = rasters
            .par_iter()
            .zip(&self.targets)
            .zip(&self.view_weights)
            .map(|((raster, (normal, mask, weight)), &view_weight)| {
                let image = interpolate(&attributes, 4, triangles, raster)?;
                let aa = antialias(&image, 4, raster, positions, triangles, &topology)?;
                // The view's loss unweighted (for the outlier weights); its gradient weighted.
                let mut loss = 0.0f32;
                let mut grad = vec![0.0f32; aa.image.len()];
                for p in 0..mask.len() {
                    let px = &aa.image[4 * p..4 * p + 4];
                    let wn = self.normal_weight * weight[p] / pixels;
                    for k in 0..3 {
                        let d = px[k] - normal[3 * p + k];
                        loss += wn * d * d;
                        grad[4 * p + k] = 2.0 * view_weight * wn * d;
                    }
                    let d = px[3] - mask[p];
                    loss += self.mask_weight * d * d / pixels;
                    grad[4 * p + 3] = 2.0 * view_weight * self.mask_weight * d / pixels;
                }
                let ga = antialias_backward(&aa, &image, 4, raster, positions, triangles, &grad)?;
                let gi = interpolate_backward(&attributes, 4, triangles, raster, &ga.colour)?;
                let mut gp = rasterize_backward(raster, positions, triangles, &gi.uv, None)?;
                for (a, b) in gp.iter_mut().zip(&ga.positions) {
                    *a = [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
                }
                Ok((loss, gp, gi.attributes))
            })
            .collect::<Result<_>>()?;
        let mut grad_positions = vec![[0.0f32; 3]; positions.len()];
        let mut grad_normals = vec![[0.0f32; 3]; positions.len()];
        let mut loss = 0.0;
        let mut view_losses = Vec::with_capacity(per_view.len());
        for ((l, gp, ga), &view_weight) in per_view.into_iter().zip(&self.view_weights) {
            loss += view_weight * l;
            view_losses.push(l);
            for (v, g) in gp.iter().enumerate() {
                for k in 0..3 {
                    grad_positions[v][k] += g[k];
                    grad_normals[v][k] += ga[4 * v + k];
                }
            }
        }
        let through_normals = vertex_normals_backward(positions, triangles, &grad_normals)?;
        for (g, n) in grad_positions.iter_mut().zip(through_normals) {
            *g = [g[0] + n[0], g[1] + n[1], g[2] + n[2]];
        }
        let curvature = self.view_curvature.as_ref().map(|per_view| {
            let mut curvature = vec![f32::NAN; positions.len()];
            let mut near_silhouette = vec![false; positions.len()];
            for (raster, change) in rasters.iter().zip(per_view) {
                // Mean change per pixel over the pixels where each vertex's triangles show.
                let mut sum = vec![0.0f32; positions.len()];
                let mut count = vec![0u32; positions.len()];
                for (p, &t) in raster.triangle.iter().enumerate() {
                    let c = change.per_pixel[p];
                    if t == w3d_raster::NO_TRIANGLE || c.is_nan() {
                        continue;
                    }
                    for v in triangles[t as usize] {
                        sum[v as usize] += c;
                        count[v as usize] += 1;
                        near_silhouette[v as usize] |= change.near_silhouette[p];
                    }
                }
                for (v, kappa) in curvature.iter_mut().enumerate() {
                    if count[v] < 2 {
                        continue;
                    }
                    let pixel = image_span(&raster.camera, Vec3::from(positions[v])) / self.size as f32;
                    let k = sum[v] / count[v] as f32 / pixel;
                    *kappa = if kappa.is_nan() { k } else { kappa.max(k) };
                }
            }
            curvature
                .iter()
                .zip(&near_silhouette)
                .map(|(&k, &near)| match (k.is_nan(), near) {
                    (true, _) => CurvatureHint::Mesh,
                    (false, true) => CurvatureHint::AtLeast(k),
                    (false, false) => CurvatureHint::Replace(k),
                })
                .collect()
        });
        Ok(FitEvaluation { loss, gradient: grad_positions, curvature, view_losses })
    }
}

/// What [`ViewFit::loss_gradient_and_curvature`] finds for one mesh.
pub(crate) struct FitEvaluation {
    /// The loss over all views.
    pub(crate) loss: f32,
    /// Its gradient with respect to every vertex position.
    pub(crate) gradient: Vec<[f32; 3]>,
    /// Per vertex, with [`CoarseOptions::curvature_from_views`] and a curvature tolerance:
    /// the curvature the views show (1 / world units) in place of the mesh's, or as a floor
    /// under it near a silhouette, or nothing where no view shows the vertex.
    pub(crate) curvature: Option<Vec<CurvatureHint>>,
    /// Each view's loss, unweighted, in rig order.
    pub(crate) view_losses: Vec<f32>,
}

/// Pixels either side of a pixel whose target normals give the views' curvature
/// ([`CoarseOptions::curvature_from_views`]): far enough apart that the noise of a
/// generated normal map averages out (σ = 0.05 per pixel reads as about 0.012 rad per
/// pixel), close enough to resolve the refinement's shortest edges (0.01, about 5 pixels
/// at 512²).
pub const VIEW_CURVATURE_STENCIL: usize = 3;

/// The angular change of one view's target normals per pixel
/// ([`normal_change_per_pixel`]).
struct NormalChange {
    /// Radians per pixel, foreshortening undone; NaN where unknown.
    per_pixel: Vec<f32>,
    /// Whether the stencil had to shrink because the mask ends within
    /// [`VIEW_CURVATURE_STENCIL`] pixels: a silhouette, where the views show least of the
    /// surface's turn (a thin rim seen edge-on is a line a few pixels thick) and the
    /// curvature only bounds the mesh's from below.
    near_silhouette: Vec<bool>,
}

/// Per pixel of a `size × size` normal map (unit world normals, 3 per pixel) and its mask:
/// the angle between the normals [`VIEW_CURVATURE_STENCIL`] pixels either side (fewer where
/// the mask ends sooner, at least one), per pixel of distance, the larger of the two image
/// axes, times `|cos|` of the normal with `camera`'s ray through the pixel. The factor undoes
/// the foreshortening: where the surface turns away from the ray by θ, a pixel across the
/// turn spans `1 / cos θ` times more surface, so on a sphere every pixel reads the same (with
/// the camera axis instead of the ray, the perspective rig's 45° views read a sphere 25 %
/// too curved). NaN where the pixel is seen at a grazing angle (`|cos| < 0.5`) or outside
/// the mask, or where no axis has a neighbour inside the mask on both sides.
fn normal_change_per_pixel(normals: &[f32], mask: &[f32], size: usize, camera: &Camera) -> NormalChange {
    let k = VIEW_CURVATURE_STENCIL;
    let normal = |x: usize, y: usize| -> Option<Vec3> {
        let p = y * size + x;
        (mask[p] >= 0.5).then(|| Vec3::new(normals[3 * p], normals[3 * p + 1], normals[3 * p + 2]))
    };
    // The angle between unit vectors from their chord (exact near 0, unlike acos).
    let angle = |a: Vec3, b: Vec3| 2.0 * (0.5 * a.distance(b)).min(1.0).asin();
    let mut per_pixel = vec![f32::NAN; size * size];
    let mut near_silhouette = vec![false; size * size];
    for y in 0..size {
        for x in 0..size {
            let Some(n) = normal(x, y) else { continue };
            let ray = camera.ray(x as f32 + 0.5, y as f32 + 0.5, size as u32, size as u32);
            let cos = n.dot(ray.direction).abs();
            if cos < 0.5 {
                continue;
            }
            // Per axis, the stencil shrinks to the farthest pixels still inside the mask on
            // each side, at least one: across a part a few pixels thick (a wing's rim seen
            // edge-on) the full stencil would leave the mask on both sides.
            let mut change = f32::NAN;
            for (dx, dy) in [(1isize, 0isize), (0, 1)] {
                let step = |sign: isize, j: usize| -> Option<(usize, usize)> {
                    let (px, py) = (x as isize + sign * dx * j as isize, y as isize + sign * dy * j as isize);
                    let inside = px >= 0 && py >= 0 && px < size as isize && py < size as isize;
                    inside.then_some((px as usize, py as usize))
                };
                // The farthest reach on one side before the mask (or the image) ends.
                let reach = |sign: isize| -> Option<(usize, Vec3)> {
                    let mut last = None;
                    for j in 1..=k {
                        match step(sign, j).and_then(|(px, py)| normal(px, py)) {
                            Some(n) => last = Some((j, n)),
                            None => break,
                        }
                    }
                    last
                };
                if let (Some((ja, a)), Some((jb, b))) = (reach(-1), reach(1)) {
                    let c = angle(a, b) / (ja + jb) as f32;
                    change = if change.is_nan() { c } else { change.max(c) };
                    near_silhouette[y * size + x] |= ja + jb < 2 * k;
                }
            }
            per_pixel[y * size + x] = change * cos;
        }
    }
    NormalChange { per_pixel, near_silhouette }
}

/// The world-space height spanned by `camera`'s image at `p` (orthographic:
/// `2·half_height`; perspective: `2·depth·tan(fov/2)`).
fn image_span(camera: &Camera, p: Vec3) -> f32 {
    match camera.projection {
        Projection::Orthographic { half_height } => 2.0 * half_height,
        Projection::Perspective { fov_y } => 2.0 * camera.depth(p).max(1e-3) * (0.5 * fov_y).tan(),
    }
}

/// Per pixel of a `size × size` mask: whether every pixel of the `(2·radius+1)²` square
/// around it (clipped to the image) has mask ≥ 0.5. Separable: a row pass, then a column pass.
fn eroded_mask(mask: &[f32], size: usize, radius: usize) -> Vec<bool> {
    let inside: Vec<bool> = mask.iter().map(|&m| m >= 0.5).collect();
    if radius == 0 {
        return inside;
    }
    let erode = |get: &dyn Fn(usize, usize) -> bool| -> Vec<bool> {
        let mut out = vec![false; size * size];
        for y in 0..size {
            for x in 0..size {
                let (lo, hi) = (x.saturating_sub(radius), (x + radius).min(size - 1));
                out[y * size + x] = (lo..=hi).all(|k| get(y, k));
            }
        }
        out
    };
    let rows = erode(&|y, x| inside[y * size + x]);
    let columns = erode(&|x, y| rows[y * size + x]);
    // `columns` is indexed [x][y]: transpose back.
    let mut out = vec![false; size * size];
    for y in 0..size {
        for x in 0..size {
            out[y * size + x] = columns[x * size + y];
        }
    }
    out
}

/// Per vertex of `mesh`, the mean length of its edges clamped to `(lo, hi)` (`lo` for a
/// vertex without edges).
fn mean_edge_lengths(mesh: &Mesh, (lo, hi): (f32, f32)) -> Vec<f32> {
    let mut sum = vec![0.0f32; mesh.vertex_count()];
    let mut count = vec![0u32; mesh.vertex_count()];
    let p = |v: u32| Vec3::from(mesh.positions()[v as usize]);
    for [a, b] in mesh.edges() {
        let length = p(a).distance(p(b));
        for v in [a, b] {
            sum[v as usize] += length;
            count[v as usize] += 1;
        }
    }
    sum.iter().zip(&count).map(|(s, &c)| if c == 0 { lo } else { (s / c as f32).clamp(lo, hi) }).collect()
}

#[cfg(test)]
mod tests {
    use super::{CoarseOptions, CurvatureHint, ViewFit, eroded_mask, mean_edge_lengths};
    use glam::Vec3;
    use w3d_core::ViewRig;

    /// A sphere's normal curvature is `1 / r` in every direction; the per-vertex curvature of
    /// [`CoarseOptions::curvature_from_views`] reads it on every vertex a view shows not too
    /// obliquely, in both rigs (orthographic and perspective image spans; without the
    /// foreshortening factor the vertex facing the front camera read 1.45 / r, from the view
    /// 45° beside it); and there is none without a curvature tolerance.
    #[test]
    fn the_views_show_a_sphere_curvature_at_its_vertices() {
        let r = 0.35f32;
        let sphere = w3d_remesh::icosphere(4, r).unwrap();
        for rig in [ViewRig::wonder3d_ortho(), ViewRig::wonder3d_persp()] {
            let views = w3d_raster::render_oracle_views(&sphere, &rig, 256).unwrap();
            let options =
                CoarseOptions::default().with_curvature_tolerance(Some(0.002)).with_curvature_from_views(true);
            let fit = ViewFit::new(&views, &options).unwrap();
            let eval = fit.loss_gradient_and_curvature(sphere.positions(), sphere.triangles()).unwrap();
            let curvature: Vec<f32> = eval
                .curvature
                .expect("curvature from the views")
                .iter()
                .map(|h| match h {
                    CurvatureHint::Replace(k) | CurvatureHint::AtLeast(k) => *k,
                    CurvatureHint::Mesh => f32::NAN,
                })
                .collect();
            let known: Vec<f32> = curvature.iter().copied().filter(|k| !k.is_nan()).collect();
            // The six views circle the equator: all but the caps near the poles, seen only at
            // grazing angles, read a curvature (87 % of the vertices in the orthographic rig,
            // 76 % in the perspective one, whose cameras see less of a near sphere).
            assert!(known.len() * 10 >= curvature.len() * 7, "{}: {} of {}", rig.name, known.len(), curvature.len());
            // Within 25 % everywhere (the low end near the grazing limit, where the stencil
            // reaches more oblique pixels), within 3 % at the median.
            let mut sorted = known.clone();
            sorted.sort_by(f32::total_cmp);
            let median = sorted[sorted.len() / 2] * r;
            assert!((median - 1.0).abs() < 0.03, "{}: median {median} / r", rig.name);
            for k in &known {
                assert!((0.75 / r..=1.1 / r).contains(k), "{}: curvature {k}, 1/r = {}", rig.name, 1.0 / r);
            }
            // The vertex facing the front camera reads 1 / r.
            let front = rig.cameras().next().unwrap().forward();
            let (v, _) = sphere
                .positions()
                .iter()
                .enumerate()
                .map(|(v, p)| (v, Vec3::from(*p).normalize().dot(-front)))
                .fold((0, f32::MIN), |a, b| if b.1 > a.1 { b } else { a });
            assert!((curvature[v] * r - 1.0).abs() < 0.05, "{}: facing vertex {}", rig.name, curvature[v] * r);
            // Without a tolerance, or with the option off (the default), there is none.
            let no_tolerance = CoarseOptions::default().with_curvature_from_views(true);
            for options in [no_tolerance, options.with_curvature_from_views(false)] {
                let fit = ViewFit::new(&views, &options).unwrap();
                assert!(
                    fit.loss_gradient_and_curvature(sphere.positions(), sphere.triangles())
                        .unwrap()
                        .curvature
                        .is_none()
                );
            }
        }
    }

    /// A square split into two triangles (sides 1, diagonal √2): each corner's mean over its
    /// edges, then the limits.
    #[test]
    fn mean_edge_lengths_average_each_vertex_edges_within_the_limits() {
        let square = w3d_core::Mesh::new(
            vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
            vec![[0, 1, 2], [0, 2, 3]],
        )
        .unwrap();
        let diagonal = (2.0 + std::f32::consts::SQRT_2) / 3.0;
        let lengths = mean_edge_lengths(&square, (0.0, 10.0));
        for (got, want) in lengths.iter().zip([diagonal, 1.0, diagonal, 1.0]) {
            assert!((got - want).abs() < 1e-6, "{lengths:?}");
        }
        assert_eq!(mean_edge_lengths(&square, (1.05, 1.1)), vec![1.1, 1.05, 1.1, 1.05]);
    }

    /// A 5×4 block in a 9×9 mask: eroded by 1 it keeps the 3×2 core; by 2, nothing; the
    /// image border does not erode (pixels beyond it are not counted).
    #[test]
    fn erosion_keeps_pixels_whose_whole_square_is_inside() {
        let size = 9;
        let mut mask = vec![0.0f32; size * size];
        for y in 2..6 {
            for x in 1..6 {
                mask[y * size + x] = 1.0;
            }
        }
        let inside = |m: &[bool]| -> Vec<(usize, usize)> {
            (0..size * size).filter(|&i| m[i]).map(|i| (i % size, i / size)).collect()
        };
        assert_eq!(inside(&eroded_mask(&mask, size, 0)).len(), 20);
        let core: Vec<(usize, usize)> = (3..5).flat_map(|y| (2..5).map(move |x| (x, y))).collect();
        assert_eq!(inside(&eroded_mask(&mask, size, 1)), core);
        assert!(inside(&eroded_mask(&mask, size, 2)).is_empty());
        let full = vec![1.0f32; size * size];
        assert_eq!(inside(&eroded_mask(&full, size, 3)).len(), size * size);
    }
}
