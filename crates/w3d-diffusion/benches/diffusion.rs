//! `cargo xtask bench diffusion`: the real-size UNet forward (batch 2 × 8 × 32 × 32, the
//! Wonder3D base config, random weights) on flex (and ndarray with the `ndarray` feature), and
//! the UNet's convolution layers with the backend `conv2d` (direct) against im2col + GEMM, and one guided denoising
//! step of the real-size multi-view cross-domain UNet (12 images at 32×32 latents, 24 UNet
//! images with guidance, `configs/wonder3d/unet_mv`) on the same backends — only with
//! `W3D_BENCH_MV_STEP=1` (`W3D_BENCH_MV_STEP=1 cargo bench -p w3d-diffusion --bench diffusion --
//! mv_step`): one iteration takes minutes on 2 cores and the models need ~8 GiB. The xtask then times diffusers on torch CPU with the same config and
//! input as the single-view forward (xtask/python/bench_diffusion_torch.py).
//!
//! `attention_*`: `nn::multi_head_attention` at the five shapes of the multi-view step's
//! attention (multi-view attention over 6 views at 32², 16² and 8², cross-domain attention at
//! 32² and 16²), against torch's `scaled_dot_product_attention` in the same xtask run.
#![allow(missing_docs)] // criterion_group! generates an undocumented function

use std::path::PathBuf;
use std::time::Duration;

use burn::module::Param;
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use w3d_diffusion::nn::{Conv2d, ConvAlgorithm, multi_head_attention};
use w3d_diffusion::{
    ClipVision, ClipVisionConfig, Conditioning, Device, MultiViewPipeline, SampleOptions, SchedulerConfig, UNet,
    UNetConfig, Vae, VaeConfig, gaussian_noise,
};

fn config_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs/wonder3d").join(name)
}

fn unet_config() -> UNetConfig {
    UNetConfig::from_file(config_path("unet/config.json")).expect("real UNet config")
}

/// Flex, and with the `ndarray` feature Burn's ndarray backend.
fn devices() -> Vec<(&'static str, Device)> {
    #[allow(unused_mut)]
    let mut devices = vec![("flex", w3d_diffusion::default_device())];
    #[cfg(feature = "ndarray")]
    devices.push(("ndarray", w3d_diffusion::ndarray_device()));
    devices
}

fn unet_forward(c: &mut Criterion) {
    let mut group = c.benchmark_group("unet_forward_b2_32x32");
    group.sample_size(10).measurement_time(Duration::from_secs(30)).warm_up_time(Duration::from_secs(1));
    for (name, device) in devices() {
        let unet = UNet::random(&unet_config(), 1, &device).expect("unet");
        let sample = gaussian_noise([2, 8, 32, 32], 1, &device);
        let context = gaussian_noise([2, 1, 768], 2, &device);
        let labels = gaussian_noise([2, 14], 3, &device);
        group.bench_function(name, |b| {
            b.iter(|| {
                let out =
                    unet.forward(sample.clone(), &[500.0], context.clone(), Some(labels.clone())).expect("forward");
                out.into_data().try_to_vec::<f32>().expect("values")
            })
        });
    }
    group.finish();
}

/// The distinct convolution layers of the real UNet at batch 2 (32×32 latents):
/// (name, c_in, c_out, side, kernel, stride, padding).
const CONV_LAYERS: &[(&str, usize, usize, usize, usize, usize, usize)] = &[
    ("conv_in 8>320 @32", 8, 320, 32, 3, 1, 1),
    ("res 320>320 @32", 320, 320, 32, 3, 1, 1),
    ("down 320 s2 @32", 320, 320, 32, 3, 2, 1),
    ("res 640>640 @16", 640, 640, 16, 3, 1, 1),
    ("res 1280>1280 @8", 1280, 1280, 8, 3, 1, 1),
    ("res 1280>1280 @4", 1280, 1280, 4, 3, 1, 1),
    ("up res 2560>1280 @8", 2560, 1280, 8, 3, 1, 1),
    ("up res 960>320 @32", 960, 320, 32, 3, 1, 1),
    ("up res 640>320 @32", 640, 320, 32, 3, 1, 1),
    ("proj 1x1 320 @32", 320, 320, 32, 1, 1, 0),
];

fn conv_layers(c: &mut Criterion) {
    let device = w3d_diffusion::default_device();
    let mut group = c.benchmark_group("conv_b2_flex");
    group.sample_size(10).measurement_time(Duration::from_secs(3)).warm_up_time(Duration::from_millis(500));
    for &(name, c_in, c_out, side, k, stride, pad) in CONV_LAYERS {
        let x = gaussian_noise([2, c_in, side, side], 1, &device);
        let conv = Conv2d {
            weight: Param::from_tensor(gaussian_noise([c_out, c_in, k, k], 2, &device) * 0.01),
            bias: Some(Param::from_tensor(gaussian_noise([c_out], 3, &device))),
            stride,
            padding: pad,
        };
        for algorithm in [ConvAlgorithm::Direct, ConvAlgorithm::Im2col, ConvAlgorithm::Auto] {
            group.bench_with_input(
                BenchmarkId::new(format!("{algorithm:?}"), name),
                &algorithm,
                |bench, &algorithm| {
                    bench.iter(|| {
                        conv.forward_with(x.clone(), algorithm).into_data().try_to_vec::<f32>().expect("values")
                    })
                },
            );
        }
    }
    group.finish();
}

/// The attention shapes of one guided step of the real-size multi-view UNet (both guidance
/// branches of 12 images, 6 views × 2 domains): name, sequences, tokens per sequence (queries =
/// keys), channels (8 heads). `mv`: multi-view attention, one sequence per branch and domain
/// over its 6 views' tokens; `cd`: cross-domain attention, one sequence per branch and view
/// over its normal and colour tokens. Each runs in 5 transformer blocks per level; the 8²
/// level's cross-domain attention (128 tokens) is left out as negligible.
const ATTENTION_SHAPES: &[(&str, usize, usize, usize)] = &[
    ("mv32", 4, 6144, 320),
    ("mv16", 4, 3072, 640),
    ("mv8", 4, 1536, 1280),
    ("cd32", 12, 2048, 320),
    ("cd16", 12, 512, 640),
];

fn attention_shapes(c: &mut Criterion) {
    for &(name, batch, tokens, channels) in ATTENTION_SHAPES {
        let mut group = c.benchmark_group(format!("attention_{name}"));
        group.sample_size(10).measurement_time(Duration::from_secs(10)).warm_up_time(Duration::from_millis(500));
        for (backend, device) in devices() {
            let [q, k, v] = [1, 2, 3].map(|seed| gaussian_noise([batch, tokens, channels], seed, &device));
            group.bench_function(backend, |b| {
                b.iter(|| {
                    let out = multi_head_attention(q.clone(), k.clone(), v.clone(), 8);
                    out.into_data().try_to_vec::<f32>().expect("values")
                })
            });
        }
        group.finish();
    }
}

/// One guided DDIM step of the real-size multi-view pipeline (random weights) per backend.
fn multiview_step(c: &mut Criterion) {
    if std::env::var_os("W3D_BENCH_MV_STEP").is_none() {
        return;
    }
    let mut group = c.benchmark_group("mv_step_b12_cfg_32x32");
    group.sample_size(10).measurement_time(Duration::from_secs(60)).warm_up_time(Duration::from_millis(1));
    for (name, device) in devices() {
        let unet =
            UNet::random(&UNetConfig::from_file(config_path("unet_mv/config.json")).expect("config"), 1, &device);
        let vae = Vae::random(&VaeConfig::from_file(config_path("vae/config.json")).expect("config"), 2, &device);
        let clip_config = ClipVisionConfig::from_file(config_path("image_encoder/config.json")).expect("config");
        let clip = ClipVision::random(&clip_config, 3, &device);
        let scheduler = SchedulerConfig::from_file(config_path("scheduler/scheduler_config.json")).expect("config");
        let pipeline = MultiViewPipeline::new(unet.expect("unet"), vae.expect("vae"), clip.expect("clip"), scheduler)
            .expect("pipeline");
        let cond = Conditioning {
            embeds: gaussian_noise([1, 768], 4, &device),
            latent: gaussian_noise([1, 4, 32, 32], 5, &device),
        };
        let options = SampleOptions { steps: 1, guidance: 2.0, eta: 1.0, ..SampleOptions::default() };
        let noise = pipeline.initial_noise(6, &device);
        group.bench_function(name, |b| {
            b.iter(|| {
                let latents = pipeline.sample_from(noise.clone(), &cond, &options, &mut |_, _| {}).expect("step");
                latents.into_data().try_to_vec::<f32>().expect("values")
            })
        });
    }
    group.finish();
}

criterion_group!(benches, attention_shapes, conv_layers, unet_forward, multiview_step);
criterion_main!(benches);
