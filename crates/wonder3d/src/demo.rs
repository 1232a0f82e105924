//! The demo: the whole extraction on the bundled spot (Keenan Crane, CC0) with no downloads —
//! oracle views → [`Pipeline::from_views`] → textured mesh, scored against the original, with
//! a labelled contact sheet. `wonder3d demo` is a thin shell over [`run_demo`].

use std::path::Path;
use std::time::Instant;

use serde::Serialize;
use w3d_eval::{EvalOptions, MeshMetrics, composite_over_white, evaluate, psnr, ssim};
use w3d_recon::Preset;

use crate::pipeline::{Output, Pipeline, Progress, Report, Stage};
use crate::sheet::{SheetRow, contact_sheet, normal_picture};
use crate::{Error, Image, Mesh, Result, ViewRig};

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
}

impl Default for DemoOptions {
    fn default() -> Self {
        DemoOptions { preset: Preset::Default, view_size: 256, texture_size: 1024 }
    }
}

impl DemoOptions {
    /// With another preset.
    pub fn with_preset(mut self, preset: Preset) -> Self {
        self.preset = preset;
        self
    }

    /// With another view size.
    pub fn with_view_size(mut self, size: u32) -> Self {
        self.view_size = size;
        self
    }

    /// With another texture size.
    pub fn with_texture_size(mut self, size: u32) -> Self {
        self.texture_size = size;
        self
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
    let (mut psnrs, mut ssims) = (Vec::new(), Vec::new());
    let labels = ["input colour", "input normal", "result colour", "result normal"];
    let mut rows: Vec<SheetRow> =
        labels.iter().map(|l| SheetRow { label: l.to_string(), images: Vec::new() }).collect();
    for (input, result) in views.views().iter().zip(result_views.views()) {
        let (Some(ci), Some(cr)) = (&input.colour, &result.colour) else {
            return Err(Error::invalid("demo views", "colour images in the oracle views"));
        };
        let (ci, cr) = (ci.with_alpha(&input.mask)?, cr.with_alpha(&result.mask)?);
        let (a, r) = (composite_over_white(&ci)?, composite_over_white(&cr)?);
        psnrs.push(psnr(&a, &r)?);
        ssims.push(ssim(&a, &r)?);
        rows[0].images.push(ci);
        rows[1].images.push(normal_picture(&input.normal, &input.mask)?);
        rows[2].images.push(cr);
        rows[3].images.push(normal_picture(&result.normal, &result.mask)?);
    }
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
        total_seconds: start.elapsed().as_secs_f64(),
    };
    Ok(Demo { output, sheet, report })
}
