//! `texture`: bilinear texture sampling with repeat / clamp addressing, and its backward
//! pass to texels and texture coordinates.
//!
//! Texture coordinates follow the OBJ convention of [`w3d_core::Mesh::with_uvs`]: u to
//! the right, v up, `(0, 0)` the bottom-left corner of the image (whose row 0 is the top).
//! Texel centres sit at `(i + 0.5) / W`, `1 − (j + 0.5) / H`.

use w3d_core::{Error, Image, Result};

/// How texture coordinates outside `[0, 1]` are addressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WrapMode {
    /// Tile the texture (`u − ⌊u⌋`), blending across the opposite border.
    Repeat,
    /// Clamp to the border texels (no uv gradient where clamped).
    Clamp,
}

/// Gradients returned by [`texture_backward`].
#[derive(Debug, Clone, PartialEq)]
pub struct TextureGrad {
    /// Gradient per texel value, `[H][W][C]` like the texture.
    pub texels: Vec<f32>,
    /// Gradient per sample of its texture coordinates.
    pub uv: Vec<[f32; 2]>,
}

/// The four taps of one bilinear lookup: texel indices, weights and the weights'
/// derivatives with respect to u and v.
struct Taps {
    index: [usize; 4],
    weight: [f64; 4],
    dweight_du: [f64; 4],
    dweight_dv: [f64; 4],
}

/// Maps one coordinate to `(i0, i1, fraction, d fraction / d coordinate)` along an axis of
/// `n` texels, where `scale` converts the coordinate to texels (negative for v).
fn axis(t: f64, n: usize, scale: f64, offset: f64, mode: WrapMode) -> (usize, usize, f64, f64) {
    let n_f = n as f64;
    match mode {
        WrapMode::Repeat => {
            let s = (t * scale + offset - 0.5).rem_euclid(n_f);
            let i0 = (s.floor() as usize).min(n - 1);
            (i0, (i0 + 1) % n, s - i0 as f64, scale)
        }
        WrapMode::Clamp => {
            let raw = t * scale + offset - 0.5;
            let s = raw.clamp(0.0, n_f - 1.0);
            let i0 = (s.floor() as usize).min(n - 1);
            let d = if raw > 0.0 && raw < n_f - 1.0 { scale } else { 0.0 };
            (i0, (i0 + 1).min(n - 1), s - i0 as f64, d)
        }
    }
}

fn taps(uv: [f32; 2], width: usize, height: usize, mode: WrapMode) -> Taps {
    let (i0, i1, fu, dfu) = axis(uv[0] as f64, width, width as f64, 0.0, mode);
    let (j0, j1, fv, dfv) = axis(uv[1] as f64, height, -(height as f64), height as f64, mode);
    let index = [j0 * width + i0, j0 * width + i1, j1 * width + i0, j1 * width + i1];
    let weight = [(1.0 - fu) * (1.0 - fv), fu * (1.0 - fv), (1.0 - fu) * fv, fu * fv];
    let dweight_du = [-(1.0 - fv) * dfu, (1.0 - fv) * dfu, -fv * dfu, fv * dfu];
    let dweight_dv = [-(1.0 - fu) * dfv, -fu * dfv, (1.0 - fu) * dfv, fu * dfv];
    Taps { index, weight, dweight_du, dweight_dv }
}

fn check_uv(uv: &[[f32; 2]]) -> Result<()> {
    if let Some(i) = uv.iter().position(|p| !p[0].is_finite() || !p[1].is_finite()) {
        return Err(Error::invalid(format!("uv[{i}]"), format!("finite texture coordinates, got {:?}", uv[i])));
    }
    Ok(())
}

/// Samples `tex` bilinearly at each texture coordinate; returns `[N][C]` values with the
/// texture's channel count.
pub fn texture(tex: &Image, uv: &[[f32; 2]], mode: WrapMode) -> Result<Vec<f32>> {
    check_uv(uv)?;
    let c = tex.channels() as usize;
    let (w, h) = (tex.width() as usize, tex.height() as usize);
    let data = tex.data();
    let mut out = vec![0.0f32; uv.len() * c];
    for (o, &p) in out.chunks_exact_mut(c).zip(uv) {
        let t = taps(p, w, h, mode);
        for (ch, oc) in o.iter_mut().enumerate() {
            *oc = (0..4).map(|k| t.weight[k] * data[t.index[k] * c + ch] as f64).sum::<f64>() as f32;
        }
    }
    Ok(out)
}

/// Backward pass of [`texture`]: `grad_out` is `[N][C]`; returns the texel gradient
/// (accumulated in f64) and the gradient of each texture coordinate.
pub fn texture_backward(tex: &Image, uv: &[[f32; 2]], mode: WrapMode, grad_out: &[f32]) -> Result<TextureGrad> {
    check_uv(uv)?;
    let c = tex.channels() as usize;
    if grad_out.len() != uv.len() * c {
        return Err(Error::invalid(
            "grad_out",
            format!("{} values ({} samples × {c}), got {}", uv.len() * c, uv.len(), grad_out.len()),
        ));
    }
    let (w, h) = (tex.width() as usize, tex.height() as usize);
    let data = tex.data();
    let mut texels = vec![0.0f64; data.len()];
    let mut uv_grad = Vec::with_capacity(uv.len());
    for (g, &p) in grad_out.chunks_exact(c).zip(uv) {
        let t = taps(p, w, h, mode);
        let (mut gu, mut gv) = (0.0f64, 0.0f64);
        for (ch, &gc) in g.iter().enumerate() {
            for k in 0..4 {
                let a = data[t.index[k] * c + ch] as f64;
                texels[t.index[k] * c + ch] += t.weight[k] * gc as f64;
                gu += gc as f64 * t.dweight_du[k] * a;
                gv += gc as f64 * t.dweight_dv[k] * a;
            }
        }
        uv_grad.push([gu as f32, gv as f32]);
    }
    Ok(TextureGrad { texels: texels.into_iter().map(|x| x as f32).collect(), uv: uv_grad })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tests_util::Lcg;

    fn random_texture(w: u32, h: u32, c: u32, rng: &mut Lcg) -> Image {
        Image::new(w, h, c, (0..w * h * c).map(|_| rng.next() as f32).collect()).unwrap()
    }

    #[test]
    fn texel_centres_return_texel_values() {
        let mut rng = Lcg(1);
        let tex = random_texture(5, 4, 3, &mut rng);
        for mode in [WrapMode::Repeat, WrapMode::Clamp] {
            for (i, j) in [(0u32, 0u32), (4, 3), (2, 1)] {
                let uv = [(i as f32 + 0.5) / 5.0, 1.0 - (j as f32 + 0.5) / 4.0];
                let out = texture(&tex, &[uv], mode).unwrap();
                for (a, b) in out.iter().zip(tex.pixel(i, j)) {
                    assert!((a - b).abs() < 1e-5);
                }
            }
        }
        // Repeat blends across the border; clamp holds the border texel.
        let right_edge = [1.0, 1.0 - 0.5 / 4.0];
        let rep = texture(&tex, &[right_edge], WrapMode::Repeat).unwrap();
        let cl = texture(&tex, &[right_edge], WrapMode::Clamp).unwrap();
        assert!((rep[0] - 0.5 * (tex.pixel(4, 0)[0] + tex.pixel(0, 0)[0])).abs() < 1e-5);
        assert!((cl[0] - tex.pixel(4, 0)[0]).abs() < 1e-5);
    }

    #[test]
    fn gradients_match_finite_differences() {
        let mut rng = Lcg(2);
        let tex = random_texture(6, 5, 2, &mut rng);
        let uv: Vec<[f32; 2]> = (0..40).map(|_| [(rng.next() * 1.3) as f32, (rng.next() * 1.3) as f32]).collect();
        let g: Vec<f32> = (0..uv.len() * 2).map(|_| rng.next() as f32).collect();
        for mode in [WrapMode::Repeat, WrapMode::Clamp] {
            let grad = texture_backward(&tex, &uv, mode, &g).unwrap();
            let loss = |tex: &Image, uv: &[[f32; 2]]| -> f64 {
                texture(tex, uv, mode).unwrap().iter().zip(&g).map(|(a, b)| *a as f64 * *b as f64).sum()
            };
            // Texels: the loss is linear in them.
            for k in [0usize, 7, 31, 59] {
                let mut t = tex.clone();
                t.data_mut()[k] += 1.0;
                let num = loss(&t, &uv) - loss(&tex, &uv);
                assert!((num - grad.texels[k] as f64).abs() < 1e-4 * (1.0 + num.abs()), "texel {k}");
            }
            // uv: central differences away from texel-centre kinks.
            let h = 2e-4f32;
            let (mut diff, mut norm) = (0.0, 0.0);
            for s in 0..uv.len() {
                for a in 0..2 {
                    let mut p = uv.clone();
                    let (hi, lo) = (uv[s][a] + h, uv[s][a] - h);
                    p[s][a] = hi;
                    let lp = loss(&tex, &p);
                    p[s][a] = lo;
                    let num = (lp - loss(&tex, &p)) / (hi - lo) as f64;
                    let ana = grad.uv[s][a] as f64;
                    diff += (num - ana).powi(2);
                    norm += num * num;
                }
            }
            let rel = (diff / norm).sqrt();
            assert!(rel < 1e-3, "{mode:?}: {rel}");
        }
    }

    #[test]
    fn non_finite_uv_is_an_error() {
        let tex = Image::filled(2, 2, 3, 0.5).unwrap();
        assert!(texture(&tex, &[[f32::NAN, 0.0]], WrapMode::Repeat).is_err());
        assert!(texture_backward(&tex, &[[0.0, 0.0]], WrapMode::Repeat, &[0.0; 2]).is_err());
    }
}
