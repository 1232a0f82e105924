//! `cargo xtask bench train`: one optimizer step (forward, backward, gradient clipping, AdamW)
//! of the multi-view cross-domain UNet on one object's 12 images (6 views × normal and
//! colour), the whole UNet trained, for the tiny test checkpoint (`tests/fixtures/wonder3d_tiny`,
//! 8×8 latents) and the small model's configurations (`configs/small/unet` and the half width
//! `configs/small/unet-half`, 16×16 latents, random weights), on flex (and ndarray with the `ndarray` feature). The xtask then times the same step in PyTorch on the CPU
//! (xtask/python/bench_train_torch.py) and records the ratios.
#![allow(missing_docs)] // criterion_group! generates an undocumented function

use std::path::PathBuf;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use w3d_diffusion::train::{ConditionDrop, Stage, StepDraws, TrainBatch, TrainOptions, Trainer};
use w3d_diffusion::{Device, SchedulerConfig, Tensor, TensorData, UNet, UNetConfig, gaussian_noise};

fn crate_path(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// The small model's UNet from `configs/small/<dir>` with random weights and the cross-domain
/// attention of stage 3.
fn small_unet(dir: &str, device: &Device) -> UNet {
    let config =
        UNetConfig::from_file(crate_path("configs/small").join(dir).join("config.json")).expect("small config");
    UNet::random(&config, 3, device).and_then(|u| u.with_cross_domain_attention(4)).expect("small UNet")
}

/// (name, UNet, scheduler, latent side) of each configuration on `device`.
fn models(device: &Device) -> Vec<(&'static str, UNet, SchedulerConfig, usize)> {
    let tiny = crate_path("tests/fixtures/wonder3d_tiny");
    let small_scheduler =
        || SchedulerConfig::from_file(crate_path("configs/small/scheduler/scheduler_config.json")).expect("scheduler");
    vec![
        (
            "tiny",
            UNet::from_dir(tiny.join("unet"), device).expect("tiny UNet"),
            SchedulerConfig::from_file(tiny.join("scheduler/scheduler_config.json")).expect("scheduler"),
            8,
        ),
        ("small", small_unet("unet", device), small_scheduler(), 16),
        // The half width the shipped small model is trained at (docs/training.md).
        ("small-half", small_unet("unet-half", device), small_scheduler(), 16),
    ]
}

/// One object in both domains: 12 images, the switcher labels of the 6 views.
fn batch(unet: &UNet, side: usize, device: &Device) -> TrainBatch {
    let context = unet.config().cross_attention_dim;
    let mut labels = Vec::new();
    for domain in 0..2 {
        for view in 0..6 {
            let v: Vec<f32> = (0..7).map(|i| if i == 5 + domain { 1.0 } else { 0.1 * view as f32 }).collect();
            labels.extend(v.iter().map(|x| x.sin()));
            labels.extend(v.iter().map(|x| x.cos()));
        }
    }
    TrainBatch {
        latents: gaussian_noise([12, 4, side, side], 1, device),
        condition_latents: gaussian_noise([1, 4, side, side], 2, device).repeat_dim(0, 12),
        image_embeddings: gaussian_noise([1, 1, context], 3, device).repeat_dim(0, 12),
        class_labels: Some(Tensor::from_data(TensorData::new(labels, [12, 14]), device)),
        domains: 2,
    }
}

fn train_step(c: &mut Criterion) {
    let mut group = c.benchmark_group("train_step");
    group.sample_size(10).measurement_time(Duration::from_secs(20)).warm_up_time(Duration::from_secs(2));
    #[allow(unused_mut)]
    let mut devices = vec![("flex", w3d_diffusion::default_device())];
    #[cfg(feature = "ndarray")]
    devices.push(("ndarray", w3d_diffusion::ndarray_device()));
    for (backend, device) in devices {
        for (name, unet, scheduler, side) in models(&device) {
            let batch = batch(&unet, side, &device);
            let options = TrainOptions::for_stage(Stage::MixedDomain).with_warmup_steps(0).with_learning_rate(1e-4);
            let mut trainer = Trainer::new(unet, scheduler, options).expect("trainer");
            let device = trainer.device();
            let batch = TrainBatch {
                latents: batch.latents.to_device(&device),
                condition_latents: batch.condition_latents.to_device(&device),
                image_embeddings: batch.image_embeddings.to_device(&device),
                class_labels: batch.class_labels.map(|l| l.to_device(&device)),
                domains: 2,
            };
            let draws = StepDraws {
                timesteps: vec![250, 600],
                noise: gaussian_noise([12, 4, side, side], 4, &device),
                condition_drops: vec![ConditionDrop::Keep],
            };
            group.bench_function(format!("{name}/{backend}"), |b| {
                b.iter(|| trainer.step_with(&batch, &draws).expect("step").loss)
            });
        }
    }
    group.finish();
}

criterion_group!(benches, train_step);
criterion_main!(benches);
