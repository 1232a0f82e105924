//! The continuous-remeshing optimizer: per-vertex Adam-like state, the reference
//! edge-length controller, and remeshing that carries the state along.

use w3d_core::{Error, Mesh, Result};

use crate::edges::EdgeTable;
use crate::ops::{self, RemeshStats};
use crate::options::RemeshOptions;
use crate::rows::{VertexRows, mean3, retain_indices};
use crate::topology::check_manifold;

/// Per-vertex state: position, first moment `m1` (3-vector), second moment `m2` (one
/// scalar), relative speed `nu` and target edge length `ref_len` (reference A.1).
#[derive(Debug, Clone, PartialEq)]
struct VertexState {
    positions: Vec<[f32; 3]>,
    m1: Vec<[f32; 3]>,
    m2: Vec<f32>,
    nu: Vec<f32>,
    ref_len: Vec<f32>,
}

impl VertexRows for VertexState {
    fn positions(&self) -> &[[f32; 3]] {
        &self.positions
    }

    fn set_position(&mut self, i: usize, p: [f32; 3]) {
        self.positions[i] = p;
    }

    fn set_mean(&mut self, dst: usize, a: usize, b: usize) {
        self.positions[dst] = mean3(self.positions[a], self.positions[b]);
        self.m1[dst] = mean3(self.m1[a], self.m1[b]);
        self.m2[dst] = 0.5 * (self.m2[a] + self.m2[b]);
        self.nu[dst] = 0.5 * (self.nu[a] + self.nu[b]);
        self.ref_len[dst] = 0.5 * (self.ref_len[a] + self.ref_len[b]);
    }

    fn push_mean(&mut self, a: usize, b: usize) {
        self.positions.push(mean3(self.positions[a], self.positions[b]));
        self.m1.push(mean3(self.m1[a], self.m1[b]));
        self.m2.push(0.5 * (self.m2[a] + self.m2[b]));
        self.nu.push(0.5 * (self.nu[a] + self.nu[b]));
        self.ref_len.push(0.5 * (self.ref_len[a] + self.ref_len[b]));
    }

    fn retain_rows(&mut self, keep: &[u32]) {
        retain_indices(&mut self.positions, keep);
        retain_indices(&mut self.m1, keep);
        retain_indices(&mut self.m2, keep);
        retain_indices(&mut self.nu, keep);
        retain_indices(&mut self.ref_len, keep);
    }
}

/// A field of lower bounds on the target edge length, evaluated at vertex positions.
type LengthField = Box<dyn Fn([f32; 3]) -> f32 + Send + Sync>;

/// Continuous remeshing (Palfinger 2022): use it like a gradient-descent optimizer of
/// vertex positions, calling [`MeshOptimizer::step`] with the loss gradient and then
/// [`MeshOptimizer::remesh`]; the vertex count and triangles change at every remesh, so
/// read [`MeshOptimizer::positions`] / [`MeshOptimizer::triangles`] afresh before computing
/// the next gradient.
///
/// The input must be a consistently oriented 2-manifold (closed or open) whose every vertex
/// is used. Closed meshes stay closed and keep their genus. With the default fold
/// relaxation, a remesh leaves no flipped face (unit normal against the sum of its edge
/// neighbours' unit normals) and no zero-area face unless the relaxation gives up after
/// its rounds ([`RemeshStats::folds_left`] reports that; never seen in the tests). **Open meshes**: boundary edges
/// are never flipped; an interior edge joining two boundary vertices is never collapsed
/// (that would pinch the surface); a collapse between an interior and a boundary vertex
/// keeps the boundary vertex's position; boundary edges may be split and collapsed (their
/// midpoint stays on the old boundary polyline), so the boundary is resampled but not moved
/// by remeshing — only the gradient moves it.
///
/// **Density control.** Each vertex carries a target edge length `ref_len`
/// ([`MeshOptimizer::target_edge_lengths`]): edges shorter than `ref_len·(1 − tol)` are
/// collapsed, longer than `ref_len·(1 + tol)` split. The controller grows it where vertices
/// still move fast and shrinks it where they have converged, within `edge_len_lims`. To
/// model no more than the images can show, bound it from below by the image-space pixel
/// footprint — e.g. `2 · 1.5 / 256` units for the 1.5-unit orthographic view at 256² —
/// with [`MeshOptimizer::set_min_edge_length_field`] (a function of position, applied after
/// every controller update) or [`MeshOptimizer::clamp_target_edge_lengths`] (per-vertex
/// values); the upper limit `edge_len_lims.1` always wins.
pub struct MeshOptimizer {
    options: RemeshOptions,
    state: VertexState,
    triangles: Vec<[u32; 3]>,
    /// Unique edges of `triangles` (any order).
    edges: Vec<[u32; 2]>,
    steps: u64,
    remeshes: u64,
    min_length_field: Option<LengthField>,
    /// Per current vertex, what to size it by instead of the mesh's curvature alone; see
    /// [`MeshOptimizer::set_curvature_hint`]. Dropped by the next remesh.
    curvature_hint: Option<Vec<CurvatureHint>>,
}

impl std::fmt::Debug for MeshOptimizer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MeshOptimizer")
            .field("options", &self.options)
            .field("vertices", &self.state.positions.len())
            .field("triangles", &self.triangles.len())
            .field("steps", &self.steps)
            .field("remeshes", &self.remeshes)
            .field("min_length_field", &self.min_length_field.is_some())
            .field("curvature_hint", &self.curvature_hint.is_some())
            .finish()
    }
}

/// `a ← a·β(1 − β^{t−1})/(1 − β^t) + b·(1 − β)/(1 − β^t)`: the weights of an EMA that keeps
/// Adam's bias correction (at `t = 1` the result is `b`).
fn lerp_unbiased_weights(beta: f32, t: u64) -> (f32, f32) {
    let beta = f64::from(beta);
    let c_prev = 1.0 - beta.powf((t - 1) as f64);
    let c = 1.0 - beta.powf(t as f64);
    ((beta * c_prev / c) as f32, ((1.0 - beta) / c) as f32)
}

impl MeshOptimizer {
    /// An optimizer starting at `positions` / `triangles` (counter-clockwise seen from
    /// outside) with `options`. All moments start at 0 and every target edge length at
    /// `edge_len_lims.1`.
    ///
    /// Errors: invalid options, non-finite positions, indices out of range, a non-manifold
    /// or inconsistently oriented mesh, or vertices no triangle uses.
    pub fn new(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>, options: RemeshOptions) -> Result<Self> {
        options.validate()?;
        if positions.len() >= u32::MAX as usize {
            return Err(Error::invalid("positions", "fewer than 2³² − 1 vertices"));
        }
        for (i, p) in positions.iter().enumerate() {
            if let Some(axis) = (0..3).find(|&k| !p[k].is_finite()) {
                return Err(Error::invalid(
                    format!("positions[{i}].{}", ["x", "y", "z"][axis]),
                    format!("a finite number, got {}", p[axis]),
                ));
            }
        }
        let summary = check_manifold(positions.len(), &triangles)?;
        if summary.unreferenced > 0 {
            return Err(Error::invalid(
                "positions",
                format!("every vertex used by a triangle, got {} unused vertices", summary.unreferenced),
            ));
        }
        let n = positions.len();
        let edges = EdgeTable::new(&triangles, None, n).edges;
        let state = VertexState {
            positions,
            m1: vec![[0.0; 3]; n],
            m2: vec![0.0; n],
            nu: vec![0.0; n],
            ref_len: vec![options.edge_len_lims.1; n],
        };
        Ok(MeshOptimizer {
            options,
            state,
            triangles,
            edges,
            steps: 0,
            remeshes: 0,
            min_length_field: None,
            curvature_hint: None,
        })
    }

    /// [`MeshOptimizer::new`] from a [`Mesh`] (its attributes are dropped).
    pub fn from_mesh(mesh: &Mesh, options: RemeshOptions) -> Result<Self> {
        Self::new(mesh.positions().to_vec(), mesh.triangles().to_vec(), options)
    }

    /// One optimizer step with `grad[v]` = ∂loss/∂position of vertex `v` (reference A.2):
    /// optional spatial smoothing of the moments, the Laplacian term
    /// `laplacian_weight · nu · (x − mean of 1-ring)`, clipping to `± grad_lim·|m1|`,
    /// bias-corrected moment updates, the move `x −= lr_t · ref_len · m1 / (√m2 + 1e-8)`
    /// (with [`RemeshOptions::curvature_tolerance`], `ref_len` at most twice the vertex's
    /// curvature cap)
    /// and, every `remesh_interval` steps, the edge-length controller
    /// `ref_len ·= 1 + (nu − nu_ref)·gain`, clamped to `edge_len_lims` and bounded below by
    /// the minimum-length field if one is set.
    ///
    /// Errors (state unchanged): `grad` not one finite 3-vector per current vertex.
    pub fn step(&mut self, grad: &[[f32; 3]]) -> Result<()> {
        let n = self.state.positions.len();
        if grad.len() != n {
            return Err(Error::invalid("grad", format!("one gradient per current vertex ({n}), got {}", grad.len())));
        }
        for (i, g) in grad.iter().enumerate() {
            if let Some(axis) = (0..3).find(|&k| !g[k].is_finite()) {
                return Err(Error::invalid(
                    format!("grad[{i}].{}", ["x", "y", "z"][axis]),
                    format!("a finite number, got {}", g[axis]),
                ));
            }
        }
        self.steps += 1;
        let t = self.steps;
        let o = self.options;
        let s = &mut self.state;

        // 1-ring means (uniform weights over unique edges).
        let smooth_state = o.gammas.iter().any(|&g| g != 0.0);
        let mut sum = vec![[0.0f32; 3]; n];
        let mut count = vec![0u32; n];
        let mut sum_state = if smooth_state { vec![[0.0f32; 5]; n] } else { Vec::new() };
        for &[a, b] in &self.edges {
            let (a, b) = (a as usize, b as usize);
            let (pa, pb) = (s.positions[a], s.positions[b]);
            sum[a] = std::array::from_fn(|k| sum[a][k] + pb[k]);
            sum[b] = std::array::from_fn(|k| sum[b][k] + pa[k]);
            count[a] += 1;
            count[b] += 1;
            if smooth_state {
                let row = |v: usize| [s.m1[v][0], s.m1[v][1], s.m1[v][2], s.m2[v], s.nu[v]];
                let (ra, rb) = (row(a), row(b));
                for k in 0..5 {
                    sum_state[a][k] += rb[k];
                    sum_state[b][k] += ra[k];
                }
            }
        }
        if smooth_state {
            for v in 0..n {
                let c = count[v].max(1) as f32;
                let nb = sum_state[v].map(|x| x / c);
                let m1 = s.m1[v];
                s.m1[v] = std::array::from_fn(|k| m1[k] + (nb[k] - m1[k]) * o.gammas[0]);
                s.m2[v] += (nb[3] - s.m2[v]) * o.gammas[1];
                s.nu[v] += (nb[4] - s.nu[v]) * o.gammas[2];
            }
        }

        // With a curvature tolerance, a vertex moves by at most `lr` times twice its capped
        // edge length (`RemeshOptions::curvature_tolerance`).
        let step_lengths: Vec<f32> = match o.curvature_tolerance {
            Some(tol) => {
                curvature_length_caps(&s.positions, &self.triangles, &self.edges, self.curvature_hint.as_deref(), tol)
                    .iter()
                    .zip(&s.ref_len)
                    .map(|(cap, &len)| len.min((CURVATURE_STEP_FACTOR * cap).max(o.edge_len_lims.0)))
                    .collect()
            }
            None => Vec::new(),
        };
        let (a1, b1) = lerp_unbiased_weights(o.betas[0], t);
        let (a2, b2) = lerp_unbiased_weights(o.betas[1], t);
        let (a3, b3) = lerp_unbiased_weights(o.betas[2], t);
        let lr = o.lr * (t as f32 * (1.0 - o.betas[0]) / o.ramp).min(1.0);
        for v in 0..n {
            let c = count[v].max(1) as f32;
            let x = s.positions[v];
            let lap = o.laplacian_weight * s.nu[v];
            let old_m1 = s.m1[v];
            let g: [f32; 3] = std::array::from_fn(|k| {
                let g = grad[v][k] + lap * (x[k] - sum[v][k] / c);
                if t > 1 {
                    let lim = o.grad_lim * old_m1[k].abs();
                    g.max(-lim).min(lim)
                } else {
                    g
                }
            });
            let m1: [f32; 3] = std::array::from_fn(|k| old_m1[k] * a1 + g[k] * b1);
            let m2 = s.m2[v] * a2 + (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]) * b2;
            let denom = m2.sqrt() + 1e-8;
            let vel = m1.map(|m| m / denom);
            let speed = (vel[0] * vel[0] + vel[1] * vel[1] + vel[2] * vel[2]).sqrt();
            s.nu[v] = if o.betas[2] != 0.0 { s.nu[v] * a3 + speed * b3 } else { speed };
            s.m1[v] = m1;
            s.m2[v] = m2;
            let scale = lr * step_lengths.get(v).copied().unwrap_or(s.ref_len[v]);
            s.positions[v] = std::array::from_fn(|k| x[k] - scale * vel[k]);
        }

        if t.is_multiple_of(u64::from(o.remesh_interval)) {
            let (lo, hi) = o.edge_len_lims;
            let mean_nu = s.nu.iter().map(|&x| f64::from(x)).sum::<f64>() as f32 / n as f32;
            for v in 0..n {
                let nu = if o.local_edge_len { s.nu[v] } else { mean_nu };
                let mut len = (s.ref_len[v] * (1.0 + (nu - o.nu_ref) * o.gain)).clamp(lo, hi);
                if let Some(field) = &self.min_length_field {
                    let floor = field(s.positions[v]);
                    if floor.is_finite() {
                        len = len.max(floor).min(hi);
                    }
                }
                s.ref_len[v] = len;
            }
        }
        Ok(())
    }

    /// Remeshes (valence-3 removal → collapse → split → pack → fold relaxation → flip, see
    /// [`ops::remesh`]) when the step count
    /// is a multiple of `remesh_interval` (always with the default interval 1); otherwise
    /// does nothing and reports zero operations. All per-vertex state follows the vertices.
    pub fn remesh(&mut self) -> RemeshStats {
        if !self.steps.is_multiple_of(u64::from(self.options.remesh_interval)) {
            return RemeshStats {
                vertices: self.state.positions.len(),
                triangles: self.triangles.len(),
                ..RemeshStats::default()
            };
        }
        self.remesh_now()
    }

    /// Remeshes now, whatever the step count. With [`RemeshOptions::curvature_tolerance`],
    /// each vertex's target length is first capped by the current mesh's curvature there.
    pub fn remesh_now(&mut self) -> RemeshStats {
        let tol = self.options.edge_len_tol;
        let caps = match self.options.curvature_tolerance {
            Some(tol) => curvature_length_caps(
                &self.state.positions,
                &self.triangles,
                &self.edges,
                self.curvature_hint.as_deref(),
                tol,
            ),
            None => Vec::new(),
        };
        // The hint is per vertex of the mesh as it was: the remesh renumbers them.
        self.curvature_hint = None;
        let lo = self.options.edge_len_lims.0;
        let target: Vec<f32> =
            self.state.ref_len.iter().enumerate().map(|(v, &r)| caps.get(v).map_or(r, |c| r.min(c.max(lo)))).collect();
        let min_len: Vec<f32> = target.iter().map(|&r| r * (1.0 - tol)).collect();
        let max_len: Vec<f32> = target.iter().map(|&r| r * (1.0 + tol)).collect();
        let seed = self.options.seed ^ self.remeshes.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        self.remeshes += 1;
        let triangles = std::mem::take(&mut self.triangles);
        let params = self.options.params();
        let (mut triangles, mut edges, mut stats) =
            ops::remesh(&mut self.state, triangles, &min_len, &max_len, &params, seed);
        // Floor passes: a pass collapses only a far-apart subset of the short edges, so a few
        // can stay below the hard lower limit; collapse just those (no splits).
        let floor = self.options.edge_len_lims.0 * (1.0 - tol);
        let floor_params = ops::RemeshParams { collapse_rank_rounds: 2, ..params };
        for pass in 0..self.options.edge_floor_passes {
            let p = &self.state.positions;
            if !edges.iter().any(|&[a, b]| crate::edges::distance(p[a as usize], p[b as usize]) < floor) {
                break;
            }
            let n = p.len();
            let seed = seed ^ (u64::from(pass) + 1).wrapping_mul(0xD1B5_4A32_D192_ED03);
            let (t, e, more) =
                ops::remesh(&mut self.state, triangles, &vec![floor; n], &vec![f32::INFINITY; n], &floor_params, seed);
            (triangles, edges) = (t, e);
            stats = RemeshStats {
                collapsed: stats.collapsed + more.collapsed,
                split: stats.split + more.split,
                flipped: stats.flipped + more.flipped,
                removed_valence3: stats.removed_valence3 + more.removed_valence3,
                folded: stats.folded + more.folded,
                floor_passes: stats.floor_passes + 1,
                ..more
            };
        }
        self.triangles = triangles;
        self.edges = edges;
        stats
    }

    /// Current vertex positions.
    pub fn positions(&self) -> &[[f32; 3]] {
        &self.state.positions
    }

    /// Current triangles, counter-clockwise seen from outside.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// Unique undirected edges of the current triangles (in no particular order).
    pub fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }

    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.state.positions.len()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Per-vertex target edge length `ref_len` (mesh units).
    pub fn target_edge_lengths(&self) -> &[f32] {
        &self.state.ref_len
    }

    /// Per-vertex first moments `m1` (bias-corrected EMA of the gradient).
    pub fn first_moments(&self) -> &[[f32; 3]] {
        &self.state.m1
    }

    /// Per-vertex second moments `m2` (bias-corrected EMA of `|gradient|²`).
    pub fn second_moments(&self) -> &[f32] {
        &self.state.m2
    }

    /// Per-vertex relative speeds `nu = |m1| / √m2` of the last step.
    pub fn relative_speeds(&self) -> &[f32] {
        &self.state.nu
    }

    /// Steps taken so far.
    pub fn step_count(&self) -> u64 {
        self.steps
    }

    /// The settings.
    pub fn options(&self) -> &RemeshOptions {
        &self.options
    }

    /// Replaces the settings (e.g. a lower learning rate for a refinement stage); the
    /// per-vertex state is kept.
    pub fn set_options(&mut self, options: RemeshOptions) -> Result<()> {
        options.validate()?;
        self.options = options;
        Ok(())
    }

    /// Overwrites the per-vertex target edge lengths (one finite value > 0 per vertex).
    /// The next controller update clamps them to `edge_len_lims` again.
    pub fn set_target_edge_lengths(&mut self, lengths: &[f32]) -> Result<()> {
        self.check_field("lengths", lengths, false)?;
        self.state.ref_len.copy_from_slice(lengths);
        Ok(())
    }

    /// Raises every target edge length to at least `lower[v]` (then caps it at
    /// `edge_len_lims.1`): the per-vertex way to stop refining below the pixel footprint.
    /// `lower` holds one finite value ≥ 0 per vertex.
    pub fn clamp_target_edge_lengths(&mut self, lower: &[f32]) -> Result<()> {
        self.check_field("lower", lower, true)?;
        let hi = self.options.edge_len_lims.1;
        for (r, &l) in self.state.ref_len.iter_mut().zip(lower) {
            *r = r.max(l).min(hi);
        }
        Ok(())
    }

    /// Sets a lower bound on the target edge length as a function of position (mesh units
    /// in, mesh units out), applied after every controller update:
    /// `ref_len = min(max(ref_len, field(x)), edge_len_lims.1)`; non-finite values are
    /// ignored. Typical use: the world-space size of a pixel at `x` in the views.
    pub fn set_min_edge_length_field(&mut self, field: impl Fn([f32; 3]) -> f32 + Send + Sync + 'static) {
        self.min_length_field = Some(Box::new(field));
    }

    /// What to size each current vertex's edges by instead of the mesh's own curvature
    /// ([`RemeshOptions::curvature_tolerance`]), where something knows the shape better than
    /// the mesh does — such as the target images of a fit, which show the surface's
    /// curvature before the mesh has it. It applies to the next [`MeshOptimizer::step`] and
    /// remesh, then is dropped (a remesh renumbers the vertices): set it again before every
    /// step. Without a curvature tolerance it has no effect.
    ///
    /// Errors: not one hint per current vertex, or a curvature that is negative or not
    /// finite.
    pub fn set_curvature_hint(&mut self, hints: Vec<CurvatureHint>) -> Result<()> {
        let n = self.state.positions.len();
        if hints.len() != n {
            return Err(Error::invalid("curvature", format!("one hint per current vertex ({n}), got {}", hints.len())));
        }
        for (i, hint) in hints.iter().enumerate() {
            if let CurvatureHint::Replace(k) | CurvatureHint::AtLeast(k) = *hint
                && !(k.is_finite() && k >= 0.0)
            {
                return Err(Error::invalid(format!("curvature[{i}]"), format!("a finite curvature ≥ 0, got {k}")));
            }
        }
        self.curvature_hint = Some(hints);
        Ok(())
    }

    /// Removes the minimum-length field.
    pub fn clear_min_edge_length_field(&mut self) {
        self.min_length_field = None;
    }

    /// The current mesh as a validated [`Mesh`].
    pub fn to_mesh(&self) -> Result<Mesh> {
        Mesh::new(self.state.positions.clone(), self.triangles.clone())
    }

    fn check_field(&self, field: &str, values: &[f32], allow_zero: bool) -> Result<()> {
        let n = self.state.positions.len();
        if values.len() != n {
            return Err(Error::invalid(field, format!("one value per current vertex ({n}), got {}", values.len())));
        }
        for (i, &v) in values.iter().enumerate() {
            if !(v.is_finite() && (v > 0.0 || (allow_zero && v == 0.0))) {
                let expected = if allow_zero { "a finite number ≥ 0" } else { "a finite number > 0" };
                return Err(Error::invalid(format!("{field}[{i}]"), format!("{expected}, got {v}")));
            }
        }
        Ok(())
    }
}

/// What [`MeshOptimizer::set_curvature_hint`] sizes one vertex by (curvatures in 1 / mesh
/// units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CurvatureHint {
    /// The mesh's own curvature (as without a hint).
    Mesh,
    /// This curvature instead of the mesh's.
    Replace(f32),
    /// The larger of this curvature and the mesh's.
    AtLeast(f32),
}

/// How far a vertex whose target edge length the curvature caps may still move per step, in
/// capped edge lengths (times the learning rate): see `RemeshOptions::curvature_tolerance`.
const CURVATURE_STEP_FACTOR: f32 = 2.0;

/// Per-vertex caps `√(8 · tol / κ)` on the target edge length, `κ` as the vertex's entry of
/// `hint` says (without one, the mesh's: [`vertex_curvatures`]). An edge of that length on a
/// surface of curvature `κ` departs from it by about `tol` at its middle (the sagitta
/// `κ l² / 8`).
fn curvature_length_caps(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    edges: &[[u32; 2]],
    hint: Option<&[CurvatureHint]>,
    tol: f32,
) -> Vec<f32> {
    curvatures_over_edges(positions, triangles, edges)
        .into_iter()
        .enumerate()
        .map(|(v, mesh)| {
            let kappa = match hint.and_then(|h| h.get(v)) {
                Some(CurvatureHint::Replace(h)) => *h,
                Some(CurvatureHint::AtLeast(h)) => h.max(mesh),
                Some(CurvatureHint::Mesh) | None => mesh,
            };
            (8.0 * tol / kappa.max(1e-12)).sqrt()
        })
        .collect()
}

/// The curvature estimate the remesher sizes edges by
/// ([`RemeshOptions::curvature_tolerance`]), per vertex of `mesh`, in 1 / mesh units: the
/// largest normal curvature at the vertex over its edges, `2 |n · e| / |e|²` (the circle
/// through both ends tangent to the vertex's area-weighted normal), averaged with the same
/// value of its neighbours so that one noisy edge does not decide. A mesh with split vertices
/// (a vertex per face corner) shows no curvature: weld it first
/// (`w3d_core::Mesh::merge_by_position`).
///
/// ```
/// // An icosphere of radius 0.4 reads a little over 1 / 0.4 everywhere (the largest over
/// // each vertex's edges).
/// let sphere = w3d_remesh::icosphere(4, 0.4)?;
/// let curvatures = w3d_remesh::vertex_curvatures(&sphere);
/// assert!(curvatures.iter().all(|k| (k * 0.4 - 1.0).abs() < 0.08)); // 1.01-1.06 times 1 / r
/// # Ok::<(), w3d_core::Error>(())
/// ```
pub fn vertex_curvatures(mesh: &Mesh) -> Vec<f32> {
    let edges = EdgeTable::new(mesh.triangles(), None, mesh.vertex_count()).edges;
    curvatures_over_edges(mesh.positions(), mesh.triangles(), &edges)
}

/// [`vertex_curvatures`] with the unique edges `[lo, hi]` of `triangles` given.
fn curvatures_over_edges(positions: &[[f32; 3]], triangles: &[[u32; 3]], edges: &[[u32; 2]]) -> Vec<f32> {
    use glam::Vec3;
    let n = positions.len();
    let p = |v: u32| Vec3::from(positions[v as usize]);
    let mut normals = vec![Vec3::ZERO; n];
    for &[a, b, c] in triangles {
        let area_normal = (p(b) - p(a)).cross(p(c) - p(a));
        for v in [a, b, c] {
            normals[v as usize] += area_normal;
        }
    }
    for normal in &mut normals {
        *normal = normal.normalize_or_zero();
    }
    let mut curvature = vec![0.0f32; n];
    for &[a, b] in edges {
        let e = p(b) - p(a);
        let len2 = e.length_squared();
        if len2 <= 0.0 {
            continue;
        }
        let (ka, kb) = (2.0 * normals[a as usize].dot(e).abs() / len2, 2.0 * normals[b as usize].dot(e).abs() / len2);
        curvature[a as usize] = curvature[a as usize].max(ka);
        curvature[b as usize] = curvature[b as usize].max(kb);
    }
    let mut sum = curvature.clone();
    let mut count = vec![1u32; n];
    for &[a, b] in edges {
        sum[a as usize] += curvature[b as usize];
        sum[b as usize] += curvature[a as usize];
        count[a as usize] += 1;
        count[b as usize] += 1;
    }
    sum.iter().zip(&count).map(|(k, c)| k / *c as f32).collect()
}
