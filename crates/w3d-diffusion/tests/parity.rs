//! Parity with diffusers / transformers on tiny random-weight models (fixtures from
//! `cargo xtask fixtures diffusion`): UNet, VAE encode/decode, CLIP image embeddings and
//! preprocessing, each within 1e-4 max-abs on both CPU backends; the CLIP text encoder and BPE
//! tokenizer (`parity_cases/clip_text.rs`); the ControlNet and the UNet with its residuals
//! (`parity_cases/controlnet.rs`); the IP-Adapter (`parity_cases/ip_adapter.rs`); one whole
//! enhancer call (`parity_cases/enhancer.rs`). The kernels' gradient cases need the `train`
//! feature (Burn's autodiff); without it their helpers and imports go unused.
#![cfg_attr(not(feature = "train"), allow(unused_imports, dead_code))]

#[path = "parity_cases/attention.rs"]
mod attention;
#[path = "parity_cases/clip_text.rs"]
mod clip_text;
mod common;
#[path = "parity_cases/controlnet.rs"]
mod controlnet;
#[path = "parity_cases/enhancer.rs"]
mod enhancer;
#[path = "parity_cases/geglu.rs"]
mod geglu;
#[path = "parity_cases/group_norm.rs"]
#[cfg(feature = "train")]
mod group_norm;
// The conv tests share this test binary (one link instead of two).
#[path = "parity_cases/conv.rs"]
mod conv;
#[path = "parity_cases/full_size.rs"]
mod full_size;
#[path = "parity_cases/linear.rs"]
#[cfg(feature = "train")]
mod linear;
// The IP-Adapter (enhancer) parity and error cases.
#[path = "parity_cases/ip_adapter.rs"]
mod ip_adapter;

use common::{fixture, max_abs, max_abs_diff, tensor, test_devices, values};
use w3d_diffusion::{ClipVision, SafetensorsFile, Tensor, TensorData, UNet, Vae, clip_preprocess};

#[test]
fn unet_matches_diffusers() {
    for (name, device) in test_devices() {
        let unet = UNet::from_dir(fixture("unet"), &device).unwrap();
        let mut io = SafetensorsFile::open(fixture("unet/io.safetensors")).unwrap();
        let timesteps: Vec<f32> = values(tensor::<1>(&mut io, "timesteps", &device));
        let out = unet
            .forward(
                tensor(&mut io, "sample", &device),
                &timesteps,
                tensor(&mut io, "context", &device),
                Some(tensor(&mut io, "class_labels", &device)),
            )
            .unwrap();
        let expected: Tensor<4> = tensor(&mut io, "out", &device);
        let scale = max_abs(expected.clone());
        let err = max_abs_diff(out, expected);
        println!("{name}: unet max-abs error {err:.2e} (output max {scale:.2})");
        assert!(err <= 1e-4, "{name}: unet max-abs error {err}");
    }
}

#[test]
fn vae_encode_and_decode_match_diffusers() {
    for (name, device) in test_devices() {
        let vae = Vae::from_dir(fixture("vae"), &device).unwrap();
        let mut io = SafetensorsFile::open(fixture("vae/io.safetensors")).unwrap();
        let mean = vae.encode_mean(tensor(&mut io, "image", &device)).unwrap();
        let err_enc = max_abs_diff(mean, tensor(&mut io, "mean", &device));
        let decoded = vae.decode(tensor(&mut io, "latents", &device)).unwrap();
        let err_dec = max_abs_diff(decoded, tensor(&mut io, "decoded", &device));
        println!("{name}: vae encode {err_enc:.2e}, decode {err_dec:.2e}");
        assert!(err_enc <= 1e-4 && err_dec <= 1e-4, "{name}: encode {err_enc}, decode {err_dec}");
        assert_eq!(vae.config().scaling_factor, 0.18215);
    }
}

#[test]
fn clip_image_embeddings_match_transformers() {
    for (name, device) in test_devices() {
        let clip = ClipVision::from_dir(fixture("clip"), &device).unwrap();
        let mut io = SafetensorsFile::open(fixture("clip/io.safetensors")).unwrap();
        let embeds = clip.image_embeds(tensor(&mut io, "pixels", &device)).unwrap();
        let err = max_abs_diff(embeds, tensor(&mut io, "embeds", &device));
        println!("{name}: clip max-abs error {err:.2e}");
        assert!(err <= 1e-4, "{name}: clip max-abs error {err}");
    }
}

#[test]
fn clip_preprocessing_matches_the_image_processor() {
    let device = w3d_diffusion::default_device();
    let mut io = SafetensorsFile::open(fixture("clip/io.safetensors")).unwrap();
    let (rgb, shape) = io.read_f32("rgb").unwrap();
    let ours = clip_preprocess(&rgb, shape[1], shape[0], 30).unwrap();
    let expected: Tensor<4> = tensor(&mut io, "pixels", &device);
    let expected = values(expected.slice([0..1, 0..3, 0..30, 0..30]));
    // PIL resamples 8-bit images in fixed point: allow one 8-bit level (1/255/std).
    let one_level = 1.0 / 255.0 / 0.26;
    let err = ours.iter().zip(&expected).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
    let mean_err = ours.iter().zip(&expected).map(|(a, b)| (a - b).abs()).sum::<f32>() / ours.len() as f32;
    println!("preprocess max error {err:.2e}, mean {mean_err:.2e} (one level = {one_level:.2e})");
    assert!(err <= one_level * 1.01, "max error {err}");
    // The embeddings of our preprocessing stay close to the reference embeddings.
    let clip = ClipVision::from_dir(fixture("clip"), &device).unwrap();
    let pixels = Tensor::<4>::from_data(TensorData::new(ours, [1, 3, 30, 30]), &device);
    let ours = clip.image_embeds(pixels).unwrap();
    let reference: Tensor<2> = tensor(&mut io, "embeds", &device);
    let err = max_abs_diff(ours, reference.slice([0..1, 0..12]));
    assert!(err <= 1e-2, "embedding error from preprocessing {err}");
}
