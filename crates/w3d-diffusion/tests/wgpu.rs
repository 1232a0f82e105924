//! The GPU path against the CPU (feature `wgpu`): the same models, inputs and noise on Burn's
//! wgpu backend and on flex agree within 1e-3 (f32). Run by `cargo xtask gpu-check`, which
//! provides Mesa's software Vulkan driver (lavapipe) on machines without a GPU and sets
//! `W3D_TEST_SOFTWARE_GPU=1`; on a machine with a GPU it checks that GPU. Without an adapter
//! these tests fail with a message saying how to get one (the test target needs the feature,
//! see Cargo.toml, and the feature is only built to run them).

mod common;

use common::{fixture, max_abs, max_abs_diff, max_abs_vec, tensor, values};
use w3d_core::Image;
use w3d_diffusion::{
    ComputeDevice, Device, MultiViewPipeline, SafetensorsFile, SampleOptions, SamplerKind, Tensor, UNet,
};

/// Largest difference allowed between wgpu and flex: f32 on both, different summation orders.
const TOLERANCE: f32 = 1e-3;

fn wgpu() -> Device {
    let opened = ComputeDevice::Wgpu.open().unwrap_or_else(|e| {
        panic!("{e}\n(install a Vulkan driver; without a GPU, Mesa's lavapipe: `apt-get install mesa-vulkan-drivers`)")
    });
    println!("adapter: {}", opened.description);
    common::wgpu_test_device().expect(
        "the only wgpu adapter is a software one; set W3D_TEST_SOFTWARE_GPU=1 to test on it (cargo xtask gpu-check does)",
    )
}

fn flex() -> Device {
    w3d_diffusion::default_device()
}

#[test]
fn the_tiny_multiview_unet_forward_matches_flex() {
    let (gpu, cpu) = (wgpu(), flex());
    let mut outputs = Vec::new();
    for device in [&gpu, &cpu] {
        let unet = UNet::from_dir(fixture("wonder3d_tiny/unet"), device).unwrap();
        let mut io = SafetensorsFile::open(fixture("multiview/unet_io.safetensors")).unwrap();
        let timesteps = values(tensor::<1>(&mut io, "timesteps", device));
        let out: Tensor<4> = unet
            .forward(
                tensor(&mut io, "sample", device),
                &timesteps,
                tensor(&mut io, "context", device),
                Some(tensor(&mut io, "class_labels_persp", device)),
            )
            .unwrap();
        outputs.push(values(out));
    }
    let err = max_abs_vec(&outputs[0], &outputs[1]);
    let scale = outputs[1].iter().fold(0.0f32, |m, v| m.max(v.abs()));
    println!(
        "tiny MV UNet forward (12 images, cross-domain attention): wgpu vs flex max-abs {err:.2e} (output max {scale:.2})"
    );
    assert!(err <= TOLERANCE, "wgpu vs flex: max-abs {err}");
}

#[test]
fn the_tiny_five_step_guided_pipeline_matches_flex() {
    let (gpu, cpu) = (wgpu(), flex());
    let mut io = SafetensorsFile::open(fixture("multiview/pipeline_io.safetensors")).unwrap();
    let (pixels, shape) = io.read_f32("image").unwrap();
    let input = Image::new(shape[1] as u32, shape[0] as u32, 3, pixels).unwrap();
    for sampler in [SamplerKind::Ddim, SamplerKind::DpmSolverPlusPlus2M] {
        let options = SampleOptions { sampler, steps: 5, guidance: 2.0, eta: 1.0, ..SampleOptions::default() };
        let mut runs = Vec::new();
        for device in [&gpu, &cpu] {
            let pipeline = MultiViewPipeline::from_dir(fixture("wonder3d_tiny"), device).unwrap();
            let cond = pipeline.condition(&input, device).unwrap();
            let noise = tensor(&mut io, "noise", device);
            let latents = pipeline.sample_from(noise, &cond, &options, &mut |_, _| {}).unwrap();
            let views = pipeline.decode(latents.clone(), options.camera).unwrap();
            let pixels: Vec<f32> = views.normals.iter().chain(&views.colours).flat_map(|i| i.data().to_vec()).collect();
            runs.push((values(cond.embeds), values(cond.latent), values(latents), pixels));
        }
        let (g, c) = (&runs[0], &runs[1]);
        let errors = [
            ("CLIP embedding", max_abs_vec(&g.0, &c.0)),
            ("VAE condition latent", max_abs_vec(&g.1, &c.1)),
            ("final latents", max_abs_vec(&g.2, &c.2)),
            ("decoded views", max_abs_vec(&g.3, &c.3)),
        ];
        for (what, err) in errors {
            println!("tiny pipeline, 5 {sampler:?} steps, guidance 2, eta 1: {what}: wgpu vs flex max-abs {err:.2e}");
            assert!(err <= TOLERANCE, "{sampler:?} {what}: wgpu vs flex max-abs {err}");
        }
    }
}

/// The shipped small model (`assets/model-small`, f16 weights), a real trained checkpoint at
/// 64² views, from a synthetic RGBA object: 5 DDIM steps at eta 1, views compared.
#[test]
fn the_shipped_small_model_generates_the_same_views_on_wgpu() {
    let (gpu, cpu) = (wgpu(), flex());
    let model = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/model-small");
    let rgba = common::disc_image(96);
    let options = SampleOptions { steps: 5, ..SampleOptions::default() };
    let mut runs = Vec::new();
    for device in [&gpu, &cpu] {
        let pipeline = MultiViewPipeline::from_dir(&model, device).unwrap();
        let views = pipeline.generate(&rgba, &options, device, &mut |_, _| {}).unwrap();
        runs.push(views.normals.iter().chain(&views.colours).flat_map(|i| i.data().to_vec()).collect::<Vec<f32>>());
    }
    let err = max_abs_vec(&runs[0], &runs[1]);
    println!("shipped small model, 5 DDIM steps at eta 1, 12 views at 64²: wgpu vs flex max-abs {err:.2e}");
    assert!(err <= TOLERANCE, "small model views: wgpu vs flex max-abs {err}");
}

#[test]
fn a_tensor_round_trips_through_the_device() {
    let gpu = wgpu();
    let t = w3d_diffusion::gaussian_noise([2, 3, 5, 7], 3, &gpu);
    let back = Tensor::<4>::from_data(t.clone().into_data(), &flex());
    let on_cpu = w3d_diffusion::gaussian_noise([2, 3, 5, 7], 3, &flex());
    assert_eq!(max_abs_diff(back, on_cpu), 0.0);
    assert!(max_abs(t) > 1.0);
}
