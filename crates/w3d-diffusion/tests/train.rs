//! Training (`w3d_diffusion::train`): the objective learns, the stage presets train what they
//! say and nothing else, accumulation averages, checkpoints round-trip, bad draws are refused.

mod common;
// The training-set reader's tests share this test binary (one link instead of two).
#[path = "train_cases/training_set.rs"]
mod training_set;

use std::collections::HashMap;

use common::{fixture, values};
use w3d_diffusion::train::{
    ConditionDrop, DiffusionObjective, LrSchedule, Stage, StepDraws, TrainBatch, TrainOptions, Trainer,
};
use w3d_diffusion::{Device, SchedulerConfig, Tensor, UNet, UNetConfig, gaussian_noise};

fn tiny_config() -> UNetConfig {
    UNetConfig::from_file(fixture("wonder3d_tiny").join("unet").join("config.json")).unwrap()
}

fn scheduler() -> SchedulerConfig {
    SchedulerConfig::from_file(fixture("wonder3d_tiny").join("scheduler").join("scheduler_config.json")).unwrap()
}

/// One object in both domains (12 images of 8×8 latents) with smooth, structured targets.
fn batch(device: &Device, seed: u64) -> TrainBatch {
    let latents = gaussian_noise([12, 4, 8, 8], seed, device) * 0.5;
    let condition = gaussian_noise([1, 4, 8, 8], seed + 1, device).repeat_dim(0, 12);
    let embeddings = gaussian_noise([1, 1, 16], seed + 2, device).repeat_dim(0, 12);
    let mut labels = Vec::new();
    for domain in 0..2 {
        for view in 0..6 {
            let v: Vec<f32> = (0..7).map(|i| if i == 5 + domain { 1.0 } else { 0.1 * view as f32 }).collect();
            labels.extend(v.iter().map(|x| x.sin()));
            labels.extend(v.iter().map(|x| x.cos()));
        }
    }
    TrainBatch {
        latents,
        condition_latents: condition,
        image_embeddings: embeddings,
        class_labels: Some(Tensor::from_data(w3d_diffusion::TensorData::new(labels, [12, 14]), device)),
        domains: 2,
    }
}

fn fixed_draws(device: &Device) -> StepDraws {
    StepDraws {
        timesteps: vec![250, 600],
        noise: gaussian_noise([12, 4, 8, 8], 99, device),
        condition_drops: vec![ConditionDrop::Keep],
    }
}

fn params_by_key(unet: &UNet) -> HashMap<String, Vec<f32>> {
    let dir = tempfile::tempdir().unwrap();
    unet.save(dir.path()).unwrap();
    let mut file =
        w3d_diffusion::SafetensorsFile::open(dir.path().join("diffusion_pytorch_model.safetensors")).unwrap();
    let keys: Vec<String> = file.shapes().map(|(k, _)| k.to_string()).collect();
    keys.into_iter().map(|k| (k.clone(), file.read_f32(&k).unwrap().0)).collect()
}

#[test]
fn a_fresh_tiny_model_fits_one_fixed_batch() {
    let device = w3d_diffusion::default_device();
    let unet = UNet::random(&tiny_config(), 7, &device).unwrap();
    let options = TrainOptions::for_stage(Stage::MixedDomain)
        .with_learning_rate(3e-3)
        .with_warmup_steps(0)
        .with_max_grad_norm(Some(1.0));
    let mut trainer = Trainer::new(unet, scheduler(), options).unwrap();
    let device = trainer.device();
    let batch = batch(&device, 3);
    let draws = fixed_draws(&device);
    let first = trainer.step_with(&batch, &draws).unwrap().loss;
    let mut last = first;
    for _ in 1..200 {
        last = trainer.step_with(&batch, &draws).unwrap().loss;
        if last * 5.0 < first {
            break;
        }
    }
    eprintln!("fixed batch: loss {first} → {last} in {} steps", trainer.steps());
    assert!(last * 5.0 < first, "loss {first} → {last} after {} steps: not a 5× drop", trainer.steps());
}

#[test]
fn gradient_checkpointing_gives_the_same_loss_gradients_and_step() {
    let device = w3d_diffusion::default_device();
    let unet = UNet::random(&tiny_config(), 5, &device).unwrap();
    let options = TrainOptions::for_stage(Stage::MixedDomain).with_warmup_steps(0);
    let mut plain = Trainer::new(unet.clone(), scheduler(), options.clone()).unwrap();
    let mut checkpointed = Trainer::new(unet, scheduler(), options.with_gradient_checkpointing(true)).unwrap();
    // The strategy is really on: the trainer's device (and so every batch made on it) carries it.
    assert_eq!(format!("{:?}", plain.device().gradient_checkpointing_strategy()), "Some(Disabled)");
    assert_eq!(format!("{:?}", checkpointed.device().gradient_checkpointing_strategy()), "Some(Balanced)");
    let (a, b) = (batch(&plain.device(), 3), batch(&checkpointed.device(), 3));
    let (draws_a, draws_b) = (fixed_draws(&plain.device()), fixed_draws(&checkpointed.device()));
    let (loss_a, grads_a) = plain.gradients(&a, &draws_a).unwrap();
    let (loss_b, grads_b) = checkpointed.gradients(&b, &draws_b).unwrap();
    assert!((loss_a - loss_b).abs() <= 1e-6 * loss_a.abs(), "loss {loss_a} vs {loss_b}");
    assert_eq!(grads_a.len(), grads_b.len());
    assert!(grads_a.len() > 100, "{} trained tensors", grads_a.len());
    for (ga, gb) in grads_a.iter().zip(&grads_b) {
        assert_eq!(ga.key, gb.key);
        let scale = ga.values.iter().fold(1e-12f32, |m, v| m.max(v.abs()));
        let err = ga.values.iter().zip(&gb.values).fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(err <= 1e-5 * scale, "{}: gradients differ by {err} (largest {scale})", ga.key);
    }
    for _ in 0..2 {
        plain.step_with(&a, &draws_a).unwrap();
        checkpointed.step_with(&b, &draws_b).unwrap();
    }
    let (pa, pb) = (params_by_key(&plain.inference_unet()), params_by_key(&checkpointed.inference_unet()));
    for (key, va) in &pa {
        let err = va.iter().zip(&pb[key]).fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(err <= 1e-6, "{key}: parameters differ by {err} after two steps");
    }
}

#[test]
fn the_moving_average_follows_diffusers_ema_and_survives_a_resume() {
    let device = w3d_diffusion::default_device();
    let unet = UNet::random(&tiny_config(), 13, &device).unwrap();
    let options = TrainOptions::for_stage(Stage::CrossDomain).with_warmup_steps(0).with_ema_decay(Some(0.5));
    let mut trainer = Trainer::new(unet, scheduler(), options.clone()).unwrap();
    let batch = batch(&trainer.device(), 9);
    let key = "mid_block.attentions.0.transformer_blocks.0.attn_joint_mid.to_q.weight";
    // Decays of steps 1, 2, 3: 0 (copy), min(0.5, 2/11), min(0.5, 3/12).
    let mut expected: Vec<f32> = Vec::new();
    for decay in [0.0f32, 2.0 / 11.0, 0.25] {
        trainer.step(&batch).unwrap();
        let current = &params_by_key(&trainer.inference_unet())[key];
        expected = if expected.is_empty() {
            current.clone()
        } else {
            expected.iter().zip(current).map(|(e, c)| e * decay + c * (1.0 - decay)).collect()
        };
    }
    let ema = params_by_key(&trainer.ema_unet().unwrap());
    let err = ema[key].iter().zip(&expected).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(err < 1e-6, "EMA differs from the formula by {err}");
    assert_ne!(ema[key], params_by_key(&trainer.inference_unet())[key], "the EMA is not the current weights");
    // Frozen parameters are the same in both.
    let conv = "conv_in.weight";
    assert_eq!(ema[conv], params_by_key(&trainer.inference_unet())[conv]);
    // The state round-trips: a trainer restored from it continues with the same average.
    let dir = tempfile::tempdir().unwrap();
    trainer.write_state(dir.path()).unwrap();
    let mut restored = Trainer::new(trainer.inference_unet(), scheduler(), options).unwrap();
    restored.load_state(dir.path()).unwrap();
    trainer.step(&batch).unwrap();
    restored.step(&batch).unwrap();
    assert_eq!(params_by_key(&trainer.ema_unet().unwrap())[key], params_by_key(&restored.ema_unet().unwrap())[key]);
    // Without EMA there is none, and a decay of 1 is refused by name.
    let plain = Trainer::new(trainer.inference_unet(), scheduler(), TrainOptions::for_stage(Stage::CrossDomain));
    assert!(plain.unwrap().ema_unet().is_none());
    let bad = TrainOptions::for_stage(Stage::CrossDomain).with_ema_decay(Some(1.0));
    let err = Trainer::new(trainer.inference_unet(), scheduler(), bad).unwrap_err().to_string();
    assert!(err.contains("ema_decay"), "{err}");
}

#[test]
fn stage_three_changes_only_the_joint_attention() {
    let device = w3d_diffusion::default_device();
    let unet = UNet::random(&tiny_config(), 11, &device).unwrap();
    let before = params_by_key(&unet);
    let options = TrainOptions::for_stage(Stage::CrossDomain).with_learning_rate(1e-3).with_warmup_steps(0);
    let mut trainer = Trainer::new(unet, scheduler(), options).unwrap();
    assert_eq!(trainer.trainable_tensors(), before.keys().filter(|k| k.contains("joint_mid")).count());
    let device = trainer.device();
    let batch = batch(&device, 5);
    for _ in 0..10 {
        assert!(trainer.step(&batch).unwrap().updated);
    }
    let after = params_by_key(&trainer.inference_unet());
    let mut changed = 0;
    for (key, old) in &before {
        let new = &after[key];
        if key.contains("attn_joint_mid.") || key.contains("norm_joint_mid.") {
            changed += usize::from(old != new);
        } else {
            assert!(old.iter().zip(new).all(|(a, b)| a.to_bits() == b.to_bits()), "{key} changed in stage 3");
        }
    }
    assert!(changed > 0, "no joint_mid parameter changed");
    // With train_all, stage 3 trains every parameter (Wonder3D v1's joint training).
    let unet = UNet::random(&tiny_config(), 11, &w3d_diffusion::default_device()).unwrap();
    let options = TrainOptions::for_stage(Stage::CrossDomain).with_train_all(true);
    assert_eq!(Trainer::new(unet, scheduler(), options).unwrap().trainable_tensors(), before.len());
}

#[test]
fn a_linear_schedule_cools_the_learning_rate_down_to_zero() {
    let device = w3d_diffusion::default_device();
    let unet = UNet::random(&tiny_config(), 11, &device).unwrap();
    let options = TrainOptions::for_stage(Stage::MixedDomain)
        .with_learning_rate(1e-3)
        .with_warmup_steps(2)
        .with_lr_schedule(LrSchedule::LinearToZero { end: 6 });
    let mut trainer = Trainer::new(unet, scheduler(), options.clone()).unwrap();
    let batch = batch(&trainer.device(), 5);
    let lrs: Vec<f64> = (0..7).map(|_| trainer.step(&batch).unwrap().learning_rate.unwrap()).collect();
    // Warm-up 0, 0.5; then from the peak at step 2 down to 0 at step 6, and 0 after.
    let expected = [0.0, 0.5, 1.0, 0.75, 0.5, 0.25, 0.0].map(|f| f * 1e-3);
    assert!(lrs.iter().zip(expected).all(|(a, b)| (a - b).abs() < 1e-15), "{lrs:?}");
    // A decay that would end inside the warm-up is refused, by name.
    let bad = options.with_lr_schedule(LrSchedule::LinearToZero { end: 2 });
    let err = Trainer::new(trainer.inference_unet(), scheduler(), bad).unwrap_err().to_string();
    assert!(err.contains("lr_schedule"), "{err}");
}

#[test]
fn stage_presets_follow_the_authors_configs() {
    assert_eq!(Stage::MultiDomain.learning_rate(), 1e-4);
    assert_eq!(Stage::MixedDomain.learning_rate(), 5e-5);
    assert_eq!(Stage::CrossDomain.learning_rate(), 2e-5);
    for stage in [Stage::MultiDomain, Stage::MixedDomain] {
        assert!(stage.trains("conv_in.weight") && stage.trains("class_embedding.linear_1.weight"));
    }
    let three = Stage::CrossDomain;
    assert!(three.trains("down_blocks.0.attentions.0.transformer_blocks.0.attn_joint_mid.to_q.weight"));
    assert!(three.trains("mid_block.attentions.0.transformer_blocks.0.norm_joint_mid.bias"));
    assert!(!three.trains("down_blocks.0.attentions.0.transformer_blocks.0.attn1.to_q.weight"));
    assert!(!three.trains("class_embedding.linear_1.weight"));
    let options = TrainOptions::for_stage(Stage::MixedDomain);
    assert_eq!((options.betas, options.weight_decay, options.epsilon), ((0.9, 0.999), 1e-2, 1e-8));
    assert_eq!((options.warmup_steps, options.max_grad_norm, options.min_snr_gamma), (100, Some(1.0), Some(5.0)));
    assert_eq!((options.class_embedding_lr_mult, options.condition_drop_rate), (10.0, 0.05));
    assert_eq!(Stage::from_number(3).unwrap(), Stage::CrossDomain);
    assert!(Stage::from_number(4).is_err());
}

#[test]
fn condition_dropout_has_the_three_cases_of_the_authors() {
    let p = 0.05;
    assert_eq!(ConditionDrop::from_uniform(0.01, p), ConditionDrop::Clip);
    assert_eq!(ConditionDrop::from_uniform(0.07, p), ConditionDrop::ClipAndImage);
    assert_eq!(ConditionDrop::from_uniform(0.12, p), ConditionDrop::Image);
    assert_eq!(ConditionDrop::from_uniform(0.16, p), ConditionDrop::Keep);
    assert_eq!(ConditionDrop::from_uniform(0.9, p), ConditionDrop::Keep);
}

#[test]
fn min_snr_weights_cap_the_easy_timesteps() {
    let objective = DiffusionObjective::new(scheduler(), Some(5.0)).unwrap();
    // Low t: SNR ≫ 5 → weight 5/SNR < 1; high t: SNR < 5 → weight 1.
    assert!(objective.weight(10) < 0.1);
    assert_eq!(objective.weight(900), 1.0);
    let plain = DiffusionObjective::new(scheduler(), None).unwrap();
    assert_eq!(plain.weight(10), 1.0);
}

#[test]
fn two_accumulated_copies_of_a_batch_step_like_one() {
    let device = w3d_diffusion::default_device();
    let run = |accumulation: usize| {
        let unet = UNet::random(&tiny_config(), 13, &device).unwrap();
        let options = TrainOptions::for_stage(Stage::MixedDomain)
            .with_learning_rate(1e-3)
            .with_warmup_steps(0)
            .with_gradient_accumulation(accumulation);
        let mut trainer = Trainer::new(unet, scheduler(), options).unwrap();
        let device = trainer.device();
        let (batch, draws) = (batch(&device, 21), fixed_draws(&device));
        for i in 0..accumulation {
            let log = trainer.step_with(&batch, &draws).unwrap();
            assert_eq!(log.updated, i + 1 == accumulation);
        }
        params_by_key(&trainer.inference_unet())
    };
    let (one, two) = (run(1), run(2));
    for (key, a) in &one {
        let worst = a.iter().zip(&two[key]).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        assert!(worst < 1e-6, "{key}: accumulated step differs by {worst}");
    }
}

#[test]
fn a_saved_checkpoint_loads_back_to_the_same_outputs() {
    let device = w3d_diffusion::default_device();
    let unet = UNet::random(&tiny_config(), 17, &device).unwrap();
    let options = TrainOptions::for_stage(Stage::MixedDomain).with_learning_rate(1e-3).with_warmup_steps(0);
    let mut trainer = Trainer::new(unet, scheduler(), options).unwrap();
    let batch_ad = batch(&trainer.device(), 31);
    trainer.step(&batch_ad).unwrap();
    let trained = trainer.inference_unet();
    let dir = tempfile::tempdir().unwrap();
    trained.save(dir.path()).unwrap();
    let loaded = UNet::from_dir(dir.path(), &device).unwrap();
    let b = batch(&device, 41);
    let input = Tensor::cat(vec![b.latents.clone(), b.condition_latents.clone()], 1);
    let t = [500.0f32; 12];
    let out =
        |u: &UNet| values(u.forward(input.clone(), &t, b.image_embeddings.clone(), b.class_labels.clone()).unwrap());
    assert_eq!(out(&trained), out(&loaded), "outputs differ after a save / load round trip");
}

#[test]
fn malformed_draws_and_options_are_refused_by_name() {
    let device = w3d_diffusion::default_device();
    let unet = UNet::random(&tiny_config(), 19, &device).unwrap();
    let bad = TrainOptions::for_stage(Stage::MixedDomain).with_condition_drop_rate(0.5);
    let e = Trainer::new(unet.clone(), scheduler(), bad).unwrap_err().to_string();
    assert!(e.contains("condition_drop_rate"), "{e}");
    let mut trainer = Trainer::new(unet, scheduler(), TrainOptions::for_stage(Stage::MixedDomain)).unwrap();
    let device = trainer.device();
    let batch = batch(&device, 1);
    let mut draws = fixed_draws(&device);
    draws.timesteps = vec![1];
    let e = trainer.step_with(&batch, &draws).unwrap_err().to_string();
    assert!(e.contains("draws.timesteps"), "{e}");
    draws.timesteps = vec![1, 5000];
    let e = trainer.step_with(&batch, &draws).unwrap_err().to_string();
    assert!(e.contains("draws.timesteps"), "{e}");
    let mut odd = batch.clone();
    odd.domains = 3;
    let e = trainer.step_with(&odd, &fixed_draws(&device)).unwrap_err().to_string();
    assert!(e.contains("batch.domains"), "{e}");
}

/// One training step against the PyTorch reference written from the authors' training script
/// (`xtask/python/fixtures_diffusion.py train_step`, on diffusers' modules): loss, gradients
/// of five named parameters, the clipped gradient norm and the parameters after AdamW.
#[test]
fn one_training_step_matches_the_pytorch_reference() {
    let mut file = w3d_diffusion::SafetensorsFile::open(fixture("train_step.safetensors")).unwrap();
    let read = |file: &mut w3d_diffusion::SafetensorsFile, key: &str| file.read_f32(key).unwrap().0;
    for (name, device) in common::test_devices() {
        let unet = UNet::from_dir(fixture("wonder3d_tiny").join("unet"), &device).unwrap();
        let options = TrainOptions::for_stage(Stage::MixedDomain).with_learning_rate(1e-3).with_warmup_steps(0);
        let mut trainer = Trainer::new(unet, scheduler(), options).unwrap();
        let d = trainer.device();
        let batch = TrainBatch {
            latents: common::tensor(&mut file, "latents", &d),
            condition_latents: common::tensor(&mut file, "condition_latents", &d),
            image_embeddings: common::tensor(&mut file, "image_embeddings", &d),
            class_labels: Some(common::tensor(&mut file, "class_labels", &d)),
            domains: 2,
        };
        let draws = StepDraws {
            timesteps: read(&mut file, "group_timesteps").iter().map(|&t| t as usize).collect(),
            noise: common::tensor(&mut file, "noise", &d),
            condition_drops: vec![ConditionDrop::Keep, ConditionDrop::ClipAndImage],
        };
        let (loss, grads) = trainer.gradients(&batch, &draws).unwrap();
        let expected_loss = read(&mut file, "loss")[0];
        let rel = ((loss - expected_loss) / expected_loss).abs();
        eprintln!("{name}: loss {loss} vs {expected_loss} (relative {rel:.2e})");
        assert!(rel < 1e-5, "{name}: loss {loss} vs PyTorch {expected_loss}");
        for key in [
            "conv_in.weight",
            "down_blocks.0.attentions.0.transformer_blocks.0.attn1.to_q.weight",
            "down_blocks.0.attentions.0.transformer_blocks.0.attn_joint_mid.to_k.weight",
            "class_embedding.linear_1.weight",
            "conv_out.weight",
        ] {
            let ours = grads.iter().find(|g| g.key == key).unwrap_or_else(|| panic!("{name}: no gradient for {key}"));
            let (expected, shape) = file.read_f32(&format!("grad.{key}")).unwrap();
            assert_eq!(ours.shape, shape, "{name}: {key} gradient shape");
            let scale = expected.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            let worst = ours.values.iter().zip(&expected).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
            eprintln!("{name}: grad {key}: max |Δ| {worst:.2e} of max |g| {scale:.2e}");
            assert!(worst <= 1e-4 * scale, "{name}: gradient of {key} differs by {worst} (scale {scale})");
        }
        let log = trainer.step_with(&batch, &draws).unwrap();
        let expected_norm = read(&mut file, "grad_norm")[0];
        let norm = log.grad_norm.unwrap();
        assert!(((norm - expected_norm) / expected_norm).abs() < 1e-4, "{name}: grad norm {norm} vs {expected_norm}");
        let after = params_by_key(&trainer.inference_unet());
        for key in [
            "conv_in.weight",
            "down_blocks.0.attentions.0.transformer_blocks.0.attn1.to_q.weight",
            "down_blocks.0.attentions.0.transformer_blocks.0.attn_joint_mid.to_k.weight",
            "class_embedding.linear_1.weight",
            "conv_out.weight",
        ] {
            // AdamW's first step moves each parameter by lr·g/(|g| + ε): where |g| is near
            // ε = 1e-8 the step turns f32 rounding of the gradient (≈1e-8 here) into a visible
            // difference, so the 1e-6 bound applies where |g| ≥ 1e-6 (100 ε) and the rest is
            // bounded by the step itself (2·lr).
            let expected = read(&mut file, &format!("after.{key}"));
            let reference_grad = read(&mut file, &format!("grad.{key}"));
            let (mut worst, mut worst_ill, mut ill) = (0.0f32, 0.0f32, 0usize);
            for ((a, b), g) in after[key].iter().zip(&expected).zip(&reference_grad) {
                let diff = (a - b).abs();
                if g.abs() >= 1e-6 {
                    worst = worst.max(diff);
                } else {
                    ill += 1;
                    worst_ill = worst_ill.max(diff);
                }
            }
            eprintln!(
                "{name}: after AdamW {key}: max |Δ| {worst:.2e} where |g| ≥ 1e-6; {ill} of {} with |g| < 1e-6: max |Δ| {worst_ill:.2e}",
                expected.len()
            );
            assert!(worst <= 1e-6, "{name}: {key} after one AdamW step differs by {worst}");
            assert!(worst_ill <= 2e-3, "{name}: {key} moved by more than one step ({worst_ill})");
        }
    }
}

#[test]
fn a_saved_pipeline_loads_back_with_identical_models() {
    let device = w3d_diffusion::default_device();
    let pipeline = w3d_diffusion::MultiViewPipeline::from_dir(fixture("wonder3d_tiny"), &device).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("model");
    pipeline.save(&out).unwrap();
    for sub in [
        "unet/config.json",
        "vae/config.json",
        "image_encoder/model.safetensors",
        "scheduler/scheduler_config.json",
        "model_index.json",
    ] {
        assert!(out.join(sub).is_file(), "{sub} missing");
    }
    let loaded = w3d_diffusion::MultiViewPipeline::from_dir(&out, &device).unwrap();
    let size = pipeline.image_size() as u32;
    let data: Vec<f32> = (0..size * size * 3).map(|i| ((i * 37 % 255) as f32) / 255.0).collect();
    let image = w3d_core::Image::new(size, size, 3, data).unwrap();
    let (a, b) = (pipeline.condition(&image, &device).unwrap(), loaded.condition(&image, &device).unwrap());
    assert_eq!(values(a.embeds), values(b.embeds), "CLIP embeddings differ after a round trip");
    assert_eq!(values(a.latent), values(b.latent), "VAE latents differ after a round trip");
    assert_eq!(pipeline.scheduler(), loaded.scheduler());
    assert_eq!(pipeline.unet().config().cd_attention_mid, loaded.unet().config().cd_attention_mid);
    // Saving again over the folder replaces it whole.
    loaded.save(&out).unwrap();
    assert!(w3d_diffusion::MultiViewPipeline::from_dir(&out, &device).is_ok());
}

#[test]
fn stage_three_starts_from_stage_two_with_a_silent_joint_attention() {
    let device = w3d_diffusion::default_device();
    let mut config = tiny_config();
    config.cd_attention_mid = false;
    let two = UNet::random(&config, 23, &device).unwrap();
    let three = two.with_cross_domain_attention(5).unwrap();
    assert!(three.config().cd_attention_mid);
    let (before, after) = (params_by_key(&two), params_by_key(&three));
    for (key, v) in &before {
        assert_eq!(&after[key], v, "{key} changed when adding the joint attention");
    }
    let joint: Vec<&String> = after.keys().filter(|k| k.contains("joint_mid.")).collect();
    assert!(!joint.is_empty() && after.len() == before.len() + joint.len());
    for key in joint.iter().filter(|k| k.ends_with("to_out.0.weight")) {
        assert!(after[*key].iter().all(|&w| w == 0.0), "{key} must start at zero");
    }
    assert!(three.with_cross_domain_attention(5).is_err(), "adding the joint attention twice must be refused");
}

#[test]
fn from_pretrained_2d_widens_conv_in_and_adds_the_switcher_embedding() {
    let device = w3d_diffusion::default_device();
    // A single-view, 4-channel UNet of the tiny shape stands for SD image variations.
    let mut sd = tiny_config();
    sd.in_channels = 4;
    sd.class_embed_type = None;
    sd.projection_class_embeddings_input_dim = None;
    sd.cd_attention_mid = false;
    sd.num_views = None;
    let source = UNet::random(&sd, 29, &device).unwrap();
    let dir = tempfile::tempdir().unwrap();
    source.save(dir.path()).unwrap();
    let weights = dir.path().join("diffusion_pytorch_model.safetensors");
    let mv = UNet::from_pretrained_2d(&tiny_config(), &weights, 3, &device).unwrap();
    let (src, dst) = (params_by_key(&source), params_by_key(&mv));
    let (w_src, w_dst) = (&src["conv_in.weight"], &dst["conv_in.weight"]);
    let (out, k) = (32, 9);
    for o in 0..out {
        for c in 0..8 {
            for i in 0..k {
                let v = w_dst[(o * 8 + c) * k + i];
                if c < 4 {
                    assert_eq!(v, w_src[(o * 4 + c) * k + i]);
                } else {
                    assert_eq!(v, 0.0, "image-latent channels of conv_in start at zero");
                }
            }
        }
    }
    let attn1 = "down_blocks.0.attentions.0.transformer_blocks.0.attn1.to_q.weight";
    assert_eq!(src[attn1], dst[attn1]);
    assert!(dst.contains_key("class_embedding.linear_1.weight"));
    // A key the multi-view model needs that is neither new nor in the file is an error.
    let mut wider = tiny_config();
    wider.block_out_channels = vec![32, 48];
    let e = UNet::from_pretrained_2d(&wider, &weights, 3, &device).unwrap_err().to_string();
    assert!(e.contains("wrong shape"), "{e}");
}

#[test]
fn half_precision_checkpoints_round_each_weight_to_f16() {
    let device = w3d_diffusion::default_device();
    let unet = UNet::random(&tiny_config(), 31, &device).unwrap();
    let dir = tempfile::tempdir().unwrap();
    unet.save_with(dir.path(), w3d_diffusion::Precision::F16).unwrap();
    let f32_bytes = {
        let other = tempfile::tempdir().unwrap();
        unet.save(other.path()).unwrap();
        std::fs::metadata(other.path().join("diffusion_pytorch_model.safetensors")).unwrap().len()
    };
    let f16_bytes = std::fs::metadata(dir.path().join("diffusion_pytorch_model.safetensors")).unwrap().len();
    assert!(f16_bytes * 10 < f32_bytes * 6, "f16 file {f16_bytes} B vs f32 {f32_bytes} B");
    let loaded = UNet::from_dir(dir.path(), &device).unwrap();
    let (a, b) = (params_by_key(&unet), params_by_key(&loaded));
    for (key, v) in &a {
        let rounded: Vec<f32> = v.iter().map(|x| half::f16::from_f32(*x).to_f32()).collect();
        assert_eq!(&rounded, &b[key], "{key}");
    }
}
