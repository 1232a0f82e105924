//! Face and vertex normals of triangle meshes on plain arrays: the one definition that
//! every crate of the workspace uses (the mesh type, remeshing, reconstruction and its
//! backward pass, the render helpers and texture fusion).
//!
//! - A **face normal** is the unnormalised cross product `(p1 − p0) × (p2 − p0)` of a
//!   counter-clockwise triangle, so it points outwards and its length is twice the
//!   triangle's area ([`face_normal`]).
//! - A **vertex normal** is the sum of the face normals of the triangles around the vertex
//!   (so each face counts with its area), divided by the sum's length; a vertex whose sum
//!   is zero (no triangle, or only zero-area ones, or ones that cancel) gets the zero
//!   vector ([`vertex_normals`], [`unit_and_length`]).
//!
//! Everything is computed in `f64` from the `f32` positions and rounded to `f32` at the
//! end. Why: reconstruction differentiates these normals (`w3d-recon`'s backward pass is
//! written against exactly this definition) and fans of thin or nearly flat triangles
//! cancel badly in `f32`. Positions may be in any frame; normals are in the same frame.
//!
//! Triangle indices must be below the number of positions (what [`crate::Mesh::new`] and
//! [`crate::mesh::validate_geometry`] check); the functions here index the slices directly
//! and panic otherwise, like slice indexing.

use glam::DVec3;

use crate::weld::weld_by_position;

/// The unnormalised normal `(p1 − p0) × (p2 − p0)` of `triangle` (length = twice its area,
/// in squared position units; zero for a degenerate triangle), in `f64`.
pub fn face_normal(positions: &[[f32; 3]], triangle: [u32; 3]) -> DVec3 {
    let [a, b, c] = triangle.map(|i| glam::Vec3::from(positions[i as usize]).as_dvec3());
    (b - a).cross(c - a)
}

/// [`face_normal`] of every triangle, in triangle order.
pub fn face_normals(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<DVec3> {
    triangles.iter().map(|&t| face_normal(positions, t)).collect()
}

/// Unit face normals of every triangle ([`face_normal`] normalised with [`unit_or_zero`]):
/// zero for zero-area triangles.
pub fn unit_face_normals(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<[f32; 3]> {
    triangles.iter().map(|&t| unit_or_zero(face_normal(positions, t)).as_vec3().to_array()).collect()
}

/// Per-vertex sums of per-face vectors: each `(triangle, vector)` adds `vector` to its three
/// corners (`num_vertices` sums; corner indices must be below it). Fed with
/// `(triangle, face_normal(triangle))` this gives the area-weighted normal sums that
/// [`vertex_normals`] normalises; callers pass an iterator so they can skip deleted faces,
/// reuse face normals they already have, or index welded vertices.
pub fn vertex_normal_sums(num_vertices: usize, faces: impl IntoIterator<Item = ([u32; 3], DVec3)>) -> Vec<DVec3> {
    let mut sums = vec![DVec3::ZERO; num_vertices];
    for (t, n) in faces {
        for v in t {
            sums[v as usize] += n;
        }
    }
    sums
}

/// The unit vector along a normal sum and the sum's length, or `None` when the length is
/// zero or not finite (the vertex then has the zero normal, and the backward pass of the
/// normalisation passes no gradient through it). The one degenerate-case rule of this
/// module: [`unit_or_zero`] and the backward pass both decide through it.
pub fn unit_and_length(sum: DVec3) -> Option<(DVec3, f64)> {
    let len = sum.length();
    (len > 0.0 && len.is_finite()).then(|| (sum / len, len))
}

/// `sum / |sum|`, or zero where [`unit_and_length`] gives `None`.
pub fn unit_or_zero(sum: DVec3) -> DVec3 {
    unit_and_length(sum).map_or(DVec3::ZERO, |(u, _)| u)
}

/// Unit area-weighted vertex normals (one per position; zero for a vertex with no
/// triangle of non-zero area, see the module docs).
pub fn vertex_normals(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<[f32; 3]> {
    vertex_normal_sums(positions.len(), triangles.iter().map(|&t| (t, face_normal(positions, t))))
        .into_iter()
        .map(|n| unit_or_zero(n).as_vec3().to_array())
        .collect()
}

/// [`vertex_normals`] of the mesh with its vertices welded by position
/// ([`weld_by_position`]), one per input vertex: vertices split along UV or colour seams
/// share one normal, so the seams do not show in smooth shading.
pub fn welded_vertex_normals(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<[f32; 3]> {
    let weld = weld_by_position(positions);
    let classes = weld.iter().map(|&w| w as usize + 1).max().unwrap_or(0);
    let sums = vertex_normal_sums(
        classes,
        triangles.iter().map(|&t| (t.map(|v| weld[v as usize]), face_normal(positions, t))),
    );
    weld.iter().map(|&w| unit_or_zero(sums[w as usize]).as_vec3().to_array()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit square in the z = 0 plane split along its diagonal, with a seam: vertices 4
    /// and 5 repeat the positions of 1 and 2 for the second triangle.
    fn seamed_square() -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let p =
            vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        (p, vec![[0, 1, 2], [4, 3, 5]])
    }

    #[test]
    fn face_normal_is_twice_the_area_along_the_right_hand_normal() {
        let p = [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 3.0, 0.0]];
        assert_eq!(face_normal(&p, [0, 1, 2]), DVec3::new(0.0, 0.0, 6.0));
        assert_eq!(face_normal(&p, [0, 2, 1]), DVec3::new(0.0, 0.0, -6.0));
        assert_eq!(unit_face_normals(&p, &[[0, 1, 2], [0, 0, 1]]), vec![[0.0, 0.0, 1.0], [0.0; 3]]);
    }

    #[test]
    fn vertex_normals_weight_faces_by_area() {
        // A big face in the xy plane (area 50) and a small one in the xz plane (area 0.5)
        // share the vertices 0 and 1: their normal leans towards the big face by 100 : 1.
        let p = [[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0], [0.0, 0.0, -0.1]];
        let n = vertex_normals(&p, &[[0, 1, 2], [0, 1, 3]]);
        let expected = DVec3::new(0.0, 1.0, 100.0).normalize();
        for v in [0, 1] {
            assert!((DVec3::from(n[v].map(f64::from)) - expected).length() < 1e-6, "{:?}", n[v]);
        }
        assert_eq!(n[2], [0.0, 0.0, 1.0]);
        assert_eq!(n[3], [0.0, 1.0, 0.0]);
    }

    #[test]
    fn degenerate_and_unused_vertices_get_zero_normals() {
        let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [5.0, 5.0, 5.0]];
        assert_eq!(vertex_normals(&p, &[[0, 1, 2]]), vec![[0.0; 3]; 4]);
        assert_eq!(unit_and_length(DVec3::ZERO), None);
        assert_eq!(unit_and_length(DVec3::new(f64::INFINITY, 0.0, 0.0)), None);
        assert_eq!(unit_and_length(DVec3::new(0.0, 3.0, 4.0)), Some((DVec3::new(0.0, 0.6, 0.8), 5.0)));
    }

    #[test]
    fn welded_normals_ignore_seams() {
        let (p, t) = seamed_square();
        // Unwelded, the seam vertices see one face each; both faces are flat here, so tilt
        // the second one to tell the two apart.
        let mut tilted = p.clone();
        tilted[3][2] = 1.0;
        let plain = vertex_normals(&tilted, &t);
        let welded = welded_vertex_normals(&tilted, &t);
        assert_eq!(plain[1], [0.0, 0.0, 1.0]);
        assert_ne!(plain[1], plain[4]);
        assert_eq!(welded[1], welded[4]);
        assert_eq!(welded[2], welded[5]);
        // The welded normal is the vertex normal of the welded mesh.
        let merged = vertex_normals(&tilted[..4], &[[0, 1, 2], [1, 3, 2]]);
        assert_eq!(welded[..4], merged[..]);
    }

    #[test]
    fn sums_skip_what_the_caller_leaves_out() {
        let (p, t) = seamed_square();
        let normals = face_normals(&p, &t);
        let alive = [false, true];
        let sums = vertex_normal_sums(
            p.len(),
            t.iter().zip(&normals).zip(alive).filter(|(_, live)| *live).map(|((&t, &n), _)| (t, n)),
        );
        assert_eq!(sums[0], DVec3::ZERO);
        assert_eq!(sums[3], DVec3::new(0.0, 0.0, 1.0));
    }
}
