//! Chart segmentation: faces grouped by normal direction with priority-driven region
//! growing over the (position-welded) face adjacency.

use std::cmp::Ordering;
use std::collections::{BinaryHeap, HashMap};

use glam::DVec3;

/// Marks "no neighbour" in [`Surface::neighbours`].
pub(crate) const NO_FACE: u32 = u32::MAX;

/// The input mesh with vertices welded by position, plus per-face geometry.
pub(crate) struct Surface {
    /// Welded vertex positions.
    pub positions: Vec<DVec3>,
    /// Triangles over welded vertices (same order as the input triangles).
    pub triangles: Vec<[u32; 3]>,
    /// For each input vertex, its welded vertex.
    pub weld: Vec<u32>,
    /// Unit face normals (zero for degenerate faces).
    pub normals: Vec<DVec3>,
    /// Face areas (world units²).
    pub areas: Vec<f64>,
    /// Neighbour across edge `k` (from corner `k` to corner `k + 1`), or [`NO_FACE`] at
    /// boundaries, non-manifold edges and edges whose two faces disagree in orientation.
    pub neighbours: Vec<[u32; 3]>,
}

impl Surface {
    pub fn new(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Self {
        let weld = w3d_core::mesh::weld_by_position(positions);
        let count = weld.iter().map(|&w| w as usize + 1).max().unwrap_or(0);
        let mut welded = vec![DVec3::ZERO; count];
        for (p, &w) in positions.iter().zip(&weld) {
            welded[w as usize] = DVec3::from(glam::Vec3::from(*p));
        }
        let tris: Vec<[u32; 3]> = triangles.iter().map(|t| t.map(|v| weld[v as usize])).collect();
        // The welded corners are the input corners, so the input triangles give the faces.
        let (normals, areas): (Vec<DVec3>, Vec<f64>) = triangles
            .iter()
            .map(|&t| {
                let n = w3d_core::normals::face_normal(positions, t);
                (n.normalize_or_zero(), 0.5 * n.length())
            })
            .unzip();
        // Directed half-edges (from, to, face, corner) sorted by undirected key.
        let mut half: Vec<([u32; 2], u32, u8)> = Vec::with_capacity(tris.len() * 3);
        for (f, t) in tris.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                if a != b {
                    half.push(([a.min(b), a.max(b)], f as u32, k as u8));
                }
            }
        }
        half.sort_unstable();
        let mut neighbours = vec![[NO_FACE; 3]; tris.len()];
        for group in half.chunk_by(|x, y| x.0 == y.0) {
            if let [(_, f, k), (_, g, l)] = group {
                let from_f = tris[*f as usize][*k as usize];
                let from_g = tris[*g as usize][*l as usize];
                // Consistently oriented neighbours traverse the shared edge in opposite directions.
                if from_f != from_g && f != g {
                    neighbours[*f as usize][*k as usize] = *g;
                    neighbours[*g as usize][*l as usize] = *f;
                }
            }
        }
        Surface { positions: welded, triangles: tris, weld, normals, areas, neighbours }
    }
}

/// Max-heap entry: a face and its alignment with the chart normal when pushed.
struct Candidate {
    alignment: f64,
    face: u32,
}

impl PartialEq for Candidate {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Candidate {}
impl PartialOrd for Candidate {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Candidate {
    fn cmp(&self, other: &Self) -> Ordering {
        self.alignment.total_cmp(&other.alignment).then_with(|| other.face.cmp(&self.face))
    }
}

/// Splits `faces` (a subset of the surface's faces) into charts: each chart grows from
/// the lowest-numbered unassigned face, always taking next the neighbouring face best
/// aligned with the chart's area-weighted mean normal, and accepting it only while its
/// normal is within `max_angle` (cosine `min_cos`) of that mean. Degenerate faces form
/// charts of their own. Every face of `faces` ends up in exactly one chart.
pub(crate) fn grow_charts(surface: &Surface, faces: &[u32], min_cos: f64) -> Vec<Vec<u32>> {
    let local: HashMap<u32, u32> = faces.iter().enumerate().map(|(i, &f)| (f, i as u32)).collect();
    let mut assigned = vec![false; faces.len()];
    let mut charts = Vec::new();
    let mut heap = BinaryHeap::new();
    for (start, &seed) in faces.iter().enumerate() {
        if assigned[start] {
            continue;
        }
        assigned[start] = true;
        let mut chart = vec![seed];
        if surface.areas[seed as usize] <= 0.0 || surface.normals[seed as usize] == DVec3::ZERO {
            charts.push(chart);
            continue;
        }
        let mut sum = surface.normals[seed as usize] * surface.areas[seed as usize];
        let mut axis = surface.normals[seed as usize];
        heap.clear();
        let push = |heap: &mut BinaryHeap<Candidate>, f: u32, axis: DVec3, assigned: &[bool]| {
            for &g in &surface.neighbours[f as usize] {
                if g != NO_FACE
                    && let Some(&l) = local.get(&g)
                    && !assigned[l as usize]
                {
                    heap.push(Candidate { alignment: surface.normals[g as usize].dot(axis), face: g });
                }
            }
        };
        push(&mut heap, seed, axis, &assigned);
        while let Some(Candidate { face, .. }) = heap.pop() {
            let l = local[&face] as usize;
            if assigned[l] || surface.areas[face as usize] <= 0.0 {
                continue;
            }
            let n = surface.normals[face as usize];
            if n.dot(axis) < min_cos {
                continue;
            }
            assigned[l] = true;
            chart.push(face);
            sum += n * surface.areas[face as usize];
            axis = sum.normalize_or(axis);
            push(&mut heap, face, axis, &assigned);
        }
        charts.push(chart);
    }
    charts
}

/// A chart's normal cone: the area-weighted normal sum and an upper bound of the angle
/// (radians) between any face normal and the sum's direction.
#[derive(Clone, Copy)]
struct Cone {
    sum: DVec3,
    half_angle: f64,
}

impl Cone {
    fn of(surface: &Surface, faces: &[u32]) -> Cone {
        let sum = faces.iter().map(|&f| surface.normals[f as usize] * surface.areas[f as usize]).sum::<DVec3>();
        let axis = sum.normalize_or_zero();
        let half_angle = faces
            .iter()
            .filter(|&&f| surface.areas[f as usize] > 0.0)
            .map(|&f| surface.normals[f as usize].dot(axis).clamp(-1.0, 1.0).acos())
            .fold(0.0, f64::max);
        Cone { sum, half_angle }
    }

    /// A cone containing both (bounded through the angles between the axes).
    fn union(self, other: Cone) -> Cone {
        let sum = self.sum + other.sum;
        let axis = sum.normalize_or_zero();
        let reach = |c: Cone| c.sum.normalize_or_zero().dot(axis).clamp(-1.0, 1.0).acos() + c.half_angle;
        Cone { sum, half_angle: reach(self).max(reach(other)) }
    }
}

/// Merges small charts into neighbours: in order of increasing area, a chart below
/// `small_area` joins the adjacent chart it shares the most edges with whose union stays
/// within the normal cone `max_angle` (radians; bounded conservatively through the charts'
/// own cones), trying the next neighbour otherwise. Returns the surviving charts.
pub(crate) fn merge_small_charts(
    surface: &Surface,
    charts: Vec<Vec<u32>>,
    small_area: f64,
    max_angle: f64,
) -> Vec<Vec<u32>> {
    let mut chart_of = vec![u32::MAX; surface.triangles.len()];
    for (c, faces) in charts.iter().enumerate() {
        for &f in faces {
            chart_of[f as usize] = c as u32;
        }
    }
    let area = |faces: &[u32]| faces.iter().map(|&f| surface.areas[f as usize]).sum::<f64>();
    let mut areas: Vec<f64> = charts.iter().map(|c| area(c)).collect();
    let mut cones: Vec<Cone> = charts.iter().map(|c| Cone::of(surface, c)).collect();
    let mut charts: Vec<Option<Vec<u32>>> = charts.into_iter().map(Some).collect();
    let mut order: Vec<usize> = (0..charts.len()).filter(|&c| areas[c] < small_area).collect();
    order.sort_by(|&a, &b| areas[a].total_cmp(&areas[b]).then(a.cmp(&b)));
    for c in order {
        let Some(faces) = charts[c].as_ref() else { continue };
        if areas[c] >= small_area {
            continue;
        }
        let mut shared: HashMap<u32, usize> = HashMap::new();
        for &f in faces {
            for &g in &surface.neighbours[f as usize] {
                if g != NO_FACE && chart_of[g as usize] != c as u32 {
                    *shared.entry(chart_of[g as usize]).or_insert(0) += 1;
                }
            }
        }
        let mut candidates: Vec<(usize, u32)> = shared.into_iter().map(|(d, n)| (n, d)).collect();
        candidates.sort_by(|a, b| b.cmp(a));
        for (_, d) in candidates {
            let d = d as usize;
            let union = cones[c].union(cones[d]);
            if union.half_angle <= max_angle {
                let moved = charts[c].take().expect("live chart");
                for &f in &moved {
                    chart_of[f as usize] = d as u32;
                }
                areas[d] += areas[c];
                cones[d] = union;
                charts[d].as_mut().expect("live chart").extend(moved);
                break;
            }
        }
    }
    charts.into_iter().flatten().collect()
}

/// Splits a connected group of faces in two: breadth-first from two far-apart seed faces
/// (the farthest face from the first, then the farthest from that), each face going to the
/// seed it is reached from first. Faces the seeds do not reach go to the second part.
pub(crate) fn split_in_two(surface: &Surface, faces: &[u32]) -> (Vec<u32>, Vec<u32>) {
    let local: HashMap<u32, usize> = faces.iter().enumerate().map(|(i, &f)| (f, i)).collect();
    let bfs = |seeds: &[usize]| {
        let mut owner = vec![usize::MAX; faces.len()];
        let mut queue = std::collections::VecDeque::new();
        for (k, &s) in seeds.iter().enumerate() {
            owner[s] = k;
            queue.push_back(s);
        }
        let mut last = seeds[0];
        while let Some(i) = queue.pop_front() {
            last = i;
            for &g in &surface.neighbours[faces[i] as usize] {
                if let Some(&j) = local.get(&g)
                    && owner[j] == usize::MAX
                {
                    owner[j] = owner[i];
                    queue.push_back(j);
                }
            }
        }
        (owner, last)
    };
    let (_, a) = bfs(&[0]);
    let (_, b) = bfs(&[a]);
    let (owner, _) = bfs(&[a, b]);
    let (mut first, mut second) = (Vec::new(), Vec::new());
    for (i, &f) in faces.iter().enumerate() {
        if owner[i] == 0 { first.push(f) } else { second.push(f) }
    }
    (first, second)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed cube (12 triangles, 8 vertices).
    fn cube() -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let p = (0..8).map(|i| [(i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32]).collect();
        let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        let t = quads.iter().flat_map(|q: &[u32; 4]| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
        (p, t)
    }

    #[test]
    fn cube_faces_become_six_charts() {
        let (p, t) = cube();
        let s = Surface::new(&p, &t);
        assert!(s.neighbours.iter().flatten().all(|&n| n != NO_FACE));
        let all: Vec<u32> = (0..t.len() as u32).collect();
        let charts = grow_charts(&s, &all, 0.5f64);
        assert_eq!(charts.len(), 6);
        assert!(charts.iter().all(|c| c.len() == 2));
        // A looser cone still never accepts a face at 90° from the mean normal.
        assert_eq!(grow_charts(&s, &all, 0.01).len(), 6);
    }

    #[test]
    fn welding_joins_split_vertices() {
        // Two triangles of a square, the diagonal's vertices duplicated.
        let p =
            vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
        let s = Surface::new(&p, &[[0, 1, 2], [3, 4, 5]]);
        assert_eq!(s.positions.len(), 4);
        assert_eq!(s.neighbours[0][2], 1);
        assert_eq!(grow_charts(&s, &[0, 1], 0.9).len(), 1);
    }
}
