//! Removing the self-intersections the coarse stage can leave.
//!
//! Continuous remeshing moves vertices along their gradients without a collision guard, so
//! where two sheets of the surface are pushed towards each other (thin parts, folds into a
//! cavity no view sees) triangles can end up crossing. [`untangle`] finds the crossing pairs
//! ([`Mesh::self_intersections`]) and moves only the vertices of those triangles, in rounds,
//! until none cross:
//!
//! * a **separation** round gives each crossing pair the smallest move that puts one of its
//!   two triangles wholly on one side of the other's plane (5 % of an edge past it; each
//!   vertex takes the mean of its pairs' moves). It moves vertices by the penetration depth only,
//!   so thin parts (the plane's wings, the rocker arm's rims) keep their shape;
//! * when a separation round does not reduce the count (moves of neighbouring pairs can
//!   undo each other in a crumpled patch), a **smoothing** round moves the vertices of the
//!   crossing triangles, and `rings` rings around them, half way towards the average of
//!   their neighbours (uniform Laplacian, which pulls a fold back into the sheet it crossed);
//! * progress is judged against the **fewest** crossings seen so far, not against the round
//!   before: every [`STALL_ROUNDS`] rounds without a new fewest, the smoothed neighbourhood
//!   grows by one ring (up to [`MAX_RINGS`]), and it shrinks back to the crossing triangles
//!   when a round reaches a new fewest;
//! * the second half of the rounds smooths only (separation moves can cycle).
//!
//! If rounds run out with crossings left, the positions with the fewest crossings seen are
//! returned (never worse than the best round).
//!
//! Why the stall counter: judged against the round before, a separation round that adds a
//! crossing (3 → 4) and the smoothing round that removes it again (4 → 3) both look like
//! the expected behaviour, the neighbourhood never grows, and the two alternate until the
//! rounds run out; in the smooth-only half a one-ring neighbourhood then settles on a fixed
//! point that still crosses (uniform-Laplacian averages of a crumpled boundary). That is
//! how spot (perspective rig, default preset: 59 pairs → 3) and the plane (orthographic,
//! quality preset: 2024 → 9) kept crossings after the oracle normals changed in their last
//! bits (`docs/accuracy.md`); on 154 coarse meshes (14 oracle meshes and the teapot and
//! teacups, both rigs, presets and remesher seeds 0–5) the old rule left crossings in 9,
//! this one in 1 (the teapot's handle, seed 3), which [`crate::reconstruct`] handles by
//! running the coarse stage again with another remesher seed.
//!
//! After the first full check, a round re-checks only the triangles whose vertices moved
//! ([`self_intersections_involving`]). Against smoothing alone the separation moves remove
//! far more (rocker arm, orthographic: 492 pairs → 0 and CD 0.0068, where smoothing alone
//! left 72 pairs).

use std::collections::HashMap;

use glam::Vec3;
use w3d_core::{Mesh, Result, normals, self_intersections, self_intersections_involving};

/// What [`untangle`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct UntangleReport {
    /// Crossing triangle pairs before.
    pub before: usize,
    /// Crossing triangle pairs after (0 unless `max_rounds` ran out).
    pub after: usize,
    /// Rounds run (separation and smoothing).
    pub rounds: usize,
}

/// How far the smoothed neighbourhood may grow beyond the crossing triangles (rings), after
/// [`STALL_ROUNDS`] rounds without progress per ring. Wider smoothing shrinks thin parts
/// (six rings from the start cost the rocker arm a Chamfer of 0.0128 instead of 0.0098),
/// and around a thin tube (the teapot's handle) eight rings wrap round it and flatten it
/// onto itself; four was the widest that helped on the 154 coarse meshes of the module docs.
const MAX_RINGS: usize = 4;

/// Rounds without a new fewest crossing count before the smoothed neighbourhood grows by
/// one ring. Measured on 70 of the coarse meshes of the module docs (remesher seeds 0 and 5):
/// 2 and 4 moved the vertices further than 8 (total displacement +31 % and +12 %) and each
/// left one mesh with crossings, 8 none.
const STALL_ROUNDS: usize = 8;

/// The step of a smoothing round towards the neighbours' average.
const STEP: f32 = 0.5;

/// How far past the other triangle's plane a separation move puts a vertex, as a fraction
/// of that triangle's longest edge. Measured (400 rounds): 0.01 leaves 22 of the rocker
/// arm's 824 crossing pairs, 0.05 none (and none on the teapot); 0.1 and 0.2 left more
/// again at 200 rounds (37, 38) — neighbouring moves then overshoot into new crossings.
const MARGIN: f32 = 0.05;

/// Moves the vertices of crossing triangles (separation, then smoothing rounds) until none
/// cross or `max_rounds` rounds have run. Topology is unchanged; positions are in the mesh's
/// own units.
pub fn untangle(mesh: &Mesh, max_rounds: usize) -> Result<(Mesh, UntangleReport)> {
    let triangles = mesh.triangles().to_vec();
    let mut positions = mesh.positions().to_vec();
    let report = untangle_positions(&mut positions, &triangles, max_rounds)?;
    Ok((Mesh::new(positions, triangles)?, report))
}

/// [`untangle`] in place on plain arrays. Fails when a triangle names a vertex that
/// `positions` does not have.
pub fn untangle_positions(
    positions: &mut [[f32; 3]],
    triangles: &[[u32; 3]],
    max_rounds: usize,
) -> Result<UntangleReport> {
    let pairs = self_intersections(positions, triangles)?;
    untangle_crossing(positions, triangles, pairs, max_rounds)
}

/// [`untangle_positions`] given the crossing pairs of `positions` (as
/// [`self_intersections`] finds them), for callers that have counted them already.
pub(crate) fn untangle_crossing(
    positions: &mut [[f32; 3]],
    triangles: &[[u32; 3]],
    mut pairs: Vec<[u32; 2]>,
    max_rounds: usize,
) -> Result<UntangleReport> {
    let before = pairs.len();
    // However many pairs: views that do not show one object (a wrong view, a diffusion
    // model's noise) leave more crossing pairs than triangles, and those untangle too. (An
    // earlier guard returned such meshes as they were, which left the plane with a wrong
    // view at 1857 crossing pairs on 1430 triangles: untangled, 85 rounds, 0.2 s. Views of
    // random normals, noise σ = 5, leave about 2.6 pairs per triangle; 400 rounds take 2–7 s
    // on 7–10 k triangles.)
    if pairs.is_empty() || max_rounds == 0 {
        return Ok(UntangleReport { before, after: before, rounds: 0 });
    }
    let n = positions.len();
    let (neighbours, faces_of) = vertex_adjacency(triangles, n);
    let (mut rounds, mut rings, mut separate) = (0, 0, true);
    // The fewest crossings seen, the positions that had them, and the rounds since.
    let (mut fewest, mut best, mut stalled) = (pairs.len(), positions.to_vec(), 0);
    while !pairs.is_empty() && rounds < max_rounds {
        let separating = separate && 2 * rounds < max_rounds;
        let moves = if separating {
            separation_moves(positions, triangles, &pairs)
        } else {
            smoothing_moves(positions, triangles, &pairs, &neighbours, rings)
        };
        let mut moved = vec![false; n];
        for &(v, p) in &moves {
            positions[v] = p;
            moved[v] = true;
        }
        rounds += 1;
        // Only pairs with a triangle that uses a moved vertex can have changed.
        let mut focus: Vec<u32> = moves.iter().flat_map(|&(v, _)| faces_of[v].iter().copied()).collect();
        focus.sort_unstable();
        focus.dedup();
        let touched = |t: u32| triangles[t as usize].iter().any(|&v| moved[v as usize]);
        let mut left: Vec<[u32; 2]> = pairs.iter().copied().filter(|&[a, b]| !touched(a) && !touched(b)).collect();
        left.extend(self_intersections_involving(positions, triangles, &focus)?);
        left.sort_unstable();
        left.dedup();
        // A separation round that did not help hands over to smoothing for one round.
        separate = !separating || left.len() < pairs.len();
        if left.len() < fewest {
            fewest = left.len();
            best.copy_from_slice(positions);
            stalled = 0;
            rings = 0;
        } else {
            stalled += 1;
            if stalled % STALL_ROUNDS == 0 {
                rings = (rings + 1).min(MAX_RINGS); // stuck: widen the neighbourhood
            }
        }
        pairs = left;
    }
    if pairs.len() > fewest {
        positions.copy_from_slice(&best);
        return Ok(UntangleReport { before, after: fewest, rounds });
    }
    Ok(UntangleReport { before, after: pairs.len(), rounds })
}

/// Per vertex of `triangles` (indices below `n`): its neighbours (sorted, no repeats) and
/// the triangles that use it.
pub(crate) fn vertex_adjacency(triangles: &[[u32; 3]], n: usize) -> (Vec<Vec<u32>>, Vec<Vec<u32>>) {
    let mut neighbours: Vec<Vec<u32>> = vec![Vec::new(); n];
    let mut faces_of: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (f, t) in triangles.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            neighbours[a as usize].push(b);
            neighbours[b as usize].push(a);
            faces_of[a as usize].push(f as u32);
        }
    }
    for list in &mut neighbours {
        list.sort_unstable();
        list.dedup();
    }
    (neighbours, faces_of)
}

/// Per moved vertex, its new position: the mean of the smallest moves that separate its
/// crossing pairs. For each pair, of the four ways to put one triangle wholly on one side
/// of the other's plane ([`MARGIN`] past it), the one that moves its vertices least.
fn separation_moves(positions: &[[f32; 3]], triangles: &[[u32; 3]], pairs: &[[u32; 2]]) -> Vec<(usize, [f32; 3])> {
    let corners = |t: u32| triangles[t as usize].map(|v| Vec3::from(positions[v as usize]));
    let mut sum: HashMap<usize, (Vec3, f32)> = HashMap::new();
    for &[a, b] in pairs {
        // (cost, moving triangle, direction, distance per corner)
        let mut best: Option<(f32, u32, Vec3, [f32; 3])> = None;
        for (mover, other) in [(a, b), (b, a)] {
            let (p, q) = (corners(mover), corners(other));
            let normal = normals::face_normal(positions, triangles[other as usize]).normalize_or_zero().as_vec3();
            if normal == Vec3::ZERO {
                continue; // a degenerate triangle has no plane
            }
            let longest = (q[1] - q[0]).length().max((q[2] - q[0]).length()).max((q[2] - q[1]).length());
            let signed = p.map(|x| (x - q[0]).dot(normal));
            for side in [1.0f32, -1.0] {
                let shift = signed.map(|d| (MARGIN * longest - side * d).max(0.0));
                let cost = shift[0] + shift[1] + shift[2];
                if best.is_none_or(|b| cost < b.0) {
                    best = Some((cost, mover, side * normal, shift));
                }
            }
        }
        if let Some((_, mover, direction, shift)) = best {
            for (&v, d) in triangles[mover as usize].iter().zip(shift) {
                if d > 0.0 {
                    let e = sum.entry(v as usize).or_insert((Vec3::ZERO, 0.0));
                    e.0 += direction * d;
                    e.1 += 1.0;
                }
            }
        }
    }
    let mut moves: Vec<(usize, [f32; 3])> =
        sum.into_iter().map(|(v, (d, c))| (v, (Vec3::from(positions[v]) + d / c).to_array())).collect();
    moves.sort_unstable_by_key(|m| m.0);
    moves
}

/// Per moved vertex, its new position: half way to the mean of its neighbours, for the
/// vertices of the crossing triangles and `rings` rings around them.
fn smoothing_moves(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    pairs: &[[u32; 2]],
    neighbours: &[Vec<u32>],
    rings: usize,
) -> Vec<(usize, [f32; 3])> {
    let n = positions.len();
    let mut region = vec![false; n];
    for &[a, b] in pairs {
        for v in triangles[a as usize].into_iter().chain(triangles[b as usize]) {
            region[v as usize] = true;
        }
    }
    for _ in 0..rings {
        let grown: Vec<usize> =
            (0..n).filter(|&v| !region[v] && neighbours[v].iter().any(|&u| region[u as usize])).collect();
        for v in grown {
            region[v] = true;
        }
    }
    (0..n)
        .filter(|&v| region[v] && !neighbours[v].is_empty())
        .map(|v| {
            let mean = neighbours[v].iter().map(|&u| Vec3::from(positions[u as usize])).sum::<Vec3>()
                / neighbours[v].len() as f32;
            let p = Vec3::from(positions[v]);
            (v, (p + STEP * (mean - p)).to_array())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An icosphere with one vertex pushed through the opposite side: the triangles around
    /// it cross the far side's triangles until smoothing pulls the spike back.
    #[test]
    fn a_vertex_pushed_through_the_opposite_side_is_pulled_back() {
        let sphere = w3d_remesh::icosphere(2, 0.5).unwrap();
        let mut positions = sphere.positions().to_vec();
        positions[0] = positions[0].map(|x| -1.3 * x);
        let mesh = Mesh::new(positions, sphere.triangles().to_vec()).unwrap();
        let crossing = mesh.self_intersections().len();
        assert!(crossing > 0);
        let (fixed, report) = untangle(&mesh, 20).unwrap();
        assert_eq!(report.before, crossing);
        assert_eq!(report.after, 0, "{report:?}");
        assert!(fixed.self_intersections().is_empty());
        // Only the neighbourhood of the crossing moved: most vertices are where they were.
        let unmoved = fixed.positions().iter().zip(sphere.positions()).filter(|(a, b)| a == b).count();
        assert!(unmoved > sphere.vertex_count() / 2, "{unmoved} of {}", sphere.vertex_count());
    }

    /// A thin disc (a sphere flattened to 4 % of its width) with its top vertex pushed
    /// through the bottom sheet: separation moves it back by about the penetration and
    /// leaves the rest of the disc, and its thickness, alone.
    #[test]
    fn a_dent_through_a_thin_part_is_separated_without_flattening_it() {
        let sphere = w3d_remesh::icosphere(3, 0.5).unwrap();
        let mut positions: Vec<[f32; 3]> = sphere.positions().iter().map(|p| [p[0], 0.04 * p[1], p[2]]).collect();
        let top = (0..positions.len()).max_by(|&a, &b| positions[a][1].total_cmp(&positions[b][1])).unwrap();
        let original = positions.clone();
        positions[top][1] = -0.03; // the bottom sheet is at y ≈ −0.02 below it
        let mesh = Mesh::new(positions, sphere.triangles().to_vec()).unwrap();
        let crossing = mesh.self_intersections().len();
        assert!(crossing > 0);
        let (fixed, report) = untangle(&mesh, 200).unwrap();
        assert_eq!((report.before, report.after), (crossing, 0), "{report:?}");
        assert!(fixed.self_intersections().is_empty());
        let moved_most = fixed
            .positions()
            .iter()
            .zip(&original)
            .enumerate()
            .filter(|&(v, _)| v != top)
            .map(|(_, (a, b))| Vec3::from(*a).distance(Vec3::from(*b)))
            .fold(0.0f32, f32::max);
        assert!(moved_most < 0.02, "a vertex other than the dent moved {moved_most}");
        let thickness = |p: &[[f32; 3]]| {
            p.iter().map(|q| q[1]).fold(f32::MIN, f32::max) - p.iter().map(|q| q[1]).fold(f32::MAX, f32::min)
        };
        assert!(thickness(fixed.positions()) > 0.9 * thickness(&original) - 0.02, "{}", thickness(fixed.positions()));
    }

    /// A sphere crumpled by moving every vertex at random by up to `amplitude` per axis.
    fn crumpled_sphere(amplitude: f32) -> Mesh {
        let sphere = w3d_remesh::icosphere(3, 0.5).unwrap();
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut uniform = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
        };
        let positions = sphere.positions().iter().map(|p| p.map(|x| x + amplitude * uniform())).collect();
        Mesh::new(positions, sphere.triangles().to_vec()).unwrap()
    }

    /// Views of no single object (a wrong view, a generator's noise) leave coarse meshes
    /// with more crossing pairs than triangles; those are untangled like any other, not
    /// returned as they are (an earlier guard did, and left the plane with a wrong view
    /// crossing itself at 1857 pairs).
    #[test]
    fn more_crossing_pairs_than_triangles_are_untangled_too() {
        for amplitude in [0.12f32, 0.2] {
            let mesh = crumpled_sphere(amplitude);
            let crossing = mesh.self_intersections().len();
            assert!(crossing > mesh.triangle_count(), "{crossing} pairs on {} triangles", mesh.triangle_count());
            let (fixed, report) = untangle(&mesh, 400).unwrap();
            assert_eq!((report.before, report.after), (crossing, 0), "{report:?}");
            assert!(report.rounds > 0);
            assert!(fixed.self_intersections().is_empty());
        }
    }

    #[test]
    fn a_clean_mesh_is_returned_unchanged() {
        let sphere = w3d_remesh::icosphere(2, 0.5).unwrap();
        let (same, report) = untangle(&sphere, 20).unwrap();
        assert_eq!(report, UntangleReport { before: 0, after: 0, rounds: 0 });
        assert_eq!(same.positions(), sphere.positions());
    }
}
