//! Fitting an untangled mesh to the views again without letting it cross itself.
//!
//! [`crate::untangle`] removes self-intersections by moving vertices with no regard for the
//! views, and where it has much to do (the plane's wings, the rocker arm's rims: hundreds of
//! crossing pairs) the rendered loss jumps several-fold. [`polish`] then runs more steps of
//! the coarse stage's loss at fixed topology (Adam, each vertex's step scaled by its mean edge
//! length) with a collision guard: after each step the triangles that moved are checked
//! against the whole mesh ([`self_intersections_involving`]) and every vertex of a crossing
//! triangle goes back to where it was before the step, repeatedly, until nothing crosses. A
//! mesh that enters without crossings therefore leaves without crossings.
//!
//! ```
//! use w3d_core::ViewRig;
//! use w3d_recon::{CoarseOptions, polish, view_loss};
//!
//! // A sphere fitted to views of a slightly larger sphere, every vertex free to move.
//! let rig = ViewRig::wonder3d_ortho();
//! let views = w3d_raster::render_oracle_views(&w3d_remesh::icosphere(3, 0.36)?, &rig, 64)?;
//! let start = w3d_remesh::icosphere(3, 0.3)?;
//! let options = CoarseOptions::default();
//! let free = vec![true; start.vertex_count()];
//! let (mesh, report) = polish(&views, &start, &free, &options, 30)?;
//! assert!(report.loss_after < report.loss_before);
//! assert!((view_loss(&views, &mesh, &options)? - report.loss_after).abs() < 1e-6);
//! assert!(mesh.self_intersections().is_empty());
//! # Ok::<(), w3d_core::Error>(())
//! ```

use std::time::Instant;

use glam::Vec3;
use w3d_core::{Error, Mesh, Result, ViewSet, self_intersections, self_intersections_involving};

use crate::coarse::{CoarseOptions, ViewFit};
use crate::untangle::vertex_adjacency;

/// What [`polish`] did.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct PolishReport {
    /// Steps run (0 when the mesh entered with crossings: the guard needs a clean start).
    pub steps: usize,
    /// Loss of the mesh as it came in (the coarse stage's loss, all views).
    pub loss_before: f32,
    /// Loss of the mesh as it leaves.
    pub loss_after: f32,
    /// Vertex moves the collision guard undid, over all steps.
    pub reverted: usize,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Each step also moves a free vertex this fraction of the way to its neighbours' mean
/// (uniform Laplacian), which keeps the surface as smooth as the coarse stage's regulariser
/// does. Measured (orthographic, default preset; rocker arm / plane / spot): without it normal
/// consistency fell to 0.847 / 0.849 / 0.962 (from 0.870 / 0.882 / 0.968 before polishing);
/// 0.05 gives 0.869 / 0.870 / 0.965 and 0.1 gives 0.883 / 0.876 / 0.968 at Chamfer
/// 0.0075 / 0.0039 / 0.0030.
const SMOOTHING: f32 = 0.1;

/// Adam's decay rates of the first and second moments.
const BETAS: (f32, f32) = (0.9, 0.99);

/// Runs `steps` steps of the coarse loss ([`crate::reconstruct_coarse`]'s normal and mask
/// terms, `options`' weights) on the vertices `v` of `mesh` with `free[v]` (one flag per
/// vertex; the others stay put) without changing the topology or letting any two triangles
/// cross. The step is `lr · (mean incident edge length)` per vertex with `lr` where the
/// coarse stage's schedule ended (`options.lr · options.lr_decay^options.steps`). A mesh
/// that already has crossing triangles is returned as it is (`steps` 0 in the report).
///
/// [`crate::reconstruct`] frees the vertices [`crate::untangle`] moved and two rings around
/// them. Measured there (orthographic oracle views, default preset, 40 steps, under a
/// second): the rocker arm's loss falls from 0.170 after untangling to 0.062 and its Chamfer
/// distance from 0.0094 to 0.0075; the plane's from 0.156 to 0.091 (CD 0.0045 → 0.0039).
pub fn polish(
    views: &ViewSet,
    mesh: &Mesh,
    free: &[bool],
    options: &CoarseOptions,
    steps: usize,
) -> Result<(Mesh, PolishReport)> {
    let start = Instant::now();
    if free.len() != mesh.vertex_count() {
        return Err(Error::invalid(
            "free",
            format!("one flag per vertex ({}), got {}", mesh.vertex_count(), free.len()),
        ));
    }
    let fit = ViewFit::new(views, options)?;
    let triangles = mesh.triangles().to_vec();
    let mut positions = mesh.positions().to_vec();
    // The loss and gradient at the current positions: computed once per render, used by the
    // next step and, after the last one, as the final loss.
    let mut current = fit.loss_and_gradient(&positions, &triangles)?;
    let loss_before = current.0;
    let mut report = PolishReport { steps: 0, loss_before, loss_after: loss_before, reverted: 0, seconds: 0.0 };
    if steps == 0 || !free.contains(&true) || !self_intersections(&positions, &triangles)?.is_empty() {
        report.seconds = start.elapsed().as_secs_f64();
        return Ok((mesh.clone(), report));
    }
    let n = positions.len();
    let (neighbours, faces_of) = vertex_adjacency(&triangles, n);
    let mut edge_sum = vec![0.0f32; n];
    let mut edge_count = vec![0.0f32; n];
    for t in &triangles {
        for k in 0..3 {
            let (a, b) = (t[k] as usize, t[(k + 1) % 3] as usize);
            let l = Vec3::from(positions[a]).distance(Vec3::from(positions[b]));
            edge_sum[a] += l;
            edge_sum[b] += l;
            edge_count[a] += 1.0;
            edge_count[b] += 1.0;
        }
    }
    let scale: Vec<f32> = edge_sum.iter().zip(&edge_count).map(|(s, c)| s / c.max(1.0)).collect();
    let lr = options.lr * options.lr_decay.powi(options.steps as i32);
    let (mut m1, mut m2) = (vec![Vec3::ZERO; n], vec![0.0f32; n]);
    let movable: Vec<usize> = (0..n).filter(|&v| free[v]).collect();
    let mut moving: Vec<u32> = movable.iter().flat_map(|&v| faces_of[v].iter().copied()).collect();
    moving.sort_unstable();
    moving.dedup();
    for step in 1..=steps {
        let (loss, grad) = current;
        if !loss.is_finite() {
            return Err(Error::invalid("views", format!("finite normal and mask values (the loss became {loss})")));
        }
        let before = positions.clone();
        let (c1, c2) = (1.0 - BETAS.0.powi(step as i32), 1.0 - BETAS.1.powi(step as i32));
        for &v in &movable {
            let g = Vec3::from(grad[v]);
            m1[v] = BETAS.0 * m1[v] + (1.0 - BETAS.0) * g;
            m2[v] = BETAS.1 * m2[v] + (1.0 - BETAS.1) * g.length_squared() / 3.0;
            let d = lr * scale[v] * (m1[v] / c1) / ((m2[v] / c2).sqrt() + 1e-12);
            let x = Vec3::from(before[v]);
            let mean = neighbours[v].iter().map(|&u| Vec3::from(before[u as usize])).sum::<Vec3>()
                / neighbours[v].len().max(1) as f32;
            positions[v] = (x - d + SMOOTHING * (mean - x)).to_array();
        }
        // The guard: undo the moves of every crossing triangle's vertices until none cross.
        let mut focus = moving.clone();
        loop {
            let pairs = self_intersections_involving(&positions, &triangles, &focus)?;
            if pairs.is_empty() {
                break;
            }
            let mut undone: Vec<usize> = pairs
                .iter()
                .flat_map(|&[a, b]| triangles[a as usize].into_iter().chain(triangles[b as usize]))
                .map(|v| v as usize)
                .filter(|&v| positions[v] != before[v])
                .collect();
            undone.sort_unstable();
            undone.dedup();
            if undone.is_empty() {
                break; // cannot happen from a clean start: only moved triangles can cross
            }
            for &v in &undone {
                positions[v] = before[v];
            }
            report.reverted += undone.len();
            focus = undone.iter().flat_map(|&v| faces_of[v].iter().copied()).collect();
            focus.sort_unstable();
            focus.dedup();
        }
        report.steps = step;
        current = fit.loss_and_gradient(&positions, &triangles)?;
    }
    report.loss_after = current.0;
    report.seconds = start.elapsed().as_secs_f64();
    Ok((Mesh::new(positions, triangles)?, report))
}

#[cfg(test)]
mod tests {
    use super::*;
    use w3d_core::ViewRig;

    /// Vertices that are not free stay exactly where they were; a mesh that comes in with
    /// crossings is returned unchanged.
    #[test]
    fn only_free_vertices_move_and_crossing_input_is_left_alone() {
        let rig = ViewRig::wonder3d_ortho();
        let views = w3d_raster::render_oracle_views(&w3d_remesh::icosphere(3, 0.36).unwrap(), &rig, 64).unwrap();
        let start = w3d_remesh::icosphere(3, 0.3).unwrap();
        let free: Vec<bool> = start.positions().iter().map(|p| p[1] > 0.0).collect();
        let (mesh, report) = polish(&views, &start, &free, &CoarseOptions::default(), 20).unwrap();
        assert_eq!(report.steps, 20);
        for ((p, q), &f) in mesh.positions().iter().zip(start.positions()).zip(&free) {
            assert_eq!(p == q, !f, "free {f}: {p:?} vs {q:?}");
        }
        assert!(report.loss_after < report.loss_before, "{report:?}");

        let mut crossing = start.positions().to_vec();
        crossing[0] = crossing[0].map(|x| -1.3 * x);
        let crossing = Mesh::new(crossing, start.triangles().to_vec()).unwrap();
        assert!(!crossing.self_intersections().is_empty());
        let all = vec![true; crossing.vertex_count()];
        let (same, report) = polish(&views, &crossing, &all, &CoarseOptions::default(), 20).unwrap();
        assert_eq!(report.steps, 0);
        assert_eq!(same.positions(), crossing.positions());
        assert!(polish(&views, &crossing, &all[1..], &CoarseOptions::default(), 20).is_err());
    }
}
