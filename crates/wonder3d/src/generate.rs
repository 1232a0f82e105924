//! [`Generator`]: the Wonder3D++ multi-view diffusion model loaded once, turning images (RGBA,
//! or photos whose background `w3d-photo` removes) into 6 normal + 6 colour views (feature
//! `diffusion`).

use std::path::Path;

use w3d_core::{Image, Result, ViewSet};
use w3d_diffusion::{Device, MultiViewPipeline, SampleOptions, WeightStorage, prepare_input};
use w3d_photo::PrepareOptions;

use crate::progress::{Progress, Stage};
use crate::sheet::{SheetRow, contact_sheet, normal_picture};

/// The views a [`Generator`] made of one image.
#[derive(Debug, Clone)]
#[non_exhaustive]
pub struct Generated {
    /// The 6 views with their rig (`wonder3d-ortho` or `wonder3d-persp`): unit normals in
    /// the input camera's frame, colours, masks from the model's white background.
    pub views: ViewSet,
    /// The conditioning image the model saw: the input cropped and centred on white at the
    /// model's resolution.
    pub input: Image,
}

impl Generated {
    /// Views and the conditioning image they were generated from.
    pub fn new(views: ViewSet, input: Image) -> Generated {
        Generated { views, input }
    }

    /// Writes the view set (the `wonder3d render` layout), `input.png` (what the model saw)
    /// and `views.png` (a labelled contact sheet of the colour and normal views) into the
    /// folder `dir`, all at once ([`ViewSet::save_with`]: a failure leaves `dir` as it was;
    /// `dir` must pass [`ViewSet::check_output_dir`]).
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<()> {
        let mut colours = SheetRow { label: "colour".into(), images: Vec::new() };
        let mut normals = SheetRow { label: "normal".into(), images: Vec::new() };
        for v in self.views.views() {
            if let Some(c) = &v.colour {
                colours.images.push(c.with_alpha(&v.mask)?);
            }
            normals.images.push(normal_picture(&v.normal, &v.mask)?);
        }
        let names: Vec<&str> = self.views.rig().views.iter().map(|v| v.name.as_str()).collect();
        let sheet = contact_sheet(&names, &[colours, normals])?;
        self.views.save_with(dir, |staging: &Path| {
            self.input.write_png(staging.join("input.png"))?;
            sheet.write_png(staging.join("views.png"))
        })
    }
}

/// A loaded multi-view diffusion model with its sampling options; load it once and generate
/// many images (loading reads every weight file).
#[derive(Debug)]
pub struct Generator {
    pipeline: MultiViewPipeline,
    device: Device,
    options: SampleOptions,
    prepare: PrepareOptions,
}

impl Generator {
    /// Loads a checkpoint directory (`unet/`, `vae/`, `image_encoder/`, `scheduler/`, the
    /// layout of `docs/weights.md`) on the default CPU device with the Wonder3D++ sampling
    /// defaults.
    pub fn load(dir: impl AsRef<Path>) -> Result<Generator> {
        Generator::load_on(dir, w3d_diffusion::default_device())
    }

    /// Loads the model `spec` names: a local checkpoint directory, or a Hugging Face Hub id
    /// `owner/name[@revision][:sub/folder]` downloaded into (or found in) the Hugging Face
    /// cache first ([`weights::resolve`](crate::weights::resolve): `HF_ENDPOINT`, `HF_HOME`,
    /// `HF_HUB_OFFLINE`; [`Stage::Download`] events in bytes), on the default CPU device.
    ///
    /// ```no_run
    /// # fn main() -> wonder3d::Result<()> {
    /// let generator = wonder3d::Generator::from_pretrained("flamehaze1115/Wonder3D_plus", &mut |p| {
    ///     eprintln!("{} {}/{}", p.stage.name(), p.done, p.total)
    /// })?;
    /// # Ok(())
    /// # }
    /// ```
    pub fn from_pretrained(spec: &str, progress: &mut dyn FnMut(Progress)) -> Result<Generator> {
        Generator::load(crate::weights::resolve(spec, progress)?)
    }

    /// Loads a checkpoint directory onto `device` (weights held in the checkpoint's own
    /// precision, [`WeightStorage::AsStored`](w3d_diffusion::WeightStorage)): a Burn device, e.g. the GPU of
    /// [`ComputeDevice::Wgpu`](crate::ComputeDevice)`.open()?.device` (feature `wgpu`).
    ///
    /// ```no_run
    /// # fn main() -> wonder3d::Result<()> {
    /// use wonder3d::{ComputeDevice, Generator};
    ///
    /// let gpu = ComputeDevice::Wgpu.open()?; // an error naming the fix without the `wgpu` feature
    /// eprintln!("generating on {}", gpu.description);
    /// let generator = Generator::load_on("ckpts", gpu.device)?;
    /// # Ok(())
    /// # }
    /// ```
    pub fn load_on(dir: impl AsRef<Path>, device: Device) -> Result<Generator> {
        // Weights stay in the checkpoint's precision: f16 checkpoints take half the memory,
        // exactly the same outputs.
        let pipeline = MultiViewPipeline::from_dir_with(dir, &device, WeightStorage::AsStored)?;
        Ok(Generator { pipeline, device, options: SampleOptions::default(), prepare: PrepareOptions::default() })
    }

    /// The same model with other sampling options (steps, guidance, eta, camera type, seed, draws).
    pub fn with_options(mut self, options: SampleOptions) -> Generator {
        self.options = options;
        self
    }

    /// The same model with other options for photos without alpha (background removal,
    /// confidence threshold); see [`w3d_photo::prepare`].
    pub fn with_prepare_options(mut self, prepare: PrepareOptions) -> Generator {
        self.prepare = prepare;
        self
    }

    /// The options for photos without alpha.
    pub fn prepare_options(&self) -> &PrepareOptions {
        &self.prepare
    }

    /// The sampling options in use.
    pub fn options(&self) -> &SampleOptions {
        &self.options
    }

    /// The underlying diffusion pipeline (for DDIM inversion, custom sampling loops …).
    pub fn pipeline(&self) -> &MultiViewPipeline {
        &self.pipeline
    }

    /// Generates the views of one image: an RGBA image whose alpha masks the object, or a
    /// photo without a meaningful alpha, whose background is first removed by
    /// [`w3d_photo::prepare`] (an error naming the reasons when that is not confident
    /// enough). Then preprocessing (crop, 75 % framing on white), CLIP and VAE conditions,
    /// guided sampling (one [`Stage::Denoise`] event per step, over all of
    /// [`SampleOptions::draws`]), decoding, and the draws' consensus.
    pub fn generate(&self, image: &Image, progress: &mut dyn FnMut(Progress)) -> Result<Generated> {
        self.generate_with(image, &self.options, progress)
    }

    /// [`Generator::generate`] with other sampling options for this one image (a batch's
    /// per-item seed or step count) without reloading or cloning the model.
    pub fn generate_with(
        &self,
        image: &Image,
        options: &SampleOptions,
        progress: &mut dyn FnMut(Progress),
    ) -> Result<Generated> {
        progress(Progress::new(Stage::Condition, 0, 1, None));
        let prepared;
        let rgba = if w3d_photo::has_meaningful_alpha(image) && image.channels() == 4 {
            image
        } else {
            prepared = w3d_photo::prepare(image, &self.prepare)?;
            &prepared.rgba
        };
        let input = prepare_input(rgba, self.pipeline.image_size() as u32)?;
        let cond = self.pipeline.condition(&input, &self.device)?;
        progress(Progress::new(Stage::Condition, 1, 1, None));
        let generated = self.pipeline.sample_views(&cond, options, &self.device, &mut |done, total| {
            progress(Progress::new(Stage::Denoise, done, total, None))
        })?;
        progress(Progress::new(Stage::Decode, 0, 1, None));
        let views = generated.to_view_set()?;
        progress(Progress::new(Stage::Decode, 1, 1, None));
        Ok(Generated { views, input })
    }
}
