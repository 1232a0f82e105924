//! The remesh operations on plain arrays: collapse, split, pack and flip, and the
//! `remesh` pass that chains them (reference part A.3–A.8).
//!
//! Triangles are `[u32; 3]`, counter-clockwise seen from outside; deleted triangles are
//! marked by an explicit `alive` mask (no dummy vertex or face). Every tie is broken by
//! index, and the only random choice (which edge of a flagged face to collapse) is a hash
//! of a seed and the face index, so the same input and seed give the same bytes.

use glam::{DVec3, Vec3};
use w3d_core::normals;

use crate::edges::{EdgeTable, NONE};
use crate::rows::{VertexRows, mean3};

/// Settings of one [`remesh`] pass (the parts of [`crate::RemeshOptions`] it uses).
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct RemeshParams {
    /// A face is "small" (and collapsed) when its area is below
    /// `area_ratio · (mean min length of its corners)²` (reference 0.5).
    pub area_ratio: f32,
    /// Probability that a flagged face collapses its shortest edge; otherwise the middle or
    /// the longest edge, each with half the rest (reference 0.8; 1 = always the shortest).
    pub shortest_probability: f32,
    /// No edge is split once the mesh has this many vertices (reference 10⁶).
    pub max_vertices: usize,
    /// Run the valence-improving edge flips after split and pack.
    pub flip: bool,
    /// Not in the reference: before the collapses, remove interior valence-3 vertices that
    /// touch an edge the pass wants to collapse (see [`remove_valence3_vertices`]); such a
    /// vertex blocks the link condition of the edges around it (default `true`).
    pub remove_valence3: bool,
    /// Not in the reference: at most this many rounds of [`relax_folds`] after the pack, so
    /// that the pass leaves no flipped and no zero-area faces; 0 turns it off (default 10).
    pub fold_relaxation_rounds: u32,
    /// Rounds of rank propagation that pick the far-apart collapses of a pass (see
    /// [`collapse_edges`]): 3 (the reference, default) or 2 (the fewest that are safe;
    /// smaller values count as 2). With 2, about twice as many edges collapse per pass in
    /// crowded regions, which is why the optimizer's floor passes use 2 (see
    /// [`crate::RemeshOptions::edge_floor_passes`]). Measured for the main pass, before the
    /// floor passes existed: on the spot oracle reconstruction
    /// (`tests/tests/end_to_end/recon_oracle.rs`, default preset) 3 gives CD 0.0028 with 9 700
    /// triangles, 2 gives CD 0.0032 with 8 272.
    pub collapse_rank_rounds: u32,
}

impl Default for RemeshParams {
    fn default() -> Self {
        RemeshParams {
            area_ratio: 0.5,
            shortest_probability: 0.8,
            max_vertices: 1_000_000,
            flip: true,
            remove_valence3: true,
            fold_relaxation_rounds: 10,
            collapse_rank_rounds: 3,
        }
    }
}

/// Chainable setters, one per field: `RemeshParams::default().with_…(…)` (the struct is
/// `#[non_exhaustive]`, so code outside this crate cannot use struct-literal syntax).
impl RemeshParams {
    w3d_core::setters! {
        with_area_ratio(area_ratio: f32);
        with_shortest_probability(shortest_probability: f32);
        with_max_vertices(max_vertices: usize);
        with_flip(flip: bool);
        with_remove_valence3(remove_valence3: bool);
        with_fold_relaxation_rounds(fold_relaxation_rounds: u32);
        with_collapse_rank_rounds(collapse_rank_rounds: u32);
    }
}

/// What one [`remesh`] pass did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub struct RemeshStats {
    /// Edges collapsed.
    pub collapsed: usize,
    /// Edges split.
    pub split: usize,
    /// Edges flipped.
    pub flipped: usize,
    /// Valence-3 vertices removed.
    pub removed_valence3: usize,
    /// Flipped or zero-area faces found before the fold relaxation.
    pub folded: usize,
    /// Flipped or zero-area faces left after the fold relaxation (0 unless it gave up).
    pub folds_left: usize,
    /// Extra collapse-only passes run by [`crate::MeshOptimizer::remesh`] for edges below
    /// the hard lower limit (see [`crate::RemeshOptions::edge_floor_passes`]; 0 here).
    pub floor_passes: usize,
    /// Vertices after the pass.
    pub vertices: usize,
    /// Triangles after the pass.
    pub triangles: usize,
}

/// A flip may bend the two faces of an edge up to this cosine of their normals' angle
/// (about 26°), or up to how bent they were before if that was more.
const MAX_FLIP_BEND_COS: f32 = 0.9;

fn v3(p: [f32; 3]) -> Vec3 {
    Vec3::from(p)
}

/// Whether an edge flip would fold the surface: one of the two new faces `edits`
/// (`(face index, new corners)`) comes out **degenerate** (zero area) or **flipped**, or an
/// untouched face next to them becomes flipped (positions do not change).
///
/// A face is flipped when its unit normal points against the sum of its edge neighbours'
/// unit normals (like the test of [`face_collapse_flags`], with the neighbours in place of
/// the corners; unit normals make it blind to splits, which keep every normal). Neighbours
/// before the flip come from `table`, after it from `edits` first. Untouched faces that
/// were already flipped may stay flipped, so a flip next to a fold is not blocked by it.
fn flip_folds(positions: &[[f32; 3]], faces: &[[u32; 3]], table: &EdgeTable, edits: &[(u32, [u32; 3]); 2]) -> bool {
    let unit_normal = |t: [u32; 3]| normals::face_normal(positions, t).normalize_or_zero();
    let edited = |f: u32| edits.iter().any(|e| e.0 == f);
    // The face before the flip that runs along `b → a`.
    let old_across = |a: u32, b: u32| {
        let e = table.find(a, b)?;
        let half = table.edge_to_face[e][usize::from(a < b)];
        (half != NONE).then_some(half / 3)
    };
    // The face (and its corners) after the flip that runs along `b → a`.
    let new_across = |a: u32, b: u32| {
        let runs = |t: [u32; 3]| (0..3).any(|k| t[k] == b && t[(k + 1) % 3] == a);
        if let Some(&(f, t)) = edits.iter().find(|e| runs(e.1)) {
            return Some((f, t));
        }
        old_across(a, b).filter(|&g| !edited(g)).map(|g| (g, faces[g as usize]))
    };
    let old_flipped = |f: u32, t: [u32; 3]| {
        let around: DVec3 = (0..3)
            .filter_map(|k| old_across(t[k], t[(k + 1) % 3]))
            .filter(|&g| g != f)
            .map(|g| unit_normal(faces[g as usize]))
            .sum();
        unit_normal(t).dot(around) < 0.0
    };
    let new_flipped = |f: u32, t: [u32; 3]| {
        let around: DVec3 = (0..3)
            .filter_map(|k| new_across(t[k], t[(k + 1) % 3]))
            .filter(|&(g, _)| g != f)
            .map(|(_, tg)| unit_normal(tg))
            .sum();
        unit_normal(t).dot(around) < 0.0
    };
    edits.iter().any(|&(f, t_new)| {
        let t = faces[f as usize];
        unit_normal(t_new) == DVec3::ZERO
            || new_flipped(f, t_new)
            || (0..3).any(|k| {
                old_across(t[k], t[(k + 1) % 3]).is_some_and(|g| {
                    let tg = faces[g as usize];
                    !edited(g) && new_flipped(g, tg) && !old_flipped(g, tg)
                })
            })
    })
}

/// 64-bit mix (SplitMix64 finaliser).
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Flags the edges that flagged faces want collapsed (reference A.5a).
///
/// A face is flagged when it is **flipped** (its normal points against the sum of its
/// corners' unit vertex normals, both as defined in [`w3d_core::normals`]) or **small**
/// (area below `area_ratio · m²`, `m` the mean of `min_edge_length` over its corners). A
/// flagged face picks its shortest edge with probability `shortest_probability`, else its
/// middle or longest edge (equal odds); the draw is a hash of `seed` and the face index.
/// Ties in length keep local edge order.
#[allow(clippy::too_many_arguments)]
pub fn face_collapse_flags(
    positions: &[[f32; 3]],
    faces: &[[u32; 3]],
    alive: &[bool],
    table: &EdgeTable,
    edge_length: &[f32],
    min_edge_length: &[f32],
    params: &RemeshParams,
    seed: u64,
) -> Vec<bool> {
    // Face normals (length = twice the area) and unit vertex normals of the live faces.
    let face_normals: Vec<DVec3> = faces
        .iter()
        .zip(alive)
        .map(|(&t, &live)| if live { normals::face_normal(positions, t) } else { DVec3::ZERO })
        .collect();
    let live_faces = faces.iter().zip(&face_normals).zip(alive).filter(|&(_, &live)| live);
    let vnormals: Vec<DVec3> = normals::vertex_normal_sums(positions.len(), live_faces.map(|((&t, &n), _)| (t, n)))
        .into_iter()
        .map(normals::unit_or_zero)
        .collect();
    let p = params.shortest_probability;
    // Draws r in [0, randlim) and takes position min(r, 2) of the edges sorted by length,
    // longest first: position 2 (the shortest) has probability 1 − 2 / randlim = p.
    let randlim = if p < 1.0 { (2.0 / (1.0 - f64::from(p))).round().max(1.0) as u64 } else { 0 };
    let mut flags = vec![false; table.edges.len()];
    for (f, t) in faces.iter().enumerate() {
        if !alive[f] {
            continue;
        }
        let n = face_normals[f];
        let reference: DVec3 = t.iter().map(|&v| vnormals[v as usize]).sum();
        let flipped = n.dot(reference) < 0.0;
        let m = t.iter().map(|&v| min_edge_length[v as usize]).sum::<f32>() / 3.0;
        let small = n.length() < f64::from(2.0 * params.area_ratio * m * m);
        if !(flipped || small) {
            continue;
        }
        let e = table.face_to_edge[f];
        let len = e.map(|e| edge_length[e as usize]);
        let local = if randlim == 0 {
            // First shortest edge.
            (0..3).fold(0, |best, k| if len[k] < len[best] { k } else { best })
        } else {
            let mut order = [0usize, 1, 2];
            order.sort_by(|&a, &b| len[b].total_cmp(&len[a])); // stable, longest first
            let r = (mix(seed ^ mix(f as u64)) % randlim).min(2) as usize;
            order[r]
        };
        flags[e[local] as usize] = true;
    }
    flags
}

/// Vertex → neighbour lists built from an edge table (compressed rows).
struct Adjacency {
    start: Vec<u32>,
    neighbours: Vec<u32>,
}

impl Adjacency {
    fn new(table: &EdgeTable, num_vertices: usize) -> Self {
        let mut start = vec![0u32; num_vertices + 1];
        for &[a, b] in &table.edges {
            start[a as usize + 1] += 1;
            start[b as usize + 1] += 1;
        }
        for v in 0..num_vertices {
            start[v + 1] += start[v];
        }
        let mut cursor = start[..num_vertices].to_vec();
        let mut neighbours = vec![0u32; start[num_vertices] as usize];
        for &[a, b] in &table.edges {
            neighbours[cursor[a as usize] as usize] = b;
            cursor[a as usize] += 1;
            neighbours[cursor[b as usize] as usize] = a;
            cursor[b as usize] += 1;
        }
        Adjacency { start, neighbours }
    }

    fn of(&self, v: u32) -> &[u32] {
        &self.neighbours[self.start[v as usize] as usize..self.start[v as usize + 1] as usize]
    }
}

/// Removes interior vertices of valence 3 flagged in `candidate` (not in the reference).
///
/// An interior valence-3 vertex `v` with the closed fan `(v, a, b), (v, b, c), (v, c, a)`
/// is deleted and its three faces are replaced by the one face `(a, b, c)`, which keeps
/// the fan's orientation: the first fan face is rewritten, the other two are marked dead
/// (`alive = false`); `v`'s row stays, unreferenced, until [`pack`]. On a 2-manifold this
/// keeps the manifold and its Euler characteristic (V − 1, E − 3, F − 2).
///
/// Skipped: boundary vertices (their fan is open), vertices whose neighbours already form a
/// face (the result would duplicate it; this also covers a neighbour of valence 3 and the
/// tetrahedron), vertices whose new face would be folded (zero area, or its unit normal
/// against the sum of the unit normals of the three faces across its edges), and any vertex whose fan shares a vertex with a fan removed earlier in
/// the same call (so `table` stays valid for every check). Candidates are visited in index
/// order. Returns the number of removed vertices.
///
/// Why: the link condition of [`collapse_edges`] rejects an edge whose opposite corner has
/// valence 3 (collapsing it would leave that corner with valence 2), so short edges around
/// such a vertex can never collapse; removing the vertex unblocks them.
pub fn remove_valence3_vertices(
    positions: &[[f32; 3]],
    faces: &mut [[u32; 3]],
    alive: &mut [bool],
    table: &EdgeTable,
    candidate: &[bool],
) -> usize {
    let num_vertices = positions.len();
    let mut slot = vec![NONE; num_vertices];
    let mut vertices: Vec<u32> = Vec::new();
    for v in 0..num_vertices {
        // Three faces forming one closed fan (checked below) means valence 3.
        if candidate[v] {
            slot[v] = vertices.len() as u32;
            vertices.push(v as u32);
        }
    }
    if vertices.is_empty() {
        return 0;
    }
    // The faces around each candidate (a closed valence-3 fan has exactly 3).
    let mut fan = vec![[NONE; 3]; vertices.len()];
    let mut fan_size = vec![0u32; vertices.len()];
    for (f, t) in faces.iter().enumerate() {
        if !alive[f] {
            continue;
        }
        for &v in t {
            let s = slot[v as usize];
            if s != NONE {
                let s = s as usize;
                if fan_size[s] < 3 {
                    fan[s][fan_size[s] as usize] = f as u32;
                }
                fan_size[s] += 1;
            }
        }
    }
    // The two corners after `v` in face `f`, in order.
    let after = |faces: &[[u32; 3]], f: u32, v: u32| {
        let t = faces[f as usize];
        let k = t.iter().position(|&c| c == v).unwrap_or(0);
        [t[(k + 1) % 3], t[(k + 2) % 3]]
    };
    let normal = |t: [u32; 3]| normals::face_normal(positions, t);
    let mut touched = vec![false; num_vertices];
    let mut removed = 0;
    for (i, &v) in vertices.iter().enumerate() {
        if fan_size[i] != 3 {
            continue;
        }
        let [f0, f1, f2] = fan[i];
        let [a, b] = after(faces, f0, v);
        let ([b1, c], [c2, a2]) = if after(faces, f1, v)[0] == b {
            (after(faces, f1, v), after(faces, f2, v))
        } else {
            (after(faces, f2, v), after(faces, f1, v))
        };
        if b1 != b || c2 != c || a2 != a || [v, a, b, c].iter().any(|&x| touched[x as usize]) {
            continue;
        }
        // Does a face {a, b, c} exist already? It would be the face across ab from v's.
        let Some(e) = table.find(a, b) else { continue };
        let exists = table.edge_to_face[e].iter().any(|&half| {
            half != NONE && {
                let (f, k) = (half as usize / 3, half as usize % 3);
                faces[f][(k + 2) % 3] == c
            }
        });
        if exists {
            continue;
        }
        // The new face may not be folded: zero-area, or flipped against the faces across
        // its edges (the outer faces of the fan, untouched so far).
        let mut around = DVec3::ZERO;
        for (x, y) in [(a, b), (b, c), (c, a)] {
            let Some(e) = table.find(x, y) else { continue };
            for half in table.edge_to_face[e] {
                if half != NONE && !faces[half as usize / 3].contains(&v) {
                    around += normal(faces[half as usize / 3]).normalize_or_zero();
                }
            }
        }
        let new = normal([a, b, c]).normalize_or_zero();
        if new == DVec3::ZERO || new.dot(around) < 0.0 {
            continue;
        }
        faces[f0 as usize] = [a, b, c];
        for f in [f1, f2] {
            alive[f as usize] = false;
        }
        for x in [v, a, b, c] {
            touched[x as usize] = true;
        }
        removed += 1;
    }
    removed
}

/// Collapses a far-apart subset of the edges with positive priority (reference A.5b).
///
/// 1. **Independent set**: edges are ranked by `(priority, index)`; an edge wins when no
///    edge touching a vertex within graph distance `rank_rounds − 1` of its endpoints ranks
///    higher (`rank_rounds` rounds of max-propagation edge → vertex → edge; the reference
///    runs 3, and at least 2 are required: the fewest that keep the winners' endpoints
///    pairwise non-adjacent, so that their face rings are disjoint and each link test stays
///    valid while the others collapse; fewer are raised to 2). See
///    [`RemeshParams::collapse_rank_rounds`] for what 2 instead of 3 changes.
/// 2. **Link condition**: the endpoints may share only the opposite corners of the edge as
///    neighbours (≤ 2 common neighbours, where two boundary vertices also share the virtual
///    vertex that closes the boundary), and the two may not both have valence 3 (a lone
///    tetrahedron). Together these keep a 2-manifold a 2-manifold of the same topology.
/// 3. **Fold-over guard** (not in the reference): the merged vertex goes to the midpoint,
///    or, when that would turn a surviving face around the edge by 90° or more (or make it
///    vanish), to the first of the two endpoints and the mean of the two 1-rings that does
///    not; the collapse is skipped when none of them works. The fallbacks matter where the
///    fit keeps pulling vertices into a crease: there the midpoint folds a face, and without
///    them a few edges stay below the lower limit pass after pass. (Stricter
///    guards block the collapses that clean up the folds made by motion: in the shape test
///    (`tests/remesh/shape_fit.rs`) the mesh then grows without bound — from ~30 k to 10⁵–10⁶
///    triangles within 300 steps, with the flipped faces growing alike. Measured variants,
///    each with the others off: rejecting collapses that leave a face around the edge
///    flipped that was not (per face, or by the flipped count or area of the faces around
///    and next to the edge); rejecting them only where no face around was flipped before;
///    rejecting faces below a quality `2·area / longest²` of 0.1; falling back to an
///    endpoint when the midpoint folds; flagging the shortest edge of every valence-3
///    vertex. The last two *add* collapses and blow up just the same, so the loop of that
///    test is sensitive to any change of which collapses run. All measured before
///    [`relax_folds`] and [`remove_valence3_vertices`] existed: with those, motion no longer
///    leaves folds for the collapses to clean up, and the same test ends at 6.4–6.6 k
///    vertices (12.7–13.2 k triangles, with 2 or 3 rank rounds).)
/// 4. **Merge**: the lower index survives with the mean of both rows (all columns) at the
///    position picked in 3; on an open mesh, an interior vertex merged with a boundary
///    vertex takes the boundary vertex's position (or the collapse is skipped when that
///    folds a face), so the boundary does not move inwards. The two faces of the edge
///    are deleted (`alive = false`).
///
/// Returns the number of collapsed edges. Vertex rows of the removed endpoints stay in
/// place, unreferenced, until [`pack`].
pub fn collapse_edges<R: VertexRows>(
    rows: &mut R,
    faces: &mut [[u32; 3]],
    alive: &mut [bool],
    table: &EdgeTable,
    priorities: &[f32],
    rank_rounds: u32,
) -> usize {
    let num_vertices = rows.len();
    let edges = &table.edges;
    let mut candidates: Vec<u32> = (0..edges.len() as u32).filter(|&e| priorities[e as usize] > 0.0).collect();
    if candidates.is_empty() {
        return 0;
    }
    candidates.sort_by(|&a, &b| priorities[a as usize].total_cmp(&priorities[b as usize]).then(a.cmp(&b)));
    let mut rank = vec![0u32; edges.len()]; // 0 = not a candidate
    for (i, &e) in candidates.iter().enumerate() {
        rank[e as usize] = i as u32 + 1;
    }
    let mut vertex_rank = vec![0u32; num_vertices];
    let mut edge_rank = rank.clone();
    for _ in 0..rank_rounds.max(2) {
        for (&[a, b], &r) in edges.iter().zip(&edge_rank) {
            vertex_rank[a as usize] = vertex_rank[a as usize].max(r);
            vertex_rank[b as usize] = vertex_rank[b as usize].max(r);
        }
        for (r, &[a, b]) in edge_rank.iter_mut().zip(edges) {
            *r = vertex_rank[a as usize].max(vertex_rank[b as usize]);
        }
    }
    let winners: Vec<u32> = candidates.into_iter().filter(|&e| edge_rank[e as usize] == rank[e as usize]).collect();

    // Link condition.
    let adjacency = Adjacency::new(table, num_vertices);
    let on_boundary = table.boundary_vertices(num_vertices);
    let mut mark = vec![NONE; num_vertices];
    let winners: Vec<u32> = winners
        .into_iter()
        .filter(|&e| {
            let [s, d] = edges[e as usize];
            for &n in adjacency.of(s) {
                mark[n as usize] = e;
            }
            let mut common = adjacency.of(d).iter().filter(|&&n| mark[n as usize] == e).count();
            let (bs, bd) = (on_boundary[s as usize], on_boundary[d as usize]);
            if bs && bd {
                common += 1; // the virtual vertex closing the boundary
            }
            let closed_degree = |v: u32, b: bool| adjacency.of(v).len() + usize::from(b);
            common <= 2 && !(closed_degree(s, bs) <= 3 && closed_degree(d, bd) <= 3)
        })
        .collect();
    if winners.is_empty() {
        return 0;
    }

    // Faces around each winner (their 1-rings are disjoint, so each face has one owner).
    let mut owner = vec![NONE; num_vertices];
    for (w, &e) in winners.iter().enumerate() {
        let [s, d] = edges[e as usize];
        owner[s as usize] = w as u32;
        owner[d as usize] = w as u32;
    }
    let mut start = vec![0u32; winners.len() + 1];
    let mut owned: Vec<(u32, u32)> = Vec::new();
    for (f, t) in faces.iter().enumerate() {
        if alive[f]
            && let Some(&v) = t.iter().find(|&&v| owner[v as usize] != NONE)
        {
            let w = owner[v as usize];
            owned.push((w, f as u32));
            start[w as usize + 1] += 1;
        }
    }
    for w in 0..winners.len() {
        start[w + 1] += start[w];
    }
    let mut ring = vec![0u32; owned.len()];
    let mut cursor = start[..winners.len()].to_vec();
    for &(w, f) in &owned {
        ring[cursor[w as usize] as usize] = f;
        cursor[w as usize] += 1;
    }

    let positions = rows.positions();
    let mut merges: Vec<(u32, u32, Option<[f32; 3]>)> = Vec::with_capacity(winners.len());
    for (w, &e) in winners.iter().enumerate() {
        let [s, d] = edges[e as usize];
        let (bs, bd) = (on_boundary[s as usize], on_boundary[d as usize]);
        let pin = match (bs, bd) {
            (true, false) => Some(positions[s as usize]),
            (false, true) => Some(positions[d as usize]),
            _ => None,
        };
        let faces_of = &ring[start[w] as usize..start[w + 1] as usize];
        // Where the merged vertex may go without folding a face of the two 1-rings: the
        // midpoint (the reference), else either endpoint (a half-edge collapse, which keeps
        // a tip or a crease where the midpoint would turn a face over).
        let folds = |p: Vec3| {
            faces_of.iter().any(|&f| {
                let t = faces[f as usize];
                if t.contains(&s) && t.contains(&d) {
                    return false; // deleted by the collapse
                }
                let old = t.map(|v| v3(positions[v as usize]));
                let new = t.map(|v| if v == s || v == d { p } else { v3(positions[v as usize]) });
                let n_old = (old[1] - old[0]).cross(old[2] - old[0]);
                let n_new = (new[1] - new[0]).cross(new[2] - new[0]);
                n_old.dot(n_new) <= 0.0
            })
        };
        let ring_mean = {
            let (mut sum, mut count) = (Vec3::ZERO, 0.0f32);
            for &f in faces_of {
                for v in faces[f as usize] {
                    if v != s && v != d {
                        sum += v3(positions[v as usize]);
                        count += 1.0;
                    }
                }
            }
            (sum / count.max(1.0)).to_array()
        };
        let target = match pin {
            Some(p) => (!folds(v3(p))).then_some(Some(p)),
            None => [
                mean3(positions[s as usize], positions[d as usize]),
                positions[s as usize],
                positions[d as usize],
                ring_mean,
            ]
            .into_iter()
            .enumerate()
            .find(|&(_, p)| !folds(v3(p)))
            .map(|(k, p)| (k > 0).then_some(p)),
        };
        if let Some(pin) = target {
            merges.push((w as u32, e, pin));
        }
    }

    for &(w, e, pin) in &merges {
        let [s, d] = edges[e as usize];
        rows.set_mean(s as usize, s as usize, d as usize);
        if let Some(p) = pin {
            rows.set_position(s as usize, p);
        }
        for &f in &ring[start[w as usize] as usize..start[w as usize + 1] as usize] {
            let t = &mut faces[f as usize];
            if t.contains(&s) && t.contains(&d) {
                alive[f as usize] = false;
            } else {
                for v in t.iter_mut() {
                    if *v == d {
                        *v = s;
                    }
                }
            }
        }
    }
    merges.len()
}

/// Splits every edge whose `split` flag is set at its midpoint (reference A.6).
///
/// New vertex rows (the mean of the endpoint rows, all columns) are appended in edge
/// order. Each live face is replaced in place by its "shrunk" face and its extra faces are
/// appended in face order: one split gives 2 faces, two give 3, three give 4; both faces
/// of an edge use the same midpoint and orientation is kept. Returns the number of splits.
pub fn split_edges<R: VertexRows>(
    rows: &mut R,
    faces: &mut Vec<[u32; 3]>,
    alive: &mut Vec<bool>,
    table: &EdgeTable,
    split: &[bool],
) -> usize {
    let mut edge_vertex = vec![NONE; table.edges.len()];
    let mut count = 0;
    for (e, &[a, b]) in table.edges.iter().enumerate() {
        if split[e] {
            edge_vertex[e] = rows.len() as u32;
            rows.push_mean(a as usize, b as usize);
            count += 1;
        }
    }
    if count == 0 {
        return 0;
    }
    for f in 0..faces.len().min(table.face_to_edge.len()) {
        if !alive[f] {
            continue;
        }
        let c = faces[f];
        let side = table.face_to_edge[f].map(|e| edge_vertex[e as usize]);
        if side == [NONE; 3] {
            continue;
        }
        let shrunk: [u32; 3] = std::array::from_fn(|k| if side[k] != NONE { side[k] } else { c[k] });
        faces[f] = shrunk;
        for k in 0..3 {
            if side[k] != NONE {
                faces.push([c[k], side[k], shrunk[(k + 2) % 3]]);
                alive.push(true);
            }
        }
    }
    count
}

/// Drops deleted faces and unreferenced vertex rows, keeping the order of both, and
/// returns the live faces reindexed to the kept rows (reference A.7).
pub fn pack<R: VertexRows>(rows: &mut R, faces: &[[u32; 3]], alive: &[bool]) -> Vec<[u32; 3]> {
    let mut new_index = vec![NONE; rows.len()];
    for (t, &live) in faces.iter().zip(alive) {
        if live {
            for &v in t {
                new_index[v as usize] = 0;
            }
        }
    }
    let mut keep = Vec::with_capacity(rows.len());
    for (v, slot) in new_index.iter_mut().enumerate() {
        if *slot == 0 {
            *slot = keep.len() as u32;
            keep.push(v as u32);
        }
    }
    rows.retain_rows(&keep);
    faces.iter().zip(alive).filter(|(_, live)| **live).map(|(t, _)| t.map(|v| new_index[v as usize])).collect()
}

/// Fraction of the way to the 1-ring mean that [`relax_folds`] moves a vertex per round.
const RELAX_STEP: f32 = 0.5;

/// The face across local edge `k` of face `f` ([`NONE`] on a boundary).
fn face_across(table: &EdgeTable, f: u32, k: usize) -> u32 {
    let [left, right] = table.edge_to_face[table.face_to_edge[f as usize][k] as usize];
    let other = if left == 3 * f + k as u32 { right } else { left };
    if other == NONE { NONE } else { other / 3 }
}

/// Whether face `f` is folded: zero-area (no unit normal), or **flipped** — its unit normal
/// points against the sum of the unit normals of the faces across its three edges (missing
/// ones on a boundary count as zero).
fn is_folded(positions: &[[f32; 3]], faces: &[[u32; 3]], table: &EdgeTable, f: u32) -> bool {
    let unit = |g: u32| normals::face_normal(positions, faces[g as usize]).normalize_or_zero();
    let n = unit(f);
    let mut around = DVec3::ZERO;
    for k in 0..3 {
        let g = face_across(table, f, k);
        if g != NONE {
            around += unit(g);
        }
    }
    n == DVec3::ZERO || n.dot(around) < 0.0
}

/// Untangles folds by moving vertices (not in the reference): positions only, no topology
/// change, no other columns touched.
///
/// Finds the **folded** faces — zero-area faces and flipped faces, whose unit normal points
/// against the sum of the unit normals of their edge neighbours — and, for at most `rounds`
/// rounds, moves the interior corners of every folded face half-way to the mean of their
/// 1-ring neighbours (a uniform Laplacian step, which pulls a vertex that was pushed through
/// its neighbours back between them), then re-evaluates the faces around the moved vertices.
/// From the fourth round on, faces still folded move their corners' 1-ring too, and from
/// the seventh two rings. Boundary vertices never move. `table` must be the edge table of
/// `faces`. Cost is proportional to the number of faces on a mesh without folds (one normal
/// and one test per face) and to the size of the folded regions otherwise.
///
/// Returns `(folded faces found, folded faces left)`.
pub fn relax_folds<R: VertexRows>(rows: &mut R, faces: &[[u32; 3]], table: &EdgeTable, rounds: u32) -> (usize, usize) {
    // A face can only be flipped if it points away from one of its neighbours, so the full
    // test runs on those few (and on zero-area faces).
    let positions = rows.positions();
    let raw = normals::face_normals(positions, faces);
    let mut suspect: Vec<bool> = raw.iter().map(|&n| n == DVec3::ZERO).collect();
    for [left, right] in &table.edge_to_face {
        if *left != NONE && *right != NONE {
            let (f, g) = (*left as usize / 3, *right as usize / 3);
            if raw[f].dot(raw[g]) < 0.0 {
                suspect[f] = true;
                suspect[g] = true;
            }
        }
    }
    let mut bad: Vec<u32> =
        (0..faces.len() as u32).filter(|&f| suspect[f as usize] && is_folded(positions, faces, table, f)).collect();
    drop((raw, suspect));
    let found = bad.len();
    if found == 0 || rounds == 0 {
        return (found, found);
    }
    let num_vertices = rows.len();
    let on_boundary = table.boundary_vertices(num_vertices);
    let adjacency = Adjacency::new(table, num_vertices);
    // Vertex → incident faces (compressed rows).
    let mut start = vec![0u32; num_vertices + 1];
    for t in faces {
        for &v in t {
            start[v as usize + 1] += 1;
        }
    }
    for v in 0..num_vertices {
        start[v + 1] += start[v];
    }
    let mut cursor = start[..num_vertices].to_vec();
    let mut incident = vec![0u32; start[num_vertices] as usize];
    for (f, t) in faces.iter().enumerate() {
        for &v in t {
            incident[cursor[v as usize] as usize] = f as u32;
            cursor[v as usize] += 1;
        }
    }
    let faces_of = |v: u32| &incident[start[v as usize] as usize..start[v as usize + 1] as usize];

    let mut vertex_mark = vec![u32::MAX; num_vertices];
    let mut face_mark = vec![u32::MAX; faces.len()];
    for round in 0..rounds {
        // The vertices to move: corners of folded faces, grown by 0, 1 or 2 rings.
        let mut moving: Vec<u32> = Vec::new();
        for &f in &bad {
            for &v in &faces[f as usize] {
                if vertex_mark[v as usize] != round {
                    vertex_mark[v as usize] = round;
                    moving.push(v);
                }
            }
        }
        for _ in 0..(round / 3).min(2) {
            let ring_end = moving.len();
            for i in 0..ring_end {
                for &n in adjacency.of(moving[i]) {
                    if vertex_mark[n as usize] != round {
                        vertex_mark[n as usize] = round;
                        moving.push(n);
                    }
                }
            }
        }
        moving.retain(|&v| !on_boundary[v as usize]);
        let positions = rows.positions();
        let targets: Vec<[f32; 3]> = moving
            .iter()
            .map(|&v| {
                let ring = adjacency.of(v);
                let mean = ring.iter().map(|&n| v3(positions[n as usize])).sum::<Vec3>() / ring.len().max(1) as f32;
                let p = v3(positions[v as usize]);
                (p + (mean - p) * RELAX_STEP).to_array()
            })
            .collect();
        for (&v, &p) in moving.iter().zip(&targets) {
            rows.set_position(v as usize, p);
        }
        // Re-evaluate the faces around the moved vertices and their edge neighbours.
        let mut changed: Vec<u32> = Vec::new();
        for &v in &moving {
            for &f in faces_of(v) {
                if face_mark[f as usize] != round {
                    face_mark[f as usize] = round;
                    changed.push(f);
                }
            }
        }
        let mut check = changed.clone();
        for &f in &changed {
            for k in 0..3 {
                let g = face_across(table, f, k);
                if g != NONE && face_mark[g as usize] != round {
                    face_mark[g as usize] = round;
                    check.push(g);
                }
            }
        }
        bad.retain(|&f| face_mark[f as usize] != round && is_folded(rows.positions(), faces, table, f));
        bad.extend(check.iter().copied().filter(|&f| is_folded(rows.positions(), faces, table, f)));
        if bad.is_empty() {
            break;
        }
    }
    (found, bad.len())
}

/// Flips interior edges to move vertex valences towards 6 (4 on a boundary) (reference
/// A.8).
///
/// For the interior edge `(e0, e1)` with opposite corners `cl` (left face) and `cr`
/// (right face), the change of `Σ (valence − target)²` is `2·Δ` with
/// `Δ = 2 + d(cl) + d(cr) − d(e0) − d(e1)`; candidates have `Δ < 0`. With `with_border`
/// the degree of vertices with no boundary edge is reduced by 2 so that interior vertices
/// aim at 6 and boundary vertices at 4 (identical to the reference's `with_border=False`
/// on closed meshes). Flips are chosen as an independent set (rank by `Δ` most negative
/// first, ties by edge index; no two flips share any of their 4 vertices), skipped when the
/// edge `(cl, cr)` already exists (it would duplicate an edge) and, with `normal_check`,
/// when either new face would turn against the old pair's summed normal, bend the pair
/// more than allowed, or leave a face of the pair or next to it flipped (normal against the
/// sum of its edge neighbours' normals) that was not flipped before. Boundary edges are
/// never flipped. The left face becomes `(e0, cr, cl)`, the right face `(e1, cl, cr)`.
///
/// Returns the flipped edges as `(edge index, new edge [lo, hi])`.
pub fn flip_edges(
    positions: &[[f32; 3]],
    faces: &mut [[u32; 3]],
    table: &EdgeTable,
    with_border: bool,
    normal_check: bool,
) -> Vec<(usize, [u32; 2])> {
    let num_vertices = positions.len();
    let mut degree: Vec<i32> = table.degrees(num_vertices).into_iter().map(|d| d as i32).collect();
    if with_border {
        let on_boundary = table.boundary_vertices(num_vertices);
        for (d, b) in degree.iter_mut().zip(on_boundary) {
            if !b {
                *d -= 2;
            }
        }
    }
    let corner = |half: u32| {
        let (f, k) = (half as usize / 3, half as usize % 3);
        faces[f][(k + 2) % 3]
    };
    // (edge, Δ, [e0, e1, cl, cr])
    let mut candidates: Vec<(u32, i32, [u32; 4])> = Vec::new();
    for (e, &[e0, e1]) in table.edges.iter().enumerate() {
        let [left, right] = table.edge_to_face[e];
        if left == NONE || right == NONE {
            continue;
        }
        let (cl, cr) = (corner(left), corner(right));
        let delta = 2 + degree[cl as usize] + degree[cr as usize] - degree[e0 as usize] - degree[e1 as usize];
        if delta < 0 && cl != cr && table.find(cl, cr).is_none() {
            candidates.push((e as u32, delta, [e0, e1, cl, cr]));
        }
    }
    // Ascending rank: largest Δ first, ties by edge index; the highest rank wins.
    candidates.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    let mut vertex_rank = vec![0u32; num_vertices];
    for (i, c) in candidates.iter().enumerate() {
        for &v in &c.2 {
            vertex_rank[v as usize] = vertex_rank[v as usize].max(i as u32 + 1);
        }
    }
    let mut flipped = Vec::new();
    for (i, &(e, _, quad)) in candidates.iter().enumerate() {
        if quad.iter().any(|&v| vertex_rank[v as usize] != i as u32 + 1) {
            continue;
        }
        let [e0, e1, cl, cr] = quad;
        if normal_check {
            let o = v3(positions[e0 as usize]);
            let [p1, l, r] = [e1, cl, cr].map(|v| v3(positions[v as usize]) - o);
            let (old_left, old_right) = (p1.cross(l), r.cross(p1));
            let (new_left, new_right) = (r.cross(l), (l - p1).cross(r - p1));
            let n = old_left + old_right;
            if n.dot(new_left) <= 0.0 || n.dot(new_right) <= 0.0 {
                continue;
            }
            // Not in the reference: keep the pair at most as bent as before (or within
            // ~26°), so that flips on curved, coarse regions do not fold the surface.
            let bend = |a: Vec3, b: Vec3| a.normalize_or_zero().dot(b.normalize_or_zero());
            if bend(new_left, new_right) < bend(old_left, old_right).min(MAX_FLIP_BEND_COS) {
                continue;
            }
        }
        let [left, right] = table.edge_to_face[e as usize];
        let (left, right) = (left / 3, right / 3);
        if normal_check {
            // Not in the reference: no face of the pair or next to it may end up flipped
            // (see `flip_folds`).
            if flip_folds(positions, faces, table, &[(left, [e0, cr, cl]), (right, [e1, cl, cr])]) {
                continue;
            }
        }
        faces[left as usize] = [e0, cr, cl];
        faces[right as usize] = [e1, cl, cr];
        flipped.push((e as usize, [cl.min(cr), cl.max(cr)]));
    }
    flipped
}

/// One continuous-remeshing pass (reference A.3, plus two steps of ours): [valence-3
/// removal] → collapse → split → pack → [fold relaxation] → flip.
///
/// `min_edge_length` / `max_edge_length` are per-vertex thresholds (the optimizer uses
/// `ref_len · (1 ∓ tol)`). Edges shorter than the mean of their endpoints' minimum, and
/// one edge of every flipped or small face, want to collapse. With
/// `params.remove_valence3`, interior valence-3 vertices at such an edge are removed first
/// ([`remove_valence3_vertices`]). Then a far-apart subset of those edges is collapsed;
/// then, unless the mesh has `max_vertices` rows, every edge longer than the mean of its
/// endpoints' maximum is split once (using the thresholds from before the collapse, as the
/// reference does); then deleted faces and unused rows are packed; then, with
/// `params.fold_relaxation_rounds > 0`, flipped and zero-area faces are untangled by moving
/// vertices ([`relax_folds`]); then edges are flipped (a flip never folds a face, so when
/// the relaxation removed every fold, the pass returns a mesh without flipped or zero-area
/// faces). With both extra steps off, this is the reference pass up to the deviations
/// documented on [`collapse_edges`] and [`flip_edges`].
///
/// Returns the new triangles, the unique edges of the new triangles (in no particular
/// order) and what was done. `rows` are rewritten in place.
pub fn remesh<R: VertexRows>(
    rows: &mut R,
    faces: Vec<[u32; 3]>,
    min_edge_length: &[f32],
    max_edge_length: &[f32],
    params: &RemeshParams,
    seed: u64,
) -> (Vec<[u32; 3]>, Vec<[u32; 2]>, RemeshStats) {
    let mut faces = faces;
    let mut alive = vec![true; faces.len()];
    let num_vertices = rows.len();

    // Collapse priorities: flagged faces' edges, and edges below their minimum length.
    let priorities = |faces: &[[u32; 3]], alive: &[bool], table: &EdgeTable| -> Vec<f32> {
        let length = table.lengths(rows.positions());
        let flags = face_collapse_flags(rows.positions(), faces, alive, table, &length, min_edge_length, params, seed);
        table
            .edges
            .iter()
            .zip(&length)
            .zip(&flags)
            .map(|((&[a, b], &len), &flag)| {
                let min = 0.5 * (min_edge_length[a as usize] + min_edge_length[b as usize]);
                let shortness = (1.0 - len / min).max(0.0);
                f32::from(u8::from(flag)) + shortness
            })
            .collect()
    };
    let mut table = EdgeTable::new(&faces, None, num_vertices);
    let mut priority = priorities(&faces, &alive, &table);

    // Valence-3 vertices at an edge that wants to collapse block its neighbours' collapses.
    let mut removed_valence3 = 0;
    if params.remove_valence3 && priority.iter().any(|&p| p > 0.0) {
        let mut candidate = vec![false; num_vertices];
        for (&[a, b], &p) in table.edges.iter().zip(&priority) {
            if p > 0.0 {
                candidate[a as usize] = true;
                candidate[b as usize] = true;
            }
        }
        removed_valence3 = remove_valence3_vertices(rows.positions(), &mut faces, &mut alive, &table, &candidate);
        if removed_valence3 > 0 {
            table = EdgeTable::new(&faces, Some(&alive), num_vertices);
            priority = priorities(&faces, &alive, &table);
        }
    }

    // Collapse.
    let collapsed = collapse_edges(rows, &mut faces, &mut alive, &table, &priority, params.collapse_rank_rounds);

    // Split.
    let mut split = 0;
    if num_vertices < params.max_vertices {
        let table = EdgeTable::new(&faces, Some(&alive), num_vertices);
        let positions = rows.positions();
        let too_long: Vec<bool> = table
            .edges
            .iter()
            .map(|&[a, b]| {
                let max = 0.5 * (max_edge_length[a as usize] + max_edge_length[b as usize]);
                crate::edges::distance(positions[a as usize], positions[b as usize]) > max
            })
            .collect();
        split = split_edges(rows, &mut faces, &mut alive, &table, &too_long);
    }

    // Pack, relax folds (positions only, so the table stays valid) and flip (which never
    // folds a face that was not folded).
    let mut faces = pack(rows, &faces, &alive);
    let table = EdgeTable::new(&faces, None, rows.len());
    let (folded, folds_left) = if params.fold_relaxation_rounds > 0 {
        relax_folds(rows, &faces, &table, params.fold_relaxation_rounds)
    } else {
        (0, 0)
    };
    let mut edges = table.edges.clone();
    let mut flipped = 0;
    if params.flip {
        let flips = flip_edges(rows.positions(), &mut faces, &table, true, true);
        flipped = flips.len();
        for (e, new_edge) in flips {
            edges[e] = new_edge;
        }
    }
    let stats = RemeshStats {
        collapsed,
        split,
        flipped,
        removed_valence3,
        folded,
        folds_left,
        floor_passes: 0,
        vertices: rows.len(),
        triangles: faces.len(),
    };
    (faces, edges, stats)
}
