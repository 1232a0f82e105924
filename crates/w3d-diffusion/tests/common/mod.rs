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

/// Largest absolute difference between `got` and `want`, relative to `want`'s largest
/// magnitude or 1, whichever is larger (values that are 0 up to rounding on both sides, such
/// as a gradient through a softmax over one key, then compare absolutely).
pub fn relative_max_diff(got: &[f32], want: &[f32]) -> f32 {
    assert_eq!(got.len(), want.len(), "lengths differ");
    let scale = want.iter().fold(0.0f32, |m, x| m.max(x.abs())).max(1.0);
    got.iter().zip(want).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max) / scale
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
/// Burn's ndarray backend, and with the `wgpu` feature wgpu on a hardware GPU, or on any
/// adapter (Mesa's software lavapipe included) when `W3D_TEST_SOFTWARE_GPU=1`, as
/// `cargo xtask gpu-check` sets it.
pub fn test_devices() -> Vec<(&'static str, Device)> {
    #[allow(unused_mut)]
    let mut devices = vec![("flex", w3d_diffusion::default_device())];
    #[cfg(feature = "ndarray")]
    devices.push(("ndarray", w3d_diffusion::ndarray_device()));
    #[cfg(feature = "wgpu")]
    if let Some(gpu) = wgpu_test_device() {
        devices.push(("wgpu", gpu));
    }
    devices
}

/// The wgpu device the tests use: a hardware GPU, or any adapter when
/// `W3D_TEST_SOFTWARE_GPU=1`.
#[cfg(feature = "wgpu")]
pub fn wgpu_test_device() -> Option<Device> {
    let opened = w3d_diffusion::ComputeDevice::Wgpu.open().ok()?;
    let software_ok = std::env::var("W3D_TEST_SOFTWARE_GPU").is_ok_and(|v| v == "1");
    (!opened.software || software_ok).then_some(opened.device)
}

/// Largest absolute difference between two value lists of the same length.
pub fn max_abs_vec(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len(), "lengths differ");
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

/// A red-to-blue shaded disc on transparent background, `side`² RGBA.
pub fn disc_image(side: u32) -> w3d_core::Image {
    let mut data = Vec::with_capacity((side * side * 4) as usize);
    let c = side as f32 / 2.0;
    for y in 0..side {
        for x in 0..side {
            let (dx, dy) = ((x as f32 + 0.5 - c) / c, (y as f32 + 0.5 - c) / c);
            let inside = dx * dx + dy * dy < 0.6;
            let t = y as f32 / side as f32;
            data.extend_from_slice(&[0.9 - 0.6 * t, 0.3, 0.2 + 0.6 * t, if inside { 1.0 } else { 0.0 }]);
        }
    }
    w3d_core::Image::new(side, side, 4, data).unwrap()
}
