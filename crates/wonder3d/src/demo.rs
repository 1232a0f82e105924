//! The demo: the whole extraction on the bundled spot (Keenan Crane, CC0) with no downloads —
//! oracle views → [`Pipeline::from_views`] → textured mesh, scored against the original, with
//! a labelled contact sheet. `wonder3d demo` is a thin shell over [`run_demo`].
//!
//! With a model ([`run_demo_from_image`], `wonder3d demo --from-image`), the demo starts
//! from a photo of spot instead — its front render on a plain backdrop, spot turned as a
//! training sample of the small model shows it ([`PHOTO_SAMPLE`]): background removal → the
//! model's 6 normal + colour views → mesh and texture, with the generated views scored
//! against spot's true views ([`w3d_eval::view_agreement`]).

use std::path::Path;
use std::time::Instant;

use serde::Serialize;
use w3d_core::{Error, Image, Mesh, Result, ViewRig, ViewSet};
use w3d_eval::{EvalOptions, MeshMetrics, composite_over_white, evaluate, psnr, ssim};
use w3d_recon::Preset;

use crate::pipeline::{Output, Pipeline, Report};
use crate::progress::{Progress, Stage};
use crate::sheet::{SheetRow, contact_sheet, normal_picture};

/// The bundled demo object: spot as a self-contained GLB (mesh, uvs and texture), turned to
/// face the `front` camera (+z); see `assets/SOURCES.md` in this crate.
const SPOT_GLB: &[u8] = include_bytes!("../assets/spot.glb");

/// Spot (Keenan Crane, CC0), normalised into the unit cube and facing `front`, with its
/// texture: the ground truth of the demo.
pub fn bundled_spot() -> Result<Mesh> {
    let mut spot = w3d_core::io::read_glb_bytes("bundled spot.glb", SPOT_GLB)?;
    spot.normalize_unit_cube();
    Ok(spot)
}

/// Options of [`run_demo`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct DemoOptions {
    /// Reconstruction preset (default [`Preset::Default`]).
    pub preset: Preset,
    /// Side of the rendered oracle views in pixels (default 256).
    pub view_size: u32,
    /// Side of the baked texture in texels (default 1024).
    pub texture_size: u32,
    /// Fits tried on the generated views of [`run_demo_from_image`], the best kept (default
    /// [`crate::pipeline::GENERATED_VIEW_STARTS`]; [`crate::Pipeline::with_generated_view_starts`]).
    pub generated_view_starts: usize,
}

impl Default for DemoOptions {
    fn default() -> Self {
        DemoOptions {
            preset: Preset::Default,
            view_size: 256,
            texture_size: 1024,
            generated_view_starts: crate::pipeline::GENERATED_VIEW_STARTS,
        }
    }
}

impl DemoOptions {
    w3d_core::setters! {
        /// With another preset.
        with_preset(preset: Preset);
        /// With another view size.
        with_view_size(view_size: u32);
        /// With another texture size.
        with_texture_size(texture_size: u32);
        /// With another number of fits on the generated views.
        with_generated_view_starts(generated_view_starts: usize);
    }
}

/// What the demo measured; `report.json`.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[non_exhaustive]
pub struct DemoReport {
    /// Where the object comes from.
    pub object: &'static str,
    /// Side of the oracle views.
    pub view_size: u32,
    /// Seconds spent rendering the oracle views and evaluating (the pipeline's own times are
    /// in [`DemoReport::pipeline`]).
    pub render_seconds: f64,
    /// Seconds spent scoring the result.
    pub evaluate_seconds: f64,
    /// Chamfer, F-score, volume IoU, normal consistency against the original.
    pub geometry: MeshMetrics,
    /// Mean PSNR (dB) of renders of the textured result against the input colour views,
    /// composited over white.
    pub texture_psnr_input_views: f64,
    /// Mean SSIM of the same pairs.
    pub texture_ssim_input_views: f64,
    /// PSNR per view, in rig order.
    pub texture_psnr_per_view: Vec<f64>,
    /// The pipeline run: preset, triangles, stage timings, reconstruction and texture reports.
    pub pipeline: Report,
    /// From an image only: the generated views against spot's true views (rendered with
    /// the generated views' rig, spot framed as the input was).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub generated_views: Option<w3d_eval::ViewAgreement>,
    /// Wall-clock seconds of the whole demo.
    pub total_seconds: f64,
}

/// The demo's result.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct Demo {
    /// The pipeline output (textured mesh, closed geometry, the oracle views).
    pub output: Output,
    /// Input colour and normal views above renders of the result, labelled.
    pub sheet: Image,
    /// The measurements.
    pub report: DemoReport,
}

impl Demo {
    /// Writes `spot.glb`, `views.png` and `report.json` into `dir` (created if needed). All
    /// three are written to temporary names first and renamed together at the end, so a
    /// failure leaves the folder as it was.
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<()> {
        let dir = dir.as_ref();
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        let json = serde_json::to_vec_pretty(&self.report).map_err(|e| Error::invalid("report", e.to_string()))?;
        let staged = [
            (dir.join(".spot.glb.partial.glb"), dir.join("spot.glb")),
            (dir.join(".views.png.partial.png"), dir.join("views.png")),
            (dir.join(".report.json.partial"), dir.join("report.json")),
        ];
        let written = (|| {
            self.output.save(&staged[0].0)?;
            self.sheet.write_png(&staged[1].0)?;
            std::fs::write(&staged[2].0, &json).map_err(|e| Error::io(&staged[2].0, e))
        })();
        if let Err(e) = written {
            for (tmp, _) in &staged {
                let _ = std::fs::remove_file(tmp);
            }
            return Err(e);
        }
        for (tmp, path) in &staged {
            std::fs::rename(tmp, path).map_err(|e| Error::io(path, e))?;
        }
        Ok(())
    }
}

/// Runs the demo: renders 6 orthographic oracle views of [`bundled_spot`], runs the
/// [`Pipeline`] with `options`, scores the closed mesh against spot and the textured mesh's
/// renders against the input colours, and draws the contact sheet.
pub fn run_demo(options: &DemoOptions, progress: &mut dyn FnMut(Progress)) -> Result<Demo> {
    let start = Instant::now();
    let rig = ViewRig::wonder3d_ortho();
    progress(Progress::new(Stage::Render, 0, 1, None));
    let spot = bundled_spot()?;
    let views = w3d_raster::render_oracle_views(&spot, &rig, options.view_size)?;
    let render_seconds = start.elapsed().as_secs_f64();
    progress(Progress::new(Stage::Render, 1, 1, None));

    let pipeline = Pipeline::new().with_preset(options.preset).with_texture_size(options.texture_size);
    let output = pipeline.from_views(&views, progress)?;

    progress(Progress::new(Stage::Evaluate, 0, 1, None));
    let t = Instant::now();
    let geometry = evaluate(&output.geometry, &spot, &EvalOptions::default())?;
    let result_views = w3d_raster::render_oracle_views(&output.mesh, &rig, options.view_size)?;
    let (psnrs, ssims, [input_colour, input_normal, result_colour, result_normal]) =
        score_renders(&views, &result_views)?;
    let row = |label: &str, images: Vec<Image>| SheetRow { label: label.to_string(), images };
    let rows = [
        row("input colour", input_colour),
        row("input normal", input_normal),
        row("result colour", result_colour),
        row("result normal", result_normal),
    ];
    let names: Vec<&str> = rig.views.iter().map(|v| v.name.as_str()).collect();
    let sheet = contact_sheet(&names, &rows)?;
    let evaluate_seconds = t.elapsed().as_secs_f64();
    progress(Progress::new(Stage::Evaluate, 1, 1, None));

    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let report = DemoReport {
        object: "spot (Keenan Crane, CC0), bundled",
        view_size: options.view_size,
        render_seconds,
        evaluate_seconds,
        geometry,
        texture_psnr_input_views: mean(&psnrs),
        texture_ssim_input_views: mean(&ssims),
        texture_psnr_per_view: psnrs,
        pipeline: output.report.clone(),
        generated_views: None,
        total_seconds: start.elapsed().as_secs_f64(),
    };
    Ok(Demo { output, sheet, report })
}

/// Grey level of the plain backdrop the demo's photo is composited on (sRGB): a mid blue-grey
/// that neither spot's white nor its black patches match.
#[cfg(feature = "diffusion")]
const BACKDROP: [f32; 3] = [0.42, 0.52, 0.66];

/// PSNR per view, SSIM per view, and the sheet's pictures (input colour, input normal, result
/// colour, result normal).
type Scores = (Vec<f64>, Vec<f64>, [Vec<Image>; 4]);

/// Texture PSNR and SSIM of each view's render of the result (`results`) against the input
/// view it was made from (`inputs`, same rig and size), both composited over white, with the
/// contact sheet's pictures of both.
fn score_renders(inputs: &ViewSet, results: &ViewSet) -> Result<Scores> {
    let (mut psnrs, mut ssims) = (Vec::new(), Vec::new());
    let mut pictures: [Vec<Image>; 4] = Default::default();
    for (input, result) in inputs.views().iter().zip(results.views()) {
        let (Some(ci), Some(cr)) = (&input.colour, &result.colour) else {
            return Err(Error::invalid("demo views", "colour images in the input views"));
        };
        let (ci, cr) = (ci.with_alpha(&input.mask)?, cr.with_alpha(&result.mask)?);
        let (a, r) = (composite_over_white(&ci)?, composite_over_white(&cr)?);
        psnrs.push(psnr(&a, &r)?);
        ssims.push(ssim(&a, &r)?);
        pictures[0].push(ci);
        pictures[1].push(normal_picture(&input.normal, &input.mask)?);
        pictures[2].push(cr);
        pictures[3].push(normal_picture(&result.normal, &result.mask)?);
    }
    Ok((psnrs, ssims, pictures))
}

/// The training sample whose pose [`run_demo_from_image`] photographs spot in: sample 0 of
/// spot in the small model's training set (`cargo xtask train-small`, dataset seed 0), drawn
/// by [`crate::dataset::sample_draw`] — yaw −29.7°, pitch 6.4°, orthographic.
///
/// Why a training pose and not spot's face-on front render: the training set renders the
/// repository's `assets/spot.obj`, which faces −z, so every training sample shows spot from
/// behind (yaw within ±60° of its back), while the bundled GLB faces the front camera. A model
/// trained on seven objects generalises to no pose it has not seen: spot face-on scores 59°
/// normal error and mask IoU 0.46, this pose 25° and 0.91 (docs/training.md).
#[cfg(feature = "diffusion")]
pub const PHOTO_SAMPLE: usize = 0;

/// How the small model trained here (`assets/model-small`, docs/training.md) samples best,
/// and how [`run_demo_from_image`] is run with it: the Wonder3D++ defaults (50 DDIM steps, eta 1,
/// seed 42) but without guidance, and with 4 draws merged into their consensus.
///
/// Why: guidance 1 skips the unconditional branch, so it halves the generation, and it scores
/// this model as well as the authors' 2 (0.4–1.2° less normal error on the training objects);
/// 4 draws take 1–2° off the normal error of one (docs/training.md, "Where the error comes
/// from"). A full-size model is sampled as its authors do ([`crate::SampleOptions::default`]).
///
/// ```
/// let options = wonder3d::demo::small_model_sampling();
/// assert_eq!((options.guidance, options.draws), (1.0, 4));
/// ```
#[cfg(feature = "diffusion")]
pub fn small_model_sampling() -> w3d_diffusion::SampleOptions {
    w3d_diffusion::SampleOptions { guidance: 1.0, draws: 4, ..Default::default() }
}

/// Spot as the training set shows it in sample [`PHOTO_SAMPLE`]: the bundled spot turned
/// back to `assets/spot.obj`'s orientation (180° about +y), then posed and framed like the
/// sample ([`crate::dataset::pose`]).
#[cfg(feature = "diffusion")]
pub fn photo_subject() -> Result<Mesh> {
    let mut spot = bundled_spot()?;
    spot.map_positions(|p| w3d_core::glam::Vec3::new(-p.x, p.y, -p.z))?;
    let draw = crate::dataset::sample_draw(0, "spot", PHOTO_SAMPLE, None);
    crate::dataset::pose(&spot, &draw)
}

/// `subject`'s front render (orthographic, `size`²) over [`BACKDROP`]: an RGB photo.
#[cfg(feature = "diffusion")]
fn spot_photo(spot: &Mesh, size: u32) -> Result<Image> {
    let front = w3d_raster::render_oracle_views(spot, &ViewRig::wonder3d_ortho(), size)?;
    let view = &front.views()[0];
    let colour = view.colour.as_ref().ok_or_else(|| Error::invalid("demo views", "a colour front view"))?;
    let photo: Vec<f32> = colour
        .data()
        .chunks_exact(3)
        .zip(view.mask.data())
        .flat_map(|(c, &m)| [0, 1, 2].map(|k| c[k] * m + BACKDROP[k] * (1.0 - m)))
        .collect();
    Image::new(size, size, 3, photo)
}

/// The demo from one image: the front render of spot posed as [`photo_subject`] poses it, at
/// `options.view_size`² composited over a plain backdrop (an RGB photo, no alpha), then
/// [`Pipeline::from_image`] with `generator` (background removal, generation, reconstruction,
/// texture). Scored like [`run_demo`]: the closed mesh against the posed spot (both
/// normalised into the unit cube, since the generated views frame the object as the photo
/// did), the textured mesh's renders against the generated colour
/// views; and the generated normals and masks against spot's true views
/// ([`DemoReport::generated_views`]). The contact sheet shows the photo, the generated and
/// the true views and renders of the result.
#[cfg(feature = "diffusion")]
pub fn run_demo_from_image(
    generator: crate::generate::Generator,
    options: &DemoOptions,
    progress: &mut dyn FnMut(Progress),
) -> Result<Demo> {
    let start = Instant::now();
    crate::pipeline::check_generated_view_starts(options.generated_view_starts)?;
    progress(Progress::new(Stage::Render, 0, 1, None));
    let subject = photo_subject()?;
    let photo = spot_photo(&subject, options.view_size)?;
    let render_seconds = start.elapsed().as_secs_f64();
    progress(Progress::new(Stage::Render, 1, 1, None));

    let pipeline = Pipeline::new()
        .with_preset(options.preset)
        .with_generated_view_starts(options.generated_view_starts)
        .with_texture_size(options.texture_size)
        .with_model(generator);
    let output = pipeline.from_image(&photo, progress)?;

    progress(Progress::new(Stage::Evaluate, 0, 1, None));
    let t = Instant::now();
    // The ground truth in the unit cube, as the prediction is normalised.
    let mut truth_mesh = subject.clone();
    truth_mesh.normalize_unit_cube();
    let geometry = evaluate(&output.geometry, &truth_mesh, &EvalOptions::default().with_normalize_pred(true))?;
    let generated = &output.views;
    let size = generated.views()[0].mask.width();
    let truth = w3d_raster::render_oracle_views(&subject, generated.rig(), size)?;
    let agreement = w3d_eval::view_agreement(&truth, generated)?;
    let result_views = w3d_raster::render_oracle_views(&output.mesh, generated.rig(), size)?;
    let (psnrs, ssims, [generated_colour, generated_normal, result_colour, result_normal]) =
        score_renders(generated, &result_views)?;
    let true_normal = truth.views().iter().map(|v| normal_picture(&v.normal, &v.mask)).collect::<Result<_>>()?;
    let row = |label: &str, images: Vec<Image>| SheetRow { label: label.to_string(), images };
    let mut rows = vec![
        row("generated colour", generated_colour),
        row("generated normal", generated_normal),
        row("true normal", true_normal),
        row("result colour", result_colour),
        row("result normal", result_normal),
    ];
    // The photo (rendered again at the views' size) and what the model saw, in a first row.
    let mut first = vec![spot_photo(&subject, size)?];
    first.extend(output.input.clone().filter(|i| i.width() == size && i.height() == size));
    rows.insert(0, SheetRow { label: "photo, model input".into(), images: first });
    let names: Vec<&str> = generated.rig().views.iter().map(|v| v.name.as_str()).collect();
    let sheet = contact_sheet(&names, &rows)?;
    let evaluate_seconds = t.elapsed().as_secs_f64();
    progress(Progress::new(Stage::Evaluate, 1, 1, None));

    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let report = DemoReport {
        object: "spot (Keenan Crane, CC0), bundled, posed as the small model's training sample 0: its front render as a photo",
        view_size: options.view_size,
        render_seconds,
        evaluate_seconds,
        geometry,
        texture_psnr_input_views: mean(&psnrs),
        texture_ssim_input_views: mean(&ssims),
        texture_psnr_per_view: psnrs,
        pipeline: output.report.clone(),
        generated_views: Some(agreement),
        total_seconds: start.elapsed().as_secs_f64(),
    };
    Ok(Demo { output, sheet, report })
}
