//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

use w3d_core::Mesh;

/// A `w × h` grid of unit squares in the z = 0 plane (vertex `r·(w+1) + c` at `(c, r, 0)`),
/// two counter-clockwise triangles per cell; `flip[row][col]` (row 0 = top row, as the
/// reference test helper draws it) picks the other diagonal.
pub fn grid(flip: &[Vec<bool>]) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let h = flip.len() as u32;
    let w = flip[0].len() as u32;
    let positions = (0..=h).flat_map(|r| (0..=w).map(move |c| [c as f32, r as f32, 0.0])).collect();
    let mut faces = Vec::new();
    for r in 0..h {
        for col in 0..w {
            let c = r * (w + 1) + col;
            if flip[(h - 1 - r) as usize][col as usize] {
                faces.push([c, c + 1, c + w + 1]);
                faces.push([c + 1, c + 1 + w + 1, c + w + 1]);
            } else {
                faces.push([c, c + 1, c + 1 + w + 1]);
                faces.push([c, c + 1 + w + 1, c + w + 1]);
            }
        }
    }
    (positions, faces)
}

/// Faces as a canonical multiset: each rotated to start at its smallest index, then sorted.
pub fn canonical(faces: &[[u32; 3]]) -> Vec<[u32; 3]> {
    let mut out: Vec<[u32; 3]> = faces
        .iter()
        .map(|t| {
            let k = (0..3).min_by_key(|&k| t[k]).unwrap();
            [t[k], t[(k + 1) % 3], t[(k + 2) % 3]]
        })
        .collect();
    out.sort();
    out
}

/// Signed z-components of the face normals (twice the signed area in the xy plane).
pub fn signed_areas_z(positions: &[[f32; 3]], faces: &[[u32; 3]]) -> Vec<f32> {
    faces
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| positions[i as usize]);
            (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        })
        .collect()
}

/// `../shared/data/meshes/<name>` beside the repository.
pub fn shared_mesh(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/meshes").join(name)
}

/// A shared test mesh, seams merged, normalised into the unit cube.
pub fn load_unit(name: &str) -> Mesh {
    let mesh = w3d_core::load_mesh(shared_mesh(name)).expect("load test mesh");
    let (mut mesh, _) = mesh.merge_by_position();
    mesh.normalize_unit_cube();
    mesh
}

use glam::Vec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use w3d_eval::MeshDistance;

/// Closest-point queries for the tests' distance losses, in f32: on a triangle mesh through
/// `w3d-eval`'s exact hierarchy ([`MeshDistance`]), on a point set through a `kiddo` k-d tree.
pub enum ClosestPoints {
    /// The surface of a triangle mesh.
    Surface(MeshDistance),
    /// A point set (the tree and its points).
    Points(ImmutableKdTree<f32, 3>, Vec<Vec3>),
}

impl ClosestPoints {
    /// Queries on the surface of the triangles `faces` of `positions`.
    pub fn new(positions: &[[f32; 3]], faces: &[[u32; 3]]) -> Self {
        let mesh = Mesh::new(positions.to_vec(), faces.to_vec()).expect("a valid mesh");
        ClosestPoints::Surface(MeshDistance::new(&mesh).expect("a mesh with area"))
    }

    /// Nearest-point queries on a point set.
    pub fn points(points: &[Vec3]) -> Self {
        let coords: Vec<[f32; 3]> = points.iter().map(|p| p.to_array()).collect();
        ClosestPoints::Points(ImmutableKdTree::new_from_slice(&coords), points.to_vec())
    }

    /// The closest point and the index of its triangle (or point).
    pub fn query(&self, p: Vec3) -> (Vec3, usize) {
        match self {
            ClosestPoints::Surface(surface) => {
                let (q, t) = surface.closest_point(p.as_dvec3());
                (q.as_vec3(), t)
            }
            ClosestPoints::Points(tree, points) => {
                let i = tree.nearest_one::<SquaredEuclidean>(&p.to_array()).item as usize;
                (points[i], i)
            }
        }
    }
}

/// Sample points of a mesh: its vertices and face centroids.
pub fn samples(positions: &[[f32; 3]], faces: &[[u32; 3]]) -> Vec<Vec3> {
    let mut out: Vec<Vec3> = positions.iter().map(|&p| Vec3::from(p)).collect();
    out.extend(faces.iter().map(|t| t.iter().map(|&v| Vec3::from(positions[v as usize])).sum::<Vec3>() / 3.0));
    out
}

/// Unnormalised face normal `cross(p1 − p0, p2 − p0)` (length = twice the area), as the
/// remesh operations compute it ([`w3d_core::normals::face_normal`]), rounded to `f32`
/// (zero exactly where theirs is).
pub fn face_normal(positions: &[[f32; 3]], t: [u32; 3]) -> Vec3 {
    w3d_core::normals::face_normal(positions, t).as_vec3()
}

/// Flipped faces of a consistently oriented mesh: a face is flipped when its unit normal
/// points against the sum of the unit normals of its edge neighbours.
pub fn flipped_faces(positions: &[[f32; 3]], faces: &[[u32; 3]]) -> Vec<bool> {
    let normals: Vec<Vec3> = faces.iter().map(|&t| face_normal(positions, t).normalize_or_zero()).collect();
    let mut by_edge = std::collections::HashMap::with_capacity(3 * faces.len());
    for (f, t) in faces.iter().enumerate() {
        for k in 0..3 {
            by_edge.insert((t[k], t[(k + 1) % 3]), f);
        }
    }
    faces
        .iter()
        .enumerate()
        .map(|(f, t)| {
            let around: Vec3 = (0..3).filter_map(|k| by_edge.get(&(t[(k + 1) % 3], t[k])).map(|&g| normals[g])).sum();
            normals[f].dot(around) < 0.0
        })
        .collect()
}
