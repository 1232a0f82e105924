//! Group normalisation (optionally followed by SiLU) and its gradients on the CPU, on plain
//! `f32` slices: the kernel [`crate::nn::GroupNorm`] runs in training on Burn's flex backend.
//!
//! Why a kernel of our own: Burn differentiates the normalisation as the ten tensor operations
//! it is written with (mean, variance, subtraction, square root, division, scale, shift,
//! sigmoid, product), each a full pass over the activations forward and again backward. Here
//! the forward is two passes per group and the backward three, with the per-group mean and
//! reciprocal standard deviation kept from the forward.
//!
//! Images are `[n, c, h, w]`; the `c` channels form `groups` groups of consecutive channels.

use rayon::prelude::*;

/// Shape of a group normalisation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct GroupNormShape {
    /// Images.
    pub batch: usize,
    /// Channels (a multiple of `groups`).
    pub channels: usize,
    /// Pixels per channel (`h · w`).
    pub pixels: usize,
    /// Groups of channels normalised together.
    pub groups: usize,
}

impl GroupNormShape {
    fn group_channels(&self) -> usize {
        self.channels / self.groups
    }

    /// Values of one (image, group) unit.
    fn group_len(&self) -> usize {
        self.group_channels() * self.pixels
    }
}

/// Per (image, group): the mean and `1/√(var + eps)` of its values (biased variance).
#[derive(Clone, Debug)]
pub(crate) struct GroupStats {
    mean: Vec<f32>,
    rstd: Vec<f32>,
}

/// `(x − mean)/√(var + eps)·weight + bias` per group, then SiLU when `silu`; returns the output
/// and the statistics [`group_norm_backward`] needs.
///
/// # Panics
/// If a slice's length does not match `shape` or `channels` is not a multiple of `groups`.
pub(crate) fn group_norm(
    x: &[f32],
    weight: &[f32],
    bias: &[f32],
    shape: GroupNormShape,
    eps: f64,
    silu: bool,
) -> (Vec<f32>, GroupStats) {
    check(x, weight, bias, shape);
    let (len, gc, pixels) = (shape.group_len(), shape.group_channels(), shape.pixels);
    let mut out = vec![0.0f32; x.len()];
    let mut mean = vec![0.0f32; shape.batch * shape.groups];
    let mut rstd = vec![0.0f32; shape.batch * shape.groups];
    if len == 0 {
        return (out, GroupStats { mean, rstd });
    }
    out.par_chunks_mut(len)
        .zip(x.par_chunks(len))
        .zip(mean.par_iter_mut().zip(rstd.par_iter_mut()))
        .enumerate()
        .for_each(|(unit, ((y, x), (mu, r)))| {
            let m = x.iter().map(|&v| f64::from(v)).sum::<f64>() / len as f64;
            let var = x.iter().map(|&v| (f64::from(v) - m).powi(2)).sum::<f64>() / len as f64;
            let inv = 1.0 / (var + eps).sqrt();
            (*mu, *r) = (m as f32, inv as f32);
            let g = unit % shape.groups;
            for (ci, (y, x)) in y.chunks_exact_mut(pixels).zip(x.chunks_exact(pixels)).enumerate() {
                let c = g * gc + ci;
                let (scale, shift) = (weight[c] * *r, bias[c] - *mu * *r * weight[c]);
                for (y, &x) in y.iter_mut().zip(x) {
                    let v = x * scale + shift;
                    *y = if silu { v * sigmoid(v) } else { v };
                }
            }
        });
    (out, GroupStats { mean, rstd })
}

/// Gradients of [`group_norm`] given the output's gradient `d_out`: of the input, the weight
/// and the bias.
///
/// # Panics
/// As [`group_norm`].
#[allow(clippy::too_many_arguments)]
pub(crate) fn group_norm_backward(
    x: &[f32],
    weight: &[f32],
    bias: &[f32],
    stats: &GroupStats,
    d_out: &[f32],
    shape: GroupNormShape,
    silu: bool,
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    check(x, weight, bias, shape);
    assert_eq!(d_out.len(), x.len(), "output gradient length");
    let (len, gc, pixels) = (shape.group_len(), shape.group_channels(), shape.pixels);
    let mut dx = vec![0.0f32; x.len()];
    if len == 0 {
        return (dx, vec![0.0; shape.channels], vec![0.0; shape.channels]);
    }
    // Per unit: the input gradient in place, and the unit's share of dweight / dbias.
    let partials: Vec<(Vec<f32>, Vec<f32>)> = dx
        .par_chunks_mut(len)
        .zip(x.par_chunks(len).zip(d_out.par_chunks(len)))
        .enumerate()
        .map_init(Vec::new, |dy_buf, (unit, (dx, (x, d_out)))| {
            let g = unit % shape.groups;
            let (mu, r) = (stats.mean[unit], stats.rstd[unit]);
            // dy: the gradient at the normalisation's output (through SiLU when present).
            dy_buf.clear();
            dy_buf.extend_from_slice(d_out);
            let (mut dw, mut db) = (vec![0.0f32; gc], vec![0.0f32; gc]);
            let (mut sum_dxhat, mut sum_dxhat_xhat) = (0.0f64, 0.0f64);
            for (ci, (dy, x)) in dy_buf.chunks_exact_mut(pixels).zip(x.chunks_exact(pixels)).enumerate() {
                let c = g * gc + ci;
                let (w, b) = (weight[c], bias[c]);
                let (mut dw_c, mut db_c, mut s1, mut s2) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
                for (dy, &x) in dy.iter_mut().zip(x) {
                    let xhat = (x - mu) * r;
                    if silu {
                        let v = xhat * w + b;
                        let s = sigmoid(v);
                        *dy *= s * (1.0 + v * (1.0 - s));
                    }
                    dw_c += f64::from(*dy * xhat);
                    db_c += f64::from(*dy);
                    let dxhat = *dy * w;
                    s1 += f64::from(dxhat);
                    s2 += f64::from(dxhat * xhat);
                }
                (dw[ci], db[ci]) = (dw_c as f32, db_c as f32);
                sum_dxhat += s1;
                sum_dxhat_xhat += s2;
            }
            // dx = rstd · (dx̂ − mean(dx̂) − x̂ · mean(dx̂ · x̂)) over the group.
            let (m1, m2) = ((sum_dxhat / len as f64) as f32, (sum_dxhat_xhat / len as f64) as f32);
            for (ci, (dx, (dy, x))) in
                dx.chunks_exact_mut(pixels).zip(dy_buf.chunks_exact(pixels).zip(x.chunks_exact(pixels))).enumerate()
            {
                let w = weight[g * gc + ci];
                for (dx, (&dy, &x)) in dx.iter_mut().zip(dy.iter().zip(x)) {
                    let xhat = (x - mu) * r;
                    *dx = r * (dy * w - m1 - xhat * m2);
                }
            }
            (dw, db)
        })
        .collect();
    let (mut dw, mut db) = (vec![0.0f32; shape.channels], vec![0.0f32; shape.channels]);
    for (unit, (pw, pb)) in partials.iter().enumerate() {
        let c0 = (unit % shape.groups) * gc;
        dw[c0..c0 + gc].iter_mut().zip(pw).for_each(|(s, v)| *s += v);
        db[c0..c0 + gc].iter_mut().zip(pb).for_each(|(s, v)| *s += v);
    }
    (dx, dw, db)
}

fn check(x: &[f32], weight: &[f32], bias: &[f32], shape: GroupNormShape) {
    assert!(shape.groups > 0 && shape.channels.is_multiple_of(shape.groups), "channels not a multiple of groups");
    assert_eq!(x.len(), shape.batch * shape.channels * shape.pixels, "input length");
    assert_eq!(weight.len(), shape.channels, "weight length");
    assert_eq!(bias.len(), shape.channels, "bias length");
}

/// `1/(1 + e^−v)` from `e = e^−|v|` (never overflows), with the crate's branch-free
/// exponential so that the loops around it vectorise.
#[inline(always)]
fn sigmoid(v: f32) -> f32 {
    let e = crate::cpu_attention::exp_scalar(-v.abs());
    let s = 1.0 / (1.0 + e);
    if v >= 0.0 { s } else { e * s }
}
