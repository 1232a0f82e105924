//! Shared helpers of the w3d-diffusion integration tests: fixture paths, tensor loading and
//! comparisons.
#![allow(dead_code)]

use std::path::PathBuf;

use w3d_diffusion::{Device, SafetensorsFile, Tensor, TensorData};

/// `tests/fixtures/<name>` of this crate (written by `cargo xtask fixtures diffusion`).
pub fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests").join("fixtures").join(name)
}

/// Tensor `key` of `file` on `device`.
pub fn tensor<const D: usize>(file: &mut SafetensorsFile, key: &str, device: &Device) -> Tensor<D> {
    let (values, shape) = file.read_f32(key).unwrap();
    let shape: [usize; D] = shape.try_into().unwrap_or_else(|s| panic!("{key}: rank {D} expected, shape {s:?}"));
    Tensor::from_data(TensorData::new(values, shape), device)
}

/// Values of `t` as a flat vector.
pub fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().unwrap()
}

/// Largest absolute difference between two tensors of the same shape.
pub fn max_abs_diff<const D: usize>(a: Tensor<D>, b: Tensor<D>) -> f32 {
    assert_eq!(a.dims(), b.dims(), "shapes differ");
    values(a).iter().zip(values(b)).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

/// Largest absolute value of a tensor.
pub fn max_abs<const D: usize>(a: Tensor<D>) -> f32 {
    values(a).iter().fold(0.0f32, |m, v| m.max(v.abs()))
}

/// The backends every parity test runs on: flex (the default), with the `ndarray` feature
/// Burn's ndarray backend, and with the `wgpu` feature on a host with a hardware GPU, wgpu.
pub fn test_devices() -> Vec<(&'static str, Device)> {
    #[allow(unused_mut)]
    let mut devices = vec![("flex", w3d_diffusion::default_device())];
    #[cfg(feature = "ndarray")]
    devices.push(("ndarray", w3d_diffusion::ndarray_device()));
    #[cfg(feature = "wgpu")]
    if let Some(gpu) = w3d_diffusion::gpu_device() {
        devices.push(("wgpu", gpu));
    }
    devices
}
