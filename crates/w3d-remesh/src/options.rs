//! Settings of the [`crate::MeshOptimizer`].

use w3d_core::{Error, Result};

use crate::ops::RemeshParams;

/// Every setting of continuous remeshing; [`Default`] gives the reference values
/// (reference A.10). Lengths are in mesh units (the unit cube `[-0.5, 0.5]³` for
/// normalised meshes).
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct RemeshOptions {
    /// Learning rate: a vertex moves at most about `lr · ref_len` per step (0.3).
    pub lr: f32,
    /// `[β₀, β₁, β₂]`: EMA weights of the first moment (3-vector), of the second moment
    /// (one scalar per vertex) and of the relative speed `nu` (0 = no smoothing)
    /// (`[0.8, 0.8, 0]`).
    pub betas: [f32; 3],
    /// Optional spatial smoothing of `[m1, m2, nu]` towards the 1-ring mean, each in
    /// `[0, 1]` (`[0, 0, 0]`).
    pub gammas: [f32; 3],
    /// Reference relative speed of the edge-length controller: vertices faster than this get
    /// longer target edges, slower ones shorter (0.3).
    pub nu_ref: f32,
    /// `(min, max)` allowed target edge length (`(0.01, 0.15)`).
    pub edge_len_lims: (f32, f32),
    /// Edges are collapsed below `ref_len · (1 − tol)` and split above `ref_len · (1 + tol)`
    /// (0.5), which drives every edge into `[lims.0 · (1 − tol), lims.1 · (1 + tol)]`.
    ///
    /// One reference pass does not guarantee this for every edge: it collapses only a
    /// far-apart subset of the short edges, a collapse lengthens the edges around it (split
    /// in the next pass), and splitting the long edge of a sliver cuts off a short one (in
    /// the shape test, `tests/remesh/shape_fit.rs`, ~40–70 edges of ~19 000 are below
    /// `lims.0 · (1 − tol)` after the reference pass in a typical step). The
    /// [`RemeshOptions::edge_floor_passes`] collapse those, so that every edge ends above the
    /// lower limit.
    pub edge_len_tol: f32,
    /// Gain of the edge-length controller (0.2).
    pub gain: f32,
    /// Weight of the uniform Laplacian added to the gradient, scaled per vertex by its last
    /// relative speed (0.02).
    pub laplacian_weight: f32,
    /// Learning-rate ramp: the rate reaches `lr` after `ramp / (1 − β₀)` steps (1).
    pub ramp: f32,
    /// Gradient components are clipped to `± grad_lim · |m1|` from the second step on (10).
    pub grad_lim: f32,
    /// The edge-length controller runs, and [`crate::MeshOptimizer::remesh`] remeshes, on
    /// steps that are multiples of this (1).
    pub remesh_interval: u32,
    /// Per-vertex target edge lengths (`true`) or one global length driven by the mean
    /// speed (`false`) (`true`).
    pub local_edge_len: bool,
    /// Run edge flips in every remesh (`true`).
    pub flip: bool,
    /// No edges are split once the mesh has this many vertices (1 000 000).
    pub max_vertices: usize,
    /// Faces with area below `area_ratio · min_len²` are collapsed (0.5).
    pub area_ratio: f32,
    /// Probability that a flagged face collapses its shortest edge (0.8).
    pub shortest_probability: f32,
    /// Seed of the random edge choice of flagged faces (0).
    pub seed: u64,
    /// Not in the reference: remove interior valence-3 vertices at edges that want to
    /// collapse, which unblocks the collapses around them (`true`; see
    /// [`crate::ops::remove_valence3_vertices`]).
    pub remove_valence3: bool,
    /// Not in the reference: at most this many rounds of fold relaxation at the end of every
    /// remesh, which moves the vertices of flipped and zero-area faces towards their 1-ring
    /// mean until none is left (10; 0 = off, the reference behaviour; see
    /// [`crate::ops::relax_folds`]).
    pub fold_relaxation_rounds: u32,
    /// Rounds of rank propagation that space the collapses of one remesh apart: 3 (the
    /// reference) or 2 (more collapses per pass; values below 2 count as 2). The floor
    /// passes always use 2. See [`crate::RemeshParams::collapse_rank_rounds`] for the
    /// measured trade-off (3).
    pub collapse_rank_rounds: u32,
    /// Not in the reference: after the pass, at most this many extra passes that only
    /// collapse edges still shorter than the hard lower limit `edge_len_lims.0 · (1 −
    /// edge_len_tol)` (no splits; 2 rank rounds), so that a remesh leaves every edge above it
    /// (8; 0 = off). They run only while such an edge is left. Measured in the shape test
    /// (300 remeshes): 2.9 floor passes per remesh on average, and no remesh left an edge
    /// below the limit; with 4 passes, 44 remeshes left up to 5 such edges.
    pub edge_floor_passes: u32,
    /// Not in the reference: a shape-following upper bound on the edge lengths. With
    /// `Some(tol)` (mesh units), every remesh cuts the edges at a vertex to at most
    /// `√(8 · tol / κ)` (but not below `edge_len_lims.0`), `κ` the largest normal curvature
    /// of the current mesh there, so that an edge's chord departs from the surface by about
    /// `tol`: flat and gently curved parts keep the lengths the speed controller gives them
    /// (up to `edge_len_lims.1`), curved ones (creases, thin rims) get shorter edges. A
    /// vertex's step stays that of its controller length, up to twice its capped length:
    /// bounding it by the capped length itself slowed the fit wherever a still-noisy mesh
    /// looks curved, and leaving it unbounded let thin parts wander (measured in the
    /// refinement, `docs/accuracy.md`). `None`: the speed controller alone, which shortens
    /// edges where vertices have stopped moving, wherever that is (the default).
    pub curvature_tolerance: Option<f32>,
}

impl Default for RemeshOptions {
    fn default() -> Self {
        RemeshOptions {
            lr: 0.3,
            betas: [0.8, 0.8, 0.0],
            gammas: [0.0; 3],
            nu_ref: 0.3,
            edge_len_lims: (0.01, 0.15),
            edge_len_tol: 0.5,
            gain: 0.2,
            laplacian_weight: 0.02,
            ramp: 1.0,
            grad_lim: 10.0,
            remesh_interval: 1,
            local_edge_len: true,
            flip: true,
            max_vertices: 1_000_000,
            area_ratio: 0.5,
            shortest_probability: 0.8,
            seed: 0,
            remove_valence3: true,
            fold_relaxation_rounds: 10,
            collapse_rank_rounds: 3,
            edge_floor_passes: 8,
            curvature_tolerance: None,
        }
    }
}

/// Chainable setters, one per field: `RemeshOptions::default().with_…(…)` (the struct is
/// `#[non_exhaustive]`, so code outside this crate cannot use struct-literal syntax).
impl RemeshOptions {
    w3d_core::setters! {
        with_lr(lr: f32);
        with_betas(betas: [f32; 3]);
        with_gammas(gammas: [f32; 3]);
        with_nu_ref(nu_ref: f32);
        with_edge_len_lims(edge_len_lims: (f32, f32));
        with_edge_len_tol(edge_len_tol: f32);
        with_gain(gain: f32);
        with_laplacian_weight(laplacian_weight: f32);
        with_ramp(ramp: f32);
        with_grad_lim(grad_lim: f32);
        with_remesh_interval(remesh_interval: u32);
        with_local_edge_len(local_edge_len: bool);
        with_flip(flip: bool);
        with_max_vertices(max_vertices: usize);
        with_area_ratio(area_ratio: f32);
        with_shortest_probability(shortest_probability: f32);
        with_seed(seed: u64);
        with_remove_valence3(remove_valence3: bool);
        with_fold_relaxation_rounds(fold_relaxation_rounds: u32);
        with_collapse_rank_rounds(collapse_rank_rounds: u32);
        with_edge_floor_passes(edge_floor_passes: u32);
        with_curvature_tolerance(curvature_tolerance: Option<f32>);
    }
}

impl RemeshOptions {
    /// Checks every setting; the error names the field and the allowed range.
    pub fn validate(&self) -> Result<()> {
        let check = |ok: bool, field: &str, expected: &str, got: String| {
            if ok {
                Ok(())
            } else {
                Err(Error::invalid(format!("RemeshOptions.{field}"), format!("{expected}, got {got}")))
            }
        };
        let positive = |v: f32| v.is_finite() && v > 0.0;
        let unit = |v: f32| (0.0..1.0).contains(&v);
        check(positive(self.lr), "lr", "a finite number > 0", self.lr.to_string())?;
        check(self.betas.iter().all(|&b| unit(b)), "betas", "values in [0, 1)", format!("{:?}", self.betas))?;
        check(
            self.gammas.iter().all(|&g| (0.0..=1.0).contains(&g)),
            "gammas",
            "values in [0, 1]",
            format!("{:?}", self.gammas),
        )?;
        check(self.nu_ref.is_finite() && self.nu_ref >= 0.0, "nu_ref", "a finite number ≥ 0", self.nu_ref.to_string())?;
        let (lo, hi) = self.edge_len_lims;
        check(
            positive(lo) && positive(hi) && lo <= hi,
            "edge_len_lims",
            "0 < min ≤ max, both finite",
            format!("{:?}", self.edge_len_lims),
        )?;
        check(unit(self.edge_len_tol), "edge_len_tol", "a value in [0, 1)", self.edge_len_tol.to_string())?;
        check(self.gain.is_finite() && self.gain >= 0.0, "gain", "a finite number ≥ 0", self.gain.to_string())?;
        check(
            self.laplacian_weight.is_finite() && self.laplacian_weight >= 0.0,
            "laplacian_weight",
            "a finite number ≥ 0",
            self.laplacian_weight.to_string(),
        )?;
        check(positive(self.ramp), "ramp", "a finite number > 0", self.ramp.to_string())?;
        check(positive(self.grad_lim), "grad_lim", "a finite number > 0", self.grad_lim.to_string())?;
        check(self.remesh_interval >= 1, "remesh_interval", "at least 1", self.remesh_interval.to_string())?;
        check(
            self.curvature_tolerance.is_none_or(positive),
            "curvature_tolerance",
            "None or a finite number > 0",
            format!("{:?}", self.curvature_tolerance),
        )?;
        check(
            self.area_ratio.is_finite() && self.area_ratio >= 0.0,
            "area_ratio",
            "a finite number ≥ 0",
            self.area_ratio.to_string(),
        )?;
        check(
            (0.0..=1.0).contains(&self.shortest_probability),
            "shortest_probability",
            "a value in [0, 1]",
            self.shortest_probability.to_string(),
        )
    }

    /// The settings of one remesh pass.
    pub fn params(&self) -> RemeshParams {
        RemeshParams {
            area_ratio: self.area_ratio,
            shortest_probability: self.shortest_probability,
            max_vertices: self.max_vertices,
            flip: self.flip,
            remove_valence3: self.remove_valence3,
            fold_relaxation_rounds: self.fold_relaxation_rounds,
            collapse_rank_rounds: self.collapse_rank_rounds,
        }
    }
}
