//! Self-intersections of a triangle mesh: pairs of triangles that share no vertex and
//! whose interiors cross (an edge of one passes through the other). Coplanar overlaps are
//! not counted. Candidate pairs come from a uniform grid over the bounding box.

use std::collections::HashMap;

use crate::{Error, Mesh, Result};
use glam::DVec3;

impl Mesh {
    /// The pairs of triangles (indices, smaller first, sorted) that share no vertex and
    /// cross each other: an edge of one passes through the interior of the other, tested
    /// in f64. Empty for a mesh without self-intersections; the check behind "no
    /// self-intersections" in the reconstruction reports.
    pub fn self_intersections(&self) -> Vec<[u32; 2]> {
        crossing_pairs(self.positions(), self.triangles())
    }
}

/// [`Mesh::self_intersections`] on plain arrays, for loops that move vertices and check
/// again without building a [`Mesh`] each time: the crossing triangle pairs (smaller index
/// first, sorted) of `triangles` over `positions`. Fails when a triangle names a vertex
/// that `positions` does not have.
pub fn self_intersections(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Result<Vec<[u32; 2]>> {
    check_indices(positions, triangles)?;
    Ok(crossing_pairs(positions, triangles))
}

/// [`self_intersections`] restricted to the pairs that involve at least one triangle of
/// `focus` (indices into `triangles`, any order, repeats allowed): after moving a few
/// vertices, only the triangles that use them can have changed, and checking those against
/// the rest is much cheaper than checking everything. Fails when a triangle names a vertex
/// that `positions` does not have or `focus` names a triangle that does not exist.
pub fn self_intersections_involving(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    focus: &[u32],
) -> Result<Vec<[u32; 2]>> {
    check_indices(positions, triangles)?;
    if let Some(&t) = focus.iter().find(|&&t| t as usize >= triangles.len()) {
        return Err(Error::invalid("focus", format!("triangle indices below {}, got {t}", triangles.len())));
    }
    let mut in_focus = vec![false; triangles.len()];
    for &t in focus {
        in_focus[t as usize] = true;
    }
    Ok(crossing_pairs_involving(positions, triangles, &in_focus))
}

/// Fails when a triangle names a vertex that `positions` does not have.
fn check_indices(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Result<()> {
    if let Some((t, tri)) =
        triangles.iter().enumerate().find(|(_, tri)| tri.iter().any(|&v| v as usize >= positions.len()))
    {
        return Err(Error::invalid(
            format!("triangles[{t}]"),
            format!("vertex indices below {}, got {tri:?}", positions.len()),
        ));
    }
    Ok(())
}

/// The cell of a point on a uniform grid over the bounding box of `p` whose cells are as
/// wide as the triangles of `tris` are on average (their bounding boxes' largest side), so a
/// triangle spans about two cells per axis; at most 256 cells per axis. (A grid of
/// (2·F)^(1/2) cells per axis put each triangle of a 9k-triangle mesh in about 30 cells and
/// made the check several times slower.)
fn grid_cell(p: &[DVec3], tris: &[[u32; 3]]) -> impl Fn(DVec3) -> [i64; 3] {
    let (lo, hi) = p
        .iter()
        .fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(a, b), v| (a.min(*v), b.max(*v)));
    let mean_extent = tris
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| p[i as usize]);
            (a.max(b).max(c) - a.min(b).min(c)).max_element()
        })
        .sum::<f64>()
        / tris.len().max(1) as f64;
    let span = (hi - lo).max_element().max(1e-12);
    let cells = ((span / mean_extent.max(1e-12)).ceil() as i64).clamp(1, 256);
    let size = span / cells as f64;
    move |v: DVec3| {
        let c = ((v - lo) / size).floor();
        [c.x as i64, c.y as i64, c.z as i64].map(|k| k.clamp(0, cells - 1))
    }
}

/// The crossing pairs; every index of `tris` is below `positions.len()`.
fn crossing_pairs(positions: &[[f32; 3]], tris: &[[u32; 3]]) -> Vec<[u32; 2]> {
    let p: Vec<DVec3> = positions.iter().map(|v| DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64)).collect();
    if tris.len() < 2 {
        return Vec::new();
    }
    let cell = grid_cell(&p, tris);
    let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
    for (t, tri) in tris.iter().enumerate() {
        let [a, b, c] = tri.map(|i| p[i as usize]);
        let (l, h) = (cell(a.min(b).min(c)), cell(a.max(b).max(c)));
        for x in l[0]..=h[0] {
            for y in l[1]..=h[1] {
                for z in l[2]..=h[2] {
                    grid.entry([x, y, z]).or_default().push(t as u32);
                }
            }
        }
    }
    let mut pairs: Vec<[u32; 2]> = Vec::new();
    for members in grid.values() {
        for (i, &s) in members.iter().enumerate() {
            for &t in &members[i + 1..] {
                let (a, b) = (tris[s as usize], tris[t as usize]);
                if a.iter().any(|v| b.contains(v)) {
                    continue;
                }
                let ta = a.map(|i| p[i as usize]);
                let tb = b.map(|i| p[i as usize]);
                if triangles_cross(ta, tb) {
                    pairs.push([s.min(t), s.max(t)]);
                }
            }
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    pairs
}

/// The crossing pairs with at least one triangle `t` where `focus[t]`: the focus triangles
/// are binned on a uniform grid over the bounding box, then every triangle is tested
/// against the focus triangles sharing a cell with it.
fn crossing_pairs_involving(positions: &[[f32; 3]], tris: &[[u32; 3]], focus: &[bool]) -> Vec<[u32; 2]> {
    let p: Vec<DVec3> = positions.iter().map(|v| DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64)).collect();
    if tris.len() < 2 || !focus.contains(&true) {
        return Vec::new();
    }
    let cell = grid_cell(&p, tris);
    let cell_range = |tri: [u32; 3]| {
        let [a, b, c] = tri.map(|i| p[i as usize]);
        (cell(a.min(b).min(c)), cell(a.max(b).max(c)))
    };
    let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
    for (t, &tri) in tris.iter().enumerate().filter(|&(t, _)| focus[t]) {
        let (l, h) = cell_range(tri);
        for x in l[0]..=h[0] {
            for y in l[1]..=h[1] {
                for z in l[2]..=h[2] {
                    grid.entry([x, y, z]).or_default().push(t as u32);
                }
            }
        }
    }
    let mut pairs: Vec<[u32; 2]> = Vec::new();
    for (s, &a) in tris.iter().enumerate() {
        let (l, h) = cell_range(a);
        let ta = a.map(|i| p[i as usize]);
        for x in l[0]..=h[0] {
            for y in l[1]..=h[1] {
                for z in l[2]..=h[2] {
                    let Some(members) = grid.get(&[x, y, z]) else { continue };
                    for &t in members {
                        // A pair of focus triangles is tested once, from its smaller index.
                        if t as usize == s || (focus[s] && (t as usize) < s) {
                            continue;
                        }
                        let b = tris[t as usize];
                        if a.iter().any(|v| b.contains(v)) {
                            continue;
                        }
                        if triangles_cross(ta, b.map(|i| p[i as usize])) {
                            pairs.push([(s as u32).min(t), (s as u32).max(t)]);
                        }
                    }
                }
            }
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    pairs
}

/// Whether an edge of either triangle passes through the other.
fn triangles_cross(a: [DVec3; 3], b: [DVec3; 3]) -> bool {
    (0..3).any(|k| segment_hits_triangle(a[k], a[(k + 1) % 3], b))
        || (0..3).any(|k| segment_hits_triangle(b[k], b[(k + 1) % 3], a))
}

/// Möller–Trumbore on the segment `p0 → p1` (parameter strictly inside (0, 1)).
fn segment_hits_triangle(p0: DVec3, p1: DVec3, t: [DVec3; 3]) -> bool {
    let d = p1 - p0;
    let (e1, e2) = (t[1] - t[0], t[2] - t[0]);
    let h = d.cross(e2);
    let det = e1.dot(h);
    if det.abs() < 1e-18 {
        return false; // parallel or coplanar
    }
    let inv = 1.0 / det;
    let s = p0 - t[0];
    let u = s.dot(h) * inv;
    if !(0.0..=1.0).contains(&u) {
        return false;
    }
    let q = s.cross(e1);
    let v = d.dot(q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return false;
    }
    let along = e2.dot(q) * inv;
    along > 1e-9 && along < 1.0 - 1e-9
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetra(offset: [f32; 3]) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
            .map(|v: [f32; 3]| [v[0] + offset[0], v[1] + offset[1], v[2] + offset[2]]);
        (p.to_vec(), vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    }

    fn two(offset: [f32; 3]) -> Mesh {
        let (mut p, mut t) = tetra([0.0; 3]);
        let (q, s) = tetra(offset);
        p.extend(q);
        t.extend(s.iter().map(|f| f.map(|i| i + 4)));
        Mesh::new(p, t).unwrap()
    }

    #[test]
    fn overlapping_shells_intersect_and_separate_ones_do_not() {
        assert!(two([2.0, 0.0, 0.0]).self_intersections().is_empty());
        let crossing = two([0.2, 0.2, 0.2]).self_intersections();
        assert!(!crossing.is_empty());
        assert!(crossing.iter().all(|&[a, b]| a < 4 && b >= 4), "{crossing:?}");
        let (p, t) = tetra([0.0; 3]);
        assert!(Mesh::new(p, t).unwrap().self_intersections().is_empty());
    }

    #[test]
    fn the_slice_entry_agrees_with_the_mesh_and_rejects_bad_indices() {
        let mesh = two([0.2, 0.2, 0.2]);
        assert_eq!(self_intersections(mesh.positions(), mesh.triangles()).unwrap(), mesh.self_intersections());
        let err = self_intersections(&mesh.positions()[..7], mesh.triangles()).unwrap_err().to_string();
        assert!(err.contains("triangles[") && err.contains("below 7"), "{err}");
    }

    #[test]
    fn focused_check_finds_exactly_the_pairs_involving_the_focus() {
        let mesh = two([0.2, 0.2, 0.2]);
        let (p, t) = (mesh.positions(), mesh.triangles());
        let all = mesh.self_intersections();
        let every: Vec<u32> = (0..8).collect();
        assert_eq!(self_intersections_involving(p, t, &every).unwrap(), all);
        for focus in [vec![0u32], vec![5], vec![1, 6, 6], vec![]] {
            let expected: Vec<[u32; 2]> =
                all.iter().copied().filter(|pair| pair.iter().any(|x| focus.contains(x))).collect();
            assert_eq!(self_intersections_involving(p, t, &focus).unwrap(), expected, "focus {focus:?}");
        }
        let err = self_intersections_involving(p, t, &[8]).unwrap_err().to_string();
        assert!(err.contains("focus") && err.contains("below 8"), "{err}");
    }
}
