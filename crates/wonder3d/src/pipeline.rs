//! [`Pipeline`]: views (or an image, with a model) → closed mesh → textured mesh, with one
//! staged progress callback and one serialisable [`Report`].

use std::path::Path;
use std::time::Instant;

use serde::Serialize;
use w3d_core::{Error, Image, Mesh, Result, ViewSet};
#[cfg(feature = "diffusion")]
use w3d_diffusion::SampleOptions;
use w3d_recon::{Preset, ReconOptions, ReconReport};
use w3d_texture::{BakeReport, TextureOptions};

#[cfg(feature = "diffusion")]
use crate::generate::{Generated, Generator};
use crate::progress::{Progress, Stage, TextureStage};

/// Wall-clock seconds of each part of a [`Pipeline`] run.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
#[non_exhaustive]
pub struct Seconds {
    /// Generating the views (0 when the run started from views).
    pub generate: f64,
    /// Mesh extraction.
    pub reconstruct: f64,
    /// Texturing (0 without texture).
    pub texture: f64,
    /// The whole run.
    pub total: f64,
}

/// Everything a [`Pipeline`] run measured; serialises to JSON with stable keys.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[non_exhaustive]
pub struct Report {
    /// The reconstruction preset, when the options came from one.
    pub preset: Option<Preset>,
    /// Triangles of the untextured mesh.
    pub triangles: usize,
    /// Stage timings.
    pub seconds: Seconds,
    /// The reconstruction's own report (start mesh, losses, crossings, per-stage timings).
    pub reconstruction: ReconReport,
    /// The texture bake's report, when the run textured the mesh.
    pub texture: Option<BakeReport>,
    /// The generation settings, when the run started from an image.
    pub generation: Option<GenerationReport>,
}

/// How the views of a run were generated.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[non_exhaustive]
pub struct GenerationReport {
    /// Sampling algorithm (`ddim`, `dpmpp-2m` or `unipc`).
    pub sampler: String,
    /// Sampling steps.
    pub steps: usize,
    /// Classifier-free guidance scale.
    pub guidance: f64,
    /// Sampling noise seed (of the first draw; the others follow it).
    pub seed: u64,
    /// Draws merged into the views (`SampleOptions::draws`).
    pub draws: usize,
    /// The rig of the generated views (`wonder3d-ortho` or `wonder3d-persp`).
    pub rig: String,
    /// The training-free accelerations of the sampling (`SampleOptions::acceleration`), as
    /// `Acceleration::describe` names them: `"none"`, or e.g. `"guidance in [0.1, 0.7],
    /// DeepCache every 2 from skip 1"`.
    pub acceleration: String,
}

/// The result of a [`Pipeline`] run.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct Output {
    /// The final mesh: textured (uvs, baked sRGB texture, vertices split along chart seams)
    /// unless the pipeline was built [`Pipeline::without_texture`], in the views' canonical
    /// frame (y up, front camera on +z; unit-cube scale).
    pub mesh: Mesh,
    /// The closed reconstructed mesh before texturing (welded, no attributes).
    pub geometry: Mesh,
    /// The views the mesh was made from (generated ones, for a run from an image).
    pub views: ViewSet,
    /// The conditioning image the model saw (white background, the model's size), for a
    /// run from an image.
    pub input: Option<Image>,
    /// What the run measured.
    pub report: Report,
}

impl Output {
    /// Writes [`Output::mesh`] to `path` (`.glb` with the texture embedded, `.obj` with
    /// `.mtl` and `.png` beside it, or `.ply`), atomically.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<()> {
        w3d_core::save_mesh(path, &self.mesh)
    }

    /// The report as pretty-printed JSON.
    pub fn report_json(&self) -> Result<String> {
        serde_json::to_string_pretty(&self.report).map_err(|e| Error::invalid("report", e.to_string()))
    }
}

/// Fits [`Pipeline::from_image`] tries on the views it generates, keeping the one that fits
/// them best ([`ReconOptions::starts`]). Generated views disagree with each other, and a
/// single fit to them then lands anywhere in a wide spread: on the small model's views of
/// the plane, eight remesher seeds gave Chamfer distances from 0.016 to 0.047, and the best
/// fit of four by final view loss averaged 0.023 (worst 0.028); on the hammer, the boot and
/// the wingnut the mean fell by 31–37 % and the worst case by 38–56 % (`docs/accuracy.md`,
/// "Several starts"). Four fits cost 2.7–4 times one fit's seconds, small beside generating
/// the views. Views no closed surface explains (a failed generation, an untrained model)
/// get one fit all the same ([`ReconOptions::hopeless_view_loss`]).
pub const GENERATED_VIEW_STARTS: usize = 4;

/// Refuses 0 fits of generated views before any long work: [`w3d_recon::reconstruct`] refuses
/// it too, but only once the views are generated.
pub(crate) fn check_generated_view_starts(starts: usize) -> Result<()> {
    if starts == 0 {
        return Err(Error::invalid("generated_view_starts", "at least 1 fit of the generated views (got 0)"));
    }
    Ok(())
}

/// The whole extraction as one configurable object: views → closed mesh (`w3d-recon`) →
/// textured mesh (`w3d-texture`), and, with a model ([`Pipeline::with_model`], feature
/// `diffusion`), image → views first.
///
/// Built with chained setters so new options never break callers:
///
/// ```
/// use wonder3d::{Pipeline, Preset};
///
/// let pipeline = Pipeline::new().with_preset(Preset::Fast).with_texture_size(512);
/// assert_eq!(pipeline.texture_options().map(|t| t.size), Some(512));
/// ```
pub struct Pipeline {
    preset: Option<Preset>,
    recon: ReconOptions,
    generated_starts: usize,
    texture: Option<TextureOptions>,
    #[cfg(feature = "diffusion")]
    model: Option<std::sync::Arc<Generator>>,
}

impl Default for Pipeline {
    fn default() -> Self {
        Pipeline::new()
    }
}

impl std::fmt::Debug for Pipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pipeline")
            .field("preset", &self.preset)
            .field("recon", &self.recon)
            .field("generated_starts", &self.generated_starts)
            .field("texture", &self.texture)
            .field("model", &self.has_model())
            .finish()
    }
}

impl Pipeline {
    /// The default preset and a 1024² texture, no model.
    pub fn new() -> Self {
        Pipeline {
            preset: Some(Preset::Default),
            recon: ReconOptions::preset(Preset::Default),
            generated_starts: GENERATED_VIEW_STARTS,
            texture: Some(TextureOptions::default()),
            #[cfg(feature = "diffusion")]
            model: None,
        }
    }

    /// Reconstruction options of a named speed/accuracy preset (`docs/accuracy.md`).
    pub fn with_preset(mut self, preset: Preset) -> Self {
        self.preset = Some(preset);
        self.recon = ReconOptions::preset(preset);
        self
    }

    /// Explicit reconstruction options (the report then names no preset).
    pub fn with_recon_options(mut self, options: ReconOptions) -> Self {
        self.preset = None;
        self.recon = options;
        self
    }

    /// Fits tried on views given to [`Pipeline::from_views`] ([`ReconOptions::starts`]; the
    /// preset's 1 unless set; the preset keeps its name in the report). Views generated
    /// elsewhere, by `wonder3d generate` for one, gain from more
    /// ([`GENERATED_VIEW_STARTS`]). At least 1: 0 is refused when the mesh is reconstructed.
    pub fn with_starts(mut self, starts: usize) -> Self {
        self.recon.starts = starts;
        self
    }

    /// Fits tried when the views are generated from an image ([`Pipeline::from_image`]; the
    /// best fit to the views is kept, [`ReconOptions::starts`]); [`GENERATED_VIEW_STARTS`]
    /// unless set. Views given to [`Pipeline::from_views`] get the reconstruction options'
    /// own count (1 in every preset). At least 1: 0 is refused when the mesh is reconstructed.
    pub fn with_generated_view_starts(mut self, starts: usize) -> Self {
        self.generated_starts = starts;
        self
    }

    /// Fits tried on generated views (see [`Pipeline::with_generated_view_starts`]).
    pub fn generated_view_starts(&self) -> usize {
        self.generated_starts
    }

    /// Texture options (and texturing on, if it was off).
    pub fn with_texture_options(mut self, options: TextureOptions) -> Self {
        self.texture = Some(options);
        self
    }

    /// Side of the square baked texture in texels (texturing on, other options kept).
    pub fn with_texture_size(mut self, size: u32) -> Self {
        self.texture = Some(self.texture.unwrap_or_default().with_size(size));
        self
    }

    /// No texturing: [`Output::mesh`] is the closed untextured mesh.
    pub fn without_texture(mut self) -> Self {
        self.texture = None;
        self
    }

    /// The reconstruction options in use.
    pub fn recon_options(&self) -> &ReconOptions {
        &self.recon
    }

    /// The texture options in use, `None` without texturing.
    pub fn texture_options(&self) -> Option<&TextureOptions> {
        self.texture.as_ref()
    }

    /// Whether a model is loaded, so [`Pipeline::from_image`] can run.
    pub fn has_model(&self) -> bool {
        #[cfg(feature = "diffusion")]
        return self.model.is_some();
        #[cfg(not(feature = "diffusion"))]
        false
    }

    /// Reconstructs and textures a mesh from views (normal maps, masks and, for texture,
    /// colours) with the rig they carry. `progress` receives [`Progress`] events (pass
    /// `&mut |_| {}` to ignore them).
    pub fn from_views(&self, views: &ViewSet, progress: &mut dyn FnMut(Progress)) -> Result<Output> {
        self.finish(views.clone(), None, None, 0.0, progress)
    }

    /// Mesh and texture from already generated or loaded views; `input`, `generation` and
    /// `generate_seconds` describe how they were made.
    fn finish(
        &self,
        views: ViewSet,
        input: Option<Image>,
        generation: Option<GenerationReport>,
        generate_seconds: f64,
        progress: &mut dyn FnMut(Progress),
    ) -> Result<Output> {
        let start = Instant::now();
        // Generated views disagree with each other, so one fit is a lottery (see
        // `GENERATED_VIEW_STARTS`); given views keep the options' count.
        let recon = match generation {
            Some(_) => self.recon.with_starts(self.generated_starts),
            None => self.recon,
        };
        let (geometry, reconstruction) = w3d_recon::reconstruct(&views, &recon, &mut |p| {
            progress(Progress::new(Stage::Reconstruct(p.stage), p.done, p.total, p.loss))
        })?;
        let reconstruct_seconds = start.elapsed().as_secs_f64();
        let t = Instant::now();
        let (mesh, texture) = match &self.texture {
            Some(options) => {
                let textured = w3d_texture::bake_with_progress(&geometry, &views, options, &mut |stage| {
                    progress(Progress::new(Stage::Texture(stage.into()), 0, 1, None))
                })?;
                progress(Progress::new(Stage::Texture(TextureStage::Dilating), 1, 1, None));
                (textured.mesh, Some(textured.report))
            }
            None => (geometry.clone(), None),
        };
        let texture_seconds = t.elapsed().as_secs_f64();
        let report = Report {
            preset: self.preset,
            triangles: geometry.triangle_count(),
            seconds: Seconds {
                generate: generate_seconds,
                reconstruct: reconstruct_seconds,
                texture: texture_seconds,
                total: generate_seconds + start.elapsed().as_secs_f64(),
            },
            reconstruction,
            texture,
            generation,
        };
        Ok(Output { mesh, geometry, views, input, report })
    }
}

#[cfg(feature = "diffusion")]
impl Pipeline {
    /// Uses `model` for [`Pipeline::from_image`]: a [`Generator`], or an
    /// `Arc<Generator>` that several pipelines (or other owners, such as the Python
    /// package's `Generator` object) share without loading the weights twice.
    pub fn with_model(mut self, model: impl Into<std::sync::Arc<Generator>>) -> Self {
        self.model = Some(model.into());
        self
    }

    /// The loaded model, if any.
    pub fn model(&self) -> Option<&Generator> {
        self.model.as_deref()
    }

    /// One image to a textured mesh: the model generates 6 normal + 6 colour views of
    /// `image` (RGBA with the object masked by alpha, or a photo whose background is removed
    /// automatically; see [`crate::Generator::generate`]), then [`Pipeline::from_views`]
    /// runs on them.
    pub fn from_image(&self, image: &Image, progress: &mut dyn FnMut(Progress)) -> Result<Output> {
        let model = self.model.as_ref().ok_or_else(|| {
            Error::invalid("pipeline model", "a loaded model (Pipeline::with_model) before from_image")
        })?;
        let start = Instant::now();
        let generated = model.generate(image, progress)?;
        self.extract_generated(generated, model.options(), start.elapsed().as_secs_f64(), progress)
    }

    /// Mesh and texture from views that `options` generated in `seconds` (the report records
    /// the settings).
    pub(crate) fn extract_generated(
        &self,
        generated: Generated,
        options: &SampleOptions,
        seconds: f64,
        progress: &mut dyn FnMut(Progress),
    ) -> Result<Output> {
        let generation = GenerationReport {
            sampler: options.sampler.name().to_string(),
            steps: options.steps,
            guidance: options.guidance,
            seed: options.seed,
            draws: options.draws,
            rig: generated.views.rig().name.clone(),
            acceleration: options.acceleration.describe(),
        };
        self.finish(generated.views, Some(generated.input), Some(generation), seconds, progress)
    }
}

#[cfg(all(test, feature = "diffusion"))]
mod tests {
    use super::*;

    /// Generated views get the generated-view count of fits, given views the options' own;
    /// the preset keeps its name when only the count changes.
    #[test]
    fn generated_views_get_several_fits() {
        use w3d_core::ViewRig;

        let sphere = w3d_remesh::icosphere(3, 0.35).unwrap();
        let views = w3d_raster::render_oracle_views(&sphere, &ViewRig::wonder3d_ortho(), 32).unwrap();
        let input = views.views()[0].mask.clone();
        let fast = ReconOptions::preset(Preset::Fast).with_coarse_steps(10);
        let pipeline = Pipeline::new().with_recon_options(fast).without_texture();
        assert_eq!(pipeline.generated_view_starts(), GENERATED_VIEW_STARTS);
        let pipeline = pipeline.with_generated_view_starts(2);
        let generated = Generated::new(views.clone(), input);
        let options = SampleOptions::default();
        let output = pipeline.extract_generated(generated, &options, 0.0, &mut |_| {}).unwrap();
        assert_eq!(output.report.reconstruction.start_losses.len(), 2);
        let given = pipeline.from_views(&views, &mut |_| {}).unwrap();
        assert_eq!(given.report.reconstruction.start_losses.len(), 1);
        let three = pipeline.with_starts(3).from_views(&views, &mut |_| {}).unwrap();
        assert_eq!(three.report.reconstruction.start_losses.len(), 3);
        let named = Pipeline::new().with_preset(Preset::Fast).with_starts(2);
        assert_eq!((named.preset, named.recon_options().starts), (Some(Preset::Fast), 2));
    }
}
