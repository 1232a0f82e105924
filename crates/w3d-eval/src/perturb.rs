//! Perturbed views for robustness measurements: what a reconstruction does with views that
//! are not perfect.

use glam::Vec3;
use w3d_core::{Result, ViewSet};

/// `views` with deterministic Gaussian noise of standard deviation `sigma` added to each
/// component of every normal inside the masks (mask ≥ 0.5), renormalised to unit length (a
/// normal that noise cancels becomes +z). The same `seed` gives the same noise.
///
/// ```
/// use w3d_core::{Mesh, ViewRig};
///
/// // Oracle views of an octahedron, then the same with noisy normals.
/// let p = vec![[0.0, 0.0, 0.4], [0.4, 0.0, 0.0], [0.0, 0.4, 0.0], [-0.4, 0.0, 0.0], [0.0, -0.4, 0.0], [0.0, 0.0, -0.4]];
/// let t = vec![[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1], [5, 2, 1], [5, 3, 2], [5, 4, 3], [5, 1, 4]];
/// let views = w3d_raster::render_oracle_views(&Mesh::new(p, t)?, &ViewRig::wonder3d_ortho(), 32)?;
/// let noisy = w3d_eval::with_normal_noise(views.clone(), 0.05, 7)?;
/// let again = w3d_eval::with_normal_noise(views.clone(), 0.05, 7)?;
/// assert_ne!(noisy.views()[0].normal.data(), views.views()[0].normal.data());
/// assert_eq!(noisy.views()[0].normal.data(), again.views()[0].normal.data());
/// # Ok::<(), w3d_core::Error>(())
/// ```
pub fn with_normal_noise(views: ViewSet, sigma: f32, seed: u64) -> Result<ViewSet> {
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut uniform = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let mut gauss = move || {
        let (u, v) = (uniform(), uniform());
        ((-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()) as f32
    };
    let (rig, mut images) = views.into_parts();
    for view in &mut images {
        let mask = view.mask.data().to_vec();
        for (n, m) in view.normal.data_mut().chunks_exact_mut(3).zip(mask) {
            if m < 0.5 {
                continue;
            }
            let v = Vec3::new(n[0] + sigma * gauss(), n[1] + sigma * gauss(), n[2] + sigma * gauss());
            n.copy_from_slice(&v.normalize_or(Vec3::Z).to_array());
        }
    }
    ViewSet::new(rig, images)
}
