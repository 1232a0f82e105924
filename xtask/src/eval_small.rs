//! `cargo xtask eval-small [--model DIR]`: the small model from images to meshes, scored
//! (`docs/training.md`): for training objects and the held-out one, the front colour view of
//! a dataset sample (seed 0, sample 0: a training sample for the training objects) goes
//! through `MultiViewPipeline::generate`, sampled as `wonder3d demo --from-image` samples the
//! small model unless the flags say otherwise; the 6 generated normal maps are compared with the
//! truth inside the true masks (mean angular error, also without the silhouette's one-pixel
//! rim, where an outline off by a pixel weighs most), the generated masks with the true ones
//! (IoU), and the mesh reconstructed from the generated views with the posed object
//! (Chamfer distance, both normalised into the unit cube; the best of `GENERATED_VIEW_STARTS` fits, as `wonder3d run` keeps it). Writes
//! `target/eval-small/eval.json` and the contact sheet `target/eval-small/small_model.png`
//! (`--sheet docs/img/small_model.png` for the committed one): per object,
//! the input, the generated views and the reconstructed mesh's normals from two cameras,
//! above the true views and the true mesh.

use std::path::Path;
use std::time::Instant;

use wonder3d::dataset::{Dataset, DatasetOptions, id_stem, sample_draw};
use wonder3d::diffusion::{CameraType, MultiViewPipeline, SampleOptions, SamplerKind};
use wonder3d::eval::{EvalOptions, evaluate};
use wonder3d::recon::{Preset, ReconOptions, reconstruct};
use wonder3d::sheet::{SheetRow, contact_sheet, normal_picture};
use wonder3d::{Image, Mesh, ViewRig, ViewSet};

use crate::train_small::{HELD_OUT_MESH, TRAIN_MESHES};

fn err(e: impl std::fmt::Display) -> String {
    e.to_string()
}

/// Timesteps at which [`condition_use`] measures the denoiser.
const PROBE_TIMESTEPS: [usize; 4] = [200, 600, 800, 950];

/// How much the model's denoising uses its condition: over 7 training samples (one per
/// object) in both domains, the mean squared error of the x₀ the model implies (from its ε or
/// v prediction) against the true latents at each of [`PROBE_TIMESTEPS`], with the sample's own
/// condition, with another object's, and with none (the unconditional branch). The latents have
/// unit variance, so 1 is no better than their mean; a model that follows its input has a
/// much lower error with its own condition than with none, most of all at the noisiest steps.
fn condition_use(pipeline: &MultiViewPipeline, data: &Path) -> Result<Vec<serde_json::Value>, String> {
    use wonder3d::diffusion::train::data::{EncodedSample, TrainingSet, assemble_batch};
    use wonder3d::diffusion::train::{ConditionDrop, DiffusionObjective, Stage, StepDraws};
    use wonder3d::diffusion::{DdimScheduler, Prediction, gaussian_noise};

    let device = wonder3d::diffusion::default_device();
    let set = TrainingSet::open(data).map_err(err)?;
    let per_object = set.len() / TRAIN_MESHES.len();
    let class_dim = pipeline.unet().config().projection_class_embeddings_input_dim.unwrap_or(14);
    let encoded: Vec<EncodedSample> = (0..TRAIN_MESHES.len())
        .map(|o| EncodedSample::encode(pipeline, &set.images(o * per_object).map_err(err)?, &device).map_err(err))
        .collect::<Result<_, _>>()?;
    let objective = DiffusionObjective::new(pipeline.scheduler().clone(), None).map_err(err)?;
    let ddim = DdimScheduler::new(pipeline.scheduler().clone(), 1).map_err(err)?;
    let to_x0 = |t: usize, mse: f64| {
        let a = ddim.alphas_cumprod()[t];
        match ddim.prediction() {
            Prediction::Epsilon => mse * (1.0 - a) / a,
            Prediction::VPrediction => mse * (1.0 - a),
            Prediction::Sample => mse,
        }
    };
    let mut rows = Vec::new();
    for t in PROBE_TIMESTEPS {
        let (mut own, mut other, mut none) = (0.0, 0.0, 0.0);
        for (k, sample) in encoded.iter().enumerate() {
            let batch = assemble_batch(Stage::CrossDomain, &[sample], &[], class_dim).map_err(err)?;
            let draws = StepDraws {
                timesteps: vec![t, t],
                noise: gaussian_noise(batch.latents.dims(), 7 + k as u64, &device),
                condition_drops: vec![ConditionDrop::Keep],
            };
            let mse = |batch: &wonder3d::diffusion::train::TrainBatch, draws: &StepDraws| -> Result<f64, String> {
                let loss = objective.loss(pipeline.unet(), batch, draws).map_err(err)?;
                Ok(f64::from(loss.into_scalar::<f32>()))
            };
            own += mse(&batch, &draws)?;
            let swap = assemble_batch(Stage::CrossDomain, &[&encoded[(k + 1) % encoded.len()]], &[], class_dim)
                .map_err(err)?;
            let mut swapped = batch.clone();
            swapped.condition_latents = swap.condition_latents;
            swapped.image_embeddings = swap.image_embeddings;
            other += mse(&swapped, &draws)?;
            let dropped = StepDraws { condition_drops: vec![ConditionDrop::ClipAndImage], ..draws.clone() };
            none += mse(&batch, &dropped)?;
        }
        let n = encoded.len() as f64;
        let (own, other, none) = (to_x0(t, own / n), to_x0(t, other / n), to_x0(t, none / n));
        eprintln!("  x0 error at t = {t}: own condition {own:.3}, another object's {other:.3}, none {none:.3}");
        rows.push(serde_json::json!({ "t": t, "own": own, "other": other, "none": none }));
    }
    Ok(rows)
}

/// The object name of a mesh path (its file stem: `spot`, `bob_tri`, …).
pub(crate) fn object_name(mesh_path: &str) -> String {
    Path::new(mesh_path).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
}

/// The mesh paths (from the workspace root) of the objects `objects` names, comma-separated;
/// without a list, every training object, then the held-out one.
pub(crate) fn pick_objects(objects: Option<&str>) -> Result<Vec<&'static str>, String> {
    let all: Vec<&'static str> = TRAIN_MESHES.iter().copied().chain([HELD_OUT_MESH]).collect();
    let Some(list) = objects else { return Ok(all) };
    list.split(',')
        .map(|name| {
            all.iter().copied().find(|m| object_name(m) == name.trim()).ok_or_else(|| {
                let names: Vec<String> = all.iter().map(|m| object_name(m)).collect();
                format!("--objects: no object {:?} (one of {})", name.trim(), names.join(", "))
            })
        })
        .collect()
}

/// The sample an object is scored on (seed 0, sample 0 at `size`: a training sample for the
/// training objects), as a one-sample dataset, and the object as that sample poses it, in the
/// unit cube as a prediction is compared with it.
pub(crate) fn scored_sample(path: &Path, size: u32) -> Result<(Dataset, Mesh), String> {
    let options = DatasetOptions::default().with_samples(1).with_size(size).with_seed(0);
    let dataset = Dataset::prepare(&[path], &options).map_err(err)?;
    // The draw of this sample (seed 0, index 0), as the dataset made it.
    let draw = sample_draw(0, &id_stem(path), 0, None);
    let mut posed = dataset.objects()[0].posed(&draw).map_err(err)?;
    posed.normalize_unit_cube();
    Ok((dataset, posed))
}

/// An object as the small model is scored on it: its sample, the true views, the posed mesh
/// in the unit cube, the model's input (the true front colour view with its mask as alpha) and
/// the sample's camera type.
pub(crate) struct ScoredObject {
    pub sample: wonder3d::dataset::Sample,
    pub truth: ViewSet,
    pub posed: Mesh,
    pub rgba: Image,
    pub camera: CameraType,
}

/// The [`ScoredObject`] of the mesh at `path`, at the model's image `size`.
pub(crate) fn scored_object(path: &Path, size: u32) -> Result<ScoredObject, String> {
    let (dataset, posed) = scored_sample(path, size)?;
    let sample = dataset.samples().next().cloned().ok_or("no sample")?;
    let truth = dataset.render_sample(0).map_err(err)?;
    let front = &truth.views()[0];
    let colour = front.colour.as_ref().ok_or("no colour view")?;
    let rgba: Vec<f32> =
        colour.data().chunks_exact(3).zip(front.mask.data()).flat_map(|(c, &m)| [c[0], c[1], c[2], m]).collect();
    let rgba = Image::new(size, size, 4, rgba).map_err(err)?;
    let camera = if sample.camera.name() == "persp" { CameraType::Perspective } else { CameraType::Orthographic };
    Ok(ScoredObject { sample, truth, posed, rgba, camera })
}

/// How `eval-small` samples (the command's flags).
pub(crate) struct Sampling {
    pub sampler: String,
    pub steps: usize,
    pub guidance: f64,
    pub eta: f64,
    pub independent_noise: bool,
    pub draws: usize,
}

/// The views of [`MESH_VIEWS`] in the rig's order, by index.
const MESH_VIEW_INDICES: [usize; 2] = [1, 3];
/// Sheet labels of the mesh pictures (`m` for mesh, as `n` and `c` for the normal and colour views).
const MESH_VIEWS: [&str; 2] = ["m f-right", "m back"];

/// Normal pictures of `mesh` (put into the unit cube) from the orthographic rig's
/// [`MESH_VIEW_INDICES`] views at `size`; blank ones without a mesh (a failed
/// reconstruction).
fn mesh_pictures(mesh: Option<&Mesh>, size: u32) -> Result<Vec<Image>, String> {
    let Some(mesh) = mesh else {
        let blank = Image::new(size, size, 3, vec![1.0; (size * size * 3) as usize]).map_err(err)?;
        return Ok(vec![blank; MESH_VIEW_INDICES.len()]);
    };
    let mut mesh = mesh.clone();
    mesh.normalize_unit_cube();
    let views = wonder3d::raster::render_oracle_views(&mesh, &ViewRig::wonder3d_ortho(), size).map_err(err)?;
    MESH_VIEW_INDICES
        .iter()
        .map(|&i| {
            let v = &views.views()[i];
            normal_picture(&v.normal, &v.mask).map_err(err)
        })
        .collect()
}

/// `rgb` (3 channels, values in `[0, 1]`) composited over white by `mask`: how the model sees a
/// view.
fn on_white(rgb: &[f32], mask: &Image) -> Result<Image, String> {
    let values: Vec<f32> = rgb
        .chunks_exact(3)
        .zip(mask.data())
        .flat_map(|(c, &m)| c.iter().map(move |&x| x * m + (1.0 - m)).collect::<Vec<_>>())
        .collect();
    Image::new(mask.width(), mask.height(), 3, values).map_err(err)
}

/// The best the model could score through its VAE: the true views on white (normals encoded
/// as `(n + 1) / 2`, as the model draws them) encoded and decoded, then read back as
/// generated views are ([`wonder3d::diffusion::GeneratedViews::to_view_set`]) — the normal error and mask IoU of
/// a perfect denoiser.
fn vae_round_trip(
    pipeline: &MultiViewPipeline,
    truth: &ViewSet,
    camera: CameraType,
    device: &wonder3d::diffusion::Device,
) -> Result<wonder3d::eval::ViewAgreement, String> {
    let mut latents = Vec::new();
    for encode_normals in [true, false] {
        for view in truth.views() {
            let image = if encode_normals {
                let encoded: Vec<f32> = view.normal.data().iter().map(|&n| (n + 1.0) * 0.5).collect();
                on_white(&encoded, &view.mask)?
            } else {
                on_white(view.colour.as_ref().ok_or("no colour view")?.data(), &view.mask)?
            };
            latents.push(pipeline.image_latent(&image, device).map_err(err)?);
        }
    }
    let decoded = pipeline.decode(wonder3d::diffusion::Tensor::cat(latents, 0), camera).map_err(err)?;
    wonder3d::eval::view_agreement(truth, &decoded.to_view_set().map_err(err)?).map_err(err)
}

pub(crate) fn run(
    model: &Path,
    out: &Path,
    sampling: &Sampling,
    objects: Option<&str>,
    sheet_path: Option<&Path>,
    data: Option<&Path>,
) -> Result<(), String> {
    if sampling.independent_noise && sampling.draws != 1 {
        return Err("--independent-noise draws once (--draws 1)".into());
    }
    let root = crate::workspace::workspace_root();
    // Checked before the model loads.
    let picks = pick_objects(objects)?;
    let picture = sheet_path.map_or_else(|| out.join("small_model.png"), |p| root.join(p));
    // The explicit sheet's folder is checked before minutes of generation, not after.
    if let Some(parent) = sheet_path.and(picture.parent()).filter(|p| !p.is_dir()) {
        return Err(format!("--sheet {}: its folder {} does not exist", picture.display(), parent.display()));
    }
    let sampler: SamplerKind = sampling.sampler.parse().map_err(err)?;
    let steps = sampling.steps;
    let device = wonder3d::diffusion::default_device();
    let pipeline = MultiViewPipeline::from_dir(model, &device).map_err(err)?;
    let probe = match data {
        Some(data) => condition_use(&pipeline, data)?,
        None => Vec::new(),
    };
    let size = pipeline.image_size() as u32;
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let mut rows = Vec::new();
    let mut records = Vec::new();
    for mesh_path in picks {
        let held_out = mesh_path == HELD_OUT_MESH;
        let ScoredObject { sample, truth, posed, rgba, camera } = scored_object(&root.join(mesh_path), size)?;
        let sample_options = SampleOptions {
            sampler,
            steps,
            guidance: sampling.guidance,
            eta: sampling.eta,
            camera,
            seed: 42,
            draws: sampling.draws,
            ..SampleOptions::default()
        };
        let t = Instant::now();
        let generated = if sampling.independent_noise {
            let input = wonder3d::diffusion::prepare_input(&rgba, size).map_err(err)?;
            let cond = pipeline.condition(&input, &device).map_err(err)?;
            let [v, c, h, w] = pipeline.noise_shape();
            let noise = wonder3d::diffusion::gaussian_noise([2 * v, c, h, w], sample_options.seed, &device);
            let latents = pipeline.sample_from(noise, &cond, &sample_options, &mut |_, _| {}).map_err(err)?;
            pipeline.decode(latents, camera).map_err(err)?
        } else {
            pipeline.generate(&rgba, &sample_options, &device, &mut |_, _| {}).map_err(err)?
        };
        let generate_s = t.elapsed().as_secs_f64();
        let views = generated.to_view_set().map_err(err)?;
        let agreement = wonder3d::eval::view_agreement(&truth, &views).map_err(err)?;
        let (angle, iou) = (agreement.normal_angle_deg, agreement.mask_iou);
        let ceiling = vae_round_trip(&pipeline, &truth, camera, &device)?;
        let name = object_name(mesh_path);
        views.save(out.join(&name)).map_err(err)?;
        // As `wonder3d run` and `demo --from-image` reconstruct generated views.
        let recon_options = ReconOptions::preset(Preset::Default).with_starts(wonder3d::GENERATED_VIEW_STARTS);
        let recon = reconstruct(&views, &recon_options, &mut |_| {});
        let chamfer = match &recon {
            Ok((mesh, _)) => {
                wonder3d::save_mesh(out.join(format!("{name}.obj")), mesh).map_err(err)?;
                let metrics = evaluate(mesh, &posed, &EvalOptions::default().with_normalize_pred(true)).map_err(err)?;
                Some(metrics.chamfer)
            }
            Err(e) => {
                eprintln!("{name}: reconstruction failed: {e}");
                None
            }
        };
        eprintln!(
            "{name:>22} ({}): normal error {angle:5.1}° ({:4.1}° leaving out the rim), mask IoU {iou:.3}, CD {}, generation {generate_s:.1} s",
            if held_out { "held out" } else { "training" },
            agreement.interior_normal_angle_deg,
            chamfer.map_or("-".into(), |c| format!("{c:.4}"))
        );
        eprintln!(
            "{:>22}   through the VAE alone: normal error {:5.1}° ({:4.1}° leaving out the rim), mask IoU {:.3}",
            "", ceiling.normal_angle_deg, ceiling.interior_normal_angle_deg, ceiling.mask_iou
        );
        records.push(serde_json::json!({
            "object": name, "held_out": held_out, "camera": sample.camera.name(),
            "normal_angle_deg": angle, "mask_iou": iou,
            "interior_normal_angle_deg": agreement.interior_normal_angle_deg, "interior_pixels": agreement.interior_pixels, "pixels": agreement.pixels,
            "vae_round_trip": {
                "normal_angle_deg": ceiling.normal_angle_deg, "mask_iou": ceiling.mask_iou,
                "interior_normal_angle_deg": ceiling.interior_normal_angle_deg,
            }, "chamfer": chamfer, "generate_seconds": generate_s,
            "steps": steps, "sampler": sampler.name(), "guidance": sampling.guidance, "eta": sampling.eta,
            "independent_noise": sampling.independent_noise, "draws": sampling.draws,
        }));
        let input = wonder3d::diffusion::prepare_input(&rgba, size).map_err(err)?;
        let pictures = |set: &ViewSet| -> Result<Vec<Image>, String> {
            set.views().iter().map(|v| normal_picture(&v.normal, &v.mask).map_err(err)).collect()
        };
        let mut gen_row = vec![input.clone()];
        gen_row.extend(pictures(&views)?);
        gen_row.extend(generated.colours.iter().cloned());
        gen_row.extend(mesh_pictures(recon.as_ref().ok().map(|(mesh, _)| mesh), size)?);
        let mut true_row = vec![input];
        true_row.extend(pictures(&truth)?);
        for v in truth.views() {
            true_row.push(on_white(v.colour.as_ref().ok_or("no colour view")?.data(), &v.mask)?);
        }
        true_row.extend(mesh_pictures(Some(&posed), size)?);
        let tag = if held_out { " (held out)" } else { "" };
        rows.push(SheetRow { label: format!("{name}{tag}: generated"), images: gen_row });
        rows.push(SheetRow { label: format!("{name}: truth"), images: true_row });
    }
    let labels = [
        "input",
        "n front",
        "n f-right",
        "n right",
        "n back",
        "n left",
        "n f-left",
        "c front",
        "c f-right",
        "c right",
        "c back",
        "c left",
        "c f-left",
        MESH_VIEWS[0],
        MESH_VIEWS[1],
    ];
    let sheet = contact_sheet(&labels, &rows).map_err(err)?;
    sheet.write_png(&picture).map_err(err)?;
    let record = serde_json::json!({
        "model": model.display().to_string(), "objects": records, "condition_use_x0_mse": probe,
    });
    std::fs::write(out.join("eval.json"), serde_json::to_vec_pretty(&record).map_err(err)?)
        .map_err(|e| format!("{}: {e}", out.display()))?;
    eprintln!("wrote {} and {}", out.join("eval.json").display(), picture.display());
    Ok(())
}
