//! The training-free accelerations of sampling on the tiny multi-view checkpoint: each one
//! skips the work it claims (counted with `compute::count_work`, not timed), changes the
//! output by a bounded amount, and with every option off the loop is the plain guided loop
//! to the bit. Bad settings are refused before any pass runs.

mod common;

use common::{fixture, max_abs_diff, values};
use w3d_diffusion::compute::{self, PassSettings, Work};
use w3d_diffusion::models::unet::FeatureCache;
use w3d_diffusion::{
    Acceleration, Conditioning, DdimScheduler, MultiViewPipeline, SampleOptions, SamplerKind, Tensor, UNetExtra,
    classifier_free_guidance, prepare_input, switcher_labels,
};

fn tiny() -> (MultiViewPipeline, Conditioning) {
    let device = w3d_diffusion::default_device();
    let pipeline = MultiViewPipeline::from_dir(fixture("wonder3d_tiny"), &device).unwrap();
    let input = prepare_input(&common::disc_image(40), pipeline.image_size() as u32).unwrap();
    let cond = pipeline.condition(&input, &device).unwrap();
    (pipeline, cond)
}

/// The UNet's inputs for the conditional branch of the 12-image batch at timestep 500.
fn unet_inputs(pipeline: &MultiViewPipeline, cond: &Conditioning) -> (Tensor<4>, Tensor<3>, Tensor<2>) {
    let device = w3d_diffusion::default_device();
    let noise = pipeline.initial_noise(3, &device).repeat_dim(0, 2);
    let sample = Tensor::cat(vec![noise, cond.latent.clone().repeat_dim(0, 12)], 1);
    let d = cond.embeds.dims()[1];
    let context = cond.embeds.clone().reshape([1, 1, d]).repeat_dim(0, 12);
    let mut labels = switcher_labels(w3d_diffusion::Domain::Normal, Default::default(), 14).unwrap();
    labels.extend(switcher_labels(w3d_diffusion::Domain::Colour, Default::default(), 14).unwrap());
    let labels = Tensor::from_data(w3d_diffusion::TensorData::new(labels, [12, 14]), &device);
    (sample, context, labels)
}

fn sample(pipeline: &MultiViewPipeline, cond: &Conditioning, options: &SampleOptions) -> (Tensor<4>, Work) {
    let noise = pipeline.initial_noise(options.seed, &w3d_diffusion::default_device());
    compute::count_work(|| pipeline.sample_from(noise, cond, options, &mut |_, _| {}).unwrap())
}

#[test]
fn a_cached_pass_from_its_own_full_pass_is_the_full_pass() {
    let (pipeline, cond) = tiny();
    let unet = pipeline.unet();
    let (x, context, labels) = unet_inputs(&pipeline, &cond);
    let extra = UNetExtra::default();
    let (reference, full) =
        compute::count_work(|| unet.forward(x.clone(), &[500.0], context.clone(), Some(labels.clone())).unwrap());
    // The tiny UNet: skips conv_in, level-0 ResNet, down-sampler, level-1 ResNet; 2 + 2 up ResNets.
    assert_eq!(unet.skip_count(), 4);
    assert_eq!((full.unet_passes, full.resnet_blocks), (1, 8));
    // Level 0 of the tiny UNet has the multi-view transformers: one down, two up, plus the mid block's.
    assert_eq!(full.transformer_blocks, 4);
    for depth in 0..unet.skip_count() {
        let mut cache = FeatureCache::new(depth);
        let run = |cache: &mut FeatureCache, reuse: bool| {
            compute::count_work(|| {
                unet.forward_cached(x.clone(), &[500.0], context.clone(), Some(labels.clone()), &extra, cache, reuse)
                    .unwrap()
            })
        };
        // Nothing cached yet: a full pass even when asked to reuse, and it fills the cache.
        let (filled, work) = run(&mut cache, true);
        assert!(cache.is_filled());
        assert_eq!(work, full, "depth {depth}");
        assert_eq!(values(filled), values(reference.clone()), "depth {depth}: full pass");
        // The shallow branch on the same inputs recomputes the same numbers.
        let (shallow, work) = run(&mut cache, true);
        assert_eq!(values(shallow), values(reference.clone()), "depth {depth}: shallow pass");
        // Down ResNets up to the skip (skips 1 and 3 are ResNets) and the last depth + 1 up ResNets.
        let down = [0, 1, 1, 2][depth];
        assert_eq!(work.resnet_blocks, down + depth as u64 + 1, "depth {depth}");
        assert_eq!(work.unet_passes, 1);
        // Transformers: the down one with skip 1, the up ones with the last two up layers.
        let transformers = u64::from(depth >= 1) + (depth as u64 + 1).min(2);
        assert_eq!(work.transformer_blocks, transformers, "depth {depth}");
    }
    let mut deep = FeatureCache::new(4);
    let err =
        unet.forward_cached(x, &[500.0], context, Some(labels), &extra, &mut deep, false).unwrap_err().to_string();
    assert!(err.contains("cache depth") && err.contains("below 4"), "{err}");
}

#[test]
fn with_every_option_off_sampling_is_the_plain_guided_loop() {
    let (pipeline, cond) = tiny();
    let device = w3d_diffusion::default_device();
    let options = SampleOptions { steps: 4, guidance: 2.0, eta: 0.0, seed: 5, ..SampleOptions::default() };
    let (latents, work) = sample(&pipeline, &cond, &options);
    assert_eq!(work.unet_passes, 8);
    assert_eq!(work.bf16_multiply_adds, 0);
    // The textbook loop: DDIM, both branches every step, through UNet::forward.
    let scheduler = DdimScheduler::new(pipeline.scheduler().clone(), 4).unwrap();
    let (_, context, labels) = unet_inputs(&pipeline, &cond);
    let mut x = pipeline.initial_noise(5, &device).repeat_dim(0, 2);
    let latent = cond.latent.clone().repeat_dim(0, 12);
    for &t in scheduler.timesteps() {
        let unet = |latent: Tensor<4>, context: Tensor<3>| {
            let input = Tensor::cat(vec![x.clone(), latent], 1);
            pipeline.unet().forward(input, &[t as f32], context, Some(labels.clone())).unwrap()
        };
        let conditional = unet(latent.clone(), context.clone());
        let unconditional = unet(latent.zeros_like(), context.zeros_like());
        let eps = classifier_free_guidance(unconditional, conditional, 2.0);
        x = scheduler.step(eps, t, x, 0.0, None).unwrap();
    }
    assert_eq!(values(latents), values(x));
}

#[test]
fn deep_cache_skips_the_deep_layers_between_full_passes() {
    let (pipeline, cond) = tiny();
    for sampler in [SamplerKind::Ddim, SamplerKind::DpmSolverPlusPlus2M] {
        let base = SampleOptions { sampler, steps: 6, guidance: 2.0, eta: 0.0, seed: 9, ..SampleOptions::default() };
        let (reference, full) = sample(&pipeline, &cond, &base);
        let cached_options =
            SampleOptions { acceleration: Acceleration::default().with_cache_interval(3).with_cache_depth(1), ..base };
        let (cached, work) = sample(&pipeline, &cond, &cached_options);
        // 6 steps × 2 branches; steps 0 and 3 full (8 ResNets), the other 4 from skip 1 (3 ResNets).
        assert_eq!(full.resnet_blocks, 6 * 2 * 8);
        assert_eq!(work.unet_passes, 12);
        assert_eq!(work.resnet_blocks, 2 * 2 * 8 + 4 * 2 * 3, "{sampler:?}");
        assert_eq!(work.transformer_blocks, 2 * 2 * 4 + 4 * 2 * 3, "{sampler:?}");
        // A bounded change (measured 2026-12-07: 0.42 with DDIM, 0.64 with DPM-Solver++; the
        // tiny model's random weights are a worst case, trained deep features change more
        // slowly between steps).
        let diff = max_abs_diff(cached, reference.clone());
        eprintln!("{sampler:?}: DeepCache every 3 from skip 1 moves the latents by {diff:.4} (max abs)");
        assert!(diff > 0.0 && diff < 1.3, "{sampler:?}: {diff}");
        // Interval 1 is the reference, to the bit.
        let (same, _) = sample(
            &pipeline,
            &cond,
            &SampleOptions { acceleration: Acceleration::default().with_cache_depth(2), ..base },
        );
        assert_eq!(values(same), values(reference));
    }
}

#[test]
fn guidance_outside_its_interval_runs_the_conditional_branch_alone() {
    let (pipeline, cond) = tiny();
    let base = SampleOptions { steps: 5, guidance: 2.0, eta: 0.0, seed: 4, ..SampleOptions::default() };
    let (reference, _) = sample(&pipeline, &cond, &base);
    let options = SampleOptions { acceleration: Acceleration::default().with_guidance_interval([0.3, 0.7]), ..base };
    let (limited, work) = sample(&pipeline, &cond, &options);
    let scheduler = DdimScheduler::new(pipeline.scheduler().clone(), 5).unwrap();
    let train = pipeline.scheduler().num_train_timesteps;
    let guided = scheduler.timesteps().iter().filter(|&&t| options.acceleration.guided_at(t, train)).count();
    assert_eq!(guided, 2, "timesteps {:?}", scheduler.timesteps());
    assert_eq!(work.unet_passes, (5 + guided) as u64);
    let diff = max_abs_diff(limited, reference.clone());
    eprintln!("guidance in [0.3, 0.7] moves the latents by {diff:.4} (max abs)");
    // Measured 1.20 (2026-12-07): the random tiny model's two branches differ a lot.
    assert!(diff > 0.0 && diff < 2.5, "{diff}");
    // An empty interval is guidance 1; [0, 1] is the reference.
    let (none, work) = sample(
        &pipeline,
        &cond,
        &SampleOptions { acceleration: Acceleration::default().with_guidance_interval([0.0, 0.0]), ..base },
    );
    let (unguided, _) = sample(&pipeline, &cond, &SampleOptions { guidance: 1.0, ..base });
    assert_eq!(work.unet_passes, 5);
    assert_eq!(values(none), values(unguided));
    // Combined with DeepCache: the unconditional branch fills its own cache when it first runs.
    let both = SampleOptions {
        acceleration: Acceleration::default().with_guidance_interval([0.3, 0.7]).with_cache_interval(2),
        ..base
    };
    let (_, work) = sample(&pipeline, &cond, &both);
    assert_eq!(work.unet_passes, 7);
    assert!(work.resnet_blocks < 7 * 8, "{work:?}");
}

#[test]
fn nonsensical_settings_are_refused_before_any_pass() {
    let (pipeline, cond) = tiny();
    let base = SampleOptions { steps: 2, ..SampleOptions::default() };
    let with = |acceleration| SampleOptions { acceleration, ..base };
    let cases: [(SampleOptions, &str); 6] = [
        (with(Acceleration::default().with_cache_interval(0)), "cache_interval"),
        (with(Acceleration::default().with_cache_interval(51)), "cache_interval"),
        (with(Acceleration::default().with_guidance_interval([-0.1, 1.0])), "guidance_interval"),
        (with(Acceleration::default().with_guidance_interval([0.8, 0.2])), "guidance_interval"),
        (with(Acceleration::default().with_pass(PassSettings::default().with_token_merge(0.95))), "token_merge"),
        (with(Acceleration::default().with_cache_interval(2).with_cache_depth(4)), "cache_depth"),
    ];
    for (options, field) in cases {
        let noise = pipeline.initial_noise(1, &w3d_diffusion::default_device());
        let (result, work) = compute::count_work(|| pipeline.sample_from(noise, &cond, &options, &mut |_, _| {}));
        let err = result.unwrap_err().to_string();
        assert!(err.contains(field), "{field}: {err}");
        assert_eq!(work.unet_passes, 0, "{field}");
    }
    assert_eq!(SampleOptions::default().acceleration.describe(), "none");
}

#[test]
fn the_enhancer_skips_the_unconditional_rows_and_the_deep_layers_it_claims() {
    use w3d_diffusion::pipelines::enhancer::{EnhancerConditioning, EnhancerOptions, EnhancerPipeline};
    let device = w3d_diffusion::default_device();
    let pipeline = EnhancerPipeline::from_dir(fixture("enhancer"), &device).unwrap();
    let grids = (w3d_diffusion::gaussian_noise([2, 3, 64, 64], 1, &device) * 0.2 + 0.5).clamp(0.0, 1.0);
    let ip_image = w3d_core::Image::filled(32, 32, 3, 0.5).unwrap();
    let options = EnhancerOptions::default();
    let conditioning = EnhancerConditioning {
        prompts: pipeline.encode_prompts(&options).unwrap(),
        image: pipeline.image_tokens(&ip_image, &options, &device).unwrap(),
    };
    let init = pipeline.encode_grids(grids.clone(), w3d_diffusion::gaussian_noise([2, 4, 8, 8], 2, &device)).unwrap();
    let noise = w3d_diffusion::gaussian_noise([2, 4, 8, 8], 3, &device);
    let run = |acceleration: Acceleration| {
        let options = options.clone().with_acceleration(acceleration);
        compute::count_work(|| {
            pipeline
                .denoise(init.clone(), noise.clone(), grids.clone(), &conditioning, &options, &mut |_, _| {})
                .unwrap()
        })
    };
    let (reference, full) = run(Acceleration::default());
    assert_eq!(full.unet_passes, 10);
    // Guidance only at noise levels ≥ 0.15: of the timesteps 200, 180, …, 20, three keep it;
    // the other seven run the two conditional rows of four, half the attention.
    let (limited, work) = run(Acceleration::default().with_guidance_interval([0.15, 1.0]));
    assert_eq!(full.attention_scores % 20, 0);
    assert_eq!(work.attention_scores, full.attention_scores / 10 * 3 + full.attention_scores / 20 * 7);
    let diff = max_abs_diff(limited, reference.clone());
    eprintln!("enhancer, guidance in [0.15, 1]: latents moved by {diff:.4} (max abs)");
    // Measured 0.99 (2026-12-07): guidance 3 on random weights moves a lot.
    assert!(diff > 0.0 && diff < 2.0, "{diff}");
    // DeepCache every 2 steps from skip 1: steps 1, 3, … run the UNet and the ControlNet only
    // as far as skip 1 and back.
    let (cached, work) = run(Acceleration::default().with_cache_interval(2));
    assert!(work.resnet_blocks < full.resnet_blocks, "{work:?} against {full:?}");
    assert_eq!(work.unet_passes, full.unet_passes);
    let diff = max_abs_diff(cached, reference.clone());
    eprintln!("enhancer, DeepCache every 2: latents moved by {diff:.4} (max abs)");
    assert!(diff > 0.0 && diff < 0.5, "{diff}");
    // Off is the reference to the bit.
    let (same, _) = run(Acceleration::default().with_cache_depth(3));
    assert_eq!(values(same), values(reference));
}
