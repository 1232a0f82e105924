//! Measuring background removal: synthetic "photos" made by compositing an RGBA object
//! over known backdrops ([`composite`]), and mask scores against the known alpha
//! ([`mask_iou`], [`boundary_f_score`]). Used by the `composites` example, the tests and
//! the benchmark.

use image::imageops::FilterType;
use w3d_core::{Error, Image, Result};

use crate::frame::alpha_bbox;

/// A backdrop behind a composited object.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Backdrop {
    /// Plain white (a product-shot sweep).
    White,
    /// Plain mid grey.
    Grey,
    /// Plain black.
    Black,
    /// A vertical gradient from near-white at the top to a darker blue-grey at the bottom.
    Gradient,
    /// White with a soft elliptical cast shadow under the object.
    ShadowOnWhite,
    /// A procedural wood grain (rings, fibres and noise): a textured surface.
    Wood,
}

impl Backdrop {
    /// Every backdrop, plain ones first.
    pub const ALL: [Backdrop; 6] =
        [Backdrop::White, Backdrop::Grey, Backdrop::Black, Backdrop::Gradient, Backdrop::ShadowOnWhite, Backdrop::Wood];

    /// A short snake_case name.
    pub fn name(self) -> &'static str {
        match self {
            Backdrop::White => "white",
            Backdrop::Grey => "grey",
            Backdrop::Black => "black",
            Backdrop::Gradient => "gradient",
            Backdrop::ShadowOnWhite => "shadow",
            Backdrop::Wood => "wood",
        }
    }
}

/// A composited test photo and the alpha it was made with.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct Composite {
    /// The photo: RGB in `[0, 1]`, quantised to 8 bits, with a little sensor noise.
    pub rgb: Image,
    /// The object's true alpha (1 channel).
    pub alpha: Image,
}

/// SplitMix64 of `x`: a fast, well-mixed hash for procedural noise.
fn hash(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// A uniform value in `[0, 1)` for integer lattice point (`x`, `y`) and `seed`.
fn lattice(x: i64, y: i64, seed: u64) -> f32 {
    (hash(seed ^ hash((x as u64).wrapping_mul(0x1_0000_0001) ^ (y as u64).rotate_left(32))) >> 40) as f32
        / (1u64 << 24) as f32
}

/// Smooth value noise in `[0, 1)`.
fn value_noise(x: f32, y: f32, seed: u64) -> f32 {
    let (x0, y0) = (x.floor(), y.floor());
    let (tx, ty) = (x - x0, y - y0);
    let (sx, sy) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
    let (ix, iy) = (x0 as i64, y0 as i64);
    let a = lattice(ix, iy, seed) * (1.0 - sx) + lattice(ix + 1, iy, seed) * sx;
    let b = lattice(ix, iy + 1, seed) * (1.0 - sx) + lattice(ix + 1, iy + 1, seed) * sx;
    a * (1.0 - sy) + b * sy
}

/// Four octaves of value noise, in about `[0, 1)`.
fn fbm(x: f32, y: f32, seed: u64) -> f32 {
    let (mut sum, mut amp, mut freq, mut norm) = (0.0, 0.5, 1.0, 0.0);
    for o in 0..4 {
        sum += amp * value_noise(x * freq, y * freq, seed.wrapping_add(o));
        norm += amp;
        amp *= 0.5;
        freq *= 2.0;
    }
    sum / norm
}

/// The backdrop colour at pixel (`x`, `y`) of a `size × size` frame.
fn backdrop_at(backdrop: Backdrop, x: f32, y: f32, size: f32, seed: u64) -> [f32; 3] {
    let v = y / size;
    match backdrop {
        Backdrop::White | Backdrop::ShadowOnWhite => [0.97, 0.97, 0.96],
        Backdrop::Grey => [0.5, 0.5, 0.52],
        Backdrop::Black => [0.04, 0.04, 0.05],
        Backdrop::Gradient => {
            let top = [0.95, 0.95, 0.97];
            let bottom = [0.42, 0.45, 0.52];
            [0, 1, 2].map(|c| top[c] * (1.0 - v) + bottom[c] * v)
        }
        Backdrop::Wood => {
            let (u, v) = (x / size * 6.0, y / size * 6.0);
            // Rings around a far-away centre, bent by noise, with fine fibres along them.
            let bend = fbm(u * 0.7, v * 0.7, seed) * 2.5;
            let r = ((u + 9.0).powi(2) + (v * 0.25 - 3.0).powi(2)).sqrt() * 3.0 + bend;
            let ring = 0.5 + 0.5 * (r * std::f32::consts::TAU).sin();
            let fibre = fbm(u * 1.5, v * 40.0, seed ^ 0xF1B5E);
            let t = 0.55 * ring.powf(3.0) + 0.45 * fibre;
            let light = [0.72, 0.52, 0.33];
            let dark = [0.42, 0.26, 0.14];
            [0, 1, 2].map(|c| light[c] * (1.0 - t) + dark[c] * t)
        }
    }
}

/// Composites the RGBA `object` (straight alpha) over `backdrop` into a `size × size` photo:
/// the object's visible box is scaled to `fill` × `size` on its longest side (premultiplied
/// Catmull-Rom / Lanczos3) and centred; [`Backdrop::ShadowOnWhite`] darkens an ellipse
/// under it. The result gets Gaussian-like sensor noise (σ ≈ 1.5/255, from `seed`) and is
/// quantised to 8 bits like a decoded file.
pub fn composite(object: &Image, backdrop: Backdrop, size: u32, fill: f32, seed: u64) -> Result<Composite> {
    if object.channels() != 4 {
        return Err(Error::invalid("object", format!("an RGBA image, got {} channels", object.channels())));
    }
    if size < 8 || !(fill > 0.0 && fill <= 1.0) {
        return Err(Error::invalid("composite", format!("size ≥ 8 and fill in (0, 1], got {size} and {fill}")));
    }
    let bbox = alpha_bbox(object).ok_or_else(|| Error::invalid("object alpha", "some visible pixel"))?;
    let mut buf = image::Rgba32FImage::new(bbox.width, bbox.height);
    for (x, y, px) in buf.enumerate_pixels_mut() {
        let p = object.pixel(bbox.x + x, bbox.y + y);
        let a = p[3].clamp(0.0, 1.0);
        px.0 = [p[0] * a, p[1] * a, p[2] * a, a];
    }
    let scale = fill * size as f32 / bbox.width.max(bbox.height) as f32;
    let nw = ((bbox.width as f32 * scale).round() as u32).clamp(1, size);
    let nh = ((bbox.height as f32 * scale).round() as u32).clamp(1, size);
    let filter = if scale <= 1.0 { FilterType::Lanczos3 } else { FilterType::CatmullRom };
    let placed = image::imageops::resize(&buf, nw, nh, filter);
    let (ox, oy) = ((size - nw) / 2, (size - nh) / 2);
    let s = size as f32;
    let n = (size * size) as usize;
    let mut rgb = vec![0.0f32; 3 * n];
    let mut alpha = vec![0.0f32; n];
    // The shadow: an elliptical Gaussian under the object's base.
    let (sx, sy) = (ox as f32 + nw as f32 / 2.0, (oy + nh) as f32 - 0.02 * nh as f32);
    let (rx, ry) = (0.42 * nw as f32, 0.07 * nh as f32 + 2.0);
    for y in 0..size {
        for x in 0..size {
            let i = (y * size + x) as usize;
            let mut bg = backdrop_at(backdrop, x as f32 + 0.5, y as f32 + 0.5, s, seed);
            if backdrop == Backdrop::ShadowOnWhite {
                let (dx, dy) = ((x as f32 + 0.5 - sx) / rx, (y as f32 + 0.5 - sy) / ry);
                let dark = 1.0 - 0.5 * (-(dx * dx + dy * dy)).exp();
                bg = bg.map(|c| c * dark);
            }
            let (mut c, mut a) = (bg, 0.0);
            if x >= ox && y >= oy && x < ox + nw && y < oy + nh {
                let p = placed.get_pixel(x - ox, y - oy).0;
                a = p[3].clamp(0.0, 1.0);
                c = [0, 1, 2].map(|k| p[k].clamp(0.0, a) + bg[k] * (1.0 - a));
            }
            // Sensor noise: the sum of two uniforms (triangular, σ ≈ 1.5/255).
            for (k, ck) in c.iter().enumerate() {
                let h = hash(seed ^ ((i as u64) << 2 | k as u64));
                let noise = ((h & 0xFFFF) as f32 + ((h >> 16) & 0xFFFF) as f32) / 65536.0 - 1.0;
                let v = (ck + noise * 3.7 / 255.0).clamp(0.0, 1.0);
                rgb[3 * i + k] = (v * 255.0).round() / 255.0;
            }
            alpha[i] = a;
        }
    }
    Ok(Composite { rgb: Image::new(size, size, 3, rgb)?, alpha: Image::new(size, size, 1, alpha)? })
}

/// The two masks as booleans (value ≥ `threshold`), after checking they are comparable.
fn binarise(pred: &Image, truth: &Image, threshold: f32) -> Result<(Vec<bool>, Vec<bool>)> {
    truth.expect_shape("truth mask", truth.width(), truth.height(), 1)?;
    pred.expect_shape("predicted mask", truth.width(), truth.height(), 1)?;
    Ok((pred.data().iter().map(|&v| v >= threshold).collect(), truth.data().iter().map(|&v| v >= threshold).collect()))
}

/// Intersection over union of two 1-channel masks binarised at `threshold` (1 when both
/// are empty).
pub fn mask_iou(pred: &Image, truth: &Image, threshold: f32) -> Result<f32> {
    let (p, t) = binarise(pred, truth, threshold)?;
    let inter = p.iter().zip(&t).filter(|&(&a, &b)| a && b).count();
    let union = p.iter().zip(&t).filter(|&(&a, &b)| a || b).count();
    Ok(if union == 0 { 1.0 } else { inter as f32 / union as f32 })
}

/// The outline of a mask: object pixels with a 4-neighbour outside it.
fn outline(m: &[bool], w: usize, h: usize) -> Vec<bool> {
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            m[i] && ((x > 0 && !m[i - 1])
                || (x + 1 < w && !m[i + 1])
                || (y > 0 && !m[i - w])
                || (y + 1 < h && !m[i + w]))
        })
        .collect()
}

/// Boundary F-score of two 1-channel masks binarised at `threshold`: precision is the
/// share of the predicted outline within `tolerance` pixels (Euclidean) of the true
/// outline, recall the converse, F their harmonic mean (1 when both outlines are empty, 0
/// when only one is).
pub fn boundary_f_score(pred: &Image, truth: &Image, threshold: f32, tolerance: u32) -> Result<f32> {
    let (p, t) = binarise(pred, truth, threshold)?;
    let (w, h) = (truth.width() as usize, truth.height() as usize);
    let (po, to) = (outline(&p, w, h), outline(&t, w, h));
    let r = tolerance as isize;
    let near = |from: &[bool], to: &[bool]| -> (usize, usize) {
        let mut hit = 0;
        let mut total = 0;
        for (i, _) in from.iter().enumerate().filter(|&(_, &on)| on) {
            total += 1;
            let (x, y) = ((i % w) as isize, (i / w) as isize);
            let found = (-r..=r).any(|dy| {
                (-r..=r).any(|dx| {
                    let (qx, qy) = (x + dx, y + dy);
                    dx * dx + dy * dy <= r * r
                        && qx >= 0
                        && qy >= 0
                        && (qx as usize) < w
                        && (qy as usize) < h
                        && to[qy as usize * w + qx as usize]
                })
            });
            hit += usize::from(found);
        }
        (hit, total)
    };
    let (ph, pt) = near(&po, &to);
    let (rh, rt) = near(&to, &po);
    Ok(match (pt, rt) {
        (0, 0) => 1.0,
        (0, _) | (_, 0) => 0.0,
        _ => {
            let (precision, recall) = (ph as f32 / pt as f32, rh as f32 / rt as f32);
            if precision + recall == 0.0 { 0.0 } else { 2.0 * precision * recall / (precision + recall) }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(size: u32, x0: u32, y0: u32, side: u32) -> Image {
        let data = (0..size * size)
            .map(|i| {
                let (x, y) = (i % size, i / size);
                if x >= x0 && y >= y0 && x < x0 + side && y < y0 + side { 1.0 } else { 0.0 }
            })
            .collect();
        Image::new(size, size, 1, data).unwrap()
    }

    #[test]
    fn scores_of_shifted_squares() {
        let a = square(40, 10, 10, 20);
        let b = square(40, 11, 10, 20); // one pixel to the right
        assert_eq!(mask_iou(&a, &a, 0.5).unwrap(), 1.0);
        let iou = mask_iou(&a, &b, 0.5).unwrap();
        assert!((iou - 380.0 / 420.0).abs() < 1e-6, "{iou}");
        assert_eq!(boundary_f_score(&a, &b, 0.5, 1).unwrap(), 1.0);
        let far = square(40, 16, 10, 20);
        assert!(boundary_f_score(&a, &far, 0.5, 2).unwrap() < 0.7);
        assert_eq!(boundary_f_score(&a, &square(40, 0, 0, 0), 0.5, 2).unwrap(), 0.0);
        assert!(mask_iou(&a, &Image::filled(41, 40, 1, 0.0).unwrap(), 0.5).is_err());
    }

    #[test]
    fn composite_keeps_the_alpha_and_the_backdrop() {
        let mut obj = Image::filled(30, 20, 4, 0.0).unwrap();
        for y in 5..15 {
            for x in 5..25 {
                obj.pixel_mut(x, y).copy_from_slice(&[0.9, 0.1, 0.1, 1.0]);
            }
        }
        for backdrop in Backdrop::ALL {
            let c = composite(&obj, backdrop, 64, 0.5, 3).unwrap();
            let a = c.alpha.data();
            let covered = a.iter().filter(|&&v| v >= 0.5).count();
            assert!((covered as i64 - 32 * 16).abs() <= 40, "{backdrop:?}: {covered}");
            let centre = c.rgb.pixel(32, 32);
            assert!(centre[0] > 0.8 && centre[1] < 0.2, "{backdrop:?}: {centre:?}");
            let corner = c.rgb.pixel(0, 0);
            assert!(corner.iter().all(|v| (0.0..=1.0).contains(v)));
        }
    }
}
