//! The optimizer's per-element arithmetic on plain `f32` slices: AdamW's update
//! ([`adamw_update`]) and the moving average of the weights ([`moving_average`]), which the
//! trainer runs on the tensors' memory on Burn's CPU backend.
//!
//! Why a kernel of our own: as tensor operations, one AdamW step is fifteen element-wise passes
//! over every trainable parameter (each allocating its result), and the moving average three
//! more, all on one core: on the small UNet's 1.45 M parameters that was several percent of a
//! training step (`docs/benchmarks.md`, "Training step"). Here each is one pass, split over the
//! cores.
//!
//! The arithmetic is the tensor operations', operation for operation in f32 (every scalar
//! rounded to f32 first, as Burn's scalar operations do, and no fused multiply-adds), so the
//! result is bit-identical to them: a run keeps reproducing its earlier losses exactly.

use rayon::prelude::*;

/// Elements per parallel task: below this a tensor is updated on the calling thread.
const CHUNK: usize = 1 << 14;

/// The scalars of one AdamW step for one parameter group, each already rounded to f32 as the
/// tensor operations round them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct AdamWScalars {
    /// Gradient-norm clipping factor.
    pub clip: f32,
    /// β₁ and 1 − β₁.
    pub beta1: f32,
    pub one_minus_beta1: f32,
    /// β₂ and 1 − β₂.
    pub beta2: f32,
    pub one_minus_beta2: f32,
    /// √(1 − β₂ᵗ), the second moment's bias correction.
    pub bias2_sqrt: f32,
    /// ε.
    pub epsilon: f32,
    /// lr / (1 − β₁ᵗ): the step size with the first moment's bias correction.
    pub step_size: f32,
    /// 1 − lr·λ: the decoupled weight decay's factor.
    pub decay: f32,
}

impl AdamWScalars {
    /// The scalars of step `step` (1-based) with learning rate `lr`, from the options' f64
    /// values.
    pub fn new(lr: f64, clip: f64, betas: (f64, f64), weight_decay: f64, epsilon: f64, step: usize) -> Self {
        let (b1, b2) = betas;
        let bias1 = 1.0 - b1.powi(step as i32);
        let bias2 = 1.0 - b2.powi(step as i32);
        Self {
            clip: clip as f32,
            beta1: b1 as f32,
            one_minus_beta1: (1.0 - b1) as f32,
            beta2: b2 as f32,
            one_minus_beta2: (1.0 - b2) as f32,
            bias2_sqrt: bias2.sqrt() as f32,
            epsilon: epsilon as f32,
            step_size: (lr / bias1) as f32,
            decay: (1.0 - lr * weight_decay) as f32,
        }
    }
}

/// One AdamW step of a parameter in place: `weight`, its gradient `grad` and its moments
/// `first` and `second` (all of one length). With `fresh` the moments start from zero (their
/// values are overwritten, as the first step's `m = (1 − β₁)·g` is).
///
/// # Panics
/// If the slices' lengths differ (a programming error: the trainer builds them together).
pub(crate) fn adamw_update(
    weight: &mut [f32],
    grad: &[f32],
    first: &mut [f32],
    second: &mut [f32],
    fresh: bool,
    s: AdamWScalars,
) {
    let n = weight.len();
    assert!(grad.len() == n && first.len() == n && second.len() == n, "adamw: slice lengths");
    let run = |w: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32]| {
        for (((w, &g), m), v) in w.iter_mut().zip(g).zip(m.iter_mut()).zip(v.iter_mut()) {
            let g = g * s.clip;
            if fresh {
                *m = g * s.one_minus_beta1;
                *v = g * g * s.one_minus_beta2;
            } else {
                *m = *m * s.beta1 + g * s.one_minus_beta1;
                *v = *v * s.beta2 + g * g * s.one_minus_beta2;
            }
            let denom = v.sqrt() / s.bias2_sqrt + s.epsilon;
            *w = *w * s.decay - *m / denom * s.step_size;
        }
    };
    if n < 2 * CHUNK {
        run(weight, grad, first, second);
        return;
    }
    weight
        .par_chunks_mut(CHUNK)
        .zip(grad.par_chunks(CHUNK))
        .zip(first.par_chunks_mut(CHUNK))
        .zip(second.par_chunks_mut(CHUNK))
        .for_each(|(((w, g), m), v)| run(w, g, m, v));
}

/// `average ← average·decay + value·(1 − decay)` in place, with both factors rounded to f32 as
/// the tensor operations round them.
///
/// # Panics
/// If the lengths differ.
pub(crate) fn moving_average(average: &mut [f32], value: &[f32], decay: f64) {
    assert_eq!(average.len(), value.len(), "moving average: slice lengths");
    let (keep, take) = (decay as f32, (1.0 - decay) as f32);
    let run = |a: &mut [f32], v: &[f32]| {
        for (a, &v) in a.iter_mut().zip(v) {
            *a = *a * keep + v * take;
        }
    };
    if average.len() < 2 * CHUNK {
        run(average, value);
        return;
    }
    average.par_chunks_mut(CHUNK).zip(value.par_chunks(CHUNK)).for_each(|(a, v)| run(a, v));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Tensor, TensorData, gaussian_noise};

    fn values(t: Tensor<1>) -> Vec<f32> {
        t.into_data().convert::<f32>().try_to_vec::<f32>().expect("f32 values")
    }

    /// The update and the moving average repeat the tensor operations they replace (the
    /// trainer's path on other backends) bit for bit: over a length that spans several
    /// parallel chunks plus a remainder, fresh and running moments, with clipping.
    #[test]
    fn slice_kernels_match_the_tensor_operations_bit_for_bit() {
        let device = crate::default_device();
        let n = 2 * CHUNK + 1234;
        let (b1, b2, wd, eps): (f64, f64, f64, f64) = (0.9, 0.999, 1e-2, 1e-8);
        let weight: Tensor<1> = gaussian_noise([n], 1, &device);
        let grad: Tensor<1> = gaussian_noise([n], 2, &device) * 0.1;
        let (mut first, mut second): (Tensor<1>, Tensor<1>) =
            (Tensor::zeros([n], &device), Tensor::zeros([n], &device));
        let mut w_host = values(weight.clone());
        let (mut m_host, mut v_host) = (vec![0.0f32; n], vec![0.0f32; n]);
        let mut w = weight;
        for step in 1..=3usize {
            let (lr, clip) = (3e-4 * step as f64, if step == 2 { 0.37 } else { 1.0 });
            // The tensor operations of the trainer's AdamW.
            let g = grad.clone() * clip;
            if step == 1 {
                first = g.clone() * (1.0 - b1);
                second = g.clone() * g * (1.0 - b2);
            } else {
                first = first * b1 + g.clone() * (1.0 - b1);
                second = second * b2 + g.clone() * g * (1.0 - b2);
            }
            let bias1 = 1.0 - b1.powi(step as i32);
            let bias2 = 1.0 - b2.powi(step as i32);
            let denom = second.clone().sqrt() / bias2.sqrt() + eps;
            let delta = first.clone() / denom * (lr / bias1);
            w = w * (1.0 - lr * wd) - delta;
            let s = AdamWScalars::new(lr, clip, (b1, b2), wd, eps, step);
            adamw_update(&mut w_host, &values(grad.clone()), &mut m_host, &mut v_host, step == 1, s);
            assert_eq!(values(w.clone()), w_host, "weights after step {step}");
            assert_eq!(values(first.clone()), m_host, "first moments after step {step}");
            assert_eq!(values(second.clone()), v_host, "second moments after step {step}");
        }
        let decay = 0.995;
        let average: Tensor<1> = gaussian_noise([n], 3, &device);
        let mut host = values(average.clone());
        moving_average(&mut host, &w_host, decay);
        let expected = average * decay + Tensor::from_data(TensorData::new(w_host, [n]), &device) * (1.0 - decay);
        assert_eq!(values(expected), host, "moving average");
    }
}
