//! `wonder3d generate IMAGE --weights DIR --out VIEWS_DIR [--camera ortho|persp] [--steps N]
//! [--guidance G] [--eta E] [--seed S]`: the 6 normal + 6 colour views of an RGBA image from the
//! Wonder3D++ multi-view diffusion model, written as a view-set folder.

use std::path::PathBuf;

use w3d_core::{Image, Result, ViewSet};
use w3d_diffusion::{CameraType, MultiViewPipeline, SampleOptions, prepare_input};

use crate::progress::stage_bar;

/// The model and sampling options shared by `generate` and `run`.
#[derive(clap::Args)]
pub struct ModelArgs {
    /// Model directory (unet/, vae/, image_encoder/, scheduler/), as published on Hugging Face
    /// (see docs/weights.md).
    #[arg(long)]
    weights: PathBuf,
    /// Camera type of the generated views: ortho or persp.
    #[arg(long, default_value = "ortho")]
    camera: String,
    /// DDIM steps.
    #[arg(long, default_value_t = SampleOptions::default().steps)]
    steps: usize,
    /// Classifier-free guidance scale (1 = no unconditional branch).
    #[arg(long, default_value_t = SampleOptions::default().guidance)]
    guidance: f64,
    /// DDIM eta: 0 deterministic, 1 the reference's stochastic sampling.
    #[arg(long, default_value_t = SampleOptions::default().eta)]
    eta: f64,
    /// Seed of all sampling noise (the same seed gives the same views).
    #[arg(long, default_value_t = SampleOptions::default().seed)]
    seed: u64,
}

/// Arguments of `wonder3d generate`.
#[derive(clap::Args)]
pub struct GenerateArgs {
    /// Input image: a PNG with an alpha channel masking the object (background removed).
    image: PathBuf,
    #[command(flatten)]
    model: ModelArgs,
    /// Output view-set folder (created if needed), the layout `wonder3d render` writes.
    #[arg(long)]
    out: PathBuf,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

/// The generated views (as a view set with its rig) and the preprocessed input image.
pub struct Generated {
    /// The 6 views (unit normals in the rig frame, colours, masks) with the rig of the
    /// chosen camera type.
    pub views: ViewSet,
    /// The conditioning image the model saw (white background, the model's resolution).
    pub input: Image,
}

/// Loads the model and generates the views of `image`, with a per-step progress bar.
pub fn generate_views(image: &PathBuf, model: &ModelArgs, quiet: bool) -> Result<Generated> {
    let camera: CameraType = model.camera.parse()?;
    let rgba = Image::read_png(image)?;
    let bar = stage_bar(quiet, "load")?;
    bar.set_message(format!("weights from {}", model.weights.display()));
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    let device = w3d_diffusion::default_device();
    let pipeline = MultiViewPipeline::from_dir(&model.weights, &device)?;
    let input = prepare_input(&rgba, pipeline.image_size() as u32)?;
    bar.set_prefix("condition");
    let cond = pipeline.condition(&input, &device)?;
    let options =
        SampleOptions { steps: model.steps, guidance: model.guidance, eta: model.eta, camera, seed: model.seed };
    bar.set_prefix("denoise");
    bar.set_message(format!("6 views x 2 domains, guidance {}", model.guidance));
    bar.disable_steady_tick();
    let noise = pipeline.initial_noise(options.seed, &device);
    let latents = pipeline.sample_from(noise, &cond, &options, &mut |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })?;
    bar.set_prefix("decode");
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    let generated = pipeline.decode(latents, camera)?;
    bar.finish_and_clear();
    let views = generated.to_view_set()?;
    Ok(Generated { views, input })
}

/// Runs `wonder3d generate`: the view set plus `input.png` (the conditioning image).
pub fn run(args: &GenerateArgs) -> Result<()> {
    let generated = generate_views(&args.image, &args.model, args.quiet)?;
    generated.views.save(&args.out)?;
    generated.input.write_png(args.out.join("input.png"))?;
    println!(
        "generated {} views ({}×{}, {}) of {} -> {}",
        generated.views.len(),
        generated.views.width(),
        generated.views.height(),
        generated.views.rig().name,
        args.image.display(),
        args.out.display()
    );
    Ok(())
}
