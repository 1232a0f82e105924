//! The Wonder3D++ multi-view cross-domain UNet and pipeline against the fixture script's
//! PyTorch reference (diffusers blocks + the multi-view / cross-domain processors written from
//! the design reference), on a tiny checkpoint with the real key names: UNet forward for both
//! camera types (both domains in each batch), the switcher labels, a 5-step guided pipeline,
//! view-permutation equivariance, the domain switcher, the fresh cross-domain initialisation,
//! legacy key names, seeding, inversion, input preprocessing and the view-set conversion; the
//! second cross-domain attention (`cd_attention_last`, its own tiny checkpoint and reference
//! forward), the authors' inference values for a config that lacks them, and the 8-bit input.

mod common;

use std::collections::HashMap;

use common::{fixture, max_abs, max_abs_diff, max_abs_vec, tensor, test_devices, values};
use w3d_core::{Image, ViewSet};
use w3d_diffusion::pipelines::multiview::{DRAWS_PER_PASS, NUM_VIEWS};
use w3d_diffusion::{
    CameraType, Domain, GeneratedViews, MultiViewPipeline, SafetensorsFile, SampleOptions, SamplerKind, Tensor,
    TensorData, UNet, UNetConfig, WeightStorage, prepare_input, switcher_labels,
};

fn unet_io() -> SafetensorsFile {
    SafetensorsFile::open(fixture("multiview/unet_io.safetensors")).unwrap()
}

/// Rows `order` of a batch tensor.
fn rows<const D: usize>(t: &Tensor<D>, order: &[usize]) -> Tensor<D> {
    let parts = order
        .iter()
        .map(|&i| {
            let mut ranges: [std::ops::Range<usize>; D] = std::array::from_fn(|d| 0..t.dims()[d]);
            ranges[0] = i..i + 1;
            t.clone().slice(ranges)
        })
        .collect();
    Tensor::cat(parts, 0)
}

#[test]
fn switcher_labels_match_the_reference() {
    let device = w3d_diffusion::default_device();
    let mut io = unet_io();
    for (camera, name) in [(CameraType::Orthographic, "ortho"), (CameraType::Perspective, "persp")] {
        let mut ours = switcher_labels(Domain::Normal, camera, 14).unwrap();
        ours.extend(switcher_labels(Domain::Colour, camera, 14).unwrap());
        let expected = values(tensor::<2>(&mut io, &format!("class_labels_{name}"), &device));
        let err = ours.iter().zip(&expected).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
        assert!(err <= 1e-6, "{name}: label error {err}");
    }
    // Wonder3D v1's 10-d labels have no camera switcher: the same values without it.
    let v1 = switcher_labels(Domain::Colour, CameraType::Orthographic, 10).unwrap();
    let plus = switcher_labels(Domain::Colour, CameraType::Orthographic, 14).unwrap();
    assert_eq!(v1.len(), 60);
    assert_eq!(v1[..3], plus[..3]);
    assert_eq!(v1[3..5], plus[5..7]);
    assert!(switcher_labels(Domain::Normal, CameraType::Perspective, 10).is_err());
}

#[test]
fn multiview_unet_matches_the_reference_for_both_domains_and_cameras() {
    for (name, device) in test_devices() {
        let unet = UNet::from_dir(fixture("wonder3d_tiny/unet"), &device).unwrap();
        assert_eq!((unet.config().views(), unet.config().cd_attention_mid), (6, true));
        let mut io = unet_io();
        let timesteps = values(tensor::<1>(&mut io, "timesteps", &device));
        for camera in ["ortho", "persp"] {
            let out = unet
                .forward(
                    tensor(&mut io, "sample", &device),
                    &timesteps,
                    tensor(&mut io, "context", &device),
                    Some(tensor(&mut io, &format!("class_labels_{camera}"), &device)),
                )
                .unwrap();
            let expected: Tensor<4> = tensor(&mut io, &format!("out_{camera}"), &device);
            let scale = max_abs(expected.clone());
            let [n, c, h, w] = expected.dims();
            for (domain, range) in [("normal", 0..n / 2), ("colour", n / 2..n)] {
                let half = |t: &Tensor<4>| t.clone().slice([range.clone(), 0..c, 0..h, 0..w]);
                let err = max_abs_diff(half(&out), half(&expected));
                println!("{name} {camera} {domain}: max-abs error {err:.2e} (output max {scale:.2})");
                assert!(err <= 1e-4, "{name} {camera} {domain}: max-abs error {err}");
            }
        }
    }
}

#[test]
fn permuting_the_views_permutes_the_output() {
    let device = w3d_diffusion::default_device();
    let unet = UNet::from_dir(fixture("wonder3d_tiny/unet"), &device).unwrap();
    let mut io = unet_io();
    let sample: Tensor<4> = tensor(&mut io, "sample", &device);
    let context: Tensor<3> = tensor(&mut io, "context", &device);
    let labels: Tensor<2> = tensor(&mut io, "class_labels_ortho", &device);
    let out = unet.forward(sample.clone(), &[421.0], context.clone(), Some(labels.clone())).unwrap();
    // The same permutation of the six views in both domain halves (labels travel with views).
    let perm = [3, 0, 5, 1, 4, 2];
    let order: Vec<usize> = perm.iter().copied().chain(perm.iter().map(|i| i + NUM_VIEWS)).collect();
    let permuted =
        unet.forward(rows(&sample, &order), &[421.0], rows(&context, &order), Some(rows(&labels, &order))).unwrap();
    let err = max_abs_diff(permuted, rows(&out, &order));
    assert!(err <= 1e-5, "equivariance error {err}");
    // Moving a view into another object's group is not a permutation of the output: the
    // multi-view attention really mixes the views of a group (control for the check above).
    let mixed: Vec<usize> = (0..2 * NUM_VIEWS)
        .map(|i| {
            if i == 0 {
                NUM_VIEWS
            } else if i == NUM_VIEWS {
                0
            } else {
                i
            }
        })
        .collect();
    let swapped =
        unet.forward(rows(&sample, &mixed), &[421.0], rows(&context, &mixed), Some(rows(&labels, &mixed))).unwrap();
    let diff = max_abs_diff(swapped, rows(&out, &mixed));
    assert!(diff > 1e-3, "swapping a view across domains changed nothing ({diff})");
}

#[test]
fn the_domain_switcher_changes_the_output() {
    let device = w3d_diffusion::default_device();
    let unet = UNet::from_dir(fixture("wonder3d_tiny/unet"), &device).unwrap();
    let mut io = unet_io();
    let sample: Tensor<4> = tensor(&mut io, "sample", &device);
    let context: Tensor<3> = tensor(&mut io, "context", &device);
    let labels: Tensor<2> = tensor(&mut io, "class_labels_ortho", &device);
    let out = unet.forward(sample.clone(), &[421.0], context.clone(), Some(labels.clone())).unwrap();
    // Both halves told to draw colours.
    let colour = switcher_labels(Domain::Colour, CameraType::Orthographic, 14).unwrap();
    let both_colour = Tensor::<2>::from_data(TensorData::new([colour.clone(), colour].concat(), [12, 14]), &device);
    let changed = unet.forward(sample, &[421.0], context, Some(both_colour)).unwrap();
    let diff = max_abs_diff(changed.slice([0..6, 0..4, 0..8, 0..8]), out.slice([0..6, 0..4, 0..8, 0..8]));
    assert!(diff > 1e-2, "the domain switch changed the normal half by only {diff}");
}

#[test]
fn fresh_cross_domain_attention_starts_as_the_identity() {
    let device = w3d_diffusion::default_device();
    let config = UNetConfig::from_file(fixture("wonder3d_tiny/unet/config.json")).unwrap();
    let mut io = unet_io();
    let sample: Tensor<4> = tensor(&mut io, "sample", &device);
    let context: Tensor<3> = tensor(&mut io, "context", &device);
    let labels: Tensor<2> = tensor(&mut io, "class_labels_ortho", &device);
    // Changing the colour half's input: does the normal half's output move?
    let other = Tensor::cat(
        vec![sample.clone().slice([0..6, 0..8, 0..8, 0..8]), sample.clone().slice([6..12, 0..8, 0..8, 0..8]) * -1.0],
        0,
    );
    let normal_half_change = |unet: &UNet| {
        let a = unet.forward(sample.clone(), &[421.0], context.clone(), Some(labels.clone())).unwrap();
        let b = unet.forward(other.clone(), &[421.0], context.clone(), Some(labels.clone())).unwrap();
        max_abs_diff(a.slice([0..6, 0..4, 0..8, 0..8]), b.slice([0..6, 0..4, 0..8, 0..8]))
    };
    let fresh = UNet::random(&config, 7, &device).unwrap();
    let trained = UNet::from_dir(fixture("wonder3d_tiny/unet"), &device).unwrap();
    let (fresh_change, trained_change) = (normal_half_change(&fresh), normal_half_change(&trained));
    assert!(fresh_change <= 1e-6, "fresh joint attention leaks across domains ({fresh_change})");
    assert!(trained_change > 1e-3, "the trained joint attention ignores the other domain ({trained_change})");
}

#[test]
fn legacy_joint_attention_names_load() {
    let device = w3d_diffusion::default_device();
    let dir = tempfile::tempdir().unwrap();
    let mut file = SafetensorsFile::open(fixture("wonder3d_tiny/unet/diffusion_pytorch_model.safetensors")).unwrap();
    let keys: Vec<String> = file.shapes().map(|(k, _)| k.to_string()).collect();
    let mut tensors: HashMap<String, (Vec<u8>, Vec<usize>)> = HashMap::new();
    for key in keys {
        let (values, shape) = file.read_f32(&key).unwrap();
        let bytes = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let legacy =
            key.replace(".attn_joint_mid.", ".attn_joint_twice.").replace(".norm_joint_mid.", ".norm_joint_twice.");
        tensors.insert(legacy, (bytes, shape));
    }
    assert!(tensors.keys().any(|k| k.contains("attn_joint_twice")));
    let views: Vec<(String, safetensors::tensor::TensorView)> = tensors
        .iter()
        .map(|(k, (b, s))| {
            (k.clone(), safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), b).unwrap())
        })
        .collect();
    safetensors::serialize_to_file(views, None, &dir.path().join("diffusion_pytorch_model.safetensors")).unwrap();
    std::fs::copy(fixture("wonder3d_tiny/unet/config.json"), dir.path().join("config.json")).unwrap();
    let legacy = UNet::from_dir(dir.path(), &device).unwrap();
    let current = UNet::from_dir(fixture("wonder3d_tiny/unet"), &device).unwrap();
    let mut io = unet_io();
    let run = |unet: &UNet, io: &mut SafetensorsFile| {
        unet.forward(
            tensor(io, "sample", &device),
            &[421.0],
            tensor(io, "context", &device),
            Some(tensor(io, "class_labels_persp", &device)),
        )
        .unwrap()
    };
    assert_eq!(values(run(&legacy, &mut io)), values(run(&current, &mut io)));
}

#[test]
fn multiview_batches_must_hold_whole_groups() {
    let device = w3d_diffusion::default_device();
    let unet = UNet::from_dir(fixture("wonder3d_tiny/unet"), &device).unwrap();
    let err = unet
        .forward(
            Tensor::zeros([6, 8, 8, 8], &device),
            &[1.0],
            Tensor::zeros([6, 1, 16], &device),
            Some(Tensor::zeros([6, 14], &device)),
        )
        .unwrap_err()
        .to_string();
    assert!(err.contains("groups of 12") && err.contains("found 6"), "{err}");
}

fn pipeline_io() -> SafetensorsFile {
    SafetensorsFile::open(fixture("multiview/pipeline_io.safetensors")).unwrap()
}

/// The fixture's 32×32 input image.
fn fixture_input(io: &mut SafetensorsFile) -> Image {
    let (pixels, shape) = io.read_f32("image").unwrap();
    Image::new(shape[1] as u32, shape[0] as u32, 3, pixels).unwrap()
}

#[test]
fn five_step_guided_pipeline_matches_the_reference() {
    for (name, device) in test_devices() {
        let pipeline = MultiViewPipeline::from_dir(fixture("wonder3d_tiny"), &device).unwrap();
        assert_eq!(pipeline.image_size(), 32);
        let mut io = pipeline_io();
        let cond = pipeline.condition(&fixture_input(&mut io), &device).unwrap();
        let err_embeds = max_abs_diff(cond.embeds.clone(), tensor(&mut io, "embeds", &device));
        let err_latent = max_abs_diff(cond.latent.clone(), tensor(&mut io, "cond_latent", &device));
        let options = SampleOptions { steps: 5, guidance: 2.0, eta: 0.0, ..SampleOptions::default() };
        let mut steps = Vec::new();
        let latents = pipeline
            .sample_from(tensor(&mut io, "noise", &device), &cond, &options, &mut |done, total| {
                steps.push((done, total))
            })
            .unwrap();
        assert_eq!(steps, (1..=5).map(|d| (d, 5)).collect::<Vec<_>>());
        let err_latents = max_abs_diff(latents.clone(), tensor(&mut io, "latents", &device));
        let views = pipeline.decode(latents, CameraType::Orthographic).unwrap();
        let decoded: Vec<f32> = values(tensor::<4>(&mut io, "decoded", &device));
        let (side, per_image) = (32usize, 3 * 32 * 32);
        let mut err_images = 0.0f32;
        for (i, image) in views.normals.iter().chain(&views.colours).enumerate() {
            for (p, v) in image.data().iter().enumerate() {
                let (y, x, c) = (p / (3 * side), (p / 3) % side, p % 3);
                let expected = decoded[i * per_image + (c * side + y) * side + x];
                err_images = err_images.max((v - expected).abs());
            }
        }
        println!(
            "{name}: embeds {err_embeds:.2e}, cond latent {err_latent:.2e}, latents {err_latents:.2e}, images {err_images:.2e}"
        );
        for (what, err) in
            [("embeds", err_embeds), ("cond", err_latent), ("latents", err_latents), ("images", err_images)]
        {
            assert!(err <= 1e-4, "{name}: {what} error {err}");
        }
    }
}

#[test]
fn the_same_seed_gives_the_same_bytes() {
    let device = w3d_diffusion::default_device();
    let pipeline = MultiViewPipeline::from_dir(fixture("wonder3d_tiny"), &device).unwrap();
    let mut rgba = Image::filled(40, 30, 4, 0.0).unwrap();
    for y in 5..25 {
        for x in 10..30 {
            rgba.pixel_mut(x, y).copy_from_slice(&[0.8, (x as f32) / 40.0, 0.2, 1.0]);
        }
    }
    let options = SampleOptions { steps: 3, camera: CameraType::Perspective, seed: 11, ..SampleOptions::default() };
    let run = |options: &SampleOptions| pipeline.generate(&rgba, options, &device, &mut |_, _| {}).unwrap();
    let (a, b) = (run(&options), run(&options));
    assert_eq!(a, b);
    assert_eq!((a.normals.len(), a.colours.len(), a.camera), (6, 6, CameraType::Perspective));
    let c = run(&SampleOptions { seed: 12, ..options });
    assert_ne!(a.colours, c.colours);
}

#[test]
fn inversion_recovers_the_noise_of_deterministic_sampling() {
    let device = w3d_diffusion::default_device();
    let pipeline = MultiViewPipeline::from_dir(fixture("wonder3d_tiny"), &device).unwrap();
    let mut io = pipeline_io();
    let cond = pipeline.condition(&fixture_input(&mut io), &device).unwrap();
    let options = SampleOptions { steps: 5, guidance: 1.0, eta: 0.0, ..SampleOptions::default() };
    let noise = pipeline.initial_noise(3, &device).repeat_dim(0, 2);
    let latents = pipeline.sample_from(noise.clone(), &cond, &options, &mut |_, _| {}).unwrap();
    let camera = options.camera;
    let plain = pipeline.invert(latents.clone(), &cond, camera, 5, 0).unwrap();
    let refined = pipeline.invert(latents.clone(), &cond, camera, 5, 6).unwrap();
    let (err_plain, err_refined) = (max_abs_diff(plain, noise.clone()), max_abs_diff(refined.clone(), noise));
    let again = pipeline.sample_from(refined, &cond, &options, &mut |_, _| {}).unwrap();
    let err_round_trip = max_abs_diff(again, latents);
    println!("inversion error: plain {err_plain:.2e}, refined {err_refined:.2e}, round trip {err_round_trip:.2e}");
    assert!(err_refined < err_plain, "refinement did not help ({err_refined} vs {err_plain})");
    assert!(err_refined <= 1e-2 && err_round_trip <= 1e-2, "{err_refined}, {err_round_trip}");
}

#[test]
fn input_preprocessing_crops_scales_centres_and_whitens() {
    // A 60×40 transparent image with an opaque 20×10 red box at (35, 5).
    let mut rgba = Image::filled(60, 40, 4, 0.0).unwrap();
    for y in 5..15 {
        for x in 35..55 {
            rgba.pixel_mut(x, y).copy_from_slice(&[1.0, 0.0, 0.0, 1.0]);
        }
    }
    let out = prepare_input(&rgba, 32).unwrap();
    assert_eq!((out.width(), out.height(), out.channels()), (32, 32, 3));
    // Longest side 24 (75 % of 32), so the box is 24×12, centred: x 4..28, y 10..22.
    let red = |x: u32, y: u32| {
        let p = out.pixel(x, y);
        p[0] > 0.99 && p[1] < 0.01 && p[2] < 0.01
    };
    let white = |x: u32, y: u32| out.pixel(x, y).iter().all(|&v| v > 0.99);
    assert!(red(4, 10) && red(27, 21) && red(16, 16));
    assert!(white(3, 16) && white(28, 16) && white(16, 9) && white(16, 22) && white(0, 0));
    assert!(prepare_input(&Image::filled(8, 8, 4, 0.0).unwrap(), 32).unwrap_err().to_string().contains("transparent"));
    assert!(prepare_input(&Image::filled(8, 8, 3, 1.0).unwrap(), 32).unwrap_err().to_string().contains("RGBA"));
}

#[test]
fn generated_views_become_a_view_set_in_the_rig_frame() {
    // Left half: a normal tilted towards +x and a dark colour; right half: white background.
    let (w, h) = (8u32, 4u32);
    let n = [0.6f32, 0.0, 0.8];
    let mut normal = Image::filled(w, h, 3, 1.0).unwrap();
    let mut colour = Image::filled(w, h, 3, 1.0).unwrap();
    for y in 0..h {
        for x in 0..w / 2 {
            normal.pixel_mut(x, y).copy_from_slice(&n.map(|v| (v + 1.0) / 2.0 * 1.02));
            colour.pixel_mut(x, y).copy_from_slice(&[0.2, 0.3, 0.4]);
        }
    }
    let views = GeneratedViews { camera: CameraType::Orthographic, normals: vec![normal; 6], colours: vec![colour; 6] };
    let set = views.to_view_set().unwrap();
    assert_eq!(set.rig(), &CameraType::Orthographic.rig());
    let v = &set.views()[2];
    assert_eq!(v.name, "right");
    assert_eq!((v.mask.pixel(0, 0)[0], v.mask.pixel(7, 3)[0]), (1.0, 0.0));
    let got = v.normal.pixel(1, 1);
    let len = (got[0] * got[0] + got[1] * got[1] + got[2] * got[2]).sqrt();
    assert!((len - 1.0).abs() < 1e-5 && (got[0] / got[2] - 0.75).abs() < 0.02, "{got:?}");
    assert_eq!(v.normal.pixel(6, 1), &[0.0, 0.0, 0.0]);
    // The folder layout `wonder3d render` writes, read back by `ViewSet::load`.
    let dir = tempfile::tempdir().unwrap();
    set.save(dir.path()).unwrap();
    let loaded = ViewSet::load(dir.path()).unwrap();
    assert_eq!((loaded.len(), loaded.rig().name.as_str()), (6, "wonder3d_ortho"));
    assert_eq!(loaded.views()[2].mask, set.views()[2].mask);
}

/// One 3×1 view set (every view alike): pixel 0 object with the normal `n` and colour `c`,
/// pixel 1 object only when `middle`, pixel 2 background.
fn one_row(n: [f32; 3], c: [f32; 3], middle: bool) -> GeneratedViews {
    let enc = n.map(|v| (v + 1.0) / 2.0);
    let mut normal = Image::filled(3, 1, 3, 1.0).unwrap();
    let mut colour = Image::filled(3, 1, 3, 1.0).unwrap();
    for x in 0..if middle { 2 } else { 1 } {
        normal.pixel_mut(x, 0).copy_from_slice(&enc);
        colour.pixel_mut(x, 0).copy_from_slice(&c);
    }
    GeneratedViews { camera: CameraType::Orthographic, normals: vec![normal; 6], colours: vec![colour; 6] }
}

#[test]
fn the_consensus_of_draws_averages_normals_and_votes_on_the_mask() {
    let s = std::f32::consts::FRAC_1_SQRT_2;
    let draws = [
        one_row([s, 0.0, s], [0.2, 0.4, 0.6], true),
        one_row([-s, 0.0, s], [0.4, 0.4, 0.6], false),
        one_row([0.0, 0.0, 1.0], [0.6, 0.4, 0.6], false),
    ];
    let merged = GeneratedViews::consensus(&draws).unwrap();
    let view = merged.to_view_set().unwrap();
    let v = &view.views()[4];
    // Pixel 0: the normalised sum of the three unit normals is +z, the colour their mean.
    let n = v.normal.pixel(0, 0);
    assert!(n[0].abs() < 1e-5 && (n[2] - 1.0).abs() < 1e-5, "{n:?}");
    let c = v.colour.as_ref().unwrap().pixel(0, 0);
    assert!((c[0] - 0.4).abs() < 1e-6 && (c[2] - 0.6).abs() < 1e-6, "{c:?}");
    // Pixel 1: one draw of three has the object there, so the consensus has not.
    assert_eq!((v.mask.pixel(1, 0)[0], v.mask.pixel(2, 0)[0]), (0.0, 0.0));
    assert_eq!(merged.colours[4].pixel(1, 0), &[1.0, 1.0, 1.0]);
    // Two draws of four (at least half) keep it, with the colour of those two.
    let four = [draws[0].clone(), draws[0].clone(), draws[1].clone(), draws[2].clone()];
    let merged = GeneratedViews::consensus(&four).unwrap();
    assert_eq!(merged.to_view_set().unwrap().views()[0].mask.pixel(1, 0)[0], 1.0);
    assert!((merged.colours[0].pixel(1, 0)[0] - 0.2).abs() < 1e-6);
    // One draw is its own consensus (up to the rounding of re-encoding its normals).
    let (alone, own) = (draws[0].to_view_set().unwrap(), GeneratedViews::consensus(&draws[..1]).unwrap());
    let own = own.to_view_set().unwrap();
    for (a, b) in alone.views().iter().zip(own.views()) {
        assert_eq!((&a.mask, &a.colour), (&b.mask, &b.colour));
        assert!(max_abs_vec(a.normal.data(), b.normal.data()) < 1e-6);
    }
    // Nothing to merge, or draws that do not match, are refused.
    assert!(GeneratedViews::consensus(&[]).is_err());
    let mut other = draws[1].clone();
    other.camera = CameraType::Perspective;
    let err = GeneratedViews::consensus(&[draws[0].clone(), other]).unwrap_err().to_string();
    assert!(err.contains("draw 1"), "{err}");
    let mut small = draws[1].clone();
    small.normals[3] = Image::filled(2, 1, 3, 1.0).unwrap();
    assert!(GeneratedViews::consensus(&[draws[0].clone(), small]).is_err());
}

#[test]
fn several_draws_are_the_consensus_of_consecutive_seeds() {
    let device = w3d_diffusion::default_device();
    let pipeline = MultiViewPipeline::from_dir(fixture("wonder3d_tiny"), &device).unwrap();
    let rgba = common::disc_image(40);
    let options = SampleOptions { steps: 2, seed: 7, ..SampleOptions::default() };
    let mut calls = Vec::new();
    let run = |options: &SampleOptions, calls: &mut Vec<(usize, usize)>| {
        pipeline.generate(&rgba, options, &device, &mut |i, n| calls.push((i, n))).unwrap()
    };
    // More draws than one pass of the UNet takes: a pass of DRAWS_PER_PASS, then the rest.
    let draws = DRAWS_PER_PASS + 1;
    let several = run(&SampleOptions { draws, ..options }, &mut calls);
    // One progress bar over all the draws' steps, moved by each batched step.
    let p = DRAWS_PER_PASS;
    let total = 2 * draws;
    assert_eq!(calls, vec![(p, total), (2 * p, total), (2 * p + 1, total), (2 * p + 2, total)]);
    // Each draw of a batch is the draw sampled alone, to the bit.
    let singles: Vec<GeneratedViews> =
        (7..7 + draws as u64).map(|seed| run(&SampleOptions { seed, ..options }, &mut Vec::new())).collect();
    assert_eq!(several, GeneratedViews::consensus(&singles).unwrap());
    assert_ne!(singles[0], singles[1]);
    // The same with a multistep sampler (its history batched too) and without guidance.
    let unipc = SampleOptions { sampler: SamplerKind::UniPc, guidance: 1.0, steps: 3, ..options };
    let pair = run(&SampleOptions { draws: 2, ..unipc }, &mut Vec::new());
    let alone: Vec<GeneratedViews> =
        (7..9).map(|seed| run(&SampleOptions { seed, ..unipc }, &mut Vec::new())).collect();
    assert_eq!(pair, GeneratedViews::consensus(&alone).unwrap());
    let err = pipeline.generate(&rgba, &SampleOptions { draws: 0, ..options }, &device, &mut |_, _| {}).unwrap_err();
    assert!(err.to_string().contains("draws"), "{err}");
}

/// Copies the tiny model directory into a temporary one.
fn tiny_copy() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    for sub in ["unet", "vae", "image_encoder", "scheduler", "feature_extractor"] {
        std::fs::create_dir_all(dir.path().join(sub)).unwrap();
        for entry in std::fs::read_dir(fixture(&format!("wonder3d_tiny/{sub}"))).unwrap() {
            let entry = entry.unwrap();
            std::fs::copy(entry.path(), dir.path().join(sub).join(entry.file_name())).unwrap();
        }
    }
    dir
}

#[test]
fn model_directory_problems_are_named() {
    let device = w3d_diffusion::default_device();
    let m = MultiViewPipeline::from_dir(fixture("no_such_model"), &device).unwrap_err().to_string();
    assert!(m.contains("not a directory"), "{m}");
    // The diffusers fp16 variant name loads; a PyTorch pickle gets conversion advice.
    let dir = tiny_copy();
    let unet = dir.path().join("unet");
    std::fs::rename(
        unet.join("diffusion_pytorch_model.safetensors"),
        unet.join("diffusion_pytorch_model.fp16.safetensors"),
    )
    .unwrap();
    MultiViewPipeline::from_dir(dir.path(), &device).unwrap();
    std::fs::rename(unet.join("diffusion_pytorch_model.fp16.safetensors"), unet.join("diffusion_pytorch_model.bin"))
        .unwrap();
    let m = MultiViewPipeline::from_dir(dir.path(), &device).unwrap_err().to_string();
    assert!(m.contains("diffusion_pytorch_model.bin") && m.contains("convert"), "{m}");
    // Latents and conditions of the wrong shape.
    let pipeline = MultiViewPipeline::from_dir(fixture("wonder3d_tiny"), &device).unwrap();
    let cond = w3d_diffusion::Conditioning {
        embeds: Tensor::zeros([1, 16], &device),
        latent: Tensor::zeros([1, 4, 8, 8], &device),
    };
    let options = SampleOptions { steps: 1, ..SampleOptions::default() };
    let m = pipeline.sample_from(Tensor::zeros([5, 4, 8, 8], &device), &cond, &options, &mut |_, _| {}).unwrap_err();
    assert!(m.to_string().contains("[6, 4, 8, 8] or [12, 4, 8, 8]"), "{m}");
    let bad = w3d_diffusion::Conditioning { embeds: Tensor::zeros([1, 12], &device), ..cond };
    let m = pipeline.sample_from(Tensor::zeros([6, 4, 8, 8], &device), &bad, &options, &mut |_, _| {}).unwrap_err();
    assert!(m.to_string().contains("embeds"), "{m}");
    // A UNet config without Wonder3D's six views.
    let dir = tiny_copy();
    let config_path = dir.path().join("unet/config.json");
    let config = std::fs::read_to_string(&config_path).unwrap().replace("\"num_views\": 6", "\"num_views\": 1");
    std::fs::write(&config_path, config).unwrap();
    let m = MultiViewPipeline::from_dir(dir.path(), &device).unwrap_err().to_string();
    assert!(m.contains("num_views") && m.contains("found 1"), "{m}");
}

/// A copy of the UNet folder `fixture(src)` in a temporary directory: every tensor goes through
/// `edit(key, values)` (`None` drops it, `Some(name)` stores it as f32 under `name`) and the
/// config text through `config`.
fn edited_unet(
    src: &str,
    edit: impl Fn(&str, &mut Vec<f32>) -> Option<String>,
    config: impl Fn(String) -> String,
) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let mut file = SafetensorsFile::open(fixture(&format!("{src}/diffusion_pytorch_model.safetensors"))).unwrap();
    let keys: Vec<String> = file.shapes().map(|(k, _)| k.to_string()).collect();
    let mut tensors: Vec<(String, Vec<u8>, Vec<usize>)> = Vec::new();
    for key in keys {
        let (mut values, shape) = file.read_f32(&key).unwrap();
        if let Some(name) = edit(&key, &mut values) {
            tensors.push((name, values.iter().flat_map(|v| v.to_le_bytes()).collect(), shape));
        }
    }
    let views: Vec<(String, safetensors::tensor::TensorView)> = tensors
        .iter()
        .map(|(k, b, s)| {
            (k.clone(), safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), b).unwrap())
        })
        .collect();
    safetensors::serialize_to_file(views, None, &dir.path().join("diffusion_pytorch_model.safetensors")).unwrap();
    let text = std::fs::read_to_string(fixture(&format!("{src}/config.json"))).unwrap();
    std::fs::write(dir.path().join("config.json"), config(text)).unwrap();
    dir
}

fn unet_last_io() -> SafetensorsFile {
    SafetensorsFile::open(fixture("multiview/unet_last_io.safetensors")).unwrap()
}

/// The `cd_attention_last` fixture's forward on `unet`, with the colour half of the sample
/// multiplied by `colour_scale`.
fn last_forward(unet: &UNet, colour_scale: f32) -> Tensor<4> {
    let device = w3d_diffusion::default_device();
    let mut io = unet_last_io();
    let sample: Tensor<4> = tensor(&mut io, "sample", &device);
    let sample = Tensor::cat(
        vec![sample.clone().slice([0..6, 0..8, 0..8, 0..8]), sample.slice([6..12, 0..8, 0..8, 0..8]) * colour_scale],
        0,
    );
    unet.forward(sample, &[421.0], tensor(&mut io, "context", &device), Some(tensor(&mut io, "class_labels", &device)))
        .unwrap()
}

fn normal_half(t: Tensor<4>) -> Tensor<4> {
    t.slice([0..6, 0..4, 0..8, 0..8])
}

#[test]
fn cd_attention_last_unet_matches_the_reference() {
    for (name, device) in test_devices() {
        let unet = UNet::from_dir(fixture("wonder3d_tiny_last/unet"), &device).unwrap();
        assert!(unet.config().cd_attention_last && unet.config().cd_attention_mid);
        let mut io = unet_last_io();
        let out = unet
            .forward(
                tensor(&mut io, "sample", &device),
                &values(tensor::<1>(&mut io, "timesteps", &device)),
                tensor(&mut io, "context", &device),
                Some(tensor(&mut io, "class_labels", &device)),
            )
            .unwrap();
        let expected: Tensor<4> = tensor(&mut io, "out", &device);
        let (err, scale) = (max_abs_diff(out, expected.clone()), max_abs(expected));
        println!("{name} cd_attention_last: max-abs error {err:.2e} (output max {scale:.2})");
        assert!(err <= 1e-4, "{name}: max-abs error {err}");
    }
}

#[test]
fn cd_attention_last_loads_its_keys_mixes_the_domains_and_is_the_identity_when_zeroed() {
    let device = w3d_diffusion::default_device();
    let src = "wonder3d_tiny_last/unet";
    let keep = |k: &str, _: &mut Vec<f32>| Some(k.to_string());
    let same = |c: String| c;
    let without_last = |c: String| c.replace("\"cd_attention_last\": true", "\"cd_attention_last\": false");
    let is_last = |k: &str| k.contains(".attn_joint_last.") || k.contains(".norm_joint_last.");
    let is_out = |k: &str, which: &str| k.contains(&format!(".attn_joint_{which}.to_out.0."));

    // The checkpoint holds the extra keys: a config without cd_attention_last rejects them.
    let dir = edited_unet(src, keep, without_last);
    let m = UNet::from_dir(dir.path(), &device).unwrap_err().to_string();
    assert!(m.contains("attn_joint_last") && m.contains("norm_joint_last"), "{m}");
    let full = UNet::from_dir(fixture(src), &device).unwrap();

    // The same network without the last joint attention: the joint attention changes the output.
    let dir = edited_unet(src, |k, _| (!is_last(k)).then(|| k.to_string()), without_last);
    let plain = UNet::from_dir(dir.path(), &device).unwrap();
    let diff = max_abs_diff(last_forward(&full, 1.0), last_forward(&plain, 1.0));
    assert!(diff > 1e-3, "attn_joint_last changed the output by only {diff}");

    // With a zero output projection (weight and bias) it is exactly the identity.
    let zero_last = |k: &str, v: &mut Vec<f32>| {
        if is_out(k, "last") {
            v.iter_mut().for_each(|x| *x = 0.0);
        }
        Some(k.to_string())
    };
    let dir = edited_unet(src, zero_last, same);
    let zeroed = UNet::from_dir(dir.path(), &device).unwrap();
    assert_eq!(values(last_forward(&zeroed, 1.0)), values(last_forward(&plain, 1.0)));

    // It mixes the domains: with the mid joint attention silenced (zero output projection),
    // the normal half's output follows the colour half's input only through attn_joint_last.
    let zero_mid = |k: &str, v: &mut Vec<f32>| {
        if is_out(k, "mid") {
            v.iter_mut().for_each(|x| *x = 0.0);
        }
        Some(k.to_string())
    };
    let dir = edited_unet(src, zero_mid, same);
    let last_only = UNet::from_dir(dir.path(), &device).unwrap();
    let leak = max_abs_diff(normal_half(last_forward(&last_only, 1.0)), normal_half(last_forward(&last_only, -1.0)));
    assert!(leak > 1e-3, "attn_joint_last ignores the other domain ({leak})");
    let zero_both = |k: &str, v: &mut Vec<f32>| {
        if is_out(k, "mid") || is_out(k, "last") {
            v.iter_mut().for_each(|x| *x = 0.0);
        }
        Some(k.to_string())
    };
    let dir = edited_unet(src, zero_both, same);
    let neither = UNet::from_dir(dir.path(), &device).unwrap();
    let leak = max_abs_diff(normal_half(last_forward(&neither, 1.0)), normal_half(last_forward(&neither, -1.0)));
    assert!(leak <= 1e-6, "the domains mix without any joint attention ({leak})");

    // Older checkpoints call it attn_joint / norm_joint.
    let legacy = |k: &str, _: &mut Vec<f32>| {
        Some(k.replace(".attn_joint_last.", ".attn_joint.").replace(".norm_joint_last.", ".norm_joint."))
    };
    let dir = edited_unet(src, legacy, same);
    let renamed = UNet::from_dir(dir.path(), &device).unwrap();
    assert_eq!(values(last_forward(&renamed, 1.0)), values(last_forward(&full, 1.0)));
}

#[test]
fn fresh_cd_attention_last_does_not_mix_the_domains() {
    let device = w3d_diffusion::default_device();
    let config = UNetConfig::from_file(fixture("wonder3d_tiny_last/unet/config.json")).unwrap();
    let fresh = UNet::random(&config, 5, &device).unwrap();
    let leak = max_abs_diff(normal_half(last_forward(&fresh, 1.0)), normal_half(last_forward(&fresh, -1.0)));
    assert!(leak <= 1e-6, "fresh joint attentions leak across domains ({leak})");
}

/// The authors' inference UNet kwargs that `config.json` may lack.
const AUTHORS_FIELDS: [&str; 7] = [
    "num_views",
    "sample_size",
    "projection_class_embeddings_input_dim",
    "cd_attention_mid",
    "multiview_attention",
    "sparse_mv_attention",
    "mvcd_attention",
];

fn tiny_unet_config_json() -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(fixture("wonder3d_tiny/unet/config.json")).unwrap()).unwrap()
}

#[test]
fn a_multiview_config_lacking_the_authors_inference_values_gets_them_and_says_so() {
    let mut json = tiny_unet_config_json();
    let object = json.as_object_mut().unwrap();
    for field in AUTHORS_FIELDS {
        object.remove(field);
    }
    object.insert("num_views".into(), serde_json::Value::Null); // null counts as lacking
    let config = UNetConfig::from_value(json).unwrap();
    let applied: Vec<(&str, String)> =
        config.applied_overrides.iter().map(|o| (o.field, o.value.to_string())).collect();
    let expected: Vec<(&str, String)> = AUTHORS_FIELDS
        .iter()
        .zip(["6", "32", "14", "true", "true", "false", "false"])
        .map(|(f, v)| (*f, v.to_string()))
        .collect();
    assert_eq!(applied, expected);
    assert!(config.differs_from_authors.is_empty());
    assert_eq!(
        (config.views(), config.sample_size, config.projection_class_embeddings_input_dim, config.cd_attention_mid),
        (6, Some(32), Some(14), true)
    );
    assert!(config.multiview_attention && !config.sparse_mv_attention && !config.mvcd_attention);
    assert_eq!(
        config.override_notes("unet/config.json"),
        ["w3d-diffusion: unet/config.json lacks num_views, sample_size, projection_class_embeddings_input_dim, \
          cd_attention_mid, multiview_attention, sparse_mv_attention, mvcd_attention: using the authors' inference \
          values 6, 32, 14, true, true, false, false"]
    );
}

#[test]
fn a_config_that_states_the_fields_is_kept_as_written() {
    // The tiny checkpoint states every field; its sample_size (8) is not the authors' 32.
    let json = tiny_unet_config_json();
    let config = UNetConfig::from_value(json.clone()).unwrap();
    assert!(config.applied_overrides.is_empty());
    let differs: Vec<(&str, String, String)> =
        config.differs_from_authors.iter().map(|d| (d.field, d.file.to_string(), d.authors.to_string())).collect();
    assert_eq!(differs, [("sample_size", "8".to_string(), "32".to_string())]);
    let as_written: UNetConfig = serde_json::from_value(json).unwrap();
    assert_eq!(UNetConfig { differs_from_authors: Vec::new(), ..config.clone() }, as_written);
    let notes = config.override_notes("cfg.json");
    assert_eq!(notes.len(), 1);
    assert!(notes[0].contains("sample_size = 8 (authors' inference: 32)"), "{notes:?}");
    // A single-view Stable Diffusion config gets nothing.
    let single = UNetConfig::from_file(fixture("unet/config.json")).unwrap();
    assert!(single.applied_overrides.is_empty() && single.differs_from_authors.is_empty());
    assert!(single.override_notes("x").is_empty());
}

#[test]
fn a_model_directory_whose_unet_config_lacks_the_multiview_fields_loads_as_the_authors_run_it() {
    let device = w3d_diffusion::default_device();
    let dir = tiny_copy();
    let config_path = dir.path().join("unet/config.json");
    let mut json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&config_path).unwrap()).unwrap();
    for field in ["num_views", "cd_attention_mid"] {
        json.as_object_mut().unwrap().remove(field);
    }
    std::fs::write(&config_path, serde_json::to_string_pretty(&json).unwrap()).unwrap();
    let pipeline = MultiViewPipeline::from_dir(dir.path(), &device).unwrap();
    let applied: Vec<&str> = pipeline.unet().config().applied_overrides.iter().map(|o| o.field).collect();
    assert_eq!(applied, ["num_views", "cd_attention_mid"]);
    // The same network as the complete config: identical predictions.
    let reference = MultiViewPipeline::from_dir(fixture("wonder3d_tiny"), &device).unwrap();
    let mut io = unet_io();
    let run = |p: &MultiViewPipeline, io: &mut SafetensorsFile| {
        p.unet()
            .forward(
                tensor(io, "sample", &device),
                &[421.0],
                tensor(io, "context", &device),
                Some(tensor(io, "class_labels_ortho", &device)),
            )
            .unwrap()
    };
    assert_eq!(values(run(&pipeline, &mut io)), values(run(&reference, &mut io)));
}

#[test]
fn input_preprocessing_truncates_to_8_bits_like_the_authors() {
    // 40×40, all object: the left half opaque, the right half at alpha 0.5 (composited over
    // white: 0.3 · 0.5 + 0.5 = 0.65). No value lies on an 8-bit level.
    let mut rgba = Image::filled(40, 40, 4, 0.0).unwrap();
    for y in 0..40 {
        for x in 0..40 {
            let p = if x < 20 { [100.6 / 255.0, 0.909_746_2, 0.3 / 255.0, 1.0] } else { [0.3, 0.3, 0.3, 0.5] };
            rgba.pixel_mut(x, y).copy_from_slice(&p);
        }
    }
    let out = prepare_input(&rgba, 32).unwrap();
    assert!(out.data().iter().all(|v| (v * 255.0 - (v * 255.0).round()).abs() < 1e-4), "off an 8-bit level");
    let level = |x: u32, y: u32| out.pixel(x, y).iter().map(|v| (v * 255.0).round() as u8).collect::<Vec<_>>();
    // Torch's half-precision `to_pil_image` gives these levels (checked with torch 2.4.1 and
    // torchvision 0.19.1): truncation, so 100.6 → 100 (not 101) and 165.75 → 165 (not 166);
    // and f16 arithmetic, so 0.9097462 → 232 where floor(255 x) in f32 is 231.
    assert_eq!(level(8, 16), [100, 232, 0]);
    assert_eq!(level(23, 16), [165, 165, 165]);
    assert_eq!(level(0, 0), [255, 255, 255]);
}

#[test]
fn conditioning_sees_the_8_bit_image() {
    let device = w3d_diffusion::default_device();
    let pipeline = MultiViewPipeline::from_dir(fixture("wonder3d_tiny"), &device).unwrap();
    let mut io = pipeline_io();
    let input = fixture_input(&mut io); // 8-bit levels
    let shifted = |delta: f32| {
        let data = input.data().iter().map(|v| (v + delta).clamp(0.0, 1.0)).collect();
        Image::new(input.width(), input.height(), 3, data).unwrap()
    };
    let base = pipeline.condition(&input, &device).unwrap();
    // A third of a level above every level: the same 8-bit image, the same conditions.
    let up = pipeline.condition(&shifted(0.3 / 255.0), &device).unwrap();
    assert_eq!(values(up.embeds), values(base.embeds.clone()));
    assert_eq!(values(up.latent), values(base.latent.clone()));
    // A third of a level below: truncation drops each non-zero level by one.
    let down = pipeline.condition(&shifted(-0.3 / 255.0), &device).unwrap();
    let change = max_abs_diff(down.latent, base.latent).max(max_abs_diff(down.embeds, base.embeds));
    assert!(change > 1e-4, "one level lower changed the conditions by only {change}");
}

/// Weights held in f16 ([`WeightStorage`]): exact for an f16 checkpoint (the shipped small
/// model generates the same views as from f32 weights, and so does the tiny one's UNet), and
/// f32 weights rounded to f16 move the tiny UNet's output by less than 1e-3 (but do move it:
/// the storage is f16).
#[test]
fn f16_weight_storage_keeps_the_outputs() {
    let small = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/model-small");
    let rgba = common::disc_image(80);
    let options = SampleOptions { steps: 1, ..SampleOptions::default() };
    for (name, device) in test_devices() {
        let views = |storage: WeightStorage| {
            let pipeline = MultiViewPipeline::from_dir_with(&small, &device, storage).unwrap();
            let v = pipeline.generate(&rgba, &options, &device, &mut |_, _| {}).unwrap();
            v.normals.iter().chain(&v.colours).flat_map(|i| i.data().to_vec()).collect::<Vec<f32>>()
        };
        let (f32_views, as_stored) = (views(WeightStorage::F32), views(WeightStorage::AsStored));
        assert_eq!(max_abs_vec(&f32_views, &as_stored), 0.0, "{name}: the f16 small model held as stored");

        let mut io = unet_io();
        let timesteps = values(tensor::<1>(&mut io, "timesteps", &device));
        let config = UNetConfig::from_file(fixture("wonder3d_tiny/unet/config.json")).unwrap();
        let forward = |unet: UNet, io: &mut SafetensorsFile| {
            let out = unet
                .forward(
                    tensor(io, "sample", &device),
                    &timesteps,
                    tensor(io, "context", &device),
                    Some(tensor(io, "class_labels_ortho", &device)),
                )
                .unwrap();
            values(out)
        };
        let file = |storage| UNet::from_dir_with(fixture("wonder3d_tiny/unet"), &device, storage).unwrap();
        let (full, half) = (forward(file(WeightStorage::F32), &mut io), forward(file(WeightStorage::F16), &mut io));
        assert_eq!(max_abs_vec(&full, &half), 0.0, "{name}: the tiny checkpoint is f16 on disk");
        let random = |storage| UNet::random_with(&config, 5, &device, storage).unwrap();
        let (full, half) = (forward(random(WeightStorage::F32), &mut io), forward(random(WeightStorage::F16), &mut io));
        let err = max_abs_vec(&full, &half);
        println!("{name}: tiny UNet, random f32 weights held in f16 vs f32: max-abs {err:.2e}");
        assert!(err > 0.0 && err <= 1e-3, "{name}: f16 storage moved the output by {err}");
    }
}
