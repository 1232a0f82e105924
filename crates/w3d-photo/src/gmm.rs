//! Gaussian mixtures of RGB colours with full covariances, the colour models of the
//! GrabCut-style segmentation: fitted by k-means (maximin seeds, deterministic) and one
//! hard-assignment estimate of weights, means and covariances.

/// One Gaussian of a mixture, stored ready for evaluation.
#[derive(Debug, Clone, Copy)]
struct Component {
    /// log(weight) − ½ log det Σ − 3/2 log 2π.
    log_norm: f32,
    mean: [f32; 3],
    /// Σ⁻¹ as (xx, xy, xz, yy, yz, zz).
    inv: [f32; 6],
}

/// A mixture of Gaussians over RGB colours.
#[derive(Debug, Clone)]
pub(crate) struct Gmm {
    comps: Vec<Component>,
}

/// At most this many samples are used for fitting (every n-th sample beyond it).
const MAX_FIT_SAMPLES: usize = 20_000;
/// k-means runs on at most this many.
const MAX_KMEANS_SAMPLES: usize = 4_000;

fn dist2(a: [f32; 3], b: [f32; 3]) -> f32 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

fn subsample(samples: &[[f32; 3]], max: usize) -> Vec<[f32; 3]> {
    if samples.len() <= max {
        return samples.to_vec();
    }
    let step = samples.len() as f64 / max as f64;
    (0..max).map(|i| samples[(i as f64 * step) as usize]).collect()
}

impl Gmm {
    /// Fits up to `k` components to `samples`; covariances get `floor` added to their
    /// diagonal (noise that no model may explain away). `None` without samples.
    pub(crate) fn fit(samples: &[[f32; 3]], k: usize, floor: f32) -> Option<Gmm> {
        if samples.is_empty() || k == 0 {
            return None;
        }
        let fit = subsample(samples, MAX_FIT_SAMPLES);
        let km = subsample(&fit, MAX_KMEANS_SAMPLES);
        // Maximin seeds: the mean, then repeatedly the sample farthest from all seeds.
        let n = km.len() as f32;
        let mean = km.iter().fold([0.0f32; 3], |a, c| [a[0] + c[0] / n, a[1] + c[1] / n, a[2] + c[2] / n]);
        let mut centres = vec![mean];
        let mut nearest: Vec<f32> = km.iter().map(|&c| dist2(c, mean)).collect();
        while centres.len() < k.min(8) {
            let (far, &d) = nearest.iter().enumerate().fold((0, &-1.0f32), |b, x| if *x.1 > *b.1 { x } else { b });
            if d <= 1e-6 {
                break; // fewer distinct colours than components
            }
            let c = km[far];
            centres.push(c);
            for (m, s) in nearest.iter_mut().zip(&km) {
                *m = m.min(dist2(*s, c));
            }
        }
        // Lloyd iterations.
        for _ in 0..6 {
            let mut sums = vec![[0.0f64; 4]; centres.len()];
            for &s in &km {
                let j = nearest_centre(&centres, s);
                sums[j][0] += f64::from(s[0]);
                sums[j][1] += f64::from(s[1]);
                sums[j][2] += f64::from(s[2]);
                sums[j][3] += 1.0;
            }
            for (c, s) in centres.iter_mut().zip(&sums) {
                if s[3] > 0.0 {
                    *c = [(s[0] / s[3]) as f32, (s[1] / s[3]) as f32, (s[2] / s[3]) as f32];
                }
            }
        }
        // Weights, means and covariances from the hard assignment of every fit sample.
        let mut acc = vec![[0.0f64; 10]; centres.len()]; // n, Σx (3), Σxxᵀ (6)
        for &s in &fit {
            let j = nearest_centre(&centres, s);
            let (x, y, z) = (f64::from(s[0]), f64::from(s[1]), f64::from(s[2]));
            let a = &mut acc[j];
            a[0] += 1.0;
            a[1] += x;
            a[2] += y;
            a[3] += z;
            a[4] += x * x;
            a[5] += x * y;
            a[6] += x * z;
            a[7] += y * y;
            a[8] += y * z;
            a[9] += z * z;
        }
        let total = fit.len() as f64;
        let mut comps = Vec::new();
        for a in &acc {
            let m = a[0];
            if m < 1.0 {
                continue;
            }
            let mu = [a[1] / m, a[2] / m, a[3] / m];
            let f = f64::from(floor);
            let cov = [
                a[4] / m - mu[0] * mu[0] + f,
                a[5] / m - mu[0] * mu[1],
                a[6] / m - mu[0] * mu[2],
                a[7] / m - mu[1] * mu[1] + f,
                a[8] / m - mu[1] * mu[2],
                a[9] / m - mu[2] * mu[2] + f,
            ];
            let Some((inv, det)) = invert_sym3(cov) else { continue };
            let log_norm = (m / total).ln() - 0.5 * det.ln() - 1.5 * (2.0 * std::f64::consts::PI).ln();
            comps.push(Component {
                log_norm: log_norm as f32,
                mean: [mu[0] as f32, mu[1] as f32, mu[2] as f32],
                inv: inv.map(|v| v as f32),
            });
        }
        (!comps.is_empty()).then_some(Gmm { comps })
    }

    /// −log density of colour `c` under the mixture.
    pub(crate) fn cost(&self, c: [f32; 3]) -> f32 {
        let mut best = f32::NEG_INFINITY;
        let mut terms = [0.0f32; 8];
        let n = self.comps.len().min(terms.len());
        for (t, comp) in terms.iter_mut().zip(&self.comps) {
            let d = [c[0] - comp.mean[0], c[1] - comp.mean[1], c[2] - comp.mean[2]];
            let i = &comp.inv;
            let q = d[0] * (i[0] * d[0] + 2.0 * (i[1] * d[1] + i[2] * d[2]))
                + d[1] * (i[3] * d[1] + 2.0 * i[4] * d[2])
                + i[5] * d[2] * d[2];
            *t = comp.log_norm - 0.5 * q;
            best = best.max(*t);
        }
        let sum: f32 = terms[..n].iter().map(|t| (t - best).exp()).sum();
        -(best + sum.ln())
    }
}

fn nearest_centre(centres: &[[f32; 3]], s: [f32; 3]) -> usize {
    let mut best = (0, f32::INFINITY);
    for (j, &c) in centres.iter().enumerate() {
        let d = dist2(s, c);
        if d < best.1 {
            best = (j, d);
        }
    }
    best.0
}

/// Inverse and determinant of a symmetric 3×3 matrix given as (xx, xy, xz, yy, yz, zz);
/// `None` unless it is positive definite enough to invert.
pub(crate) fn invert_sym3(m: [f64; 6]) -> Option<([f64; 6], f64)> {
    let [a, b, c, d, e, f] = m;
    let c00 = d * f - e * e;
    let c01 = c * e - b * f;
    let c02 = b * e - c * d;
    let det = a * c00 + b * c01 + c * c02;
    // Also refuses a NaN determinant.
    if det.is_nan() || det <= 1e-30 {
        return None;
    }
    let c11 = a * f - c * c;
    let c12 = b * c - a * e;
    let c22 = a * d - b * b;
    Some(([c00 / det, c01 / det, c02 / det, c11 / det, c12 / det, c22 / det], det))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_clusters_are_told_apart() {
        let mut samples = Vec::new();
        for i in 0..500 {
            let t = (i % 10) as f32 * 0.002;
            samples.push([0.9 + t, 0.9 - t, 0.9]);
            samples.push([0.1, 0.2 + t, 0.6 - t]);
        }
        let gmm = Gmm::fit(&samples, 5, 1e-4).unwrap();
        assert!(gmm.cost([0.9, 0.9, 0.9]) < gmm.cost([0.5, 0.5, 0.5]) - 20.0);
        assert!(gmm.cost([0.1, 0.21, 0.59]) < gmm.cost([0.9, 0.1, 0.1]) - 20.0);
    }

    #[test]
    fn inverse_is_an_inverse() {
        let m = [2.0, 0.3, -0.2, 1.5, 0.1, 1.0];
        let (inv, det) = invert_sym3(m).unwrap();
        let full = |v: [f64; 6]| [[v[0], v[1], v[2]], [v[1], v[3], v[4]], [v[2], v[4], v[5]]];
        let (a, b) = (full(m), full(inv));
        for (i, row) in a.iter().enumerate() {
            for j in 0..3 {
                let p: f64 = row.iter().zip(&b).map(|(x, col)| x * col[j]).sum();
                assert!((p - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
        assert!(det > 0.0);
    }
}
