//! What a sampling loop adds around the scheduler: classifier-free guidance and seeded
//! Gaussian noise.

use burn::tensor::{Device, Tensor, TensorData};

/// Classifier-free guidance: `uncond + scale · (cond − uncond)`.
pub fn classifier_free_guidance<const D: usize>(uncond: Tensor<D>, cond: Tensor<D>, scale: f64) -> Tensor<D> {
    uncond.clone() + (cond - uncond) * scale
}

/// Standard-normal noise of `shape` from `seed` (SplitMix64 + Box–Muller): the same seed gives
/// the same values on every backend.
pub fn gaussian_noise<const D: usize>(shape: [usize; D], seed: u64, device: &Device) -> Tensor<D> {
    let n: usize = shape.iter().product();
    let mut state = seed;
    let mut next = move || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let mut values = Vec::with_capacity(n);
    while values.len() < n {
        let (u1, u2) = (next(), next());
        let r = (-2.0 * u1.ln()).sqrt();
        let a = std::f64::consts::TAU * u2;
        values.push((r * a.cos()) as f32);
        if values.len() < n {
            values.push((r * a.sin()) as f32);
        }
    }
    Tensor::from_data(TensorData::new(values, shape), device)
}
