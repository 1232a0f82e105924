//! The training-set reader: model images composited on the sample's background, encoded
//! once, assembled into the batches of the three stages; malformed sets refused by name.

use std::path::Path;

use crate::common::fixture;
use w3d_core::{Image, ViewImages, ViewSet};
use w3d_diffusion::train::Stage;
use w3d_diffusion::train::data::{Background, EncodedSample, TrainDomain, TrainingSet, assemble_batch};
use w3d_diffusion::{CameraType, MultiViewPipeline};

const SIZE: u32 = 32; // the tiny fixture model's image side (8 × the VAE's 4)

/// A sphere's views: normals in the front camera frame rotated per view, a blue-to-red colour
/// ramp, mask = the disc.
fn sphere_views(camera: CameraType) -> ViewSet {
    let rig = camera.rig();
    let views = rig
        .views
        .iter()
        .enumerate()
        .map(|(k, view)| {
            let (mut normal, mut colour, mut mask) = (Vec::new(), Vec::new(), Vec::new());
            let azimuth = [0.0f32, 45.0, 90.0, 180.0, -90.0, -45.0][k].to_radians();
            for y in 0..SIZE {
                for x in 0..SIZE {
                    let u = (x as f32 + 0.5) / SIZE as f32 * 2.0 - 1.0;
                    let v = 1.0 - (y as f32 + 0.5) / SIZE as f32 * 2.0;
                    let r2 = (u * u + v * v) / 0.36;
                    if r2 < 1.0 {
                        let (nx, ny, nz) = (u / 0.6, v / 0.6, (1.0 - r2).sqrt());
                        // Camera frame of this view → the front camera's frame (rotation about +y).
                        let (s, c) = azimuth.sin_cos();
                        normal.extend([c * nx + s * nz, ny, -s * nx + c * nz]);
                        colour.extend([0.5 + 0.5 * u, 0.3, 0.5 - 0.5 * u]);
                        mask.push(1.0);
                    } else {
                        normal.extend([0.0; 3]);
                        colour.extend([0.0; 3]);
                        mask.push(0.0);
                    }
                }
            }
            ViewImages {
                name: view.name.clone(),
                normal: Image::new(SIZE, SIZE, 3, normal).unwrap(),
                colour: Some(Image::new(SIZE, SIZE, 3, colour).unwrap()),
                mask: Image::new(SIZE, SIZE, 1, mask).unwrap(),
                depth: None,
            }
        })
        .collect();
    ViewSet::new(rig, views).unwrap()
}

fn write_set(dir: &Path, samples: &[(&str, CameraType, &str)]) {
    let mut entries = Vec::new();
    for (i, (id, camera, background)) in samples.iter().enumerate() {
        sphere_views(*camera).save(dir.join(id)).unwrap();
        let camera = if *camera == CameraType::Orthographic { "ortho" } else { "persp" };
        entries.push(serde_json::json!({
            "id": id, "source": "sphere", "sample": i, "camera": camera, "background": background,
            "yaw_deg": 0.0, "pitch_deg": 0.0, "colouring": "mesh"
        }));
    }
    let index = serde_json::json!({
        "format": "wonder3d-rs dataset", "version": 2, "size": SIZE, "seed": 0,
        "views": ["front", "front_right", "right", "back", "left", "front_left"],
        "samples": entries,
    });
    std::fs::write(dir.join("dataset.json"), serde_json::to_vec_pretty(&index).unwrap()).unwrap();
}

#[test]
fn model_images_share_the_samples_background() {
    let dir = tempfile::tempdir().unwrap();
    write_set(dir.path(), &[("a", CameraType::Orthographic, "black"), ("b", CameraType::Perspective, "grey")]);
    let set = TrainingSet::open(dir.path()).unwrap();
    assert_eq!((set.len(), set.size()), (2, SIZE));
    let images = set.images(1).unwrap();
    assert_eq!(images.camera, CameraType::Perspective);
    let [normals, colours, masks] = &images.domains;
    assert_eq!((normals.len(), colours.len(), masks.len()), (6, 6, 6));
    // Corner pixel: background grey in colour and normal, black in the mask.
    assert_eq!(colours[0].pixel(0, 0), [0.5, 0.5, 0.5]);
    assert_eq!(normals[3].pixel(0, 0), [0.5, 0.5, 0.5]);
    assert_eq!(masks[0].pixel(0, 0), [0.0, 0.0, 0.0]);
    // Centre of the front view: a normal facing the camera encodes to ≈ (0.5, 0.5, 1).
    let c = normals[0].pixel(SIZE / 2, SIZE / 2);
    assert!((c[2] - 1.0).abs() < 0.02 && (c[0] - 0.5).abs() < 0.05, "front normal {c:?}");
    assert_eq!(masks[0].pixel(SIZE / 2, SIZE / 2), [1.0, 1.0, 1.0]);
    let black = set.images(0).unwrap();
    assert_eq!(black.domains[1][0].pixel(0, 0), [0.0, 0.0, 0.0]);
    // The input image is the front view framed as inference frames a photo: the disc (60 % of
    // the side) grows to 75 %, on the sample's background.
    let input = &images.inputs[1];
    let grey = f32::from(w3d_diffusion::quantize_u8(0.5)) / 255.0; // 8-bit, truncated as inference
    assert_eq!(input.pixel(0, 0), [grey; 3]);
    let row = SIZE / 2;
    let covered = (0..SIZE).filter(|&x| input.pixel(x, row) != [grey; 3]).count() as f32 / SIZE as f32;
    assert!((covered - 0.75).abs() < 0.07, "input covers {covered} of its width");
    // A background override composites every sample, inputs and targets, on it instead.
    let white = set.clone().with_background(Some(Background::White));
    for index in 0..2 {
        let images = white.images(index).unwrap();
        assert_eq!(images.domains[0][3].pixel(0, 0), [1.0; 3]);
        assert_eq!(images.domains[1][0].pixel(0, 0), [1.0; 3]);
        assert_eq!(images.domains[2][0].pixel(0, 0), [0.0; 3], "masks stay black outside the object");
        assert_eq!(images.inputs[1].pixel(0, 0), [1.0; 3]);
    }
    assert_eq!(white.with_background(None).images(0).unwrap().domains[1][0].pixel(0, 0), [0.0; 3]);
}

#[test]
fn batches_of_the_three_stages_have_the_authors_layout() {
    let dir = tempfile::tempdir().unwrap();
    write_set(dir.path(), &[("a", CameraType::Orthographic, "white"), ("b", CameraType::Perspective, "black")]);
    let set = TrainingSet::open(dir.path()).unwrap();
    let device = w3d_diffusion::default_device();
    let pipeline = MultiViewPipeline::from_dir(fixture("wonder3d_tiny"), &device).unwrap();
    let encoded: Vec<EncodedSample> =
        (0..2).map(|i| EncodedSample::encode(&pipeline, &set.images(i).unwrap(), &device).unwrap()).collect();
    let refs: Vec<&EncodedSample> = encoded.iter().collect();
    let joint = assemble_batch(Stage::CrossDomain, &refs, &[], 14).unwrap();
    assert_eq!(joint.latents.dims(), [24, 4, 8, 8]);
    assert_eq!(joint.domains, 2);
    assert_eq!(joint.image_embeddings.dims()[0], 24);
    // Normal half first: image 0 is object a's normal front view, image 12 its colour front.
    let same = |a: w3d_diffusion::Tensor<4>, b: w3d_diffusion::Tensor<4>| crate::common::max_abs_diff(a, b) == 0.0;
    assert!(same(joint.latents.clone().narrow(0, 0, 6), encoded[0].latents[0].clone()));
    assert!(same(joint.latents.clone().narrow(0, 12, 6), encoded[0].latents[1].clone()));
    // Stages 2 and 3 condition on the colour input image (the front view, framed as inference frames a photo).
    assert!(same(joint.condition_latents.clone().narrow(0, 0, 1), encoded[0].input_latents[1].clone()));
    assert!(same(joint.condition_latents.clone().narrow(0, 17, 1), encoded[0].input_latents[1].clone()));
    let labels = crate::common::values(joint.class_labels.clone().unwrap());
    // task switch sin values: columns 5, 6 (normal [1, 0]) for row 0, colour [0, 1] for row 12.
    assert!((labels[5] - 1f32.sin()).abs() < 1e-6 && labels[6].abs() < 1e-6);
    assert!(labels[12 * 14 + 5].abs() < 1e-6 && (labels[12 * 14 + 6] - 1f32.sin()).abs() < 1e-6);

    let mixed = assemble_batch(Stage::MixedDomain, &refs, &[TrainDomain::Colour, TrainDomain::Normal], 14).unwrap();
    assert_eq!((mixed.latents.dims()[0], mixed.domains), (12, 1));
    assert!(same(mixed.latents.clone().narrow(0, 6, 6), encoded[1].latents[0].clone()));
    let e = assemble_batch(Stage::MixedDomain, &refs, &[TrainDomain::Mask, TrainDomain::Normal], 14).unwrap_err();
    assert!(e.to_string().contains("domains"), "{e}");

    // Stage 1: no switcher (task [0, 0]); the condition is the input image of the same domain.
    let multi = assemble_batch(Stage::MultiDomain, &refs, &[TrainDomain::Mask, TrainDomain::Normal], 14).unwrap();
    assert!(same(multi.condition_latents.clone().narrow(0, 0, 1), encoded[0].input_latents[2].clone()));
    assert!(same(multi.condition_latents.clone().narrow(0, 6, 1), encoded[1].input_latents[0].clone()));
    let labels = crate::common::values(multi.class_labels.unwrap());
    assert!(labels[5].abs() < 1e-6 && labels[6].abs() < 1e-6, "stage 1 task label must be [0, 0]");
}

#[test]
fn malformed_sets_are_refused_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    write_set(dir.path(), &[("a", CameraType::Orthographic, "white")]);
    let index = dir.path().join("dataset.json");
    let original = std::fs::read_to_string(&index).unwrap();
    for (from, to, field) in [
        ("\"ortho\"", "\"fisheye\"", "samples[0].camera"),
        ("\"white\"", "\"plaid\"", "samples[0].background"),
        ("\"id\": \"a\"", "\"id\": \"../a\"", "samples[0].id"),
        ("\"id\": \"a\"", "\"id\": \"missing\"", "samples[0].id"),
        ("\"version\": 2", "\"version\": 7", "format"),
        ("\"front_left\"", "\"top\"", "views"),
    ] {
        std::fs::write(&index, original.replace(from, to)).unwrap();
        let e = TrainingSet::open(dir.path()).unwrap_err().to_string();
        assert!(e.contains(field) && e.contains("dataset.json"), "{from} → {to}: {e}");
    }
    std::fs::write(&index, original.replace(&format!("\"size\": {SIZE}"), "\"size\": 64")).unwrap();
    let set = TrainingSet::open(dir.path()).unwrap();
    let e = set.images(0).unwrap_err().to_string();
    assert!(e.contains("mask_front.png") && e.contains("64"), "{e}");
    std::fs::write(&index, &original).unwrap();
    std::fs::remove_file(dir.path().join("a").join("colour_back.png")).unwrap();
    let e = TrainingSet::open(dir.path()).unwrap().images(0).unwrap_err().to_string();
    assert!(e.contains("colour_back.png"), "{e}");
}

fn log_losses(out: &Path) -> Vec<(u64, f64)> {
    std::fs::read_to_string(out.join(w3d_diffusion::train::LOG_FILE))
        .unwrap()
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap();
            (v["step"].as_u64().unwrap(), v["loss"].as_f64().unwrap())
        })
        .collect()
}

/// A pipeline of the tiny fixture models with a fresh UNet without cross-domain attention
/// (stages 1 and 2 train that one).
fn stage_two_pipeline(device: &w3d_diffusion::Device) -> MultiViewPipeline {
    let (unet, vae, clip, scheduler) =
        MultiViewPipeline::from_dir(fixture("wonder3d_tiny"), device).unwrap().into_parts();
    let mut config = unet.config().clone();
    config.cd_attention_mid = false;
    let unet = w3d_diffusion::UNet::random(&config, 3, device).unwrap();
    MultiViewPipeline::new(unet, vae, clip, scheduler).unwrap()
}

#[test]
fn a_resumed_run_continues_the_uninterrupted_one_exactly() {
    use w3d_diffusion::train::data::EncodedSet;
    use w3d_diffusion::train::{RunEvent, RunOptions, TrainOptions, run_training, run_training_encoded};
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    std::fs::create_dir(&data).unwrap();
    write_set(&data, &[("a", CameraType::Orthographic, "white"), ("b", CameraType::Perspective, "grey")]);
    let set = TrainingSet::open(&data).unwrap();
    let device = w3d_diffusion::default_device();
    let options =
        TrainOptions::for_stage(Stage::MixedDomain).with_learning_rate(1e-3).with_warmup_steps(2).with_seed(5);
    let run = RunOptions::default().with_steps(6).with_checkpoint_every(3).with_objects_per_batch(2);
    let whole = dir.path().join("whole");
    let mut steps = 0;
    run_training(stage_two_pipeline(&device), &set, options.clone(), &run, &whole, false, &mut |e| {
        if let RunEvent::Step(_) = e {
            steps += 1;
        }
    })
    .unwrap();
    assert_eq!(steps, 6);
    let expected = log_losses(&whole);
    assert_eq!(expected.iter().map(|(s, _)| *s).collect::<Vec<_>>(), [1, 2, 3, 4, 5, 6]);
    MultiViewPipeline::from_dir(whole.join("checkpoint"), &device).unwrap();

    let split = dir.path().join("split");
    let first = run.clone().with_steps(3);
    run_training(stage_two_pipeline(&device), &set, options.clone(), &first, &split, false, &mut |_| {}).unwrap();
    // A second fresh run into the same folder is refused; resuming continues it.
    let e =
        run_training(stage_two_pipeline(&device), &set, options.clone(), &run, &split, false, &mut |_| {}).unwrap_err();
    assert!(e.to_string().contains("resume"), "{e}");
    // The second half on the set encoded once beforehand, as a recipe shares one encoding
    // between its phases: the same losses as encoding the set in the run.
    let encoded = EncodedSet::encode(&stage_two_pipeline(&device), &set, &device, &mut |_, _| {}).unwrap();
    assert_eq!((encoded.len(), encoded.size()), (2, set.size()));
    let mut resumed_at = None;
    run_training_encoded(stage_two_pipeline(&device), &encoded, options.clone(), &run, &split, true, &mut |e| {
        if let RunEvent::Resumed { step } = e {
            resumed_at = Some(step);
        }
    })
    .unwrap();
    assert_eq!(resumed_at, Some(3));
    assert_eq!(log_losses(&split), expected, "the resumed run's losses differ from the uninterrupted run's");
    let shared = dir.path().join("shared");
    run_training_encoded(stage_two_pipeline(&device), &encoded, options.clone(), &run, &shared, false, &mut |_| {})
        .unwrap();
    assert_eq!(log_losses(&shared), expected, "a run on a shared encoding differs from one encoding the set");
    let missing = dir.path().join("nothing");
    let e = run_training(stage_two_pipeline(&device), &set, options, &run, &missing, true, &mut |_| {}).unwrap_err();
    assert!(e.to_string().contains("trainer_state.json"), "{e}");
}

/// A one-sample set's model images (in its temporary folder), the device and a random VAE of
/// the tiny configuration: the start of the VAE training tests.
fn vae_training_start() -> (tempfile::TempDir, Vec<Image>, w3d_diffusion::Device, w3d_diffusion::Vae) {
    let dir = tempfile::tempdir().unwrap();
    write_set(dir.path(), &[("a", CameraType::Orthographic, "grey")]);
    let set = TrainingSet::open(dir.path()).unwrap();
    let images: Vec<Image> = set.images(0).unwrap().domains.into_iter().flatten().collect();
    let device = w3d_diffusion::default_device();
    let config = w3d_diffusion::VaeConfig::from_file(fixture("wonder3d_tiny").join("vae").join("config.json")).unwrap();
    let vae = w3d_diffusion::Vae::random(&config, 1, &device).unwrap();
    (dir, images, device, vae)
}

#[test]
fn a_small_vae_learns_to_reconstruct_the_views() {
    use w3d_diffusion::train::{VaeTrainOptions, train_vae};
    let (dir, images, device, vae) = vae_training_start();
    let mut losses = Vec::new();
    let options = VaeTrainOptions::default().with_steps(60).with_batch(4).with_learning_rate(3e-3);
    let vae = train_vae(vae, &images, &options, &mut |_, loss| losses.push(loss)).unwrap();
    let early: f32 = losses[..5].iter().sum::<f32>() / 5.0;
    let late: f32 = losses[losses.len() - 5..].iter().sum::<f32>() / 5.0;
    eprintln!("vae loss {early} → {late}, scaling factor {}", vae.config().scaling_factor);
    assert!(late * 3.0 < early, "VAE loss {early} → {late}: not a 3× drop");
    assert!(vae.config().scaling_factor.is_finite() && vae.config().scaling_factor > 0.0);
    let out = dir.path().join("vae");
    vae.save(&out).unwrap();
    let loaded = w3d_diffusion::Vae::from_dir(&out, &device).unwrap();
    assert_eq!(loaded.config().scaling_factor, vae.config().scaling_factor);
}

#[test]
fn a_decoder_only_fine_tune_keeps_the_encoder_and_its_scaling() {
    use w3d_diffusion::train::{VaeTrainOptions, train_vae};
    use w3d_diffusion::{Tensor, TensorData};
    let (_dir, images, device, vae) = vae_training_start();
    // A VAE trained a little (whole), so its latents carry the images.
    let options = VaeTrainOptions::default().with_steps(30).with_batch(4).with_learning_rate(3e-3);
    let vae = train_vae(vae, &images, &options, &mut |_, _| {}).unwrap();
    let (w, h) = (images[0].width() as usize, images[0].height() as usize);
    let batch: Vec<Tensor<4>> = images
        .iter()
        .map(|image| {
            let t: Tensor<3> = Tensor::from_data(TensorData::new(image.data().to_vec(), [h, w, 3]), &device);
            t.permute([2, 0, 1]).reshape([1, 3, h, w]) * 2.0 - 1.0
        })
        .collect();
    let x = Tensor::cat(batch, 0);
    let values = |t: Tensor<4>| t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap();
    let error = |vae: &w3d_diffusion::Vae| {
        let diff = vae.decode(vae.encode_mean(x.clone()).unwrap()).unwrap() - x.clone();
        (diff.clone() * diff).mean().into_scalar::<f32>()
    };
    let mean_before = values(vae.encode_mean(x.clone()).unwrap());
    let (scaling, error_before) = (vae.config().scaling_factor, error(&vae));
    let options = options.with_steps(40).with_sample_posterior(false).with_decoder_only(true);
    let vae = train_vae(vae, &images, &options, &mut |_, _| {}).unwrap();
    assert_eq!(values(vae.encode_mean(x.clone()).unwrap()), mean_before, "the encoder changed");
    assert_eq!(vae.config().scaling_factor, scaling, "the scaling factor changed");
    let error_after = error(&vae);
    eprintln!("reconstruction error {error_before} → {error_after}");
    assert!(error_after < 0.8 * error_before, "reconstruction error {error_before} → {error_after}");
}
