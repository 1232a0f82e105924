//! Which backend a tensor lives on, and the tensor-level glue between Burn's tensors and the
//! slice kernels of this folder: whether a kernel may take a tensor, its values as a `Vec`,
//! half-precision weights widened to f32 on all cores.

use burn::backend::DispatchDevice;
use burn::tensor::{DType, FloatDType, Tensor, TensorData};

/// `t` in f32: weights held in half precision ([`crate::WeightStorage::F16`]) are widened
/// where they are used, one layer at a time, so the arithmetic is f32 whatever the storage.
pub(crate) fn as_f32<const D: usize>(t: Tensor<D>) -> Tensor<D> {
    if t.dtype() == DType::F32 {
        return t;
    }
    widen_f16_on_cpu(&t).unwrap_or_else(|| t.cast(FloatDType::F32))
}

/// Values converted per parallel task by [`widen_f16_on_cpu`].
const WIDEN_CHUNK: usize = 1 << 16;

/// An f16 tensor on a CPU backend widened to f32 with the `half` crate's vectorised slice
/// conversion (F16C where the CPU has it), on all cores; `None` for other dtypes, devices or an
/// autodiff graph. Burn's `cast` on flex converts one element at a time on one core, which
/// cost several seconds of every real-size guided step with f16 weights (`docs/benchmarks.md`).
fn widen_f16_on_cpu<const D: usize>(t: &Tensor<D>) -> Option<Tensor<D>> {
    use half::slice::HalfFloatSliceExt;
    use rayon::prelude::*;
    if t.dtype() != DType::F16 || t.is_autodiff() || !on_cpu_backend(&t.device()) {
        return None;
    }
    let data = t.clone().into_data();
    let narrow = data.as_slice::<half::f16>().ok()?;
    let mut wide = vec![0.0f32; narrow.len()];
    wide.par_chunks_mut(WIDEN_CHUNK)
        .zip(narrow.par_chunks(WIDEN_CHUNK))
        .for_each(|(wide, narrow)| narrow.convert_to_f32_slice(wide));
    Some(Tensor::from_data(TensorData::new(wide, t.shape()), &t.device()))
}

#[cfg(feature = "train")]
/// Whether `device` is Burn's flex backend (with or without autodiff).
pub(crate) fn on_flex(device: &burn::tensor::Device) -> bool {
    matches!(device.clone().inner().as_dispatch(), DispatchDevice::Flex(_))
}

/// Whether `device` belongs to one of Burn's CPU backends (flex; ndarray with the feature),
/// where the crate's own CPU kernels may run on the tensors' memory.
pub(crate) fn on_cpu_backend(device: &burn::tensor::Device) -> bool {
    match device.clone().inner().as_dispatch() {
        DispatchDevice::Flex(_) => true,
        #[cfg(feature = "ndarray")]
        DispatchDevice::NdArray(_) => true,
        // GPU backends (feature `wgpu`) and autodiff; unreachable in a build with flex alone.
        #[allow(unreachable_patterns)]
        _ => false,
    }
}

/// Whether the crate's CPU inference kernels (attention, GEGLU) may take `t`: f32 values on a
/// CPU backend, with no autodiff graph to keep.
pub(crate) fn cpu_inference_f32<const D: usize>(t: &Tensor<D>) -> bool {
    t.dtype() == DType::F32 && !t.is_autodiff() && on_cpu_backend(&t.device())
}

/// The values of a tensor [`cpu_inference_f32`] accepted. Taken by value: a tensor that holds
/// its values alone (the output of a projection) on flex gives them up without a copy.
pub(crate) fn cpu_values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec::<f32>().expect("f32 values (checked by cpu_inference_f32)")
}
