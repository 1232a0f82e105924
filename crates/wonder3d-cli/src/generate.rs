//! `wonder3d generate IMAGE --weights DIR --out VIEWS_DIR [--camera ortho|persp]
//! [--scheduler ddim|dpmpp-2m|unipc] [--steps N] [--guidance G] [--eta E] [--seed S] [--draws K] [--device cpu|wgpu]
//! [--min-confidence C] [--guidance-interval LO,HI] [--cache-interval N] [--cache-depth D]
//! [--products auto|f32|bf16] [--token-merge R]`: the 6 normal + 6 colour views of a photo or RGBA
//! image from the Wonder3D++ multi-view diffusion model, written as a view-set folder with a
//! contact sheet. The image is prepared as `wonder3d prepare` does first.

use std::path::PathBuf;

use wonder3d::{Error, Result};

use crate::args::{AccelerationArgs, CameraArg, DeviceArg, SchedulerArg};

/// The model directory and its sampling options, shared by `generate` and `run`.
#[derive(clap::Args)]
#[cfg_attr(not(feature = "diffusion"), allow(dead_code))]
pub struct ModelArgs {
    /// Model directory (unet/, vae/, image_encoder/, scheduler/), as published (docs/weights.md),
    /// or a Hugging Face Hub id owner/name[@revision][:sub/folder] (e.g.
    /// flamehaze1115/Wonder3D_plus), downloaded once into the Hugging Face cache (HF_HOME,
    /// HF_ENDPOINT, HF_HUB_OFFLINE); an existing folder always wins.
    #[arg(long, value_name = "DIR|HUB_ID")]
    pub weights: PathBuf,
    #[command(flatten)]
    pub sampling: SamplingArgs,
}

/// Sampling and input options of the model, shared by `generate`, `run`, `batch` and `demo`
/// (defaults: the Wonder3D++ sampling settings — 50 DDIM steps, guidance 2, eta 1, seed 42,
/// one draw, no training-free acceleration; `demo --from-image` with the small model samples as
/// `wonder3d::demo::small_model_sampling` says where guidance and draws are left out).
#[derive(clap::Args)]
#[cfg_attr(not(feature = "diffusion"), allow(dead_code))]
pub struct SamplingArgs {
    /// Camera type of the generated views.
    #[arg(long, value_enum, default_value_t = CameraArg::Ortho)]
    pub camera: CameraArg,
    /// Where the model runs: `wgpu` needs a build with the `wgpu` feature (docs/gpu.md).
    #[arg(long, value_enum, default_value_t = DeviceArg::Cpu)]
    pub device: DeviceArg,
    /// Sampling algorithm.
    #[arg(long, value_enum, default_value_t = SchedulerArg::Ddim)]
    pub scheduler: SchedulerArg,
    /// Sampling steps (50 is the authors' DDIM setting; 20 with dpmpp-2m or unipc).
    #[arg(long, default_value_t = 50, allow_hyphen_values = true, value_parser = crate::args::steps)]
    pub steps: usize,
    /// Classifier-free guidance scale; 1 skips the unconditional branch and halves the
    /// generation [default: 2, the authors' setting; `demo --from-image` with the small
    /// model: 1, as good for it at half the cost (docs/training.md)].
    #[arg(long, allow_hyphen_values = true, value_parser = crate::args::guidance)]
    pub guidance: Option<f64>,
    /// DDIM eta: 0 deterministic, 1 the reference's stochastic sampling (dpmpp-2m and unipc ignore it).
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true, value_parser = crate::args::eta)]
    pub eta: f64,
    /// Seed of all sampling noise (the same seed gives the same views).
    #[arg(long, default_value_t = 42, allow_hyphen_values = true, value_parser = crate::args::seed)]
    pub seed: u64,
    /// Draws to generate (seeds `seed`, `seed + 1`, …), merged per pixel into their consensus;
    /// each costs a whole generation [default: 1, the authors' sampling; `demo --from-image`
    /// with the small model: 4, which lowers its normal error by 1–2° (docs/training.md)].
    #[arg(long, allow_hyphen_values = true, value_parser = crate::args::draws)]
    pub draws: Option<usize>,
    /// Refuse automatic background removal less confident than this, in [0, 1] (photos
    /// without alpha; 0 accepts every mask).
    #[arg(long, default_value_t = 0.5, allow_hyphen_values = true, value_parser = crate::args::confidence)]
    pub min_confidence: f32,
    #[command(flatten)]
    pub acceleration: AccelerationArgs,
}

impl SamplingArgs {
    /// The preparation of the input image these arguments ask for (checked).
    #[cfg_attr(not(feature = "diffusion"), allow(dead_code))]
    pub fn prepare_options(&self) -> Result<wonder3d::PrepareOptions> {
        if !(0.0..=1.0).contains(&self.min_confidence) {
            return Err(Error::invalid("--min-confidence", format!("a value in [0, 1], got {}", self.min_confidence)));
        }
        Ok(wonder3d::PrepareOptions::default().with_min_confidence(self.min_confidence))
    }

    /// Checks every setting that needs no model (the preparation of the input, the
    /// accelerations), so that a bad value is refused before any image is read or weights
    /// load; the accelerations' description as the reports name it (`"none"` for none).
    pub fn check(&self) -> Result<String> {
        self.prepare_options()?;
        self.acceleration.check()
    }
}

/// Arguments of `wonder3d generate`.
#[derive(clap::Args)]
#[cfg_attr(not(feature = "diffusion"), allow(dead_code))]
pub struct GenerateArgs {
    /// Input image: a photo (JPEG, PNG or WebP; background removed automatically) or an RGBA
    /// image whose alpha masks the object.
    pub image: PathBuf,
    #[command(flatten)]
    pub model: ModelArgs,
    /// Output view-set folder (created if needed), the layout `wonder3d render` writes, plus
    /// `input.png` (what the model saw) and `views.png` (a labelled contact sheet).
    #[arg(long)]
    pub out: PathBuf,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

#[cfg(feature = "diffusion")]
mod with_model {
    use super::*;
    use crate::progress;
    use wonder3d::{CameraType, ComputeDevice, Generator, SampleOptions, SamplerKind};

    /// Loads the model of `--weights` (a folder, or a Hub id downloaded first with its bytes on
    /// `bar`) onto the device of `args`, with its sampling options (the guidance and draws of
    /// `defaults` where the command line leaves them out). The accelerations are checked and
    /// the device opens first, so a bad value or a missing GPU backend is named before the
    /// weights are downloaded or read; a GPU is named on stderr (with a warning when it is a
    /// software adapter), and so, in one line, are bf16 products this CPU lacks.
    pub fn load(
        weights: &std::path::Path,
        args: &SamplingArgs,
        defaults: &SampleOptions,
        bar: &indicatif::ProgressBar,
    ) -> Result<Generator> {
        let (acceleration, note) = args.acceleration.acceleration()?;
        let device = args.device.compute_device().open()?;
        if device.kind != ComputeDevice::Cpu {
            eprintln!("device: {}", device.description);
        }
        if let Some(note) = note {
            eprintln!("note: {note}");
        }
        let options = SampleOptions { acceleration, ..sample_options(args, defaults) };
        let dir = crate::weights::resolve("--weights", weights, wonder3d::weights::Layout::MultiView, bar)?;
        bar.set_message(format!("weights from {}", dir.display()));
        let generator = Generator::load_on(&dir, device.device)?
            .with_options(options)
            .with_prepare_options(args.prepare_options()?);
        // The cache depth needs the model: checked once it is loaded, before any sampling (the
        // library checks it again when sampling starts, naming its field).
        let skips = generator.pipeline().unet().skip_count();
        if acceleration.cache_interval > 1 && acceleration.cache_depth >= skips {
            return Err(Error::invalid(
                "--cache-depth",
                format!(
                    "a skip of this model's UNet, 0 to {} (found {}; {})",
                    skips.saturating_sub(1),
                    acceleration.cache_depth,
                    weights.display()
                ),
            ));
        }
        Ok(generator)
    }

    /// The sampling options of `args`, with the guidance and draws of `defaults` where the
    /// command line leaves them out (every other setting has a command-line default), without
    /// the accelerations ([`load`] checks them and resolves the products).
    fn sample_options(args: &SamplingArgs, defaults: &SampleOptions) -> SampleOptions {
        let camera = match args.camera {
            CameraArg::Ortho => CameraType::Orthographic,
            CameraArg::Persp => CameraType::Perspective,
        };
        let sampler = match args.scheduler {
            SchedulerArg::Ddim => SamplerKind::Ddim,
            SchedulerArg::DpmPp2m => SamplerKind::DpmSolverPlusPlus2M,
            SchedulerArg::Unipc => SamplerKind::UniPc,
        };
        SampleOptions {
            sampler,
            steps: args.steps,
            guidance: args.guidance.unwrap_or(defaults.guidance),
            eta: args.eta,
            camera,
            seed: args.seed,
            draws: args.draws.unwrap_or(defaults.draws),
            ..SampleOptions::default()
        }
    }

    /// Runs `wonder3d generate`.
    pub fn run(args: &GenerateArgs) -> Result<()> {
        wonder3d::outputs::for_flag("--out", wonder3d::outputs::check_out_dir(&args.out))?;
        wonder3d::outputs::check_inputs_outside(("--out", &args.out), &[("IMAGE", &args.image)])?;
        args.model.sampling.check()?;
        // Read and prepare the image before loading the weights: a refused photo fails fast.
        let prepared = wonder3d::prepare_image(&args.image, &args.model.sampling.prepare_options()?)?;
        if !args.quiet {
            eprintln!("{}", crate::prepare::describe(&args.image, &prepared));
        }
        let rgba = prepared.rgba;
        let bar = progress::bar(args.quiet)?;
        bar.set_prefix("load");
        let generator = load(&args.model.weights, &args.model.sampling, &SampleOptions::default(), &bar)?;
        let generated = generator.generate(&rgba, &mut progress::follow(&bar))?;
        bar.finish_and_clear();
        generated.save(&args.out)?;
        println!(
            "generated {} views ({}×{}, {}) of {} -> {}{}",
            generated.views.len(),
            generated.views.width(),
            generated.views.height(),
            generated.views.rig().name,
            args.image.display(),
            args.out.display(),
            crate::args::acceleration_note(&generator.options().acceleration.describe())
        );
        Ok(())
    }
}

#[cfg(feature = "diffusion")]
pub use with_model::{load, run};

/// The error of `generate` and `run` in a binary built without the model.
#[cfg(not(feature = "diffusion"))]
pub fn without_model() -> Error {
    Error::invalid(
        "wonder3d generate / run",
        "a binary built with the diffusion model: this one was built with --no-default-features; \
         rebuild with `cargo install wonder3d-cli` or `cargo run --release -p wonder3d-cli -- …`",
    )
}

/// Runs `wonder3d generate` (this binary has no model).
#[cfg(not(feature = "diffusion"))]
pub fn run(_: &GenerateArgs) -> Result<()> {
    Err(without_model())
}
