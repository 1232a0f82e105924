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
    let len = shape.group_len();
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
            let unit = ForwardUnit { x, y, weight, bias, shape, group: unit % shape.groups, eps };
            (*mu, *r) = simd_dispatch!(forward_unit(unit, silu));
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
    let (len, gc) = (shape.group_len(), shape.group_channels());
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
            // dy: the gradient at the normalisation's output (through SiLU when present).
            dy_buf.clear();
            dy_buf.extend_from_slice(d_out);
            let (mut dw, mut db) = (vec![0.0f32; gc], vec![0.0f32; gc]);
            let unit = BackwardUnit {
                x,
                dy: dy_buf,
                dx,
                dw: &mut dw,
                db: &mut db,
                weight,
                bias,
                shape,
                group: unit % shape.groups,
                mean: stats.mean[unit],
                rstd: stats.rstd[unit],
            };
            simd_dispatch!(backward_unit(unit, silu));
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

/// Calls `$name::<true|false>` (by `$silu`) compiled for the widest vector instructions the
/// CPU has. The kernels' sums run in [`LANES`] fixed lanes and Rust never fuses a multiply and
/// an add on its own, so every variant computes the same bits; only the speed differs.
macro_rules! simd_dispatch {
    ($name:ident($unit:expr, $silu:expr)) => {{
        let unit = $unit;
        #[cfg(target_arch = "x86_64")]
        {
            if std::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU has the feature the variant is compiled for (checked here).
                #[allow(unsafe_code)]
                unsafe {
                    call_variant!(simd::avx512, $name, unit, $silu)
                }
            } else if std::is_x86_feature_detected!("avx2") {
                // SAFETY: as above.
                #[allow(unsafe_code)]
                unsafe {
                    call_variant!(simd::avx2, $name, unit, $silu)
                }
            } else {
                call_variant!(self, $name, unit, $silu)
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            call_variant!(self, $name, unit, $silu)
        }
    }};
}
use simd_dispatch;

/// The `$silu` variant of `$module::$name` applied to `$unit`.
macro_rules! call_variant {
    ($module:path, $name:ident, $unit:expr, $silu:expr) => {{
        use $module as m;
        if $silu { m::$name::<true>($unit) } else { m::$name::<false>($unit) }
    }};
}
use call_variant;

/// The kernels compiled for AVX-512 and AVX2 (the portable ones, with the target's features
/// enabled so the compiler vectorises their lanes that wide).
#[cfg(target_arch = "x86_64")]
mod simd {
    macro_rules! variant {
        ($module:ident, $features:literal) => {
            pub(super) mod $module {
                use super::super::{BackwardUnit, ForwardUnit};

                /// [`super::super::forward_unit`] with the module's target features.
                #[target_feature(enable = $features)]
                pub(crate) fn forward_unit<const SILU: bool>(unit: ForwardUnit<'_>) -> (f32, f32) {
                    super::super::forward_unit::<SILU>(unit)
                }

                /// [`super::super::backward_unit`] with the module's target features.
                #[target_feature(enable = $features)]
                pub(crate) fn backward_unit<const SILU: bool>(unit: BackwardUnit<'_>) {
                    super::super::backward_unit::<SILU>(unit)
                }
            }
        };
    }
    variant!(avx512, "avx512f");
    variant!(avx2, "avx2");
}

/// Independent accumulators of the kernels' sums: one SIMD register's worth of f64 on
/// AVX-512 (a single accumulator would serialise the loop and keep it scalar).
const LANES: usize = 8;

/// One (image, group) of the forward.
struct ForwardUnit<'a> {
    x: &'a [f32],
    y: &'a mut [f32],
    weight: &'a [f32],
    bias: &'a [f32],
    shape: GroupNormShape,
    group: usize,
    eps: f64,
}

/// The forward of one unit: its mean and reciprocal standard deviation (returned), then the
/// normalised, scaled and shifted values (through SiLU with `SILU`).
#[inline(always)]
fn forward_unit<const SILU: bool>(u: ForwardUnit<'_>) -> (f32, f32) {
    let (len, gc, pixels) = (u.shape.group_len(), u.shape.group_channels(), u.shape.pixels);
    let m = lane_sum(u.x, f64::from) / len as f64;
    let var = lane_sum(u.x, |v| (f64::from(v) - m) * (f64::from(v) - m)) / len as f64;
    let (mu, r) = (m as f32, (1.0 / (var + u.eps).sqrt()) as f32);
    for (ci, (y, x)) in u.y.chunks_exact_mut(pixels).zip(u.x.chunks_exact(pixels)).enumerate() {
        let c = u.group * gc + ci;
        let (scale, shift) = (u.weight[c] * r, u.bias[c] - mu * r * u.weight[c]);
        for (y, &x) in y.iter_mut().zip(x) {
            let v = x * scale + shift;
            *y = if SILU { v * sigmoid(v) } else { v };
        }
    }
    (mu, r)
}

/// `Σ f(v)` over `values` in f64, in [`LANES`] interleaved partial sums added at the end.
#[inline(always)]
fn lane_sum(values: &[f32], f: impl Fn(f32) -> f64) -> f64 {
    let mut lanes = [0.0f64; LANES];
    let mut chunks = values.chunks_exact(LANES);
    for chunk in &mut chunks {
        for (s, &v) in lanes.iter_mut().zip(chunk) {
            *s += f(v);
        }
    }
    chunks.remainder().iter().fold(lanes.iter().sum::<f64>(), |s, &v| s + f(v))
}

/// One (image, group) of the backward.
struct BackwardUnit<'a> {
    x: &'a [f32],
    /// The output's gradient on entry; the gradient at the normalisation's output after.
    dy: &'a mut [f32],
    dx: &'a mut [f32],
    /// This unit's channels' shares of the weight's and the bias's gradients.
    dw: &'a mut [f32],
    db: &'a mut [f32],
    weight: &'a [f32],
    bias: &'a [f32],
    shape: GroupNormShape,
    group: usize,
    mean: f32,
    rstd: f32,
}

/// What one channel's values are normalised with.
#[derive(Clone, Copy)]
struct ChannelCoefficients {
    mean: f32,
    rstd: f32,
    weight: f32,
    bias: f32,
}

/// One block of at most [`LANES`] values of a channel in the backward: `dy` through SiLU (with
/// `SILU`) in place, and the four per-lane sums of [`backward_unit`]. Each step is its own loop
/// over the block, a shape the compiler turns into vector instructions; a function rather than
/// a closure so that it is compiled with the calling variant's target features.
#[inline(always)]
fn backward_block<const SILU: bool>(dy: &mut [f32], x: &[f32], c: ChannelCoefficients, sums: &mut [[f64; LANES]; 4]) {
    let mut xhat = [0.0f32; LANES];
    for (h, &x) in xhat.iter_mut().zip(x) {
        *h = (x - c.mean) * c.rstd;
    }
    if SILU {
        for (dy, &h) in dy.iter_mut().zip(&xhat) {
            let v = h * c.weight + c.bias;
            let s = sigmoid(v);
            *dy *= s * (1.0 + v * (1.0 - s));
        }
    }
    for (lane, (&dy, &h)) in dy.iter().zip(&xhat).enumerate() {
        let dxhat = dy * c.weight;
        sums[0][lane] += f64::from(dy * h);
        sums[1][lane] += f64::from(dy);
        sums[2][lane] += f64::from(dxhat);
        sums[3][lane] += f64::from(dxhat * h);
    }
}

/// The backward of one unit: `dy` through SiLU (with `SILU`), the channels' weight and bias
/// gradients, then `dx = rstd · (dx̂ − mean(dx̂) − x̂ · mean(dx̂ · x̂))` over the group.
#[inline(always)]
fn backward_unit<const SILU: bool>(u: BackwardUnit<'_>) {
    let (len, gc, pixels) = (u.shape.group_len(), u.shape.group_channels(), u.shape.pixels);
    let (mu, r) = (u.mean, u.rstd);
    let (mut sum_dxhat, mut sum_dxhat_xhat) = (0.0f64, 0.0f64);
    for (ci, (dy, x)) in u.dy.chunks_exact_mut(pixels).zip(u.x.chunks_exact(pixels)).enumerate() {
        let c = u.group * gc + ci;
        let (w, b) = (u.weight[c], u.bias[c]);
        // Per lane: Σ dy·x̂, Σ dy, Σ dx̂, Σ dx̂·x̂ (dx̂ = dy·w).
        let mut sums = [[0.0f64; LANES]; 4];
        let coefficients = ChannelCoefficients { mean: mu, rstd: r, weight: w, bias: b };
        let mut dy_chunks = dy.chunks_exact_mut(LANES);
        let mut x_chunks = x.chunks_exact(LANES);
        for (dy, x) in (&mut dy_chunks).zip(&mut x_chunks) {
            backward_block::<SILU>(dy, x, coefficients, &mut sums);
        }
        backward_block::<SILU>(dy_chunks.into_remainder(), x_chunks.remainder(), coefficients, &mut sums);
        let [dw_c, db_c, s1, s2] = sums.map(|lanes| lanes.iter().sum::<f64>());
        (u.dw[ci], u.db[ci]) = (dw_c as f32, db_c as f32);
        sum_dxhat += s1;
        sum_dxhat_xhat += s2;
    }
    let (m1, m2) = ((sum_dxhat / len as f64) as f32, (sum_dxhat_xhat / len as f64) as f32);
    for (ci, (dx, (dy, x))) in
        u.dx.chunks_exact_mut(pixels).zip(u.dy.chunks_exact(pixels).zip(u.x.chunks_exact(pixels))).enumerate()
    {
        let w = u.weight[u.group * gc + ci];
        for (dx, (&dy, &x)) in dx.iter_mut().zip(dy.iter().zip(x)) {
            let xhat = (x - mu) * r;
            *dx = r * (dy * w - m1 - xhat * m2);
        }
    }
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
    let e = crate::kernels::attention::exp_scalar(-v.abs());
    let s = 1.0 / (1.0 + e);
    if v >= 0.0 { s } else { e * s }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic values in about [−2, 2] (a small LCG; no dependency needed).
    fn values(n: usize, seed: u32) -> Vec<f32> {
        let mut state = seed;
        (0..n)
            .map(|_| {
                state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (state >> 8) as f32 / (1u32 << 24) as f32 * 4.0 - 2.0
            })
            .collect()
    }

    /// Every compiled variant the CPU can run gives the portable kernels' bits, forward and
    /// backward, with and without SiLU (the claim `simd_dispatch!` rests on). A group of 3
    /// channels of 13 pixels leaves a partial block of lanes in every channel.
    #[test]
    fn every_variant_computes_the_same_bits() {
        let shape = GroupNormShape { batch: 1, channels: 3, pixels: 13, groups: 1 };
        let (x, weight, bias, d_out) = (values(39, 1), values(3, 2), values(3, 3), values(39, 4));
        type Forward = fn(ForwardUnit<'_>) -> (f32, f32);
        type Backward = fn(BackwardUnit<'_>);
        let run = |forward: Forward, backward: Backward| {
            let mut y = vec![0.0f32; 39];
            let (mean, rstd) =
                forward(ForwardUnit { x: &x, y: &mut y, weight: &weight, bias: &bias, shape, group: 0, eps: 1e-5 });
            let (mut dy, mut dx, mut dw, mut db) = (d_out.clone(), vec![0.0f32; 39], vec![0.0f32; 3], vec![0.0f32; 3]);
            backward(BackwardUnit {
                x: &x,
                dy: &mut dy,
                dx: &mut dx,
                dw: &mut dw,
                db: &mut db,
                weight: &weight,
                bias: &bias,
                shape,
                group: 0,
                mean,
                rstd,
            });
            [y, dx, dw, db, vec![mean, rstd]].map(|v| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>())
        };
        for silu in [false, true] {
            let portable: (Forward, Backward) = if silu {
                (forward_unit::<true>, backward_unit::<true>)
            } else {
                (forward_unit::<false>, backward_unit::<false>)
            };
            let expected = run(portable.0, portable.1);
            #[cfg(target_arch = "x86_64")]
            for (feature, detected) in
                [("avx512f", std::is_x86_feature_detected!("avx512f")), ("avx2", std::is_x86_feature_detected!("avx2"))]
            {
                if !detected {
                    continue;
                }
                // SAFETY: the CPU has the variant's feature (detected just above).
                #[allow(unsafe_code)]
                let got = unsafe {
                    match (feature, silu) {
                        ("avx512f", true) => {
                            run(|u| simd::avx512::forward_unit::<true>(u), |u| simd::avx512::backward_unit::<true>(u))
                        }
                        ("avx512f", false) => {
                            run(|u| simd::avx512::forward_unit::<false>(u), |u| simd::avx512::backward_unit::<false>(u))
                        }
                        (_, true) => {
                            run(|u| simd::avx2::forward_unit::<true>(u), |u| simd::avx2::backward_unit::<true>(u))
                        }
                        (_, false) => {
                            run(|u| simd::avx2::forward_unit::<false>(u), |u| simd::avx2::backward_unit::<false>(u))
                        }
                    }
                };
                assert_eq!(got, expected, "{feature}, silu {silu}");
            }
        }
    }
}
