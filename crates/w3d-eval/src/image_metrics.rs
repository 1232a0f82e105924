//! Image metrics: PSNR and SSIM on images composited over white, as SyncDreamer's
//! `eval_nvs.py` prepares them, with SSIM matching scikit-image's
//! `structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
//! data_range=1)` averaged over channels.

use w3d_core::{Error, Image, Mesh, Result, ViewRig};

/// Composites an image over a white background: RGBA → RGB `c·a + (1 − a)`, grey+alpha
/// → grey the same way; grey and RGB images are returned unchanged. Values are taken as
/// they are (no colour-space conversion). Errors on more than 4 channels.
pub fn composite_over_white(image: &Image) -> Result<Image> {
    let c = image.channels() as usize;
    let data: Vec<f32> = match c {
        1 | 3 => return Ok(image.clone()),
        2 | 4 => image
            .data()
            .chunks_exact(c)
            .flat_map(|px| {
                let a = px[c - 1];
                px[..c - 1].iter().map(move |&v| v * a + (1.0 - a))
            })
            .collect(),
        _ => return Err(Error::invalid("image channels", format!("1 to 4 channels, got {c}"))),
    };
    Image::new(image.width(), image.height(), c as u32 - 1, data)
}

/// Both images composited over white, checked to have the same size and channel count.
fn prepare(a: &Image, b: &Image) -> Result<(Image, Image)> {
    let (a, b) = (composite_over_white(a)?, composite_over_white(b)?);
    b.expect_shape("image b", a.width(), a.height(), a.channels())?;
    Ok((a, b))
}

/// Peak signal-to-noise ratio `10 · log10(1 / MSE)` in dB, for values in `[0, 1]`
/// (data range 1), after compositing both images over white; the MSE is over every
/// pixel and channel. Identical images give `+∞`. Errors when the images differ in size
/// or (after compositing) in channel count.
pub fn psnr(a: &Image, b: &Image) -> Result<f64> {
    let (a, b) = prepare(a, b)?;
    let n = a.data().len() as f64;
    let mse = a.data().iter().zip(b.data()).map(|(&x, &y)| (f64::from(x) - f64::from(y)).powi(2)).sum::<f64>() / n;
    Ok(10.0 * (1.0 / mse).log10())
}

/// Gaussian window radius (`truncate = 3.5`, σ = 1.5 → an 11-tap window).
const RADIUS: usize = 5;
const SIGMA: f64 = 1.5;

/// Normalised 1-D Gaussian taps, `exp(−x² / 2σ²)` for `x = −5 … 5`.
fn gaussian_taps() -> [f64; 2 * RADIUS + 1] {
    let mut taps = [0.0; 2 * RADIUS + 1];
    for (i, t) in taps.iter_mut().enumerate() {
        let x = i as f64 - RADIUS as f64;
        *t = (-0.5 * x * x / (SIGMA * SIGMA)).exp();
    }
    let sum: f64 = taps.iter().sum();
    taps.map(|t| t / sum)
}

/// Index `i` (possibly outside `0..n`) mirrored about the edges, repeating the edge
/// sample (`… b a | a b c … | c b …`, scipy's "reflect"); valid for `|overhang| ≤ n`.
fn reflect(i: isize, n: usize) -> usize {
    let n = n as isize;
    let j = if i < 0 {
        -i - 1
    } else if i >= n {
        2 * n - 1 - i
    } else {
        i
    };
    j as usize
}

/// Separable Gaussian blur of a `w × h` plane (row-major), reflect boundary.
fn blur(plane: &[f64], w: usize, h: usize, taps: &[f64]) -> Vec<f64> {
    let r = RADIUS as isize;
    let mut rows = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            rows[y * w + x] =
                taps.iter().enumerate().map(|(t, &k)| k * plane[y * w + reflect(x as isize + t as isize - r, w)]).sum();
        }
    }
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            out[y * w + x] =
                taps.iter().enumerate().map(|(t, &k)| k * rows[reflect(y as isize + t as isize - r, h) * w + x]).sum();
        }
    }
    out
}

/// Mean SSIM of one channel plane, averaged over the pixels at least `RADIUS` from the
/// border (as scikit-image crops).
fn ssim_plane(x: &[f64], y: &[f64], w: usize, h: usize) -> f64 {
    const C1: f64 = 0.01 * 0.01;
    const C2: f64 = 0.03 * 0.03;
    let taps = gaussian_taps();
    let product = |p: &[f64], q: &[f64]| p.iter().zip(q).map(|(a, b)| a * b).collect::<Vec<f64>>();
    let (ux, uy) = (blur(x, w, h, &taps), blur(y, w, h, &taps));
    let uxx = blur(&product(x, x), w, h, &taps);
    let uyy = blur(&product(y, y), w, h, &taps);
    let uxy = blur(&product(x, y), w, h, &taps);
    let mut total = 0.0;
    for row in RADIUS..h - RADIUS {
        for col in RADIUS..w - RADIUS {
            let i = row * w + col;
            let (vx, vy, vxy) = (uxx[i] - ux[i] * ux[i], uyy[i] - uy[i] * uy[i], uxy[i] - ux[i] * uy[i]);
            let num = (2.0 * ux[i] * uy[i] + C1) * (2.0 * vxy + C2);
            let den = (ux[i] * ux[i] + uy[i] * uy[i] + C1) * (vx + vy + C2);
            total += num / den;
        }
    }
    total / ((h - 2 * RADIUS) * (w - 2 * RADIUS)) as f64
}

/// Structural similarity in `[−1, 1]` after compositing both images over white:
/// Gaussian-weighted local statistics (11 × 11 window, σ = 1.5, reflect boundary,
/// population covariance), `K1 = 0.01`, `K2 = 0.03`, data range 1, the SSIM map averaged
/// over pixels at least 5 from the border and then over channels — scikit-image's
/// `structural_similarity(..., gaussian_weights=True, sigma=1.5,
/// use_sample_covariance=False, data_range=1, channel_axis=-1)`.
///
/// Errors when the images differ in size or channel count (after compositing), or are
/// smaller than 11 pixels along a side.
pub fn ssim(a: &Image, b: &Image) -> Result<f64> {
    let (a, b) = prepare(a, b)?;
    let (w, h, c) = (a.width() as usize, a.height() as usize, a.channels() as usize);
    if w < 2 * RADIUS + 1 || h < 2 * RADIUS + 1 {
        return Err(Error::invalid("image size", format!("at least 11×11 pixels for SSIM, got {w}×{h}")));
    }
    let plane =
        |img: &Image, ch: usize| img.data().iter().skip(ch).step_by(c).map(|&v| f64::from(v)).collect::<Vec<f64>>();
    let total: f64 = (0..c).map(|ch| ssim_plane(&plane(&a, ch), &plane(&b, ch), w, h)).sum();
    Ok(total / c as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pattern(w: u32, h: u32, c: u32, f: impl Fn(u32, u32, u32) -> f32) -> Image {
        let data = (0..h)
            .flat_map(|y| (0..w).flat_map(move |x| (0..c).map(move |ch| (x, y, ch))))
            .map(|(x, y, ch)| f(x, y, ch));
        Image::new(w, h, c, data.collect()).unwrap()
    }

    #[test]
    fn compositing_over_white() {
        let rgba = Image::new(1, 1, 4, vec![0.2, 0.4, 1.0, 0.5]).unwrap();
        let rgb = composite_over_white(&rgba).unwrap();
        assert_eq!(rgb.channels(), 3);
        assert!(rgb.data().iter().zip([0.6, 0.7, 1.0]).all(|(v, e)| (v - e).abs() < 1e-6), "{:?}", rgb.data());
        let transparent = Image::new(1, 1, 2, vec![0.0, 0.0]).unwrap();
        assert_eq!(composite_over_white(&transparent).unwrap().data(), &[1.0]);
    }

    #[test]
    fn psnr_of_a_constant_offset() {
        let a = pattern(16, 12, 3, |x, y, c| (x + y + c) as f32 / 40.0);
        let b = pattern(16, 12, 3, |x, y, c| (x + y + c) as f32 / 40.0 + 0.1);
        assert!((psnr(&a, &b).unwrap() - 20.0).abs() < 1e-4);
        assert_eq!(psnr(&a, &a).unwrap(), f64::INFINITY);
    }

    #[test]
    fn ssim_is_one_for_equal_images_and_drops_with_noise() {
        let a = pattern(24, 20, 3, |x, y, c| ((x * 7 + y * 3 + c) % 11) as f32 / 10.0);
        let b =
            pattern(24, 20, 3, |x, y, c| ((x * 7 + y * 3 + c) % 11) as f32 / 10.0 * 0.8 + ((x * y) % 5) as f32 * 0.02);
        assert!((ssim(&a, &a).unwrap() - 1.0).abs() < 1e-12);
        let s = ssim(&a, &b).unwrap();
        assert!(s < 0.99 && s > 0.0, "ssim {s}");
        assert!((s - ssim(&b, &a).unwrap()).abs() < 1e-12, "ssim is symmetric");
    }

    #[test]
    fn mismatched_or_tiny_images_are_errors() {
        let a = Image::filled(16, 16, 3, 0.5).unwrap();
        let b = Image::filled(16, 15, 3, 0.5).unwrap();
        let e = psnr(&a, &b).unwrap_err().to_string();
        assert!(e.contains("image b") && e.contains("16×16"), "{e}");
        assert!(ssim(&a, &Image::filled(16, 16, 1, 0.5).unwrap()).is_err());
        let tiny = Image::filled(10, 16, 3, 0.5).unwrap();
        assert!(ssim(&tiny, &tiny).unwrap_err().to_string().contains("11×11"));
        assert!(composite_over_white(&Image::filled(2, 2, 5, 0.0).unwrap()).is_err());
    }
}

/// Mean PSNR and SSIM over the views of [`novel_view_fidelity`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct NovelViewFidelity {
    /// Mean PSNR in dB.
    pub psnr: f64,
    /// Mean SSIM.
    pub ssim: f64,
}

/// The novel-view protocol of `eval_nvs.py`: `truth` and `ours` (meshes with colours or a
/// texture, in the canonical frame) rendered through the 16 SyncDreamer views at
/// `size × size`, each colour image with its mask as alpha and composited over white; the
/// mean [`psnr`] and [`ssim`] over the views.
pub fn novel_view_fidelity(truth: &Mesh, ours: &Mesh, size: u32) -> Result<NovelViewFidelity> {
    let rig = ViewRig::syncdreamer16();
    let render = |mesh: &Mesh| -> Result<Vec<Image>> {
        w3d_raster::render_oracle_views(mesh, &rig, size)?
            .views()
            .iter()
            .map(|v| {
                let colour = v.colour.as_ref().ok_or_else(|| Error::invalid("views", "colour renders"))?;
                composite_over_white(&colour.with_alpha(&v.mask)?)
            })
            .collect()
    };
    let (a, b) = (render(truth)?, render(ours)?);
    let (mut p, mut q) = (0.0, 0.0);
    for (x, y) in a.iter().zip(&b) {
        p += psnr(x, y)?;
        q += ssim(x, y)?;
    }
    Ok(NovelViewFidelity { psnr: p / a.len() as f64, ssim: q / a.len() as f64 })
}
