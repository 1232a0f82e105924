//! The colour guided filter (He, Sun and Tang, "Guided Image Filtering", 2010/2013),
//! written for this crate: a locally affine map from the guide's colour to the filtered
//! value, so a soft mask takes the photo's edges. Box means by running sums, O(pixels).

use rayon::prelude::*;

use crate::gmm::invert_sym3;

/// Mean over the clipped `(2r+1)²` window of every pixel (separable running sums).
pub(crate) fn box_mean(src: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    // Horizontal pass: window sums per row.
    let mut tmp = vec![0.0f32; w * h];
    for (row, out) in src.chunks_exact(w).zip(tmp.chunks_exact_mut(w)) {
        let mut prefix = Vec::with_capacity(w + 1);
        prefix.push(0.0f64);
        for &v in row {
            prefix.push(prefix[prefix.len() - 1] + f64::from(v));
        }
        for (x, o) in out.iter_mut().enumerate() {
            let (a, b) = (x.saturating_sub(r), (x + r + 1).min(w));
            *o = ((prefix[b] - prefix[a]) / (b - a) as f64) as f32;
        }
    }
    // Vertical pass on the row means.
    let mut out = vec![0.0f32; w * h];
    let mut prefix = vec![0.0f64; (h + 1) * w];
    for y in 0..h {
        for x in 0..w {
            prefix[(y + 1) * w + x] = prefix[y * w + x] + f64::from(tmp[y * w + x]);
        }
    }
    for y in 0..h {
        let (a, b) = (y.saturating_sub(r), (y + r + 1).min(h));
        let k = (b - a) as f64;
        for x in 0..w {
            out[y * w + x] = ((prefix[b * w + x] - prefix[a * w + x]) / k) as f32;
        }
    }
    out
}

/// Filters `p` (one value per pixel) guided by the RGB image `guide`: window radius `r`,
/// regularisation `eps` (larger = smoother, less edge-following).
pub(crate) fn guided_filter(guide: &[[f32; 3]], p: &[f32], w: usize, h: usize, r: usize, eps: f32) -> Vec<f32> {
    let n = w * h;
    // The 13 window means the filter needs: I (3), p, I·p (3), I·Iᵀ (6), in parallel.
    let products: [fn(&[f32; 3], f32) -> f32; 13] = [
        |g, _| g[0],
        |g, _| g[1],
        |g, _| g[2],
        |_, pv| pv,
        |g, pv| g[0] * pv,
        |g, pv| g[1] * pv,
        |g, pv| g[2] * pv,
        |g, _| g[0] * g[0],
        |g, _| g[0] * g[1],
        |g, _| g[0] * g[2],
        |g, _| g[1] * g[1],
        |g, _| g[1] * g[2],
        |g, _| g[2] * g[2],
    ];
    let means: Vec<Vec<f32>> = products
        .par_iter()
        .map(|f| {
            let v: Vec<f32> = guide.iter().zip(p).map(|(g, &pv)| f(g, pv)).collect();
            box_mean(&v, w, h, r)
        })
        .collect();
    let mean_i = [&means[0], &means[1], &means[2]];
    let mean_p = &means[3];
    let mean_ip = [&means[4], &means[5], &means[6]];
    let ii = [&means[7], &means[8], &means[9], &means[10], &means[11], &means[12]];
    // Per pixel: the affine coefficients (a: 3, b: 1) of the window's least-squares fit.
    let coefs: Vec<[f32; 4]> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mu = [mean_i[0][i], mean_i[1][i], mean_i[2][i]];
            let cov_ip = [
                mean_ip[0][i] - mu[0] * mean_p[i],
                mean_ip[1][i] - mu[1] * mean_p[i],
                mean_ip[2][i] - mu[2] * mean_p[i],
            ];
            let sigma = [
                f64::from(ii[0][i] - mu[0] * mu[0] + eps),
                f64::from(ii[1][i] - mu[0] * mu[1]),
                f64::from(ii[2][i] - mu[0] * mu[2]),
                f64::from(ii[3][i] - mu[1] * mu[1] + eps),
                f64::from(ii[4][i] - mu[1] * mu[2]),
                f64::from(ii[5][i] - mu[2] * mu[2] + eps),
            ];
            let coef = match invert_sym3(sigma) {
                Some((inv, _)) => {
                    let c = cov_ip.map(f64::from);
                    [
                        (inv[0] * c[0] + inv[1] * c[1] + inv[2] * c[2]) as f32,
                        (inv[1] * c[0] + inv[3] * c[1] + inv[4] * c[2]) as f32,
                        (inv[2] * c[0] + inv[4] * c[1] + inv[5] * c[2]) as f32,
                    ]
                }
                None => [0.0; 3],
            };
            [coef[0], coef[1], coef[2], mean_p[i] - coef[0] * mu[0] - coef[1] * mu[1] - coef[2] * mu[2]]
        })
        .collect();
    let a: [Vec<f32>; 3] = [0, 1, 2].map(|k| coefs.iter().map(|c| c[k]).collect());
    let b: Vec<f32> = coefs.iter().map(|c| c[3]).collect();
    let mut smoothed: Vec<Vec<f32>> = [&a[0], &a[1], &a[2], &b].par_iter().map(|v| box_mean(v, w, h, r)).collect();
    let mean_b = smoothed.pop().unwrap_or_default();
    let mean_a = [&smoothed[0], &smoothed[1], &smoothed[2]];
    (0..n)
        .into_par_iter()
        .map(|i| {
            let g = guide[i];
            mean_a[0][i] * g[0] + mean_a[1][i] * g[1] + mean_a[2][i] * g[2] + mean_b[i]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_mean_averages_clipped_windows() {
        let src: Vec<f32> = (0..12).map(|v| v as f32).collect(); // 4×3
        let m = box_mean(&src, 4, 3, 1);
        // Corner (0, 0): pixels 0, 1, 4, 5.
        assert!((m[0] - 2.5).abs() < 1e-6);
        // Centre (1, 1): 0 1 2 4 5 6 8 9 10.
        assert!((m[5] - 5.0).abs() < 1e-6);
    }

    #[test]
    fn filtered_mask_snaps_to_the_guide_edge() {
        // The guide has an edge at x = 10; the mask's edge is off by two pixels.
        let (w, h) = (20, 8);
        let guide: Vec<[f32; 3]> = (0..w * h).map(|i| if i % w < 10 { [0.9; 3] } else { [0.2, 0.3, 0.8] }).collect();
        let p: Vec<f32> = (0..w * h).map(|i| if i % w < 12 { 1.0 } else { 0.0 }).collect();
        let q = guided_filter(&guide, &p, w, h, 4, 1e-4);
        let row = &q[4 * w..5 * w];
        assert!(row[9] > 0.7 && row[11] < 0.5, "{row:?}");
    }
}
