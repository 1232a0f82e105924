//! The real-size Wonder3D base configs parse; the real-size models instantiate and run one
//! forward within 8 GiB peak memory, the real-size ControlNet has the published parameter
//! count, one guided step of the real-size enhancer (SD1.5 UNet + ControlNet at 128² latents,
//! `real_size_enhancer_step`), and one guided denoising step of the real-size
//! multi-view UNet (12 images at 32×32 latents, 24 UNet images with guidance) is timed with its
//! peak memory on each test backend, with f32 and with f16 weight storage (`W3D_STEP_WEIGHTS=f32` or
//! `f16` for one of them; ignored by default: slow; run with
//! `cargo test --release --workspace --test parity full_size:: -- --ignored --nocapture --test-threads 1`).

use std::path::PathBuf;
use std::time::Instant;

use burn::module::Module;
use w3d_diffusion::{
    ClipVision, ClipVisionConfig, Conditioning, ControlNet, ControlNetConfig, DdimScheduler, MultiViewPipeline,
    SampleOptions, SchedulerConfig, Tensor, UNet, UNetConfig, Vae, VaeConfig, WeightStorage, gaussian_noise,
};

use crate::common::test_devices;

fn config(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs").join("wonder3d").join(path)
}

fn enhancer_config(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs").join("enhancer").join(path)
}

/// Peak resident memory of this process in bytes (`VmHWM`).
fn peak_rss() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    let line = status.lines().find(|l| l.starts_with("VmHWM:")).unwrap();
    line.split_whitespace().nth(1).unwrap().parse::<u64>().unwrap() * 1024
}

#[test]
fn real_configs_parse() {
    let unet = UNetConfig::from_file(config("unet/config.json")).unwrap();
    assert_eq!((unet.heads(0).unwrap(), unet.time_embed_dim(), unet.in_channels), (8, 1280, 8));
    let mv = UNetConfig::from_file(config("unet_mv/config.json")).unwrap();
    assert_eq!((mv.views(), mv.cd_attention_mid, mv.multiview_mid_block()), (6, true, true));
    let vae = VaeConfig::from_file(config("vae/config.json")).unwrap();
    assert_eq!(vae.downscale(), 8);
    let clip = ClipVisionConfig::from_file(config("image_encoder/config.json")).unwrap();
    assert_eq!(clip.patches_per_side(), 16);
    let scheduler = SchedulerConfig::from_file(config("scheduler/scheduler_config.json")).unwrap();
    assert_eq!(scheduler, SchedulerConfig::stable_diffusion());
    assert_eq!(DdimScheduler::new(scheduler, 50).unwrap().timesteps()[0], 981);
    let controlnet = ControlNetConfig::from_file(enhancer_config("controlnet/config.json")).unwrap();
    assert_eq!((controlnet.unet.heads(2).unwrap(), controlnet.control_downscale()), (8, 8));
}

/// Wonder3D++'s SD1.5 ControlNet at real size: the parameter counts of diffusers'
/// `ControlNetModel` (361 279 120) and of the MVControlNet with its joint attention
/// (385 053 200, the 1.54 GB f32 file), and one forward's 12 + 1 residual shapes.
#[test]
#[ignore = "slow: real-size ControlNet (~1.5 GB of weights)"]
fn real_size_controlnet_has_the_published_parameter_count() {
    let device = w3d_diffusion::default_device();
    let c = ControlNetConfig::from_file(enhancer_config("controlnet/config.json")).unwrap();
    let stock = ControlNet::random(&c, false, 1, &device).unwrap();
    assert_eq!(stock.num_params(), 361_279_120);
    drop(stock);
    let t = Instant::now();
    let mv = ControlNet::random(&c, true, 1, &device).unwrap();
    println!("controlnet built in {:.1} s", t.elapsed().as_secs_f64());
    assert_eq!(mv.num_params(), 385_053_200);
    assert_eq!(mv.named_parameters().iter().filter(|p| p.key.contains("joint_mid.")).count(), 49);
    let t = Instant::now();
    let residuals = mv
        .forward(
            Tensor::zeros([2, 4, 16, 16], &device),
            &[500.0],
            Tensor::zeros([2, 77, 768], &device),
            Tensor::zeros([2, 3, 128, 128], &device),
            1.0,
        )
        .unwrap();
    println!("controlnet forward (2 × 16² latents) in {:.1} s", t.elapsed().as_secs_f64());
    let shapes: Vec<[usize; 4]> = residuals.down.iter().map(|r| r.dims()).collect();
    let level = |c: usize, s: usize| [2, c, s, s];
    assert_eq!(
        shapes,
        [
            level(320, 16),
            level(320, 16),
            level(320, 16),
            level(320, 8),
            level(640, 8),
            level(640, 8),
            level(640, 4),
            level(1280, 4),
            level(1280, 4),
            level(1280, 2),
            level(1280, 2),
            level(1280, 2),
        ]
    );
    assert_eq!(residuals.mid.dims(), [2, 1280, 2, 2]);
}

#[test]
#[ignore = "slow: real-size models (~4 GB of weights)"]
fn real_size_models_run_within_8_gib() {
    let device = w3d_diffusion::default_device();
    let gib = |b: u64| b as f64 / (1u64 << 30) as f64;

    let t = Instant::now();
    let unet = UNet::random(&UNetConfig::from_file(config("unet/config.json")).unwrap(), 1, &device).unwrap();
    println!("unet built in {:.1} s, peak RSS {:.2} GiB", t.elapsed().as_secs_f64(), gib(peak_rss()));
    let t = Instant::now();
    let out = unet
        .forward(
            Tensor::zeros([2, 8, 32, 32], &device),
            &[500.0],
            Tensor::zeros([2, 1, 768], &device),
            Some(Tensor::zeros([2, 14], &device)),
        )
        .unwrap();
    assert_eq!(out.dims(), [2, 4, 32, 32]);
    let values = out.into_data().try_to_vec::<f32>().unwrap();
    assert!(values.iter().all(|v| v.is_finite()));
    println!("unet forward (2 x 8 x 32 x 32) {:.1} s, peak RSS {:.2} GiB", t.elapsed().as_secs_f64(), gib(peak_rss()));
    drop(unet);

    let vae = Vae::random(&VaeConfig::from_file(config("vae/config.json")).unwrap(), 2, &device).unwrap();
    let t = Instant::now();
    let latent = vae.encode_mean(Tensor::zeros([1, 3, 256, 256], &device)).unwrap();
    assert_eq!(latent.dims(), [1, 4, 32, 32]);
    let image = vae.decode(latent).unwrap();
    assert_eq!(image.dims(), [1, 3, 256, 256]);
    println!("vae encode + decode 256² {:.1} s, peak RSS {:.2} GiB", t.elapsed().as_secs_f64(), gib(peak_rss()));
    drop(vae);

    let clip =
        ClipVision::random(&ClipVisionConfig::from_file(config("image_encoder/config.json")).unwrap(), 3, &device)
            .unwrap();
    let t = Instant::now();
    let embeds = clip.image_embeds(Tensor::zeros([1, 3, 224, 224], &device)).unwrap();
    assert_eq!(embeds.dims(), [1, 768]);
    println!("clip 224² {:.1} s, peak RSS {:.2} GiB", t.elapsed().as_secs_f64(), gib(peak_rss()));
    assert!(peak_rss() < 8 << 30, "peak RSS {:.2} GiB", gib(peak_rss()));
}

/// Resets the peak-RSS counter (`VmHWM`) to the current RSS.
fn reset_peak_rss() {
    std::fs::write("/proc/self/clear_refs", "5").unwrap();
}

#[test]
#[ignore = "slow: real-size multi-view UNet (~0.9 G parameters), one guided step per backend"]
fn real_size_multiview_guided_step() {
    let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
    // f16 first: memory freed by a run stays with the allocator and would count in the next.
    // `W3D_STEP_WEIGHTS=f16` or `f32` times one storage only.
    let storages: Vec<WeightStorage> = match std::env::var("W3D_STEP_WEIGHTS").as_deref() {
        Ok("f16") => vec![WeightStorage::F16],
        Ok("f32") => vec![WeightStorage::F32],
        _ => vec![WeightStorage::F16, WeightStorage::F32],
    };
    for ((name, device), storage) in
        test_devices().into_iter().flat_map(|d| storages.iter().map(move |&s| (d.clone(), s)))
    {
        let name = format!("{name}, {storage:?} weights");
        let t = Instant::now();
        let unet_config = UNetConfig::from_file(config("unet_mv/config.json")).unwrap();
        let unet = UNet::random_with(&unet_config, 1, &device, storage).unwrap();
        let params = unet.num_params();
        let vae =
            Vae::random_with(&VaeConfig::from_file(config("vae/config.json")).unwrap(), 2, &device, storage).unwrap();
        let clip_config = ClipVisionConfig::from_file(config("image_encoder/config.json")).unwrap();
        let clip = ClipVision::random_with(&clip_config, 3, &device, storage).unwrap();
        let scheduler = SchedulerConfig::from_file(config("scheduler/scheduler_config.json")).unwrap();
        let pipeline = MultiViewPipeline::new(unet, vae, clip, scheduler).unwrap();
        println!(
            "{name}: MV UNet {:.1} M parameters; models built in {:.1} s",
            params as f64 / 1e6,
            t.elapsed().as_secs_f64()
        );
        let cond = Conditioning {
            embeds: gaussian_noise([1, 768], 4, &device),
            latent: gaussian_noise([1, 4, 32, 32], 5, &device),
        };
        let options = SampleOptions { steps: 1, guidance: 2.0, eta: 1.0, ..SampleOptions::default() };
        let noise = pipeline.initial_noise(6, &device);
        reset_peak_rss();
        let rss_models = peak_rss();
        let t = Instant::now();
        let latents = pipeline.sample_from(noise, &cond, &options, &mut |_, _| {}).unwrap();
        let values = latents.into_data().try_to_vec::<f32>().unwrap();
        let seconds = t.elapsed().as_secs_f64();
        assert_eq!(values.len(), 12 * 4 * 32 * 32);
        assert!(values.iter().all(|v| v.is_finite()));
        println!(
            "{name}: one guided step (24 x 8 x 32 x 32 through the MV UNet + DDIM) {seconds:.1} s; RSS with all models {:.2} GiB, peak during the step {:.2} GiB",
            gib(rss_models),
            gib(peak_rss())
        );
    }
}

/// One guided denoising step of the refinement enhancer at real size: the SD1.5 UNet (f16
/// weights) and Wonder3D++'s ControlNet with cross-domain attention on the 4 guidance rows
/// of a 1024² grid pair (128² latents), 77 text tokens, then guidance and a UniPC step — the
/// cost of one of the 10 (first iteration) or 5 (later ones) steps of an enhancer call. The
/// IP-Adapter's image attention (4 tokens per cross-attention) is left out: it adds a few
/// thousandths of the step's arithmetic. Timed, with peak memory.
#[test]
#[ignore = "slow: real-size enhancer (SD1.5 UNet + ControlNet, ~1.2 G parameters), one guided step at 128² latents"]
fn real_size_enhancer_step() {
    use w3d_diffusion::{UNetExtra, UniPcMultistepScheduler, classifier_free_guidance};
    let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
    let device = w3d_diffusion::default_device();
    let t = Instant::now();
    let unet_config = UNetConfig::from_file(enhancer_config("unet/config.json")).unwrap();
    let unet = UNet::random_with(&unet_config, 1, &device, WeightStorage::F16).unwrap();
    let control_config = ControlNetConfig::from_file(enhancer_config("controlnet/config.json")).unwrap();
    let controlnet = ControlNet::random(&control_config, true, 2, &device).unwrap();
    println!(
        "SD1.5 UNet {:.1} M + ControlNet {:.1} M parameters, built in {:.1} s",
        unet.num_params() as f64 / 1e6,
        controlnet.num_params() as f64 / 1e6,
        t.elapsed().as_secs_f64()
    );
    let latents: Tensor<4> = gaussian_noise([2, 4, 128, 128], 3, &device);
    let control: Tensor<4> = gaussian_noise([4, 3, 1024, 1024], 4, &device).clamp(0.0, 1.0);
    let context: Tensor<3> = gaussian_noise([4, 77, 768], 5, &device);
    let mut scheduler = UniPcMultistepScheduler::new(UniPcMultistepScheduler::stable_diffusion_config(), 50).unwrap();
    scheduler.set_begin_index(40).unwrap();
    let timestep = scheduler.run_timesteps()[0];
    reset_peak_rss();
    let rss_models = peak_rss();
    let t = Instant::now();
    let rows = Tensor::cat(vec![latents.clone(), latents.clone()], 0);
    let residuals = controlnet.forward(rows.clone(), &[timestep as f32], context.clone(), control, 0.7).unwrap();
    let t_control = t.elapsed().as_secs_f64();
    let extra = UNetExtra { control: Some(residuals), ip: None };
    let out = unet.forward_with(rows, &[timestep as f32], context, None, &extra).unwrap();
    let eps = classifier_free_guidance(out.clone().narrow(0, 0, 2), out.narrow(0, 2, 2), 3.0);
    let next = scheduler.step(eps, timestep, latents).unwrap();
    let values = next.into_data().try_to_vec::<f32>().unwrap();
    let seconds = t.elapsed().as_secs_f64();
    assert!(values.iter().all(|v| v.is_finite()));
    println!(
        "one enhancer step (ControlNet {t_control:.1} s + UNet, 4 rows at 128²): {seconds:.1} s; RSS with the models {:.2} GiB, peak during the step {:.2} GiB",
        gib(rss_models),
        gib(peak_rss())
    );
}
