//! Background removal for product-style photos: a smooth background surface fitted to the
//! image border, shadow-aware background likelihoods, GrabCut-style graph cuts with colour
//! mixtures, clean-up of the mask, a soft boundary by guided filtering, and a confidence
//! score with named reasons.

use rayon::prelude::*;
use w3d_core::{Error, Image, Result};

use crate::gmm::Gmm;
use crate::matte::guided_filter;
use crate::maxflow::Graph;

/// Options of [`remove_background`]. Build from `Default` and chain `with_*` setters.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct SegmentOptions {
    /// Longest side of the image the segmentation runs on (the photo is area-averaged down
    /// to it; the soft boundary is then computed at full resolution). Default 320.
    pub work_size: u32,
    /// Graph-cut rounds, each refitting the colour models to the last cut (GrabCut).
    /// Default 2 (a third round changes the composite scores of `docs/input.md` by < 0.002).
    pub iterations: usize,
    /// Weight of the boundary term: higher gives smoother outlines that prefer strong
    /// colour edges. Default 50 (GrabCut's γ).
    pub smoothness: f32,
    /// Whether pixels that are a darker version of the local background colour (same
    /// chromaticity: cast shadows) count as background. Default on.
    pub shadows: bool,
    /// Gaussians per colour mixture (object and background), 1 to 8. Default 5.
    pub components: usize,
    /// Object pieces smaller than this fraction of the largest piece are dropped. Default
    /// 0.05.
    pub keep_fraction: f32,
    /// Holes (background regions enclosed by the object) smaller than this fraction of the
    /// object's area are filled. Default 0.002.
    pub fill_holes: f32,
}

impl Default for SegmentOptions {
    fn default() -> Self {
        SegmentOptions {
            work_size: 320,
            iterations: 2,
            smoothness: 50.0,
            shadows: true,
            components: 5,
            keep_fraction: 0.05,
            fill_holes: 0.002,
        }
    }
}

impl SegmentOptions {
    w3d_core::setters! {
        /// The same options with another analysis size.
        with_work_size(work_size: u32);
        /// The same options with another number of graph-cut rounds.
        with_iterations(iterations: usize);
        /// The same options with another boundary weight.
        with_smoothness(smoothness: f32);
        /// The same options with shadow handling on or off.
        with_shadows(shadows: bool);
        /// The same options with another number of mixture components.
        with_components(components: usize);
        /// The same options with another smallest kept piece.
        with_keep_fraction(keep_fraction: f32);
        /// The same options with another largest filled hole.
        with_fill_holes(fill_holes: f32);
    }

    fn validate(&self) -> Result<()> {
        if self.work_size < 16 {
            return Err(Error::invalid("segment options work_size", format!("at least 16, got {}", self.work_size)));
        }
        if !(1..=8).contains(&self.components) {
            return Err(Error::invalid("segment options components", format!("1 to 8, got {}", self.components)));
        }
        if !(self.smoothness.is_finite() && self.smoothness >= 0.0) {
            return Err(Error::invalid("segment options smoothness", format!("≥ 0, got {}", self.smoothness)));
        }
        for (name, v) in [("keep_fraction", self.keep_fraction), ("fill_holes", self.fill_holes)] {
            if !(0.0..=1.0).contains(&v) {
                return Err(Error::invalid(format!("segment options {name}"), format!("in [0, 1], got {v}")));
            }
        }
        Ok(())
    }
}

/// Why automatic background removal may be wrong; each lowers the confidence.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Reason {
    /// Nothing stands out from the background.
    NoObject,
    /// The "object" covers almost the whole frame: there is little or no background.
    ObjectFillsFrame,
    /// The border of the photo is not a smooth background (clutter, texture, a scene).
    ClutteredBackground,
    /// The object runs into the edge of the photo (cut off, or the background model failed).
    TouchesBorder,
    /// Much of the object has colours the background model explains as well.
    LowContrast,
    /// The object falls apart into several similar-sized pieces.
    Fragmented,
}

impl Reason {
    /// A stable snake_case name (for JSON and logs).
    pub fn name(self) -> &'static str {
        match self {
            Reason::NoObject => "no_object",
            Reason::ObjectFillsFrame => "object_fills_frame",
            Reason::ClutteredBackground => "cluttered_background",
            Reason::TouchesBorder => "touches_border",
            Reason::LowContrast => "low_contrast",
            Reason::Fragmented => "fragmented",
        }
    }

    /// What it means, in words.
    pub fn description(self) -> &'static str {
        match self {
            Reason::NoObject => "no object stands out from the background",
            Reason::ObjectFillsFrame => "the object fills the frame, leaving no background to remove",
            Reason::ClutteredBackground => "the background is cluttered or not uniform",
            Reason::TouchesBorder => "the object touches the border of the photo",
            Reason::LowContrast => "the object is hard to tell from the background",
            Reason::Fragmented => "the object falls apart into several pieces",
        }
    }
}

/// One reason that lowered the confidence, with what was measured.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct Issue {
    /// Which reason.
    pub reason: Reason,
    /// The measurement behind it (see [`Measures`] for units).
    pub value: f32,
    /// The factor in `[0, 1]` it multiplied the confidence by.
    pub factor: f32,
}

impl std::fmt::Display for Issue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let what = match self.reason {
            Reason::NoObject | Reason::ObjectFillsFrame => {
                format!("object covers {:.1} % of the photo", self.value * 100.0)
            }
            Reason::ClutteredBackground => format!("border varies by {:.1}/255 around a smooth fit", self.value),
            Reason::TouchesBorder => format!("{:.0} % of the border is object", self.value * 100.0),
            Reason::LowContrast => format!("{:.0} % of the object looks like background", self.value * 100.0),
            Reason::Fragmented => format!("the largest piece is {:.0} % of the object", self.value * 100.0),
        };
        write!(f, "{} ({what}; ×{:.2})", self.reason.description(), self.factor)
    }
}

/// What the segmentation measured.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[non_exhaustive]
pub struct Measures {
    /// Robust spread of the border pixels around the fitted background surface, in 8-bit
    /// levels (0–255): a few for a studio backdrop, tens for clutter or texture.
    pub border_noise: f32,
    /// Fraction of the photo the object covers.
    pub object_fraction: f32,
    /// Fraction of the outermost pixel ring that is object.
    pub border_contact: f32,
    /// Fraction of the object whose colour alone would be called background (the boundary
    /// term held it in).
    pub ambiguous_fraction: f32,
    /// The largest piece's share of the object, before small pieces are dropped.
    pub main_share: f32,
    /// Background area that only the shadow model explains (darker, same chromaticity as
    /// the backdrop), as a fraction of the object's area.
    pub shadow_fraction: f32,
}

/// How much to trust an automatic segmentation: a score in `[0, 1]` (1 = no doubt) and the
/// reasons that lowered it.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct Confidence {
    /// The product of the issues' factors.
    pub score: f32,
    /// Every reason whose factor is below 1, worst first.
    pub issues: Vec<Issue>,
    /// The measurements the score came from.
    pub measures: Measures,
}

impl Confidence {
    /// Full confidence (a mask that came with the image).
    pub fn certain() -> Confidence {
        Confidence { score: 1.0, issues: Vec::new(), measures: Measures::default() }
    }

    /// The issues as one line ("none" without issues).
    pub fn summary(&self) -> String {
        if self.issues.is_empty() {
            return "none".into();
        }
        self.issues.iter().map(|i| i.to_string()).collect::<Vec<_>>().join("; ")
    }

    fn from_measures(m: Measures) -> Confidence {
        // (reason, value, factor): each factor is a linear ramp between a value that raises
        // no doubt and one that rules the result out (or down to a floor).
        let ramp = |x: f32, good: f32, bad: f32, floor: f32| {
            let t = ((x - good) / (bad - good)).clamp(0.0, 1.0);
            1.0 - t * (1.0 - floor)
        };
        let mut issues = vec![
            Issue {
                reason: Reason::NoObject,
                value: m.object_fraction,
                factor: ramp(m.object_fraction, 0.005, 0.0005, 0.0),
            },
            Issue {
                reason: Reason::ObjectFillsFrame,
                value: m.object_fraction,
                factor: ramp(m.object_fraction, 0.75, 0.95, 0.0),
            },
            Issue {
                reason: Reason::ClutteredBackground,
                value: m.border_noise,
                factor: ramp(m.border_noise, 8.0, 24.0, 0.0),
            },
            Issue {
                reason: Reason::TouchesBorder,
                value: m.border_contact,
                factor: ramp(m.border_contact, 0.02, 0.25, 0.2),
            },
            Issue {
                reason: Reason::LowContrast,
                value: m.ambiguous_fraction,
                factor: ramp(m.ambiguous_fraction, 0.15, 0.5, 0.0),
            },
            Issue { reason: Reason::Fragmented, value: m.main_share, factor: ramp(m.main_share, 0.85, 0.4, 0.2) },
        ];
        issues.retain(|i| i.factor < 0.999);
        issues.sort_by(|a, b| a.factor.total_cmp(&b.factor));
        let score = issues.iter().map(|i| i.factor).product::<f32>().clamp(0.0, 1.0);
        Confidence { score, issues, measures: m }
    }
}

/// The result of [`remove_background`].
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct Segmentation {
    /// The object's soft mask at the input's resolution (1 channel, 1 = object).
    pub alpha: Image,
    /// How far to trust it.
    pub confidence: Confidence,
}

/// Separates the object of a product-style photo (one object on a plain, graded or softly
/// shadowed background) from its background, with no model and no network.
///
/// `image` has 1 (grey), 3 (RGB) or 4 channels (the alpha of RGBA is ignored here) with
/// sRGB values in `[0, 1]`. The method, step by step:
///
/// 1. The photo is area-averaged to at most [`SegmentOptions::work_size`] on its longest side.
/// 2. A smooth background (a quadratic surface per channel) is fitted to a band along the
///    border by iteratively reweighted least squares (Tukey weights), so an object touching
///    the border or a vignette does not pull it; the spread of the inliers is the noise
///    level of the background.
/// 3. Each pixel's background cost is the −log likelihood of its colour under that surface,
///    or, with [`SegmentOptions::shadows`], under a darkened copy of it with the same
///    chromaticity (a cast shadow), mixed with a colour mixture learnt from the background.
///    The object's cost comes from its own colour mixture (a uniform density at first).
/// 4. Graph cuts (our Boykov–Kolmogorov max-flow) minimise those costs plus a boundary term
///    over 8-neighbour pairs that is cheap across strong colour edges (GrabCut's
///    `γ·exp(−β‖ΔI‖²)`); the mixtures are refitted to each cut, [`SegmentOptions::iterations`]
///    times.
/// 5. Small pieces are dropped, small holes filled, and the mask is brought back to full
///    resolution with a soft boundary from a colour guided filter in a narrow band.
///
/// Fails only on invalid input (no pixels, an unsupported channel count, bad options); a
/// photo that defeats the method gives a low [`Confidence`] with its reasons.
pub fn remove_background(image: &Image, options: &SegmentOptions) -> Result<Segmentation> {
    options.validate()?;
    let full = to_rgb(image)?;
    let (w, h) = (image.width() as usize, image.height() as usize);
    let scale = (options.work_size as f32 / w.max(h) as f32).min(1.0);
    let (ww, wh) = (((w as f32 * scale).round() as usize).max(1), ((h as f32 * scale).round() as usize).max(1));
    let work = if (ww, wh) == (w, h) { full.clone() } else { area_resize(&full, w, h, ww, wh) };

    let (mask, measures) = segment_work(&work, ww, wh, options);
    let alpha = refine_full(&full, w, h, &mask, ww, wh);
    let confidence = Confidence::from_measures(measures);
    Ok(Segmentation { alpha: Image::new(w as u32, h as u32, 1, alpha)?, confidence })
}

/// The image's pixels as RGB (grey is repeated, alpha dropped).
pub(crate) fn to_rgb(image: &Image) -> Result<Vec<[f32; 3]>> {
    let c = image.channels() as usize;
    let px = |p: &[f32]| match c {
        1 | 2 => [p[0], p[0], p[0]],
        _ => [p[0], p[1], p[2]],
    };
    if !(1..=4).contains(&c) {
        return Err(Error::invalid("image channels", format!("1 (grey), 2, 3 (RGB) or 4 (RGBA) channels, got {c}")));
    }
    if let Some(i) = image.data().iter().position(|v| !v.is_finite()) {
        return Err(Error::invalid(format!("image value {i}"), "a finite number"));
    }
    Ok(image.data().chunks_exact(c).map(px).collect())
}

/// Area-average resampling of an RGB buffer (each output pixel averages the input pixels
/// whose centres fall in its footprint).
fn area_resize(src: &[[f32; 3]], w: usize, h: usize, nw: usize, nh: usize) -> Vec<[f32; 3]> {
    let span = |i: usize, from: usize, to: usize| {
        let a = i * from / to;
        (a, ((i + 1) * from / to).clamp(a + 1, from))
    };
    let xs: Vec<(usize, usize)> = (0..nw).map(|x| span(x, w, nw)).collect();
    let mut out = vec![[0.0f32; 3]; nw * nh];
    let mut acc = vec![[0.0f32; 3]; nw];
    for (y, out_row) in out.chunks_exact_mut(nw).enumerate() {
        let (y0, y1) = span(y, h, nh);
        acc.iter_mut().for_each(|a| *a = [0.0; 3]);
        for row in src[y0 * w..y1 * w].chunks_exact(w) {
            for (a, &(x0, x1)) in acc.iter_mut().zip(&xs) {
                for p in &row[x0..x1] {
                    a[0] += p[0];
                    a[1] += p[1];
                    a[2] += p[2];
                }
            }
        }
        for ((o, a), &(x0, x1)) in out_row.iter_mut().zip(&acc).zip(&xs) {
            let k = ((y1 - y0) * (x1 - x0)) as f32;
            *o = [a[0] / k, a[1] / k, a[2] / k];
        }
    }
    out
}

/// A quadratic surface per colour channel over normalised coordinates `u, v ∈ [−1, 1]`.
#[derive(Debug, Clone, Copy)]
struct Surface {
    coef: [[f32; 3]; 6],
}

fn basis(u: f32, v: f32) -> [f32; 6] {
    [1.0, u, v, u * u, u * v, v * v]
}

impl Surface {
    fn at(&self, u: f32, v: f32) -> [f32; 3] {
        let b = basis(u, v);
        let mut c = [0.0f32; 3];
        for (k, bk) in b.iter().enumerate() {
            for (ch, cv) in c.iter_mut().enumerate() {
                *cv += bk * self.coef[k][ch];
            }
        }
        c
    }

    /// Robust fit to `(u, v, colour)` samples (Tukey-weighted IRLS). Returns the surface,
    /// the robust residual scale (per-channel σ) and the inlier weights.
    fn fit(samples: &[(f32, f32, [f32; 3])]) -> Option<(Surface, f32, Vec<f32>)> {
        let mut weights = vec![1.0f32; samples.len()];
        let mut surface = None;
        let mut sigma = 0.0f32;
        for _ in 0..6 {
            let mut ata = [[0.0f64; 6]; 6];
            let mut atb = [[0.0f64; 3]; 6];
            let mut wsum = 0.0f64;
            for (&(u, v, c), &wt) in samples.iter().zip(&weights) {
                if wt <= 0.0 {
                    continue;
                }
                let b = basis(u, v);
                let wt = f64::from(wt);
                wsum += wt;
                for i in 0..6 {
                    for j in 0..6 {
                        ata[i][j] += wt * f64::from(b[i] * b[j]);
                    }
                    for ch in 0..3 {
                        atb[i][ch] += wt * f64::from(b[i] * c[ch]);
                    }
                }
            }
            if wsum < 6.0 {
                return None;
            }
            // A light ridge on the curvature terms keeps the interior well-posed.
            for (i, row) in ata.iter_mut().enumerate().skip(3) {
                row[i] += 1e-3 * wsum;
            }
            let coef = solve6(ata, atb)?;
            let s = Surface { coef: coef.map(|r| r.map(|v| v as f32)) };
            let res: Vec<f32> = samples
                .iter()
                .map(|&(u, v, c)| {
                    let b = s.at(u, v);
                    ((c[0] - b[0]).powi(2) + (c[1] - b[1]).powi(2) + (c[2] - b[2]).powi(2)).sqrt()
                })
                .collect();
            let mut sorted = res.clone();
            let mid = sorted.len() / 2;
            let median = *sorted.select_nth_unstable_by(mid, f32::total_cmp).1;
            // The median of a 3-D Gaussian residual's norm is ≈ 1.54 σ.
            sigma = median / 1.54;
            let cutoff = (6.0 * sigma).max(6.0 / 255.0);
            for (wt, r) in weights.iter_mut().zip(&res) {
                let t = *r / cutoff;
                *wt = if t < 1.0 { (1.0 - t * t).powi(2) } else { 0.0 };
            }
            surface = Some(s);
        }
        surface.map(|s| (s, sigma, weights))
    }
}

/// Solves the 6×6 normal equations for three right-hand sides (Gaussian elimination with
/// partial pivoting).
fn solve6(mut a: [[f64; 6]; 6], mut b: [[f64; 3]; 6]) -> Option<[[f64; 3]; 6]> {
    for col in 0..6 {
        let pivot = (col..6).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[pivot][col].abs() < 1e-12 {
            return None;
        }
        a.swap(col, pivot);
        b.swap(col, pivot);
        let (pivot_row, pivot_b) = (a[col], b[col]);
        for (row, rhs) in a.iter_mut().zip(b.iter_mut()).skip(col + 1) {
            let f = row[col] / pivot_row[col];
            for (v, p) in row.iter_mut().zip(&pivot_row).skip(col) {
                *v -= f * p;
            }
            for (v, p) in rhs.iter_mut().zip(&pivot_b) {
                *v -= f * p;
            }
        }
    }
    let mut x = [[0.0f64; 3]; 6];
    for r in (0..6).rev() {
        for ch in 0..3 {
            let mut s = b[r][ch];
            for k in r + 1..6 {
                s -= a[r][k] * x[k][ch];
            }
            x[r][ch] = s / a[r][r];
        }
    }
    Some(x)
}

/// −log density of an isotropic 3-D Gaussian with standard deviation `sigma` at squared
/// distance `d2`.
fn gauss_cost(d2: f32, sigma: f32) -> f32 {
    0.5 * d2 / (sigma * sigma) + 3.0 * sigma.ln() + 1.5 * (2.0 * std::f32::consts::PI).ln()
}

/// −log(e^−a + e^−b).
fn softmin(a: f32, b: f32) -> f32 {
    let m = a.min(b);
    m - ((m - a).exp() + (m - b).exp()).ln()
}

/// Background cost of each work pixel under the surface model (plain, or shadowed).
fn surface_costs(work: &[[f32; 3]], w: usize, h: usize, surface: &Surface, noise: f32, shadows: bool) -> Vec<f32> {
    let sigma = noise.max(2.5 / 255.0);
    let sigma_shadow = (1.5 * sigma).max(0.012);
    // Shadows are a priori rarer than plain background, and deep ones rarer still.
    let shadow_prior = (1.0f32 / 0.01).ln();
    let mut out = vec![0.0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let v = (y as f32 + 0.5) / h as f32 * 2.0 - 1.0;
        for (x, o) in row.iter_mut().enumerate() {
            let u = (x as f32 + 0.5) / w as f32 * 2.0 - 1.0;
            let c = work[y * w + x];
            let b = surface.at(u, v);
            let d2 = (c[0] - b[0]).powi(2) + (c[1] - b[1]).powi(2) + (c[2] - b[2]).powi(2);
            let mut cost = gauss_cost(d2, sigma);
            if shadows {
                let bb = b[0] * b[0] + b[1] * b[1] + b[2] * b[2];
                // A shadow needs a lit background to fall on.
                if bb > 3.0 * 0.2 * 0.2 {
                    let s = (c[0] * b[0] + c[1] * b[1] + c[2] * b[2]) / bb;
                    if (0.25..1.0).contains(&s) {
                        let r2 = (c[0] - s * b[0]).powi(2) + (c[1] - s * b[1]).powi(2) + (c[2] - s * b[2]).powi(2);
                        let shadow = gauss_cost(r2, sigma_shadow) + shadow_prior + 3.0 * (1.0 - s);
                        cost = softmin(cost, shadow);
                    }
                }
            }
            *o = cost;
        }
    });
    out
}

/// Fixed-point scale of the graph's capacities (costs are in nats).
const CAP_SCALE: f32 = 64.0;
/// Largest per-pixel cost difference the cut sees, in nats.
const MAX_UNARY: f32 = 30.0;
/// Density of the object's colours before anything is known about them (uniform on the
/// unit RGB cube: −log 1 = 0), and the weight of that uniform part later.
const UNIFORM_COST: f32 = 0.0;

/// The segmentation at work resolution: a 0/1 mask and the measurements.
fn segment_work(work: &[[f32; 3]], w: usize, h: usize, options: &SegmentOptions) -> (Vec<bool>, Measures) {
    let n = w * h;
    let band = (w.min(h) / 40).max(2).min(w.min(h) / 2).max(1);
    let coords = |i: usize| {
        let (x, y) = (i % w, i / w);
        ((x as f32 + 0.5) / w as f32 * 2.0 - 1.0, (y as f32 + 0.5) / h as f32 * 2.0 - 1.0)
    };
    let border: Vec<usize> = (0..n)
        .filter(|&i| {
            let (x, y) = (i % w, i / w);
            x < band || y < band || x + band >= w || y + band >= h
        })
        .collect();
    let samples: Vec<(f32, f32, [f32; 3])> = border
        .iter()
        .map(|&i| {
            let (u, v) = coords(i);
            (u, v, work[i])
        })
        .collect();
    let mut measures = Measures::default();
    let (mut surface, noise) = match Surface::fit(&samples) {
        Some((s, sigma, _)) => (s, sigma),
        None => {
            // Too few border pixels for a surface (a tiny image): a constant background.
            let mean = samples.iter().fold([0.0f32; 3], |a, s| [a[0] + s.2[0], a[1] + s.2[1], a[2] + s.2[2]]);
            let k = samples.len().max(1) as f32;
            let mut coef = [[0.0f32; 3]; 6];
            coef[0] = [mean[0] / k, mean[1] / k, mean[2] / k];
            (Surface { coef }, 0.0)
        }
    };
    measures.border_noise = noise * 255.0;
    let colour_floor = (noise.max(2.0 / 255.0)).powi(2);

    // Pairwise weights (8 neighbours: right, down, down-right, down-left).
    let offsets: [(isize, isize, f32); 4] =
        [(1, 0, 1.0), (0, 1, 1.0), (1, 1, std::f32::consts::FRAC_1_SQRT_2), (-1, 1, std::f32::consts::FRAC_1_SQRT_2)];
    let mut diff_sum = 0.0f64;
    let mut diff_n = 0usize;
    for y in 0..h {
        for x in 0..w {
            for &(dx, dy, _) in &offsets {
                let (qx, qy) = (x as isize + dx, y as isize + dy);
                if qx < 0 || qx >= w as isize || qy >= h as isize {
                    continue;
                }
                let (p, q) = (work[y * w + x], work[qy as usize * w + qx as usize]);
                diff_sum += f64::from((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2));
                diff_n += 1;
            }
        }
    }
    let beta = if diff_sum > 0.0 { (diff_n as f64 / (2.0 * diff_sum)) as f32 } else { 0.0 };

    // Start: the object is whatever the plain background surface (no shadows) explains worse
    // than a uniform colour density would. Shadows start on the object's side, so the
    // object's mixture also learns grey and dark object colours that the shadow model could
    // otherwise claim; the boundary term then gives soft-edged shadows back to the background.
    let mut label: Vec<bool> =
        surface_costs(work, w, h, &surface, noise, false).iter().map(|&c| c > UNIFORM_COST + 2.0).collect();
    let mut bg_surface = surface_costs(work, w, h, &surface, noise, options.shadows);
    let mut unary = vec![0.0f32; n];
    for round in 0..options.iterations.max(1) {
        let fg_samples: Vec<[f32; 3]> = (0..n).filter(|&i| label[i]).map(|i| work[i]).collect();
        let bg_samples: Vec<[f32; 3]> = (0..n).filter(|&i| !label[i]).map(|i| work[i]).collect();
        if fg_samples.len() < 8 {
            break;
        }
        let fg = Gmm::fit(&fg_samples, options.components, colour_floor);
        let bg = Gmm::fit(&bg_samples, options.components, colour_floor);
        unary.par_iter_mut().zip(work.par_iter().zip(&bg_surface)).for_each(|(u, (&c, &surface_cost))| {
            let fg_cost = match &fg {
                Some(g) => softmin(g.cost(c) + (1.0f32 / 0.9).ln(), UNIFORM_COST + (1.0f32 / 0.1).ln()),
                None => UNIFORM_COST,
            };
            let bg_cost = match &bg {
                Some(g) => softmin(surface_cost + 2.0f32.ln(), g.cost(c) + 2.0f32.ln()),
                None => surface_cost,
            };
            *u = (bg_cost - fg_cost).clamp(-MAX_UNARY, MAX_UNARY);
        });
        label = cut(&unary, work, w, h, &offsets, beta, options.smoothness);
        if round == 0 {
            // Refit the background surface to everything the cut called background: the
            // interior of a graded backdrop is then modelled, not extrapolated.
            let step = (n / 40_000).max(1);
            let inner: Vec<(f32, f32, [f32; 3])> = (0..n)
                .step_by(step)
                .filter(|&i| !label[i])
                .map(|i| {
                    let (u, v) = coords(i);
                    (u, v, work[i])
                })
                .collect();
            if let Some((s, _, _)) = Surface::fit(&inner) {
                surface = s;
                bg_surface = surface_costs(work, w, h, &surface, noise, options.shadows);
            }
        }
    }

    // Clean up: keep the main piece(s), fill small holes.
    let (comp, sizes) = components(&label, w, h, true);
    let total: usize = sizes.iter().sum();
    let largest = sizes.iter().copied().max().unwrap_or(0);
    measures.main_share = if total > 0 { largest as f32 / total as f32 } else { 1.0 };
    let keep_min = ((largest as f32 * options.keep_fraction).ceil() as usize).max(1);
    let mut mask: Vec<bool> = comp.iter().map(|&c| c != u32::MAX && sizes[c as usize] >= keep_min).collect();
    let area: usize = mask.iter().filter(|&&m| m).count();
    let inverse: Vec<bool> = mask.iter().map(|&m| !m).collect();
    let (holes, hole_sizes) = components(&inverse, w, h, false);
    let mut touches = vec![false; hole_sizes.len()];
    for i in 0..n {
        let (x, y) = (i % w, i / w);
        if (x == 0 || y == 0 || x + 1 == w || y + 1 == h) && holes[i] != u32::MAX {
            touches[holes[i] as usize] = true;
        }
    }
    let hole_max = area as f32 * options.fill_holes;
    for i in 0..n {
        let c = holes[i];
        if c != u32::MAX && !touches[c as usize] && (hole_sizes[c as usize] as f32) <= hole_max {
            mask[i] = true;
        }
    }

    let area: usize = mask.iter().filter(|&&m| m).count();
    measures.object_fraction = area as f32 / n as f32;
    let ring: Vec<usize> = (0..n)
        .filter(|&i| {
            let (x, y) = (i % w, i / w);
            x == 0 || y == 0 || x + 1 == w || y + 1 == h
        })
        .collect();
    measures.border_contact = ring.iter().filter(|&&i| mask[i]).count() as f32 / ring.len().max(1) as f32;
    let ambiguous = (0..n).filter(|&i| mask[i] && unary[i] < -3.0).count();
    measures.ambiguous_fraction = if area > 0 { ambiguous as f32 / area as f32 } else { 0.0 };
    if options.shadows && area > 0 {
        let plain = surface_costs(work, w, h, &surface, noise, false);
        let shadowed = (0..n).filter(|&i| !mask[i] && plain[i] > bg_surface[i] + 3.0).count();
        measures.shadow_fraction = shadowed as f32 / area as f32;
    }
    (mask, measures)
}

/// One graph cut: `unary[i] > 0` favours the object. Returns the object mask.
fn cut(
    unary: &[f32],
    work: &[[f32; 3]],
    w: usize,
    h: usize,
    offsets: &[(isize, isize, f32); 4],
    beta: f32,
    smoothness: f32,
) -> Vec<bool> {
    let n = w * h;
    let mut g = Graph::new(n, 4 * n);
    for (i, &u) in unary.iter().enumerate() {
        let c = (u.abs() * CAP_SCALE).round() as i64;
        if u > 0.0 {
            g.add_terminal(i, c, 0);
        } else {
            g.add_terminal(i, 0, c);
        }
    }
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            for &(dx, dy, inv_dist) in offsets {
                let (qx, qy) = (x as isize + dx, y as isize + dy);
                if qx < 0 || qx >= w as isize || qy >= h as isize {
                    continue;
                }
                let q = qy as usize * w + qx as usize;
                let (a, b) = (work[p], work[q]);
                let d2 = (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2);
                let wgt = (smoothness * inv_dist * (-beta * d2).exp() * CAP_SCALE).round() as i64;
                if wgt > 0 {
                    g.add_edge(p, q, wgt, wgt);
                }
            }
        }
    }
    g.max_flow().1
}

/// Connected components (4-neighbour) of the `true` pixels: per pixel its component id
/// (`u32::MAX` for `false` pixels) and the component sizes. `eight` uses 8 neighbours.
pub(crate) fn components(on: &[bool], w: usize, h: usize, eight: bool) -> (Vec<u32>, Vec<usize>) {
    let mut id = vec![u32::MAX; on.len()];
    let mut sizes = Vec::new();
    let mut stack = Vec::new();
    for start in 0..on.len() {
        if !on[start] || id[start] != u32::MAX {
            continue;
        }
        let c = sizes.len() as u32;
        let mut size = 0;
        id[start] = c;
        stack.push(start);
        while let Some(p) = stack.pop() {
            size += 1;
            let (x, y) = ((p % w) as isize, (p / w) as isize);
            for dy in -1..=1isize {
                for dx in -1..=1isize {
                    if (dx == 0 && dy == 0) || (!eight && dx != 0 && dy != 0) {
                        continue;
                    }
                    let (qx, qy) = (x + dx, y + dy);
                    if qx < 0 || qy < 0 || qx >= w as isize || qy >= h as isize {
                        continue;
                    }
                    let q = qy as usize * w + qx as usize;
                    if on[q] && id[q] == u32::MAX {
                        id[q] = c;
                        stack.push(q);
                    }
                }
            }
        }
        sizes.push(size);
    }
    (id, sizes)
}

/// The work-resolution mask brought to full resolution with a soft boundary: bilinear
/// upsampling, then a colour guided filter (guide: the photo) inside a narrow band around
/// the outline; outside the band the mask stays binary.
fn refine_full(full: &[[f32; 3]], w: usize, h: usize, mask: &[bool], ww: usize, wh: usize) -> Vec<f32> {
    let factor = (w as f32 / ww as f32).max(h as f32 / wh as f32);
    // Bilinear upsampling of the 0/1 mask (pixel centres aligned).
    let mut p = vec![0.0f32; w * h];
    p.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let sy = ((y as f32 + 0.5) * wh as f32 / h as f32 - 0.5).clamp(0.0, (wh - 1) as f32);
        let (y0, ty) = (sy.floor() as usize, sy.fract());
        let y1 = (y0 + 1).min(wh - 1);
        for (x, out) in row.iter_mut().enumerate() {
            let sx = ((x as f32 + 0.5) * ww as f32 / w as f32 - 0.5).clamp(0.0, (ww - 1) as f32);
            let (x0, tx) = (sx.floor() as usize, sx.fract());
            let x1 = (x0 + 1).min(ww - 1);
            let m = |xx: usize, yy: usize| if mask[yy * ww + xx] { 1.0 } else { 0.0 };
            let top = m(x0, y0) * (1.0 - tx) + m(x1, y0) * tx;
            let bottom = m(x0, y1) * (1.0 - tx) + m(x1, y1) * tx;
            *out = top * (1.0 - ty) + bottom * ty;
        }
    });
    let binary: Vec<bool> = p.iter().map(|&v| v >= 0.5).collect();
    let radius = ((1.5 * factor).ceil() as usize).max(2);
    let q = guided_filter(full, &p, w, h, radius, 1e-3);
    let reach = radius + factor.ceil() as usize;
    let near = band(&binary, w, h, reach);
    binary
        .iter()
        .zip(&q)
        .zip(&near)
        .map(|((&b, &q), &in_band)| {
            let a = if in_band {
                q.clamp(0.0, 1.0)
            } else if b {
                1.0
            } else {
                0.0
            };
            if a < 0.02 {
                0.0
            } else if a > 0.98 {
                1.0
            } else {
                a
            }
        })
        .collect()
}

/// Pixels within `r` (Chebyshev distance) of a change in `mask`: dilation differs from
/// erosion there. Separable running min / max, O(n·r)-free via prefix counts.
fn band(mask: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    // Count of `true` pixels in each (2r+1)² window, through a summed-area table.
    let mut sat = vec![0u32; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0u32;
        for x in 0..w {
            row += u32::from(mask[y * w + x]);
            sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
        }
    }
    let mut out = vec![false; w * h];
    for y in 0..h {
        let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(h));
        for x in 0..w {
            let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(w));
            let count =
                sat[y1 * (w + 1) + x1] + sat[y0 * (w + 1) + x0] - sat[y0 * (w + 1) + x1] - sat[y1 * (w + 1) + x0];
            let area = ((y1 - y0) * (x1 - x0)) as u32;
            out[y * w + x] = count > 0 && count < area;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 120×90 photo: a red disc with a darker rim on a light grey background.
    fn disc_photo() -> (Image, Vec<bool>) {
        let (w, h) = (120u32, 90u32);
        let mut img = Image::filled(w, h, 3, 0.85).unwrap();
        let mut truth = vec![false; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                let d = ((x as f32 - 60.0).powi(2) + (y as f32 - 45.0).powi(2)).sqrt();
                if d < 25.0 {
                    let shade = 0.9 - 0.3 * d / 25.0;
                    img.pixel_mut(x, y).copy_from_slice(&[shade, 0.15, 0.1]);
                    truth[(y * w + x) as usize] = true;
                }
            }
        }
        (img, truth)
    }

    #[test]
    fn disc_on_plain_background_is_found() {
        let (img, truth) = disc_photo();
        let seg = remove_background(&img, &SegmentOptions::default()).unwrap();
        let agree = seg.alpha.data().iter().zip(&truth).filter(|&(&a, &t)| (a >= 0.5) == t).count();
        assert!(agree as f32 / truth.len() as f32 > 0.995, "agreement {agree}/{}", truth.len());
        assert!(seg.confidence.score > 0.9, "{:?}", seg.confidence);
    }

    #[test]
    fn empty_backdrop_has_no_object() {
        let img = Image::filled(64, 48, 3, 0.7).unwrap();
        let seg = remove_background(&img, &SegmentOptions::default()).unwrap();
        assert!(seg.alpha.data().iter().all(|&a| a == 0.0));
        assert_eq!(seg.confidence.score, 0.0);
        assert_eq!(seg.confidence.issues[0].reason, Reason::NoObject);
    }

    #[test]
    fn max_flow_is_exercised_on_tiny_images() {
        for (w, h) in [(1, 1), (2, 1), (1, 5), (3, 3)] {
            let img = Image::filled(w, h, 3, 0.5).unwrap();
            let seg = remove_background(&img, &SegmentOptions::default()).unwrap();
            assert_eq!((seg.alpha.width(), seg.alpha.height()), (w, h));
            assert!(seg.confidence.score < 0.5);
        }
    }

    #[test]
    fn band_marks_the_outline() {
        let (w, h) = (7, 5);
        let mask: Vec<bool> = (0..w * h).map(|i| i % w >= 3).collect();
        let b = band(&mask, w, h, 1);
        for (i, &on) in b.iter().enumerate() {
            assert_eq!(on, (2..=3).contains(&(i % w)), "pixel {i}");
        }
    }
}
