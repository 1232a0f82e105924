//! A diagnostic alignment: point-to-point ICP with rotation, uniform scale and translation
//! (a similarity), each step solved in closed form (Horn's quaternion method for the
//! rotation, then the least-squares scale and translation, which together give Umeyama's
//! optimum). The evaluation protocol reports metrics without alignment; this tells how much
//! of an error is pose and scale rather than shape.

use glam::{DMat3, DQuat, DVec3};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use w3d_core::{Error, Mesh, Result};

use crate::sampling::sample_surface;

/// Options of [`align_icp_scale`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct IcpOptions {
    /// Surface samples per mesh (default 50 000).
    pub samples: usize,
    /// Sampling seed; the prediction uses `seed`, the ground truth `seed + 1`.
    pub seed: u64,
    /// Most ICP iterations (default 100).
    pub max_iterations: usize,
    /// Stop when the mean nearest-neighbour distance (world units) changes by less than
    /// this between iterations (default 1e-7).
    pub tolerance: f64,
}

impl Default for IcpOptions {
    fn default() -> Self {
        IcpOptions { samples: 50_000, seed: 0, max_iterations: 100, tolerance: 1e-7 }
    }
}

/// Chainable setters, one per field: `IcpOptions::default().with_…(…)` (the struct is
/// `#[non_exhaustive]`, so code outside this crate cannot use struct-literal syntax).
impl IcpOptions {
    w3d_core::setters! {
        with_samples(samples: usize);
        with_seed(seed: u64);
        with_max_iterations(max_iterations: usize);
        with_tolerance(tolerance: f64);
    }
}

/// A similarity transform `p ↦ scale · rotation · p + translation` (world units).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct Similarity {
    /// Uniform scale factor (positive).
    pub scale: f64,
    /// Proper rotation (orthonormal, determinant +1).
    pub rotation: DMat3,
    /// Translation, applied after scale and rotation.
    pub translation: DVec3,
}

impl Similarity {
    /// The identity transform.
    pub const IDENTITY: Similarity = Similarity { scale: 1.0, rotation: DMat3::IDENTITY, translation: DVec3::ZERO };

    /// The transformed point.
    pub fn apply(&self, p: DVec3) -> DVec3 {
        self.scale * (self.rotation * p) + self.translation
    }

    /// Angle of the rotation in degrees, in `[0, 180]`.
    pub fn rotation_deg(&self) -> f64 {
        let cos = 0.5 * (self.rotation.x_axis.x + self.rotation.y_axis.y + self.rotation.z_axis.z - 1.0);
        cos.clamp(-1.0, 1.0).acos().to_degrees()
    }

    /// A copy of `mesh` with every position transformed (stored normals are kept as they
    /// are; the metrics use face normals recomputed from the positions).
    pub fn apply_to_mesh(&self, mesh: &Mesh) -> Result<Mesh> {
        let mut out = mesh.clone();
        out.map_positions(|p| self.apply(p.as_dvec3()).as_vec3())?;
        Ok(out)
    }
}

/// Eigenvector of the largest eigenvalue of a symmetric 4×4 matrix, by cyclic Jacobi
/// rotations (converges quadratically; a 4×4 needs a handful of sweeps).
fn top_eigenvector(mut a: [[f64; 4]; 4]) -> [f64; 4] {
    let mut v = [[0.0; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    let scale: f64 = a.iter().flatten().map(|x| x * x).sum::<f64>().sqrt();
    for _sweep in 0..50 {
        let off: f64 = (0..4).flat_map(|p| (p + 1..4).map(move |q| (p, q))).map(|(p, q)| a[p][q] * a[p][q]).sum();
        if off.sqrt() <= 1e-15 * scale {
            break;
        }
        for p in 0..4 {
            for q in p + 1..4 {
                if a[p][q] == 0.0 {
                    continue;
                }
                // The rotation J (J_pp = J_qq = c, J_pq = s, J_qp = −s) that zeroes a_pq in Jᵀ A J.
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for row in a.iter_mut().chain(v.iter_mut()) {
                    let (kp, kq) = (row[p], row[q]);
                    row[p] = c * kp - s * kq;
                    row[q] = s * kp + c * kq;
                }
                let (head, tail) = a.split_at_mut(q);
                for (pk, qk) in head[p].iter_mut().zip(tail[0].iter_mut()) {
                    (*pk, *qk) = (c * *pk - s * *qk, s * *pk + c * *qk);
                }
            }
        }
    }
    let best = (0..4).max_by(|&i, &j| a[i][i].total_cmp(&a[j][j])).unwrap_or(0);
    [v[0][best], v[1][best], v[2][best], v[3][best]]
}

/// The similarity minimising `Σ |dst_i − (s R src_i + t)|²` (Umeyama's optimum): the
/// rotation from Horn's quaternion method, then `s = Σ y'·R x' / Σ |x'|²` on the centred
/// points and `t = ȳ − s R x̄`. Errors when `src` has no spread (a single point).
pub(crate) fn fit_similarity(src: &[DVec3], dst: &[DVec3]) -> Result<Similarity> {
    let n = src.len().min(dst.len()) as f64;
    let (cx, cy) = (src.iter().sum::<DVec3>() / n, dst.iter().sum::<DVec3>() / n);
    let mut m = [[0.0f64; 3]; 3]; // m[a][b] = Σ x'_a y'_b
    let mut spread = 0.0;
    for (x, y) in src.iter().zip(dst) {
        let (x, y) = ((*x - cx).to_array(), (*y - cy).to_array());
        for a in 0..3 {
            for b in 0..3 {
                m[a][b] += x[a] * y[b];
            }
            spread += x[a] * x[a];
        }
    }
    if !(spread > 0.0 && spread.is_finite()) {
        return Err(Error::invalid("icp source points", "points with a positive, finite spread"));
    }
    let [[sxx, sxy, sxz], [syx, syy, syz], [szx, szy, szz]] = m;
    let horn = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    let [w, x, y, z] = top_eigenvector(horn);
    let rotation = DMat3::from_quat(DQuat::from_xyzw(x, y, z, w).normalize());
    let aligned: f64 = src.iter().zip(dst).map(|(x, y)| (*y - cy).dot(rotation * (*x - cx))).sum();
    let scale = aligned / spread;
    if !(scale > 0.0 && scale.is_finite()) {
        return Err(Error::invalid("icp correspondences", format!("a positive best-fit scale, got {scale}")));
    }
    Ok(Similarity { scale, rotation, translation: cy - scale * (rotation * cx) })
}

/// Aligns `pred` onto `gt` with a similarity, by point-to-point ICP on seeded surface
/// samples: start from the transform that matches the sample centroids and RMS radii,
/// then repeat (at most `options.max_iterations` times) "match every transformed predicted
/// sample to its nearest ground-truth sample (k-d tree), refit the similarity in closed form
/// ([`Similarity`] from the original samples to their matches)" until the mean matching
/// distance changes by less than `options.tolerance`. Deterministic for given inputs.
///
/// Apply the result with [`Similarity::apply_to_mesh`] to get the aligned prediction.
/// Errors: a zero sample or iteration count, a tolerance that is negative or not finite,
/// a zero-area mesh.
pub fn align_icp_scale(pred: &Mesh, gt: &Mesh, options: &IcpOptions) -> Result<Similarity> {
    if options.max_iterations == 0 {
        return Err(Error::invalid("icp options.max_iterations", "at least 1 iteration, got 0"));
    }
    if !(options.tolerance >= 0.0 && options.tolerance.is_finite()) {
        return Err(Error::invalid(
            "icp options.tolerance",
            format!("a non-negative, finite distance, got {}", options.tolerance),
        ));
    }
    let to_d = |p: &[f32; 3]| DVec3::from(p.map(f64::from));
    let src: Vec<DVec3> = sample_surface(pred, options.samples, options.seed)?.points.iter().map(to_d).collect();
    let gt_points = sample_surface(gt, options.samples, options.seed.wrapping_add(1))?.points;
    let dst: Vec<DVec3> = gt_points.iter().map(to_d).collect();
    let tree: ImmutableKdTree<f64, 3> =
        ImmutableKdTree::new_from_slice(&dst.iter().map(|p| p.to_array()).collect::<Vec<_>>());

    let centroid = |ps: &[DVec3]| ps.iter().sum::<DVec3>() / ps.len() as f64;
    let rms = |ps: &[DVec3], c: DVec3| (ps.iter().map(|p| p.distance_squared(c)).sum::<f64>() / ps.len() as f64).sqrt();
    let (cs, cd) = (centroid(&src), centroid(&dst));
    let scale = rms(&dst, cd) / rms(&src, cs);
    let mut transform = Similarity { scale, rotation: DMat3::IDENTITY, translation: cd - scale * cs };

    let mut previous = f64::INFINITY;
    for _ in 0..options.max_iterations {
        let matches: Vec<(DVec3, f64)> = src
            .par_iter()
            .map(|p| {
                let n = tree.nearest_one::<SquaredEuclidean>(&transform.apply(*p).to_array());
                (dst[n.item as usize], n.distance.max(0.0).sqrt())
            })
            .collect();
        let mean = matches.iter().map(|m| m.1).sum::<f64>() / matches.len() as f64;
        if (previous - mean).abs() < options.tolerance {
            break;
        }
        previous = mean;
        let targets: Vec<DVec3> = matches.into_iter().map(|m| m.0).collect();
        transform = fit_similarity(&src, &targets)?;
    }
    Ok(transform)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closed_form_fit_recovers_an_exact_similarity() {
        let src: Vec<DVec3> =
            (0..50).map(|i| DVec3::new((i as f64 * 0.37).sin(), (i as f64 * 0.91).cos(), i as f64 * 0.02)).collect();
        let truth = Similarity {
            scale: 1.7,
            rotation: DMat3::from_quat(DQuat::from_axis_angle(DVec3::new(1.0, -2.0, 0.5).normalize(), 2.5)),
            translation: DVec3::new(0.3, -1.0, 2.0),
        };
        let dst: Vec<DVec3> = src.iter().map(|p| truth.apply(*p)).collect();
        let fit = fit_similarity(&src, &dst).unwrap();
        assert!((fit.scale - 1.7).abs() < 1e-12, "{}", fit.scale);
        assert!((fit.rotation - truth.rotation).abs().to_cols_array().iter().all(|&e| e < 1e-12), "{fit:?}");
        assert!(fit.translation.distance(truth.translation) < 1e-12);
        assert!((truth.rotation_deg() - 2.5f64.to_degrees()).abs() < 1e-9);
        assert!(fit_similarity(&[DVec3::ONE; 3], &dst[..3]).unwrap_err().to_string().contains("spread"));
    }
}
