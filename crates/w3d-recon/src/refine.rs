//! Mesh refinement: a reconstructed mesh fitted again to sharper views (Wonder3D++'s
//! refinement stage; `docs/architecture.md`).
//!
//! After the coarse mesh, each refinement iteration gets enhanced views from four cameras
//! (front, right, back, left) at 512² — sharper than the six 256² views the mesh was built
//! from — and fits the mesh to them: [`refine_mesh`] runs the coarse stage's optimisation
//! again from the mesh as it is (no new start), with finer edges and a shorter schedule,
//! then the coarse stage's clean-up ([`crate::untangle`] and [`crate::polish`]), so the result
//! is closed and free of crossing triangles like the coarse result. Last, a quadric
//! simplification ([`w3d_remesh::simplify`]) removes the triangles the shape does not need:
//! the fit's edges are at most 0.03 long, finer than a flat part needs.
//!
//! Defaults (`docs/accuracy.md`, "Refinement", has the measurements): 100 steps and the
//! learning rate decayed by 0.99 per step as in the reference; target edge lengths between
//! 0.01 and 0.03 (bounded below by two pixels of the views, as in the coarse stage) that
//! follow the shape: cut short where the surface is curved, so that an edge's chord stays
//! within 0.0012 of it ([`RefineOptions::curvature_tolerance`]), long where it is flat — the
//! curvature the enhanced normal maps show ([`RefineOptions::curvature_from_views`]), since
//! the mesh being fitted shows noise as curvature and lacks the detail still to come; the
//! normal loss kept 2 pixels inside the silhouette (a 5×5 erosion of the target masks, as in
//! the reference), where a generative model's normals are least reliable; and the input
//! mesh kept when the result agrees no better with the views
//! ([`RefineOptions::keep_input_unless_better`]). The reference's edge lengths,
//! 0.005–0.008, gave spot 105–125 k triangles and 42–46 s per iteration at 512² on 2 cores,
//! with a worse Chamfer distance and novel-view PSNR; edges sized by the remesher's speed
//! alone (0.01–0.016) left spot's smooth flanks as finely cut as its ears, and the fit of so
//! many small edges to smooth-shaded views drifted (+5–7 % CD with an enhancer that changes
//! nothing).
//!
//! ```
//! use w3d_core::ViewRig;
//! use w3d_recon::{RefineOptions, refine_mesh};
//!
//! // A coarse sphere refined against views of a slightly larger, finer one.
//! let truth = w3d_remesh::icosphere(5, 0.36)?;
//! let views = w3d_raster::render_oracle_views(&truth, &ViewRig::wonder3d_ortho(), 96)?
//!     .subset(["front", "right", "back", "left"])?;
//! let coarse = w3d_remesh::icosphere(3, 0.33)?;
//! let options = RefineOptions::default().with_steps(30).with_edge_len_lims((0.03, 0.05));
//! let (mesh, report) = refine_mesh(&views, &coarse, &options, &mut |_, _, _| {})?;
//! assert!(mesh.topology().is_watertight() && mesh.self_intersections().is_empty());
//! assert!(report.fit.losses.last() < report.fit.losses.first());
//! # Ok::<(), w3d_core::Error>(())
//! ```

use std::time::Instant;

use w3d_core::{Mesh, Result, ViewSet};

use crate::coarse::{CoarseOptions, CoarseReport, ViewFit, reconstruct_coarse};
use crate::pipeline::{COARSE_RESEEDS, polish_moved};
use crate::polish::PolishReport;
use crate::untangle::{UntangleReport, untangle};
use glam::Vec3;
use w3d_remesh::{SimplifyOptions, SimplifyReport, simplify_keeping};

/// Options of [`refine_mesh`]. Lengths are in world (unit-cube) units.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct RefineOptions {
    /// Optimisation steps (one render, one step, one remesh each).
    pub steps: usize,
    /// Learning rate of the remeshing optimiser at the first step. Lower than the coarse
    /// stage's 0.2: the mesh starts close, and every step also remeshes and smooths it.
    /// Measured on spot (coarse mesh from 128² views with normal noise σ = 0.05, CD 0.0038;
    /// one iteration at 256², 60 steps, edges 0.012–0.02): with the oracle enhancer CD
    /// 0.0031 at lr 0.2, 0.0032 at 0.03, 0.0033 at 0.02; with the identity enhancer (which
    /// should change nothing) 0.0044 at 0.2 (+16 %), 0.0040 at 0.05, 0.0039 at 0.03 (+2 %),
    /// 0.0038 at 0.02.
    pub lr: f32,
    /// Multiplicative learning-rate decay per step.
    pub lr_decay: f32,
    /// Smallest and largest target edge length (see the module documentation for why not
    /// the reference's 0.005–0.008).
    pub edge_len_lims: (f32, f32),
    /// Curvature bound on the target edge lengths, in world units
    /// ([`CoarseOptions::curvature_tolerance`]): where the surface is curved, edges are cut
    /// short enough that their chords stay within about this of it, down to
    /// `edge_len_lims.0`; elsewhere they may grow to `edge_len_lims.1`. `None` leaves the
    /// sizing to the remesher's speed controller, which shortens the edges wherever the
    /// vertices have stopped moving, whatever the shape.
    pub curvature_tolerance: Option<f32>,
    /// Size by the curvature the enhanced normal maps show rather than the mesh's own
    /// ([`CoarseOptions::curvature_from_views`]; on by default). Measured with the oracle
    /// enhancer on five objects in two rigs (`docs/accuracy.md`, "Curvature read from the
    /// enhanced views"), against the mesh's curvature at tolerance 0.002: a better surface
    /// Chamfer distance on four of five objects in the orthographic rig (koala 0.0021 →
    /// 0.0017, plane 0.0015 → 0.0013; spot +1.4 %) and within 3.3 % in perspective, with fewer
    /// of the uniform meshes' triangles at equal accuracy on four objects of five. The views
    /// read curvature about 0.6–0.8 of the mesh's estimate, hence the tighter default
    /// tolerance.
    pub curvature_from_views: bool,
    /// Weight of the Laplacian regulariser inside the remeshing optimiser's update.
    pub laplacian_weight: f32,
    /// Pixels the target masks are eroded by for the normal loss (see
    /// [`CoarseOptions::normal_mask_erosion`]).
    pub normal_mask_erosion: u32,
    /// Most rounds of [`crate::untangle`] on the result (0 skips it).
    pub untangle_rounds: usize,
    /// Steps of [`crate::polish`] on the vertices untangling moved (0 skips it).
    pub polish_steps: usize,
    /// Tolerance of the quadric simplification of the result ([`w3d_remesh::simplify`]),
    /// in world units, or `None` to keep every triangle of the fit. The fit's edge lengths
    /// follow how far its vertices still move, not the shape, so flat and gently curved
    /// parts carry more triangles than they need; the simplification removes them while the
    /// surface moves by about the tolerance. The default, 0.0005 (a sixth of a pixel of the
    /// 512² views), took two oracle iterations on the five objects of `docs/accuracy.md`
    /// ("Refinement") from 8–30 k triangles to 5–16 k with the Chamfer distance unchanged
    /// (±0.0001) and novel-view PSNR within −0.39…+0.15 dB; 0.001 halved spot again but cost
    /// it up to 0.4 dB.
    pub simplify_tolerance: Option<f32>,
    /// Return the input mesh (without attributes) when the refined one agrees no better
    /// with the views ([`crate::view_loss`] with the fit's weights, before and after): a
    /// refinement iteration must not make the mesh worse than the views say it is. Views that
    /// show nothing new (the identity enhancer, which returns renders of the mesh itself)
    /// still make the fit move the surface by a fraction of an edge — a four-times finer mesh
    /// fitted to smooth-shaded renders of a coarse one; up to +6 % Chamfer distance on the
    /// test objects of `docs/accuracy.md` ("Refinement") — and an iteration that gives back
    /// what the previous one gained (the thin plane's second iteration) is caught the same
    /// way. On by default.
    pub keep_input_unless_better: bool,
    /// Seed of the remesher's random choices.
    pub seed: u64,
}

impl Default for RefineOptions {
    fn default() -> Self {
        RefineOptions {
            steps: 100,
            lr: 0.03,
            lr_decay: 0.99,
            edge_len_lims: (0.01, 0.03),
            curvature_tolerance: Some(0.0012),
            curvature_from_views: true,
            laplacian_weight: CoarseOptions::default().laplacian_weight,
            normal_mask_erosion: 2,
            untangle_rounds: 400,
            polish_steps: 40,
            simplify_tolerance: Some(0.0005),
            keep_input_unless_better: true,
            seed: 0,
        }
    }
}

/// Chainable setters, one per field (the struct is `#[non_exhaustive]`).
impl RefineOptions {
    w3d_core::setters! {
        with_steps(steps: usize);
        with_lr(lr: f32);
        with_lr_decay(lr_decay: f32);
        with_edge_len_lims(edge_len_lims: (f32, f32));
        with_curvature_from_views(curvature_from_views: bool);
        with_curvature_tolerance(curvature_tolerance: Option<f32>);
        with_laplacian_weight(laplacian_weight: f32);
        with_normal_mask_erosion(normal_mask_erosion: u32);
        with_untangle_rounds(untangle_rounds: usize);
        with_polish_steps(polish_steps: usize);
        with_simplify_tolerance(simplify_tolerance: Option<f32>);
        with_keep_input_unless_better(keep_input_unless_better: bool);
        with_seed(seed: u64);
    }

    /// The coarse-stage options the fit runs with.
    fn fit(&self) -> CoarseOptions {
        CoarseOptions::default()
            .with_steps(self.steps)
            .with_lr(self.lr)
            .with_lr_decay(self.lr_decay)
            .with_edge_len_lims(self.edge_len_lims)
            .with_curvature_tolerance(self.curvature_tolerance)
            .with_curvature_from_views(self.curvature_from_views)
            .with_start_at_mesh_edge_lengths(true)
            .with_laplacian_weight(self.laplacian_weight)
            .with_normal_mask_erosion(self.normal_mask_erosion)
            .with_seed(self.seed)
    }
}

/// What [`refine_mesh`] did.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct RefineReport {
    /// The fit to the views (losses and triangle counts per step).
    pub fit: CoarseReport,
    /// Untangling of the fitted mesh.
    pub untangle: UntangleReport,
    /// Times the fit ran again because untangling left crossings (see [`refine_mesh`]; at
    /// most [`COARSE_RESEEDS`]); the report's fit and untangling are those of the run kept.
    pub reseeds: usize,
    /// Whether the kept fit ran without the curvature bound on the edge lengths
    /// ([`RefineOptions::curvature_tolerance`]): the last resort of [`refine_mesh`] when
    /// untangling leaves crossings after every reseeded fit.
    pub curvature_bound_dropped: bool,
    /// Polishing of the vertices untangling moved.
    pub polish: PolishReport,
    /// The simplification of the polished mesh (`None` when
    /// [`RefineOptions::simplify_tolerance`] is `None`, or when the polished mesh was kept
    /// because it had crossing triangles or the simplification kept making some).
    pub simplify: Option<SimplifyReport>,
    /// [`crate::view_loss`] of the input mesh against the views.
    pub loss_input: f32,
    /// [`crate::view_loss`] of the refined mesh (after simplification) against the views.
    pub loss_refined: f32,
    /// Whether the input mesh came back because the refined one agreed no better with the
    /// views ([`RefineOptions::keep_input_unless_better`]).
    pub kept_input: bool,
    /// Triangles of the returned mesh.
    pub triangles: usize,
    /// Wall-clock seconds of the whole refinement.
    pub seconds: f64,
}

/// Fits `mesh` (closed, manifold, in the rig's world frame; attributes are dropped) to the
/// normal maps and masks of `views` (square images through their rig, typically the four
/// enhanced views of one refinement iteration) and cleans the result up like
/// [`crate::reconstruct`] does, fitting again with other remesher seeds when untangling
/// leaves crossings, and last without the curvature bound on the edge lengths; the input
/// comes back instead when the result agrees no better with the views
/// ([`RefineOptions::keep_input_unless_better`]). `progress` is called after every fitting
/// step with `(steps done, steps in all, loss before the step)`; a rerun counts its steps
/// from the start again.
pub fn refine_mesh(
    views: &ViewSet,
    mesh: &Mesh,
    options: &RefineOptions,
    progress: &mut dyn FnMut(usize, usize, f32),
) -> Result<(Mesh, RefineReport)> {
    let start = Instant::now();
    let fit_options = options.fit();
    let rounds = options.untangle_rounds;
    let mut kept = fit_and_untangle(views, mesh, &fit_options, rounds, progress)?;
    // Untangling that ends with crossings left gets the fit again with the next remesher
    // seeds (at most `COARSE_RESEEDS` times), as `crate::reconstruct` does for the coarse
    // stage; the run with the fewest crossings left is kept. Unlike there, the reruns keep
    // the remesher's repairs off: on the plane's one-edge-thick wings (perspective rig) a
    // repaired rerun cleared the crossings but CD went 0.0050 → 0.0157 (`cargo xtask
    // refine-table --all --size 256`, 2026-12-04). Without reruns the teacup turned to open
    // towards the front (perspective rig) kept 2 crossing pairs after one identity iteration.
    let mut reseeds = 0;
    while kept.untangle.after > 0 && rounds > 0 && reseeds < COARSE_RESEEDS {
        reseeds += 1;
        let again_options = fit_options.with_seed(fit_options.seed.wrapping_add(reseeds as u64));
        let again = fit_and_untangle(views, mesh, &again_options, rounds, progress)?;
        if again.untangle.after < kept.untangle.after {
            kept = again;
        }
    }
    // Last resort: the fit once more without the curvature bound, whose short edges on a
    // thin, strongly curved wall can crumple into crossings that neither untangling nor other
    // seeds clear (the teacup turned to open towards the front, perspective rig, identity
    // enhancer: 7 crossing pairs left, 2026-12-04); the speed controller's sizing left none on
    // every test mesh. Kept only if it leaves fewer crossings.
    let mut curvature_bound_dropped = false;
    if kept.untangle.after > 0 && rounds > 0 && fit_options.curvature_tolerance.is_some() {
        let again = fit_and_untangle(views, mesh, &fit_options.with_curvature_tolerance(None), rounds, progress)?;
        if again.untangle.after < kept.untangle.after {
            kept = again;
            curvature_bound_dropped = true;
        }
    }
    let FitRun { fitted, fit, untangled, untangle: untangle_report } = kept;
    let (polished, polish_report) = polish_moved(views, &fitted, &untangled, &fit_options, options.polish_steps)?;
    let (refined, simplify_report) = match options.simplify_tolerance {
        Some(tolerance) => simplify_without_crossings(polished, tolerance)?,
        None => (polished, None),
    };
    // Both meshes against one set of targets; the loss does not depend on the sizing.
    let judge = ViewFit::new(views, &fit_options.with_curvature_tolerance(None))?;
    let loss_input = judge.loss_and_gradient(mesh.positions(), mesh.triangles())?.0;
    let loss_refined = judge.loss_and_gradient(refined.positions(), refined.triangles())?.0;
    let better = loss_refined < loss_input;
    let kept_input = options.keep_input_unless_better && !better;
    let refined = if kept_input { mesh.clone().without_attributes() } else { refined };
    let report = RefineReport {
        fit,
        untangle: untangle_report,
        reseeds,
        curvature_bound_dropped,
        polish: polish_report,
        simplify: simplify_report,
        loss_input,
        loss_refined,
        kept_input,
        triangles: refined.triangle_count(),
        seconds: start.elapsed().as_secs_f64(),
    };
    Ok((refined, report))
}

/// One fit of the views from the start mesh and its untangling (`rounds` at most).
struct FitRun {
    fitted: Mesh,
    fit: CoarseReport,
    untangled: Mesh,
    untangle: UntangleReport,
}

fn fit_and_untangle(
    views: &ViewSet,
    mesh: &Mesh,
    options: &CoarseOptions,
    rounds: usize,
    progress: &mut dyn FnMut(usize, usize, f32),
) -> Result<FitRun> {
    let (fitted, fit) = reconstruct_coarse(views, mesh, options, progress)?;
    let (untangled, untangle) = untangle(&fitted, rounds)?;
    Ok(FitRun { fitted, fit, untangled, untangle })
}

/// Simplifications that made triangles cross are redone at most this many times, each time
/// keeping more of the input where the crossings were.
pub const SIMPLIFY_RETRIES: usize = 3;

/// The simplification step of [`refine_mesh`]: [`w3d_remesh::simplify_keeping`] at
/// `tolerance` (world units), done again while it makes triangles cross (two parts of the
/// surface closer than a collapse moves them, such as a thin wing's two sides), each time
/// keeping every input vertex inside the crossing triangles' bounding boxes grown by their
/// longest edge, so that the rest of the mesh is still simplified; at most
/// [`SIMPLIFY_RETRIES`] times. `mesh` itself comes back, with no report, when it already had
/// crossings or the retries run out; so a mesh free of crossings stays free of them.
///
/// ```
/// let sphere = w3d_remesh::geodesic_sphere(24, 0.4)?;
/// let (simple, report) = w3d_recon::simplify_without_crossings(sphere.clone(), 0.002)?;
/// assert!(simple.triangle_count() < sphere.triangle_count() && simple.self_intersections().is_empty());
/// assert_eq!(report.map(|r| r.triangles_after), Some(simple.triangle_count()));
/// # Ok::<(), w3d_core::Error>(())
/// ```
pub fn simplify_without_crossings(mesh: Mesh, tolerance: f32) -> Result<(Mesh, Option<SimplifyReport>)> {
    if !mesh.self_intersections().is_empty() {
        return Ok((mesh, None));
    }
    let options = SimplifyOptions::default().with_tolerance(tolerance);
    let mut keep = vec![false; mesh.vertex_count()];
    for _ in 0..=SIMPLIFY_RETRIES {
        let simplified = simplify_keeping(&mesh, &options, &keep)?;
        let crossings = simplified.mesh.self_intersections();
        if crossings.is_empty() {
            return Ok((simplified.mesh, Some(simplified.report)));
        }
        let mut regions: Vec<(Vec3, Vec3)> = Vec::new();
        for t in crossings.iter().flatten() {
            let [a, b, c] = simplified.mesh.triangle_corners(*t as usize);
            let reach = a.distance(b).max(b.distance(c)).max(c.distance(a));
            regions.push((a.min(b).min(c) - reach, a.max(b).max(c) + reach));
        }
        for (k, p) in keep.iter_mut().zip(mesh.positions()) {
            let p = Vec3::from(*p);
            *k |= regions.iter().any(|(lo, hi)| p.cmpge(*lo).all() && p.cmple(*hi).all());
        }
    }
    Ok((mesh, None))
}
