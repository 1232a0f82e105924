//! Error-bounded simplification by quadric edge collapse (Garland & Heckbert 1997,
//! "Surface Simplification Using Quadric Error Metrics"), for meshes that carry more
//! triangles than their shape needs: flat and gently curved parts lose vertices, curved
//! parts and features keep them, and the surface moves by no more than a tolerance given in
//! mesh units.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use glam::DVec3;
use w3d_core::{Error, Mesh, Result};

/// Settings of [`simplify`]. Lengths are in mesh units (the unit cube `[-0.5, 0.5]³` for
/// normalised meshes).
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct SimplifyOptions {
    /// The largest error a collapse may have: the area-weighted root-mean-square distance
    /// from the merged vertex to the planes of the original triangles it stands for
    /// (0.0005, a sixth of a pixel of a 512² view of the unit cube in the Wonder3D rig).
    /// 0 removes only vertices that lie exactly in the plane of their neighbourhood.
    pub tolerance: f32,
    /// Collapses stop before the mesh would have fewer triangles than this (4).
    pub min_triangles: usize,
    /// A collapse is refused when it turns the normal of a triangle it keeps by more than
    /// this many degrees (45): the guard against folds, which a quadric cannot see.
    pub max_normal_turn_deg: f32,
    /// A collapse is refused when a triangle it reshapes ends below this quality and below
    /// its own quality before (0.2). Quality is `4√3 · area / Σ edge²`: 1 for an equilateral
    /// triangle, 0 for a degenerate one; slivers shade and texture badly.
    pub min_quality: f32,
}

impl Default for SimplifyOptions {
    fn default() -> Self {
        SimplifyOptions { tolerance: 0.0005, min_triangles: 4, max_normal_turn_deg: 45.0, min_quality: 0.2 }
    }
}

/// Chainable setters, one per field: `SimplifyOptions::default().with_…(…)` (the struct is
/// `#[non_exhaustive]`).
impl SimplifyOptions {
    w3d_core::setters! {
        with_tolerance(tolerance: f32);
        with_min_triangles(min_triangles: usize);
        with_max_normal_turn_deg(max_normal_turn_deg: f32);
        with_min_quality(min_quality: f32);
    }

    fn check(&self) -> Result<()> {
        if !(self.tolerance.is_finite() && self.tolerance >= 0.0) {
            return Err(Error::invalid("tolerance", format!("a finite distance ≥ 0, got {}", self.tolerance)));
        }
        if !(self.max_normal_turn_deg > 0.0 && self.max_normal_turn_deg <= 180.0) {
            return Err(Error::invalid(
                "max_normal_turn_deg",
                format!("an angle in (0, 180] degrees, got {}", self.max_normal_turn_deg),
            ));
        }
        if !(0.0..1.0).contains(&self.min_quality) {
            return Err(Error::invalid("min_quality", format!("a quality in [0, 1), got {}", self.min_quality)));
        }
        Ok(())
    }
}

/// What [`simplify`] did.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct SimplifyReport {
    /// Triangles of the input mesh.
    pub triangles_before: usize,
    /// Triangles of the simplified mesh.
    pub triangles_after: usize,
    /// Edge collapses done (each removes one vertex and two triangles).
    pub collapses: usize,
    /// The largest error of a collapse done, in mesh units (see
    /// [`SimplifyOptions::tolerance`]; 0 when nothing collapsed).
    pub max_error: f64,
}

/// A symmetric 4×4 quadric `Σ w (n·x + d)²` over planes `(n, d)` with weights `w`, stored as
/// its upper triangle, plus the sum of the weights.
#[derive(Debug, Clone, Copy, Default)]
struct Quadric {
    /// `a11 a12 a13 a14 a22 a23 a24 a33 a34 a44`.
    q: [f64; 10],
    weight: f64,
}

impl Quadric {
    fn plane(n: DVec3, d: f64, w: f64) -> Self {
        let p = [n.x, n.y, n.z, d];
        let mut q = [0.0; 10];
        let mut k = 0;
        for i in 0..4 {
            for j in i..4 {
                q[k] = w * p[i] * p[j];
                k += 1;
            }
        }
        Quadric { q, weight: w }
    }

    fn add(&self, o: &Quadric) -> Quadric {
        let mut q = self.q;
        for (a, b) in q.iter_mut().zip(o.q) {
            *a += b;
        }
        Quadric { q, weight: self.weight + o.weight }
    }

    /// `Σ w (n·x + d)²` at `x`, never negative.
    fn eval(&self, x: DVec3) -> f64 {
        let [a11, a12, a13, a14, a22, a23, a24, a33, a34, a44] = self.q;
        let v = x.x * (a11 * x.x + 2.0 * (a12 * x.y + a13 * x.z + a14))
            + x.y * (a22 * x.y + 2.0 * (a23 * x.z + a24))
            + x.z * (a33 * x.z + 2.0 * a34)
            + a44;
        v.max(0.0)
    }

    /// The root-mean-square plane distance at `x` (the error [`SimplifyOptions::tolerance`]
    /// bounds).
    fn rms(&self, x: DVec3) -> f64 {
        if self.weight > 0.0 { (self.eval(x) / self.weight).sqrt() } else { 0.0 }
    }

    /// The point minimising the quadric, when the 3×3 system is well conditioned.
    fn minimiser(&self) -> Option<DVec3> {
        let [a11, a12, a13, a14, a22, a23, a24, a33, a34, _] = self.q;
        let m = glam::DMat3::from_cols(DVec3::new(a11, a12, a13), DVec3::new(a12, a22, a23), DVec3::new(a13, a23, a33));
        let det = m.determinant();
        let trace = a11 + a22 + a33;
        // Relative to the scale of the matrix: a flat or cylindrical neighbourhood has a
        // (nearly) singular system and no unique best point.
        if trace.is_nan() || trace <= 0.0 || det.abs() <= 1e-9 * (trace / 3.0).powi(3) {
            return None;
        }
        let x = m.inverse() * -DVec3::new(a14, a24, a34);
        x.is_finite().then_some(x)
    }
}

fn quality(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let area2 = (b - a).cross(c - a).length();
    let sum = (b - a).length_squared() + (c - b).length_squared() + (a - c).length_squared();
    if sum > 0.0 { 2.0 * 3f64.sqrt() * area2 / sum } else { 0.0 }
}

/// One candidate collapse in the queue: the edge `(u, v)` with the stamps its vertices had
/// when it was costed (a later change to either makes the entry stale).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
struct Candidate {
    /// The error's bits: for non-negative floats the integer order is the numeric order.
    cost_bits: u64,
    u: u32,
    v: u32,
    stamp_u: u32,
    stamp_v: u32,
}

struct Simplifier {
    pos: Vec<DVec3>,
    faces: Vec<[u32; 3]>,
    face_alive: Vec<bool>,
    /// Live faces around each vertex.
    vertex_faces: Vec<Vec<u32>>,
    quadrics: Vec<Quadric>,
    removed: Vec<bool>,
    /// Vertices kept by the caller or on a boundary or non-manifold edge: never moved or
    /// removed.
    locked: Vec<bool>,
    stamps: Vec<u32>,
    live_faces: usize,
    cos_max_turn: f64,
    min_quality: f64,
    /// Faces below this doubled area count as degenerate (relative to the mesh's size).
    min_area2: f64,
}

impl Simplifier {
    /// The simplifier's state for `mesh`, and the mesh's unique edges `[min, max]` (sorted
    /// once here, for the locks and for the first costing).
    fn new(mesh: &Mesh, options: &SimplifyOptions, keep: &[bool]) -> (Self, Vec<[u32; 2]>) {
        let pos: Vec<DVec3> = mesh.positions().iter().map(|p| DVec3::from(p.map(f64::from))).collect();
        let faces = mesh.triangles().to_vec();
        let n = pos.len();
        let mut vertex_faces = vec![Vec::new(); n];
        let mut quadrics = vec![Quadric::default(); n];
        for (f, t) in faces.iter().enumerate() {
            let [a, b, c] = t.map(|i| pos[i as usize]);
            let cross = (b - a).cross(c - a);
            let len = cross.length();
            if len > 0.0 {
                let normal = cross / len;
                let plane = Quadric::plane(normal, -normal.dot(a), 0.5 * len);
                for &i in t {
                    quadrics[i as usize] = quadrics[i as usize].add(&plane);
                }
            }
            for &i in t {
                vertex_faces[i as usize].push(f as u32);
            }
        }
        let mut locked: Vec<bool> = (0..n).map(|i| keep.get(i).copied().unwrap_or(false)).collect();
        let mut edges: Vec<[u32; 2]> =
            faces.iter().flat_map(|t| w3d_core::mesh::triangle_edges(*t)).map(|[a, b]| [a.min(b), a.max(b)]).collect();
        edges.sort_unstable();
        for run in edges.chunk_by(|a, b| a == b) {
            if run.len() != 2 {
                locked[run[0][0] as usize] = true;
                locked[run[0][1] as usize] = true;
            }
        }
        edges.dedup();
        let (lo, hi) = mesh.bbox();
        let diagonal = f64::from((hi - lo).length());
        let simplifier = Simplifier {
            pos,
            live_faces: faces.len(),
            face_alive: vec![true; faces.len()],
            faces,
            vertex_faces,
            quadrics,
            removed: vec![false; n],
            locked,
            stamps: vec![0; n],
            cos_max_turn: f64::from(options.max_normal_turn_deg).to_radians().cos(),
            min_quality: f64::from(options.min_quality),
            min_area2: 1e-14 * diagonal * diagonal,
        };
        (simplifier, edges)
    }

    /// The vertices sharing a live face with `v` (sorted, without `v`).
    fn ring(&self, v: u32) -> Vec<u32> {
        let mut ring: Vec<u32> =
            self.vertex_faces[v as usize].iter().flat_map(|&f| self.faces[f as usize]).filter(|&x| x != v).collect();
        ring.sort_unstable();
        ring.dedup();
        ring
    }

    /// Where the collapse of `(u, v)` puts the merged vertex, and its error.
    fn placement(&self, u: u32, v: u32) -> (DVec3, f64) {
        let q = self.quadrics[u as usize].add(&self.quadrics[v as usize]);
        let (pu, pv) = (self.pos[u as usize], self.pos[v as usize]);
        let mid = 0.5 * (pu + pv);
        // The optimum, unless the system is singular or it lies far from the edge (a
        // nearly singular system can put it anywhere along a valley of the quadric).
        let mut best: Option<(DVec3, f64)> =
            q.minimiser().filter(|x| x.distance(mid) <= pu.distance(pv)).map(|x| (x, q.rms(x)));
        for x in [mid, pu, pv] {
            let e = q.rms(x);
            if best.is_none_or(|(_, b)| e < b) {
                best = Some((x, e));
            }
        }
        best.unwrap_or((mid, 0.0))
    }

    fn push(&self, heap: &mut BinaryHeap<Reverse<Candidate>>, u: u32, v: u32) {
        if self.locked[u as usize] || self.locked[v as usize] {
            return;
        }
        let (_, e) = self.placement(u, v);
        heap.push(Reverse(Candidate {
            cost_bits: e.to_bits(),
            u,
            v,
            stamp_u: self.stamps[u as usize],
            stamp_v: self.stamps[v as usize],
        }));
    }

    /// Whether collapsing `(u, v)` to `p` keeps the mesh a clean 2-manifold: exactly two
    /// faces on the edge, the link condition, every valence ≥ 3, and no kept face that
    /// degenerates, flips, turns too far or becomes a sliver.
    fn can_collapse(&self, u: u32, v: u32, p: DVec3) -> bool {
        let shared: Vec<u32> =
            self.vertex_faces[u as usize].iter().copied().filter(|&f| self.faces[f as usize].contains(&v)).collect();
        if shared.len() != 2 {
            return false;
        }
        let opposite: Vec<u32> =
            shared.iter().flat_map(|&f| self.faces[f as usize]).filter(|&x| x != u && x != v).collect();
        if opposite.len() != 2 || opposite[0] == opposite[1] {
            return false;
        }
        let (ring_u, ring_v) = (self.ring(u), self.ring(v));
        let common = ring_u.iter().filter(|x| ring_v.binary_search(x).is_ok()).count();
        if common != 2 || ring_u.len() + ring_v.len() < 3 + 4 {
            return false;
        }
        if opposite.iter().any(|&o| self.ring(o).len() <= 3) {
            return false;
        }
        for (moving, other) in [(u, v), (v, u)] {
            for &f in &self.vertex_faces[moving as usize] {
                let t = self.faces[f as usize];
                if t.contains(&other) {
                    continue;
                }
                let before = t.map(|i| self.pos[i as usize]);
                let after = t.map(|i| if i == moving { p } else { self.pos[i as usize] });
                let n0 = (before[1] - before[0]).cross(before[2] - before[0]);
                let n1 = (after[1] - after[0]).cross(after[2] - after[0]);
                let (l0, l1) = (n0.length(), n1.length());
                if l1 <= self.min_area2 {
                    return false;
                }
                if l0 > self.min_area2 && n0.dot(n1) < self.cos_max_turn * l0 * l1 {
                    return false;
                }
                let q1 = quality(after[0], after[1], after[2]);
                if q1 < self.min_quality && q1 < quality(before[0], before[1], before[2]) {
                    return false;
                }
            }
        }
        true
    }

    /// Merges `v` into `u` at `p`.
    fn collapse(&mut self, u: u32, v: u32, p: DVec3) {
        let faces_v = std::mem::take(&mut self.vertex_faces[v as usize]);
        for f in faces_v {
            let t = self.faces[f as usize];
            if t.contains(&u) {
                self.face_alive[f as usize] = false;
                self.live_faces -= 1;
                for &x in &t {
                    if x != v {
                        self.vertex_faces[x as usize].retain(|&g| g != f);
                    }
                }
            } else {
                self.faces[f as usize] = t.map(|x| if x == v { u } else { x });
                self.vertex_faces[u as usize].push(f);
            }
        }
        self.removed[v as usize] = true;
        self.pos[u as usize] = p;
        self.quadrics[u as usize] = self.quadrics[u as usize].add(&self.quadrics[v as usize]);
    }
}

/// Simplifies `mesh` by quadric edge collapse until the next collapse would move the surface
/// by more than [`SimplifyOptions::tolerance`] (or leave fewer than
/// [`SimplifyOptions::min_triangles`]), cheapest collapse first, each merged vertex placed
/// where it minimises the quadric error. Only attributes-free geometry comes back: normals,
/// uvs, colours and texture are dropped (bake them again on the result).
///
/// A collapse is done only when the mesh stays a 2-manifold with the same topology (the
/// link condition, valences ≥ 3) and no triangle degenerates, flips, turns by more than
/// [`SimplifyOptions::max_normal_turn_deg`] or becomes a sliver; vertices on boundary or
/// non-manifold edges never move. Collapses are local, so a collapse can still make two
/// distant parts of the surface cross where they are closer than the tolerance: check with
/// [`Mesh::self_intersections`] when that matters.
///
/// ```
/// use w3d_remesh::{SimplifyOptions, geodesic_sphere, simplify};
///
/// // A finely tessellated flat-topped shape: squash a sphere into a lens.
/// let mut mesh = geodesic_sphere(24, 0.5)?;
/// mesh.map_positions(|p| glam::Vec3::new(p.x, p.y.clamp(-0.2, 0.2), p.z))?;
/// let (simple, report) = simplify(&mesh, &SimplifyOptions::default().with_tolerance(0.002))?;
/// assert!(simple.topology().is_watertight());
/// // The two flat caps need only a few triangles.
/// assert!(report.triangles_after < report.triangles_before / 2, "{report:?}");
/// # Ok::<(), w3d_core::Error>(())
/// ```
///
/// Errors: options out of range (see [`SimplifyOptions`]).
pub fn simplify(mesh: &Mesh, options: &SimplifyOptions) -> Result<(Mesh, SimplifyReport)> {
    simplify_keeping(mesh, options, &[]).map(|s| (s.mesh, s.report))
}

/// A mesh simplified by [`simplify_keeping`], with where its vertices came from.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct Simplified {
    /// The simplified mesh (geometry only).
    pub mesh: Mesh,
    /// For each vertex of [`mesh`](Self::mesh), the input vertex it is (moved, when
    /// collapses merged others into it).
    pub source_vertex: Vec<u32>,
    /// What the simplification did.
    pub report: SimplifyReport,
}

/// [`simplify`] with the input vertices where `keep` is `true` neither moved nor removed
/// (`keep` may be shorter than the vertex list; missing entries count as `false`). Use it
/// to protect a region, for example where a first simplification made two parts of the
/// surface cross (see [`Simplified::source_vertex`] to find the input vertices of a
/// crossing).
///
/// Errors: options out of range (see [`SimplifyOptions`]).
pub fn simplify_keeping(mesh: &Mesh, options: &SimplifyOptions, keep: &[bool]) -> Result<Simplified> {
    options.check()?;
    let (mut s, edges) = Simplifier::new(mesh, options, keep);
    let tolerance = f64::from(options.tolerance);
    let mut heap = BinaryHeap::new();
    for [a, b] in edges {
        s.push(&mut heap, a, b);
    }
    let mut collapses = 0;
    let mut max_error = 0.0f64;
    while let Some(Reverse(c)) = heap.pop() {
        let (u, v) = (c.u as usize, c.v as usize);
        if s.removed[u] || s.removed[v] || s.stamps[u] != c.stamp_u || s.stamps[v] != c.stamp_v {
            continue;
        }
        let error = f64::from_bits(c.cost_bits);
        if error > tolerance || s.live_faces < options.min_triangles + 2 {
            break;
        }
        let (p, _) = s.placement(c.u, c.v);
        if !s.can_collapse(c.u, c.v, p) {
            continue;
        }
        s.collapse(c.u, c.v, p);
        collapses += 1;
        max_error = max_error.max(error);
        // The merged vertex has a new quadric and its neighbours a new neighbourhood: cost
        // every edge around them again (their older queue entries go stale).
        let ring = s.ring(c.u);
        s.stamps[u] += 1;
        for &x in &ring {
            s.stamps[x as usize] += 1;
        }
        let mut around: Vec<[u32; 2]> = Vec::new();
        for &x in std::iter::once(&c.u).chain(&ring) {
            for y in s.ring(x) {
                around.push([x.min(y), x.max(y)]);
            }
        }
        around.sort_unstable();
        around.dedup();
        for [x, y] in around {
            s.push(&mut heap, x, y);
        }
    }
    let mut index = vec![u32::MAX; s.pos.len()];
    let mut positions = Vec::new();
    let mut source_vertex = Vec::new();
    let mut triangles = Vec::with_capacity(s.live_faces);
    for (f, t) in s.faces.iter().enumerate() {
        if !s.face_alive[f] {
            continue;
        }
        triangles.push(t.map(|i| {
            let slot = &mut index[i as usize];
            if *slot == u32::MAX {
                *slot = positions.len() as u32;
                positions.push(s.pos[i as usize].as_vec3().to_array());
                source_vertex.push(i);
            }
            *slot
        }));
    }
    let report = SimplifyReport {
        triangles_before: mesh.triangle_count(),
        triangles_after: triangles.len(),
        collapses,
        max_error,
    };
    Ok(Simplified { mesh: Mesh::new(positions, triangles)?, source_vertex, report })
}
