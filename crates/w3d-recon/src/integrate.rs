//! Normal-map integration: from one view's normal map and mask to a depth map.
//!
//! For an orthographic view, the visible surface is a height field `z(x, y)` in the camera
//! frame (+x right, +y up, +z towards the camera) with normal ∝ `(−∂z/∂x, −∂z/∂y, 1)`.
//! Between 4-neighbouring foreground pixels `p`, `q` with mean camera-frame normal `n̄`
//! this gives one linear equation, written without dividing by `n̄_z` so that grazing
//! normals (n̄_z → 0, unreliable near the silhouette) weigh nothing instead of exploding:
//!
//! * horizontal, `q` right of `p`: `n̄_z (z_q − z_p) = −n̄_x h`
//! * vertical, `q` below `p`: `n̄_z (z_q − z_p) = +n̄_y h`
//!
//! with `h` the pixel size in world units. The height is fixed by anchoring silhouette
//! pixels (foreground pixels with a background 4-neighbour) to the plane through the
//! origin facing the camera, as Wonder3D does (the silhouette of an object centred at
//! the origin lies near that plane). The weighted least-squares system is solved with
//! Jacobi-preconditioned conjugate gradients in f64.
//!
//! Limits (measured): on a sphere of radius 0.4 at 128² the shape is exact to 0.005 mean
//! absolute error, with a global offset of up to one rim pixel's height (≈ 0.07) that one
//! view cannot determine. Depth *discontinuities inside* the silhouette (a leg in front
//! of a body) are not modelled yet: the parts stay linked through grazing normals and are
//! anchored to the origin plane, so on spot's front view the mean error is ≈ 0.2. The
//! coarse optimisation has to correct such an initialisation.

use glam::Vec3;
use w3d_core::{Camera, Error, Image, Projection, Result};

/// Options of [`integrate_normals`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct IntegrateOptions {
    /// Weight of the silhouette anchor equations relative to the gradient equations.
    pub boundary_weight: f64,
    /// Pixels with mask ≥ this value are foreground.
    pub mask_threshold: f32,
    /// Maximum conjugate-gradient iterations.
    pub max_iterations: usize,
    /// Stop when the residual norm falls below this fraction of the right-hand side's.
    pub tolerance: f64,
}

impl Default for IntegrateOptions {
    fn default() -> Self {
        IntegrateOptions { boundary_weight: 0.1, mask_threshold: 0.5, max_iterations: 4000, tolerance: 1e-8 }
    }
}

/// Chainable setters, one per field: `IntegrateOptions::default().with_…(…)` (the struct is
/// `#[non_exhaustive]`, so code outside this crate cannot use struct-literal syntax).
impl IntegrateOptions {
    w3d_core::setters! {
        with_boundary_weight(boundary_weight: f64);
        with_mask_threshold(mask_threshold: f32);
        with_max_iterations(max_iterations: usize);
        with_tolerance(tolerance: f64);
    }
}

/// Integrates a view's normal map (unit normals in the canonical world frame, 3 channels)
/// inside its mask (1 channel) into a depth map: distance in front of `camera` along its
/// viewing axis in world units, 0 on the background. Orthographic cameras only.
pub fn integrate_normals(normal: &Image, mask: &Image, camera: &Camera, options: &IntegrateOptions) -> Result<Image> {
    integrate_normals_anchored(normal, mask, camera, None, options)
}

/// [`integrate_normals`] with the silhouette pixels anchored to the depths of `anchor`
/// (1 channel, same size; e.g. where each silhouette ray enters the visual hull) instead
/// of the plane through the origin. Non-finite anchor values fall back to that plane.
pub fn integrate_normals_anchored(
    normal: &Image,
    mask: &Image,
    camera: &Camera,
    anchor: Option<&Image>,
    options: &IntegrateOptions,
) -> Result<Image> {
    let (w, h) = (normal.width(), normal.height());
    if let Some(a) = anchor {
        a.expect_shape("anchor", w, h, 1)?;
    }
    let origin_depth = camera.depth(Vec3::ZERO) as f64;
    normal.expect_shape("normal", w, h, 3)?;
    mask.expect_shape("mask", w, h, 1)?;
    let Projection::Orthographic { half_height } = camera.projection else {
        return Err(Error::invalid("camera.projection", "an orthographic camera for normal integration"));
    };
    let pixel = 2.0 * half_height as f64 / h as f64;
    let (wu, hu) = (w as usize, h as usize);
    let inside = |x: usize, y: usize| mask.data()[y * wu + x] >= options.mask_threshold;
    // Unknown index of each foreground pixel.
    let mut index = vec![u32::MAX; wu * hu];
    let mut count = 0u32;
    for y in 0..hu {
        for x in 0..wu {
            if inside(x, y) {
                index[y * wu + x] = count;
                count += 1;
            }
        }
    }
    if count == 0 {
        return Err(Error::invalid("mask", "at least one foreground pixel"));
    }
    let to_camera = camera.basis().transpose();
    let cam_normal = |i: usize| -> Vec3 {
        let n = &normal.data()[3 * i..3 * i + 3];
        to_camera * Vec3::new(n[0], n[1], n[2])
    };
    // Equations a·(z_q − z_p) = b (gradient) and c·z_p = c·z0 (anchor), accumulated into
    // the normal equations M z = r with M = Σ aᵀa (a graph Laplacian) + anchors.
    let n = count as usize;
    let mut diag = vec![0.0f64; n];
    let mut rhs = vec![0.0f64; n];
    let mut links: Vec<(u32, u32, f64)> = Vec::new(); // (p, q, a²) off-diagonal entries
    for y in 0..hu {
        for x in 0..wu {
            let p = y * wu + x;
            if index[p] == u32::MAX {
                continue;
            }
            let np = cam_normal(p);
            for (dx, dy) in [(1usize, 0usize), (0, 1)] {
                let (qx, qy) = (x + dx, y + dy);
                if qx >= wu || qy >= hu || index[qy * wu + qx] == u32::MAX {
                    continue;
                }
                let q = qy * wu + qx;
                let m = (np + cam_normal(q)) * 0.5;
                let a = m.z.max(0.0) as f64;
                if a == 0.0 {
                    continue;
                }
                let b = if dx == 1 { -(m.x as f64) * pixel } else { m.y as f64 * pixel };
                let (ip, iq) = (index[p] as usize, index[q] as usize);
                diag[ip] += a * a;
                diag[iq] += a * a;
                rhs[iq] += a * b;
                rhs[ip] -= a * b;
                links.push((ip as u32, iq as u32, a * a));
            }
            let boundary = (x == 0 || !inside(x - 1, y))
                || (x + 1 == wu || !inside(x + 1, y))
                || (y == 0 || !inside(x, y - 1))
                || (y + 1 == hu || !inside(x, y + 1));
            // Anchor silhouette pixels to z = 0 (the origin plane); a tiny pull everywhere
            // keeps disconnected islands of reliable normals well posed.
            diag[index[p] as usize] += if boundary { options.boundary_weight } else { 1e-9 };
            if boundary {
                let z0 = anchor.map_or(0.0, |a| origin_depth - a.data()[p] as f64);
                if z0.is_finite() {
                    rhs[index[p] as usize] += options.boundary_weight * z0;
                }
            }
        }
    }
    let apply = |z: &[f64], out: &mut [f64]| {
        for i in 0..n {
            out[i] = diag[i] * z[i];
        }
        for &(p, q, a2) in &links {
            let (p, q) = (p as usize, q as usize);
            out[p] -= a2 * z[q];
            out[q] -= a2 * z[p];
        }
    };
    let z = conjugate_gradients(&apply, &diag, &rhs, options.max_iterations, options.tolerance);
    // Camera-frame height z relative to the origin plane → depth along the view axis.
    let mut depth = vec![0.0f32; wu * hu];
    for (p, &i) in index.iter().enumerate() {
        if i != u32::MAX {
            depth[p] = (origin_depth - z[i as usize]) as f32;
        }
    }
    Image::new(w, h, 1, depth)
}

/// Solves `M z = r` for symmetric positive-definite `M` (given by `apply`) with a Jacobi
/// preconditioner `diag`, starting from zero.
pub(crate) fn conjugate_gradients(
    apply: &dyn Fn(&[f64], &mut [f64]),
    diag: &[f64],
    rhs: &[f64],
    max_iterations: usize,
    tolerance: f64,
) -> Vec<f64> {
    let n = rhs.len();
    let mut z = vec![0.0; n];
    let mut r = rhs.to_vec();
    let mut s: Vec<f64> = r.iter().zip(diag).map(|(r, d)| r / d).collect();
    let mut p = s.clone();
    let mut mp = vec![0.0; n];
    let mut rs: f64 = r.iter().zip(&s).map(|(a, b)| a * b).sum();
    let stop = tolerance * rhs.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-300);
    for _ in 0..max_iterations {
        if r.iter().map(|v| v * v).sum::<f64>().sqrt() <= stop {
            break;
        }
        apply(&p, &mut mp);
        let alpha = rs / p.iter().zip(&mp).map(|(a, b)| a * b).sum::<f64>();
        for i in 0..n {
            z[i] += alpha * p[i];
            r[i] -= alpha * mp[i];
            s[i] = r[i] / diag[i];
        }
        let rs_new: f64 = r.iter().zip(&s).map(|(a, b)| a * b).sum();
        let beta = rs_new / rs;
        rs = rs_new;
        for i in 0..n {
            p[i] = s[i] + beta * p[i];
        }
    }
    z
}
