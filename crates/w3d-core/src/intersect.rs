//! Self-intersections of a triangle mesh: pairs of triangles that share no vertex and
//! whose interiors cross (an edge of one passes through the other). Coplanar overlaps are
//! not counted. Candidate pairs come from a uniform grid over the bounding box (each pair
//! tested once, in the first cell both bounding boxes cover); triangles too large for the
//! grid are tested by bounding-box overlap.

use std::collections::HashMap;

use crate::error::{Error, Result};
use crate::mesh::Mesh;
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

/// A triangle whose bounding box covers more grid cells than this is not binned: it is
/// tested against the other triangles whose bounding boxes overlap its own. The grid's cells
/// are as wide as an average triangle, and a crumpled mesh (reconstructed from views that
/// contradict each other) has a few long spikes spanning most of the grid: binned, each cost
/// up to 256³ cell visits per check, which made one 6k-triangle untangle take 15 s.
const MAX_BINNED_CELLS: i64 = 64;

/// The triangles' bounding boxes and their cell ranges on a uniform grid over the bounding
/// box of `p` whose cells are as wide as the triangles are on average (their bounding
/// boxes' largest side), so a triangle spans about two cells per axis; at most 256 cells per
/// axis. (A grid of (2·F)^(1/2) cells per axis put each triangle of a 9k-triangle mesh in
/// about 30 cells and made the check several times slower.)
struct Binning {
    /// Per triangle: its corners' minimum and maximum.
    boxes: Vec<(DVec3, DVec3)>,
    /// Per triangle: its first and last cell per axis.
    cells: Vec<([i64; 3], [i64; 3])>,
    /// Cells per axis.
    per_axis: i64,
}

impl Binning {
    fn new(p: &[DVec3], tris: &[[u32; 3]]) -> Self {
        let boxes: Vec<(DVec3, DVec3)> = tris
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| p[i as usize]);
                (a.min(b).min(c), a.max(b).max(c))
            })
            .collect();
        let (lo, hi) = p
            .iter()
            .fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(a, b), v| (a.min(*v), b.max(*v)));
        let mean_extent = boxes.iter().map(|(a, b)| (*b - *a).max_element()).sum::<f64>() / boxes.len().max(1) as f64;
        let span = (hi - lo).max_element().max(1e-12);
        let cells = ((span / mean_extent.max(1e-12)).ceil() as i64).clamp(1, 256);
        let size = span / cells as f64;
        let cell = |v: DVec3| {
            let c = ((v - lo) / size).floor();
            [c.x as i64, c.y as i64, c.z as i64].map(|k| k.clamp(0, cells - 1))
        };
        let per_axis = cells;
        let cells = boxes.iter().map(|&(a, b)| (cell(a), cell(b))).collect();
        Self { boxes, cells, per_axis }
    }

    /// The number of cells.
    fn len(&self) -> usize {
        (self.per_axis * self.per_axis * self.per_axis) as usize
    }

    /// The index of cell `c` (below [`Binning::len`]).
    fn index(&self, c: [i64; 3]) -> usize {
        ((c[0] * self.per_axis + c[1]) * self.per_axis + c[2]) as usize
    }

    /// Whether triangle `t` is binned (its box covers at most [`MAX_BINNED_CELLS`] cells).
    fn binned(&self, t: usize) -> bool {
        let (l, h) = self.cells[t];
        (0..3).map(|k| h[k] - l[k] + 1).product::<i64>() <= MAX_BINNED_CELLS
    }

    /// Whether the bounding boxes of triangles `s` and `t` overlap.
    fn boxes_overlap(&self, s: usize, t: usize) -> bool {
        let ((a0, a1), (b0, b1)) = (self.boxes[s], self.boxes[t]);
        a0.cmple(b1).all() && b0.cmple(a1).all()
    }

    /// Whether binned triangles `s` and `t` are to be tested in cell index `cell`: their boxes overlap
    /// and `c` is the first cell they share (per axis the larger of their first cells), so a
    /// pair sharing several cells is tested once.
    fn test_in(&self, cell: usize, s: usize, t: usize) -> bool {
        let (ls, lt) = (self.cells[s].0, self.cells[t].0);
        cell == self.index([ls[0].max(lt[0]), ls[1].max(lt[1]), ls[2].max(lt[2])]) && self.boxes_overlap(s, t)
    }

    /// Calls `f` with every cell of triangle `t`.
    fn for_each_cell(&self, t: usize, mut f: impl FnMut([i64; 3])) {
        let (l, h) = self.cells[t];
        for x in l[0]..=h[0] {
            for y in l[1]..=h[1] {
                for z in l[2]..=h[2] {
                    f([x, y, z]);
                }
            }
        }
    }
}

/// Whether triangles `s` and `t` share no vertex and cross.
fn pair_crosses(p: &[DVec3], tris: &[[u32; 3]], s: usize, t: usize) -> bool {
    let (a, b) = (tris[s], tris[t]);
    !a.iter().any(|v| b.contains(v)) && triangles_cross(a.map(|i| p[i as usize]), b.map(|i| p[i as usize]))
}

/// The crossing pairs; every index of `tris` is below `positions.len()`.
fn crossing_pairs(positions: &[[f32; 3]], tris: &[[u32; 3]]) -> Vec<[u32; 2]> {
    let p: Vec<DVec3> = positions.iter().map(|v| DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64)).collect();
    if tris.len() < 2 {
        return Vec::new();
    }
    let bins = Binning::new(&p, tris);
    let mut grid: HashMap<usize, Vec<u32>> = HashMap::new();
    let mut large = Vec::new();
    for t in 0..tris.len() {
        if bins.binned(t) {
            bins.for_each_cell(t, |c| grid.entry(bins.index(c)).or_default().push(t as u32));
        } else {
            large.push(t);
        }
    }
    let mut pairs: Vec<[u32; 2]> = Vec::new();
    for (&c, members) in &grid {
        for (i, &s) in members.iter().enumerate() {
            for &t in &members[i + 1..] {
                if bins.test_in(c, s as usize, t as usize) && pair_crosses(&p, tris, s as usize, t as usize) {
                    pairs.push([s.min(t), s.max(t)]);
                }
            }
        }
    }
    // Each unbinned triangle against every triangle its box overlaps (a pair of two
    // unbinned triangles once, from the smaller index).
    for &s in &large {
        for t in 0..tris.len() {
            if t == s || (t < s && !bins.binned(t)) || !bins.boxes_overlap(s, t) {
                continue;
            }
            if pair_crosses(&p, tris, s, t) {
                pairs.push([s.min(t) as u32, s.max(t) as u32]);
            }
        }
    }
    pairs.sort_unstable();
    pairs.dedup();
    pairs
}

/// The crossing pairs with at least one triangle `t` where `focus[t]`: the binned focus
/// triangles go on a uniform grid over the bounding box, and every binned triangle is
/// tested against the focus triangles sharing a cell with it; unbinned triangles (see
/// [`MAX_BINNED_CELLS`]) are tested by bounding-box overlap instead.
fn crossing_pairs_involving(positions: &[[f32; 3]], tris: &[[u32; 3]], focus: &[bool]) -> Vec<[u32; 2]> {
    let p: Vec<DVec3> = positions.iter().map(|v| DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64)).collect();
    if tris.len() < 2 || !focus.contains(&true) {
        return Vec::new();
    }
    let bins = Binning::new(&p, tris);
    // The cells holding a focus triangle, as bits: most triangles are far from the focus,
    // and a bit test is much cheaper than a hash lookup.
    let mut grid: HashMap<usize, Vec<u32>> = HashMap::new();
    let mut occupied = vec![0u64; bins.len().div_ceil(64)];
    let (mut focus_list, mut large_focus) = (Vec::new(), Vec::new());
    for t in (0..tris.len()).filter(|&t| focus[t]) {
        focus_list.push(t);
        if bins.binned(t) {
            bins.for_each_cell(t, |c| {
                let i = bins.index(c);
                occupied[i / 64] |= 1 << (i % 64);
                grid.entry(i).or_default().push(t as u32);
            });
        } else {
            large_focus.push(t);
        }
    }
    let mut pairs: Vec<[u32; 2]> = Vec::new();
    let mut test = |s: usize, t: usize| {
        if pair_crosses(&p, tris, s, t) {
            pairs.push([s.min(t) as u32, s.max(t) as u32]);
        }
    };
    for (s, &s_in_focus) in focus.iter().enumerate() {
        if bins.binned(s) {
            // Binned focus triangles sharing a cell; a pair of two focus triangles is
            // tested once, from its smaller index.
            bins.for_each_cell(s, |c| {
                let i = bins.index(c);
                if occupied[i / 64] & (1 << (i % 64)) == 0 {
                    return;
                }
                for &t in &grid[&i] {
                    let t = t as usize;
                    if t != s && !(s_in_focus && t < s) && bins.test_in(i, s, t) {
                        test(s, t);
                    }
                }
            });
        } else {
            // An unbinned triangle against every focus triangle its box overlaps.
            for &t in &focus_list {
                if t != s && bins.boxes_overlap(s, t) {
                    test(s, t);
                }
            }
        }
    }
    // Unbinned focus triangles against the binned triangles their boxes overlap.
    for &t in &large_focus {
        for s in (0..tris.len()).filter(|&s| s != t && bins.binned(s)) {
            if bins.boxes_overlap(s, t) {
                test(s, t);
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

    /// Small random triangles and a few long spikes across the whole box (too many cells to
    /// be binned), as a crumpled reconstruction has: both checks find exactly the pairs an
    /// all-pairs test finds.
    #[test]
    fn long_spikes_are_checked_like_every_other_triangle() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let (mut positions, mut triangles) = (Vec::new(), Vec::new());
        for k in 0..400u32 {
            let centre = [next(), next(), next()];
            let size = if k % 50 == 0 { 1.5 } else { 0.08 };
            for _ in 0..3 {
                positions.push(centre.map(|c| c + size * (next() - 0.5)));
            }
            triangles.push([3 * k, 3 * k + 1, 3 * k + 2]);
        }
        let p: Vec<DVec3> = positions.iter().map(|v| DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64)).collect();
        let bins = Binning::new(&p, &triangles);
        assert!((0..triangles.len()).filter(|&t| !bins.binned(t)).count() >= 4);
        let mut expected = Vec::new();
        for s in 0..triangles.len() {
            for t in s + 1..triangles.len() {
                if pair_crosses(&p, &triangles, s, t) {
                    expected.push([s as u32, t as u32]);
                }
            }
        }
        assert!(expected.len() > 20, "{}", expected.len());
        assert_eq!(self_intersections(&positions, &triangles).unwrap(), expected);
        for focus in [vec![0u32, 7, 50], vec![100, 101, 102, 103], (0..400).step_by(3).collect()] {
            let want: Vec<[u32; 2]> =
                expected.iter().copied().filter(|pair| pair.iter().any(|x| focus.contains(x))).collect();
            assert_eq!(self_intersections_involving(&positions, &triangles, &focus).unwrap(), want, "{focus:?}");
        }
    }
}
