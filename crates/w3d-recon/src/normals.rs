//! Area-weighted vertex normals and their backward pass.
//!
//! The forward definition is the workspace's one, [`w3d_core::normals`]; this module adds
//! the index check and the backward pass, written against that definition (same face
//! normals, same f64 sums, same degenerate-case rule [`unit_and_length`]).
//!
//! Normal losses compare rendered normals with target normal maps. The rendered normals
//! are interpolated *vertex normals*, which are functions of the vertex positions; this
//! module gives the exact gradient of those normals with respect to the positions, so a
//! normal loss can move the surface (the barycentric gradient of the rasteriser alone
//! only slides colours across pixels).

use glam::DVec3;
use w3d_core::normals::{face_normal, unit_and_length, vertex_normal_sums};
use w3d_core::{Error, Result};

/// Unit area-weighted vertex normals ([`w3d_core::normals::vertex_normals`]: for each
/// vertex the normalised sum of the unnormalised cross products `(b − a) × (c − a)` of its
/// triangles; zero where that sum is zero), after checking the indices. Positions in any
/// frame; normals are in the same frame.
pub fn vertex_normals(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Result<Vec<[f32; 3]>> {
    w3d_core::mesh::validate_geometry(positions, triangles)?;
    Ok(w3d_core::normals::vertex_normals(positions, triangles))
}

/// The per-vertex sums that [`vertex_normals`] normalises.
fn normal_sums(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<DVec3> {
    vertex_normal_sums(positions.len(), triangles.iter().map(|&t| (t, face_normal(positions, t))))
}

/// Backward of [`vertex_normals`]: given `grad_normals` = ∂L/∂(unit normal) per vertex,
/// returns ∂L/∂(position) per vertex. Vertices with a zero normal pass no gradient.
pub fn vertex_normals_backward(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    grad_normals: &[[f32; 3]],
) -> Result<Vec<[f32; 3]>> {
    w3d_core::mesh::validate_geometry(positions, triangles)?;
    if grad_normals.len() != positions.len() {
        return Err(Error::invalid(
            "grad_normals",
            format!("one gradient per vertex ({}), got {}", positions.len(), grad_normals.len()),
        ));
    }
    // ∂L/∂sum_v = (g − u (u·g)) / |sum_v| with u = sum_v / |sum_v|.
    let grad_sums: Vec<DVec3> = normal_sums(positions, triangles)
        .into_iter()
        .zip(grad_normals)
        .map(|(n, g)| {
            // The forward's degenerate case (zero normal) passes no gradient.
            let Some((u, len)) = unit_and_length(n) else { return DVec3::ZERO };
            let g = glam::Vec3::from(*g).as_dvec3();
            (g - u * u.dot(g)) / len
        })
        .collect();
    let mut grad = vec![DVec3::ZERO; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| glam::Vec3::from(positions[i as usize]).as_dvec3());
        // The face's cross product c_f = e1 × e2 (`face_normal`, in the same f64 from the
        // same corners) feeds all three corner sums.
        let g: DVec3 = t.iter().map(|&v| grad_sums[v as usize]).sum();
        let (e1, e2) = (b - a, c - a);
        // d(G·(e1 × e2)) = de1·(e2 × G) + de2·(G × e1).
        let (g1, g2) = (e2.cross(g), g.cross(e1));
        grad[t[0] as usize] -= g1 + g2;
        grad[t[1] as usize] += g1;
        grad[t[2] as usize] += g2;
    }
    Ok(grad.into_iter().map(|g| g.as_vec3().to_array()).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// A bumpy closed octahedron-like mesh from a seed-dependent perturbation.
    fn bumpy(offsets: &[f32]) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let base =
            [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]];
        let positions = base
            .iter()
            .enumerate()
            .map(|(i, p): (usize, &[f32; 3])| std::array::from_fn(|k| p[k] + offsets[3 * i + k]))
            .collect();
        let triangles = vec![[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]];
        (positions, triangles)
    }

    fn loss(positions: &[[f32; 3]], triangles: &[[u32; 3]], weights: &[[f32; 3]]) -> f64 {
        vertex_normals(positions, triangles)
            .unwrap()
            .iter()
            .zip(weights)
            .map(|(n, w)| (0..3).map(|k| n[k] as f64 * w[k] as f64).sum::<f64>())
            .sum()
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

        /// Central differences of a random linear loss of the normals.
        #[test]
        fn backward_matches_finite_differences(
            offsets in prop::collection::vec(-0.3f32..0.3, 18),
            weights in prop::collection::vec(prop::array::uniform3(-1.0f32..1.0), 6),
        ) {
            let (positions, triangles) = bumpy(&offsets);
            let grad = vertex_normals_backward(&positions, &triangles, &weights).unwrap();
            let h = 1e-3f32;
            for v in 0..positions.len() {
                for k in 0..3 {
                    let mut plus = positions.clone();
                    plus[v][k] += h;
                    let mut minus = positions.clone();
                    minus[v][k] -= h;
                    let fd = (loss(&plus, &triangles, &weights) - loss(&minus, &triangles, &weights)) / (2.0 * h as f64);
                    let an = grad[v][k] as f64;
                    prop_assert!((fd - an).abs() <= 2e-3 * (1.0 + fd.abs()), "vertex {} axis {}: fd {} vs {}", v, k, fd, an);
                }
            }
        }
    }

    #[test]
    fn octahedron_normals_point_outwards() {
        let (positions, triangles) = bumpy(&[0.0; 18]);
        for (p, n) in positions.iter().zip(vertex_normals(&positions, &triangles).unwrap()) {
            assert!((0..3).all(|k| (p[k] - n[k]).abs() < 1e-6), "{p:?} vs {n:?}");
        }
    }

    #[test]
    fn gradient_length_mismatch_is_an_error() {
        let (positions, triangles) = bumpy(&[0.0; 18]);
        let err = vertex_normals_backward(&positions, &triangles, &[[0.0; 3]; 2]).unwrap_err();
        assert!(err.to_string().contains("grad_normals"), "{err}");
    }
}
