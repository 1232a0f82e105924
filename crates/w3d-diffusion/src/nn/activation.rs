//! The GEGLU activation of the transformer blocks' feed-forward (diffusers' `GEGLU`).

use burn::tensor::activation::gelu;
use burn::tensor::{Tensor, TensorData};

#[cfg(feature = "train")]
use crate::kernels::autodiff;
use crate::kernels::dispatch::{cpu_inference_f32, cpu_values};

/// The GEGLU gate `hidden · gelu(gate)` (exact GELU) of the halves `[hidden, gate]` of the
/// last dimension of `projection`: `[n, t, 2·inner]` → `[n, t, inner]`.
///
/// On Burn's CPU backends this is the crate's kernel (one pass, on all cores), in training on
/// flex a single differentiable operation with a one-pass backward; elsewhere Burn's slice,
/// `gelu` and product. The kernel's arithmetic is flex's, so the values are the same either
/// way.
pub fn geglu(projection: Tensor<3>) -> Tensor<3> {
    let [n, t, two_inner] = projection.dims();
    let inner = two_inner / 2;
    if inner > 0 && cpu_inference_f32(&projection) {
        let device = projection.device();
        let out = crate::kernels::geglu::geglu(&cpu_values(projection), inner);
        return Tensor::from_data(TensorData::new(out, [n, t, inner]), &device);
    }
    #[cfg(feature = "train")]
    if let Some(strategy) = autodiff::geglu_applies(&projection) {
        return autodiff::geglu_op(projection, strategy);
    }
    let hidden = projection.clone().slice([0..n, 0..t, 0..inner]);
    let gate = projection.slice([0..n, 0..t, inner..two_inner]);
    hidden * gelu(gate)
}
