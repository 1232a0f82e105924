//! `interpolate`: per-vertex attributes → per-pixel values, and its backward pass.

use w3d_core::{Error, Result};

use crate::raster::{NO_TRIANGLE, Raster};

/// Gradients returned by [`interpolate_backward`].
#[derive(Debug, Clone, PartialEq)]
pub struct InterpolateGrad {
    /// Gradient per attribute value, `[vertex][channel]` (same layout as the attributes).
    pub attributes: Vec<f32>,
    /// Gradient per pixel of the barycentrics `(u, v)`; feed it to
    /// [`crate::rasterize_backward`] to reach the vertex positions.
    pub uv: Vec<[f32; 2]>,
}

fn check(attributes: &[f32], channels: usize, triangles: &[[u32; 3]], raster: &Raster) -> Result<()> {
    if channels == 0 {
        return Err(Error::invalid("channels", "at least one channel"));
    }
    if attributes.len() != raster.vertex_count * channels {
        return Err(Error::invalid(
            "attributes",
            format!(
                "{} values ({} vertices × {channels} channels), got {}",
                raster.vertex_count * channels,
                raster.vertex_count,
                attributes.len()
            ),
        ));
    }
    // Branch-free scans first; locate the culprit only on failure.
    if crate::raster::count_non_finite(attributes) > 0
        && let Some(i) = attributes.iter().position(|v| !v.is_finite())
    {
        return Err(Error::invalid(format!("attributes[{i}]"), "a finite number"));
    }
    raster.check(raster.vertex_count, triangles)?;
    let n = u32::try_from(raster.vertex_count).unwrap_or(u32::MAX);
    let bad = triangles.iter().fold(0u32, |b, t| b + ((t[0] >= n) | (t[1] >= n) | (t[2] >= n)) as u32);
    if bad > 0
        && let Some((i, t)) =
            triangles.iter().enumerate().find(|(_, t)| t.iter().any(|&v| v as usize >= raster.vertex_count))
    {
        return Err(Error::invalid(
            format!("triangles[{i}]"),
            format!("vertex indices below {}, got {t:?}", raster.vertex_count),
        ));
    }
    Ok(())
}

/// Interpolates per-vertex attributes (`[vertex][channel]`, `channels` values per vertex)
/// over the raster: `out = u·a₀ + v·a₁ + (1 − u − v)·a₂` with the raster's
/// perspective-correct barycentrics; 0 on empty pixels. Returns a `[H][W][C]` image.
pub fn interpolate(attributes: &[f32], channels: usize, triangles: &[[u32; 3]], raster: &Raster) -> Result<Vec<f32>> {
    check(attributes, channels, triangles, raster)?;
    let mut out = vec![0.0f32; raster.pixel_count() * channels];
    for ((o, &t), uv) in out.chunks_exact_mut(channels).zip(&raster.triangle).zip(&raster.uv) {
        if t == NO_TRIANGLE {
            continue;
        }
        let tri = triangles[t as usize].map(|v| v as usize * channels);
        let b = [uv[0], uv[1], 1.0 - uv[0] - uv[1]];
        for (c, oc) in o.iter_mut().enumerate() {
            *oc = b[0] * attributes[tri[0] + c] + b[1] * attributes[tri[1] + c] + b[2] * attributes[tri[2] + c];
        }
    }
    Ok(out)
}

/// Backward pass of [`interpolate`]: given `grad_out` (`[H][W][C]`, the loss gradient of
/// the interpolated image), returns the gradient of the attributes (accumulated in f64)
/// and of the per-pixel barycentrics.
pub fn interpolate_backward(
    attributes: &[f32],
    channels: usize,
    triangles: &[[u32; 3]],
    raster: &Raster,
    grad_out: &[f32],
) -> Result<InterpolateGrad> {
    check(attributes, channels, triangles, raster)?;
    if grad_out.len() != raster.pixel_count() * channels {
        return Err(Error::invalid(
            "grad_out",
            format!("{} values, got {}", raster.pixel_count() * channels, grad_out.len()),
        ));
    }
    let mut acc = vec![0.0f64; attributes.len()];
    let mut uv_grad = vec![[0.0f32; 2]; raster.pixel_count()];
    for (i, (g, &t)) in grad_out.chunks_exact(channels).zip(&raster.triangle).enumerate() {
        if t == NO_TRIANGLE {
            continue;
        }
        let tri = triangles[t as usize].map(|v| v as usize * channels);
        let [u, v] = raster.uv[i].map(|x| x as f64);
        let b = [u, v, 1.0 - u - v];
        let (mut gu, mut gv) = (0.0f64, 0.0f64);
        for (c, &gc) in g.iter().enumerate() {
            let gc = gc as f64;
            let a = tri.map(|k| attributes[k + c] as f64);
            for k in 0..3 {
                acc[tri[k] + c] += b[k] * gc;
            }
            gu += gc * (a[0] - a[2]);
            gv += gc * (a[1] - a[2]);
        }
        uv_grad[i] = [gu as f32, gv as f32];
    }
    Ok(InterpolateGrad { attributes: acc.into_iter().map(|x| x as f32).collect(), uv: uv_grad })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::project::{Projector, to_dvec};
    use crate::raster::{pixel_barycentrics, rasterize, rasterize_backward};
    use crate::tests_util::{Lcg, relative_error};
    use glam::{DVec3, Vec3};
    use w3d_core::{Camera, Projection};

    /// Interpolated loss `Σ g·interp(attr)` with fixed coverage, in f64, at `positions`.
    fn loss(raster: &Raster, positions: &[DVec3], tris: &[[u32; 3]], attr: &[f64], c: usize, g: &[f32]) -> f64 {
        let projector = Projector::new(&raster.camera, raster.width, raster.height);
        let clip: Vec<_> = positions.iter().map(|&p| projector.project(p)).collect();
        let mut total = 0.0;
        for (i, &t) in raster.triangle.iter().enumerate() {
            if t == NO_TRIANGLE {
                continue;
            }
            let (col, row) = ((i % raster.width as usize) as u32, (i / raster.width as usize) as u32);
            let tri = tris[t as usize];
            let (_, a, s) = pixel_barycentrics(&projector, tri.map(|k| clip[k as usize]), col, row);
            let b = [a[0] / s, a[1] / s, a[2] / s];
            for ch in 0..c {
                let value: f64 = (0..3).map(|k| b[k] * attr[tri[k] as usize * c + ch]).sum();
                total += g[i * c + ch] as f64 * value;
            }
        }
        total
    }

    /// Interpolation gradients w.r.t. attributes and positions (through u, v) against
    /// central differences; returns the larger relative error.
    pub(crate) fn check_interpolate(
        positions: &[[f32; 3]],
        tris: &[[u32; 3]],
        camera: &Camera,
        size: u32,
        seed: u64,
        vertices: &[usize],
    ) -> f64 {
        let c = 3;
        let raster = rasterize(positions, tris, camera, size, size).unwrap();
        let mut rng = Lcg(seed);
        let attr: Vec<f32> = (0..positions.len() * c).map(|_| rng.next() as f32).collect();
        let g: Vec<f32> = (0..raster.pixel_count() * c).map(|_| rng.next() as f32).collect();
        let grad = interpolate_backward(&attr, c, tris, &raster, &g).unwrap();
        let pos_grad = rasterize_backward(&raster, positions, tris, &grad.uv, None).unwrap();
        let base: Vec<DVec3> = positions.iter().map(|&p| to_dvec(p)).collect();
        let attr64: Vec<f64> = attr.iter().map(|&a| a as f64).collect();
        let h = 1e-6;
        let num_pos: Vec<[f64; 3]> = vertices
            .iter()
            .map(|&v| {
                std::array::from_fn(|axis| {
                    let mut p = base.clone();
                    p[v][axis] += h;
                    let lp = loss(&raster, &p, tris, &attr64, c, &g);
                    p[v][axis] -= 2.0 * h;
                    (lp - loss(&raster, &p, tris, &attr64, c, &g)) / (2.0 * h)
                })
            })
            .collect();
        // The loss is linear in the attributes: one difference per value is exact up to rounding.
        let num_attr: Vec<[f64; 3]> = vertices
            .iter()
            .map(|&v| {
                std::array::from_fn(|ch| {
                    let mut a = attr64.clone();
                    a[v * c + ch] += 1.0;
                    let lp = loss(&raster, &base, tris, &a, c, &g);
                    a[v * c + ch] -= 2.0;
                    (lp - loss(&raster, &base, tris, &a, c, &g)) / 2.0
                })
            })
            .collect();
        let attr_grad: Vec<[f32; 3]> =
            vertices.iter().map(|&v| [0, 1, 2].map(|ch| grad.attributes[v * c + ch])).collect();
        let pos_grad: Vec<[f32; 3]> = vertices.iter().map(|&v| pos_grad[v]).collect();
        relative_error(&pos_grad, &num_pos).max(relative_error(&attr_grad, &num_attr))
    }

    #[test]
    fn interpolates_vertex_values_and_matches_gradients() {
        let positions = vec![[-0.5, -0.4, 0.1], [0.6, -0.5, -0.2], [0.1, 0.6, 0.3], [0.7, 0.5, 0.0]];
        let tris = vec![[0, 1, 2], [1, 3, 2]];
        for projection in [Projection::Orthographic { half_height: 1.0 }, Projection::Perspective { fov_y: 1.0 }] {
            let cam = Camera::look_at(Vec3::new(0.2, 0.1, 2.0), Vec3::ZERO, Vec3::Y, projection).unwrap();
            let err = check_interpolate(&positions, &tris, &cam, 24, 3, &[0, 1, 2, 3]);
            assert!(err < 1e-4, "{projection:?}: {err}");
            // Interpolating the positions themselves reproduces the depth.
            let raster = rasterize(&positions, &tris, &cam, 24, 24).unwrap();
            let flat: Vec<f32> = positions.iter().flatten().copied().collect();
            let world = interpolate(&flat, 3, &tris, &raster).unwrap();
            for (i, p) in world.chunks_exact(3).enumerate() {
                if raster.triangle[i] != NO_TRIANGLE {
                    assert!((cam.depth(Vec3::new(p[0], p[1], p[2])) - raster.depth[i]).abs() < 1e-4);
                }
            }
        }
    }

    #[test]
    fn wrong_attribute_count_is_an_error() {
        let cam =
            Camera::look_at(Vec3::Z * 2.0, Vec3::ZERO, Vec3::Y, Projection::Orthographic { half_height: 1.0 }).unwrap();
        let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let r = rasterize(&p, &[[0, 1, 2]], &cam, 8, 8).unwrap();
        assert!(interpolate(&[0.0; 5], 2, &[[0, 1, 2]], &r).is_err());
        assert!(interpolate(&[0.0; 6], 0, &[[0, 1, 2]], &r).is_err());
        assert!(interpolate_backward(&[0.0; 6], 2, &[[0, 1, 2]], &r, &[0.0; 3]).is_err());
    }
}
