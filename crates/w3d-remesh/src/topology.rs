//! Manifold checks: what continuous remeshing needs from its input, and what it keeps.

use w3d_core::{Error, Result};

use crate::edges::{EdgeTable, NONE};

/// Counts describing an oriented 2-manifold triangle mesh (with or without boundary).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub struct ManifoldSummary {
    /// Vertices used by at least one triangle.
    pub vertices: usize,
    /// Vertex rows no triangle uses.
    pub unreferenced: usize,
    /// Unique undirected edges.
    pub edges: usize,
    /// Triangles.
    pub faces: usize,
    /// Edges with one triangle.
    pub boundary_edges: usize,
    /// Connected components.
    pub components: usize,
    /// Euler characteristic V − E + F (referenced vertices only).
    pub euler: i64,
}

impl ManifoldSummary {
    /// No boundary edges.
    pub fn is_closed(&self) -> bool {
        self.boundary_edges == 0
    }

    /// Genus `(2·components − euler) / 2` of a closed mesh.
    pub fn genus(&self) -> Option<i64> {
        let twice = 2 * self.components as i64 - self.euler;
        (self.is_closed() && twice >= 0 && twice % 2 == 0).then_some(twice / 2)
    }
}

/// Checks that `triangles` over `num_vertices` vertex rows form a consistently oriented
/// 2-manifold: indices in range and distinct within a triangle, every edge used by at most
/// two triangles in opposite directions, and the triangles around every vertex forming a
/// single fan (closed, or open at a boundary). Errors name the first offending triangle,
/// edge or vertex.
pub fn check_manifold(num_vertices: usize, triangles: &[[u32; 3]]) -> Result<ManifoldSummary> {
    if triangles.is_empty() {
        return Err(Error::invalid("triangles", "at least one triangle, got none"));
    }
    for (i, t) in triangles.iter().enumerate() {
        if let Some(&bad) = t.iter().find(|&&v| v as usize >= num_vertices) {
            return Err(Error::invalid(
                format!("triangles[{i}]"),
                format!("vertex indices below {num_vertices}, got {bad} in {t:?}"),
            ));
        }
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            return Err(Error::invalid(format!("triangles[{i}]"), format!("three distinct vertex indices, got {t:?}")));
        }
    }
    let table = EdgeTable::new(triangles, None, num_vertices);
    if table.non_manifold > 0 {
        // With two directions per edge, a third use always repeats a direction.
        let mut directed: Vec<[u32; 2]> =
            triangles.iter().flat_map(|t| [[t[0], t[1]], [t[1], t[2]], [t[2], t[0]]]).collect();
        directed.sort_unstable();
        let e = directed.windows(2).find(|w| w[0] == w[1]).map(|w| w[0]).unwrap_or_default();
        return Err(Error::invalid(
            format!("triangles: edge {e:?}"),
            format!(
                "every edge used by at most two triangles, in opposite directions \
                 (a consistently oriented manifold); {} edges are not",
                table.non_manifold
            ),
        ));
    }
    // Faces per vertex, and one (face, corner) to start each fan walk from.
    let mut fan = vec![0usize; num_vertices];
    let mut first = vec![(NONE, 0u8); num_vertices];
    for (f, t) in triangles.iter().enumerate() {
        for (k, &v) in t.iter().enumerate() {
            fan[v as usize] += 1;
            if first[v as usize].0 == NONE {
                first[v as usize] = (f as u32, k as u8);
            }
        }
    }
    let corner_of = |f: usize, v: u32| triangles[f].iter().position(|&c| c == v).unwrap_or(0);
    let twin = |half: u32| {
        let e = table.face_to_edge[half as usize / 3][half as usize % 3] as usize;
        let [l, r] = table.edge_to_face[e];
        if l == half { r } else { l }
    };
    for v in 0..num_vertices as u32 {
        let (f0, k0) = first[v as usize];
        if f0 == NONE {
            continue;
        }
        let (f0, k0) = (f0 as usize, k0 as usize);
        // Walk across the outgoing edge of each face until back at the start or at a boundary.
        let mut seen = 1;
        let (mut f, mut k) = (f0, k0);
        let mut open = false;
        loop {
            let next = twin((3 * f + k) as u32);
            if next == NONE {
                open = true;
                break;
            }
            let g = next as usize / 3;
            if g == f0 || seen > fan[v as usize] {
                break;
            }
            seen += 1;
            (f, k) = (g, corner_of(g, v));
        }
        if open {
            // Walk the other way across incoming edges.
            let (mut f, mut k) = (f0, k0);
            loop {
                let next = twin((3 * f + (k + 2) % 3) as u32);
                if next == NONE || seen > fan[v as usize] {
                    break;
                }
                let g = next as usize / 3;
                seen += 1;
                (f, k) = (g, corner_of(g, v));
            }
        }
        if seen != fan[v as usize] {
            return Err(Error::invalid(
                format!("triangles around vertex {v}"),
                format!(
                    "one fan of triangles (a manifold vertex), got {} triangles of which one fan holds {seen}",
                    fan[v as usize]
                ),
            ));
        }
    }
    // Components by union-find over edges.
    let mut parent: Vec<u32> = (0..num_vertices as u32).collect();
    fn find(parent: &mut [u32], mut v: u32) -> u32 {
        while parent[v as usize] != v {
            parent[v as usize] = parent[parent[v as usize] as usize];
            v = parent[v as usize];
        }
        v
    }
    for &[a, b] in &table.edges {
        let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
        if ra != rb {
            parent[ra.max(rb) as usize] = ra.min(rb);
        }
    }
    let vertices = fan.iter().filter(|&&n| n > 0).count();
    let components = (0..num_vertices as u32).filter(|&v| fan[v as usize] > 0 && find(&mut parent, v) == v).count();
    Ok(ManifoldSummary {
        vertices,
        unreferenced: num_vertices - vertices,
        edges: table.edges.len(),
        faces: triangles.len(),
        boundary_edges: table.boundary_count(),
        components,
        euler: vertices as i64 - table.edges.len() as i64 + triangles.len() as i64,
    })
}
