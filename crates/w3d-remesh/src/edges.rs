//! Edge tables of a triangle list: unique undirected edges, face → edge and edge → face maps.

/// Marks "no face" in [`EdgeTable::edge_to_face`] and "deleted face" in
/// [`EdgeTable::face_to_edge`].
pub const NONE: u32 = u32::MAX;

/// The unique undirected edges of the live triangles of a mesh and how they connect.
///
/// Edges are `[lo, hi]` with `lo < hi`, sorted lexicographically (so the edges of one `lo`
/// vertex are contiguous). Local edge `k` of triangle `(c0, c1, c2)` runs from `c_k` to
/// `c_{(k+1) % 3}`; the corner opposite local edge `k` is `c_{(k+2) % 3}`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EdgeTable {
    /// Unique edges `[lo, hi]`, `lo < hi`, sorted.
    pub edges: Vec<[u32; 2]>,
    /// For each triangle, the edge index of its local edges 0, 1, 2 ([`NONE`] for deleted
    /// triangles).
    pub face_to_edge: Vec<[u32; 3]>,
    /// For each edge, `[left, right]` half-edge ids `3·face + k`: **left** is the triangle
    /// that traverses the edge `lo → hi`, **right** the one that traverses `hi → lo`;
    /// [`NONE`] where there is no such triangle (a boundary edge).
    pub edge_to_face: Vec<[u32; 2]>,
    /// `first_edge[v]..first_edge[v + 1]` are the edges whose `lo` vertex is `v`
    /// (length `V + 1`).
    pub first_edge: Vec<u32>,
    /// Number of edges used by more than one triangle in the same direction or by more
    /// than two triangles (0 for an oriented 2-manifold).
    pub non_manifold: usize,
}

impl EdgeTable {
    /// Builds the table of the triangles whose `alive` flag is set (all triangles when
    /// `alive` is `None`). Indices must be below `num_vertices` (checked by callers).
    /// Runs in O(V + F): a counting sort of the half-edges by their lower vertex.
    pub fn new(triangles: &[[u32; 3]], alive: Option<&[bool]>, num_vertices: usize) -> Self {
        let live = |f: usize| alive.is_none_or(|a| a[f]);
        let mut first = vec![0u32; num_vertices + 1];
        for (f, t) in triangles.iter().enumerate() {
            if live(f) {
                for k in 0..3 {
                    first[t[k].min(t[(k + 1) % 3]) as usize + 1] += 1;
                }
            }
        }
        for v in 0..num_vertices {
            first[v + 1] += first[v];
        }
        let total = first[num_vertices] as usize;
        // Key: hi vertex in the upper half, half-edge id in the lower half.
        let mut keys = vec![0u64; total];
        let mut cursor: Vec<u32> = first[..num_vertices].to_vec();
        for (f, t) in triangles.iter().enumerate() {
            if live(f) {
                for k in 0..3 {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    let (lo, hi) = if a < b { (a, b) } else { (b, a) };
                    let slot = &mut cursor[lo as usize];
                    keys[*slot as usize] = (u64::from(hi) << 32) | (3 * f + k) as u64;
                    *slot += 1;
                }
            }
        }
        let mut edges = Vec::with_capacity(total / 2 + 1);
        let mut edge_to_face: Vec<[u32; 2]> = Vec::with_capacity(total / 2 + 1);
        let mut face_to_edge = vec![[NONE; 3]; triangles.len()];
        let mut first_edge = vec![0u32; num_vertices + 1];
        let mut non_manifold = 0;
        for lo in 0..num_vertices {
            first_edge[lo] = edges.len() as u32;
            let bucket = &mut keys[first[lo] as usize..first[lo + 1] as usize];
            insertion_sort(bucket);
            let mut previous_hi = NONE;
            let mut bad = false;
            for &key in bucket.iter() {
                let hi = (key >> 32) as u32;
                let half = key as u32;
                if hi != previous_hi {
                    edges.push([lo as u32, hi]);
                    edge_to_face.push([NONE; 2]);
                    previous_hi = hi;
                    bad = false;
                }
                let e = edges.len() - 1;
                let (f, k) = (half as usize / 3, half as usize % 3);
                face_to_edge[f][k] = e as u32;
                let side = usize::from(triangles[f][k] != lo as u32);
                if edge_to_face[e][side] == NONE {
                    edge_to_face[e][side] = half;
                } else if !bad {
                    bad = true;
                    non_manifold += 1;
                }
            }
        }
        first_edge[num_vertices] = edges.len() as u32;
        EdgeTable { edges, face_to_edge, edge_to_face, first_edge, non_manifold }
    }

    /// The index of edge `{a, b}`, if it exists.
    pub fn find(&self, a: u32, b: u32) -> Option<usize> {
        let (lo, hi) = if a < b { (a, b) } else { (b, a) };
        let range = self.first_edge[lo as usize] as usize..self.first_edge[lo as usize + 1] as usize;
        self.edges[range.clone()].iter().position(|e| e[1] == hi).map(|i| range.start + i)
    }

    /// Whether edge `e` has a triangle on only one side.
    pub fn is_boundary(&self, e: usize) -> bool {
        self.edge_to_face[e][0] == NONE || self.edge_to_face[e][1] == NONE
    }

    /// Number of edges with a triangle on only one side.
    pub fn boundary_count(&self) -> usize {
        (0..self.edges.len()).filter(|&e| self.is_boundary(e)).count()
    }

    /// Number of unique edges at each vertex (length `num_vertices`).
    pub fn degrees(&self, num_vertices: usize) -> Vec<u32> {
        let mut degree = vec![0u32; num_vertices];
        for e in &self.edges {
            degree[e[0] as usize] += 1;
            degree[e[1] as usize] += 1;
        }
        degree
    }

    /// Flags the vertices that lie on a boundary edge (length `num_vertices`).
    pub fn boundary_vertices(&self, num_vertices: usize) -> Vec<bool> {
        let mut on_boundary = vec![false; num_vertices];
        for (e, [a, b]) in self.edges.iter().enumerate() {
            if self.is_boundary(e) {
                on_boundary[*a as usize] = true;
                on_boundary[*b as usize] = true;
            }
        }
        on_boundary
    }

    /// Euclidean length of every edge.
    pub fn lengths(&self, positions: &[[f32; 3]]) -> Vec<f32> {
        self.edges.iter().map(|&[a, b]| distance(positions[a as usize], positions[b as usize])).collect()
    }
}

/// Sorts a short bucket in place (buckets hold about six half-edges).
fn insertion_sort(keys: &mut [u64]) {
    for i in 1..keys.len() {
        let key = keys[i];
        let mut j = i;
        while j > 0 && keys[j - 1] > key {
            keys[j] = keys[j - 1];
            j -= 1;
        }
        keys[j] = key;
    }
}

/// Euclidean distance between two points.
pub(crate) fn distance(a: [f32; 3], b: [f32; 3]) -> f32 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
}
