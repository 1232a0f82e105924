//! `wonder3d demo [--out DIR]`: the whole mesh-extraction pipeline on the bundled spot (CC0),
//! with no downloads (`wonder3d::demo`). `--from-image` starts from a photo of spot (posed as
//! in one of the small model's training samples) and generates the views with the small model in the repository's
//! `assets/model-small` (or `--weights DIR`).

use std::path::PathBuf;

use wonder3d::Result;
use wonder3d::demo::{DemoOptions, run_demo};
use wonder3d::outputs::check_out_folder;

use crate::args::PresetArg;
use crate::progress;

/// Arguments of `wonder3d demo`.
#[derive(clap::Args)]
pub struct DemoArgs {
    /// Output folder (created if needed): spot.glb, views.png, report.json.
    #[arg(long, default_value = "wonder3d-demo")]
    out: PathBuf,
    /// Reconstruction preset.
    #[arg(long, value_enum, default_value_t = PresetArg::Default)]
    preset: PresetArg,
    /// Side of the rendered views in pixels.
    #[arg(long, default_value_t = DemoOptions::default().view_size, allow_hyphen_values = true, value_parser = crate::args::view_size)]
    size: u32,
    /// Side of the baked texture in texels.
    #[arg(long, default_value_t = DemoOptions::default().texture_size, allow_hyphen_values = true, value_parser = crate::args::texture_size)]
    texture_size: u32,
    /// Start from a photo of spot (its front render, turned as a training sample of the small
    /// model shows it): background removal, the model's 6 views, then the same extraction and
    /// report (needs a binary with the diffusion model).
    #[arg(long)]
    from_image: bool,
    /// With --from-image: the model directory or Hugging Face Hub id (docs/weights.md; default:
    /// the small model trained here, `assets/model-small` of the repository; docs/training.md).
    #[arg(long, requires = "from_image", value_name = "DIR|HUB_ID")]
    weights: Option<PathBuf>,
    /// With --from-image: reconstructions tried from the generated views, each with its own remesher
    /// seed; the one that fits the views best is kept (docs/accuracy.md, "Several starts"); one only when the
    /// first fit shows views no closed surface explains.
    #[arg(long, default_value_t = wonder3d::GENERATED_VIEW_STARTS, allow_hyphen_values = true, value_parser = crate::args::starts)]
    starts: usize,
    #[command(flatten)]
    sampling: crate::generate::SamplingArgs,
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
}

/// Where the small model is looked for: `assets/model-small` under the current directory
/// (a clone's root), then in the workspace this binary was built from.
#[cfg_attr(not(feature = "diffusion"), allow(dead_code))]
fn small_model_dir() -> Result<PathBuf> {
    let candidates = [
        PathBuf::from("assets/model-small"),
        PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../assets/model-small")),
    ];
    candidates.iter().find(|dir| dir.join("model_index.json").is_file()).cloned().ok_or_else(|| {
        wonder3d::Error::invalid(
            "--weights",
            "a model directory: the small model is in assets/model-small of a clone of the repository \
             (not found from here); pass --weights DIR (docs/training.md)",
        )
    })
}

/// Runs `wonder3d demo`.
pub fn run(args: &DemoArgs) -> Result<()> {
    wonder3d::outputs::for_flag("--out", check_out_folder(&args.out))?;
    wonder3d::TextureOptions::default().with_size(args.texture_size).validate()?;
    let options = DemoOptions::default()
        .with_preset(args.preset.into())
        .with_view_size(args.size)
        .with_texture_size(args.texture_size)
        .with_generated_view_starts(args.starts);
    let demo = if args.from_image {
        from_image(args, &options)?
    } else {
        let bar = progress::bar(args.quiet)?;
        let demo = run_demo(&options, &mut progress::follow(&bar))?;
        bar.finish_and_clear();
        demo
    };
    demo.save(&args.out)?;
    let r = &demo.report;
    if let Some(g) = &r.generated_views {
        let acceleration =
            r.pipeline.generation.as_ref().map_or(String::new(), |g| crate::args::acceleration_note(&g.acceleration));
        println!(
            "generated views against spot's{acceleration}: normal error {:.1}° inside the true mask ({:.1}° leaving out its one-pixel rim), mask IoU {:.3}",
            g.normal_angle_deg, g.interior_normal_angle_deg, g.mask_iou
        );
    }
    println!(
        "spot: {} triangles, Chamfer {:.4}, F@0.02 {:.3}, IoU {:.3}, texture PSNR {:.1} dB, {:.1} s in all",
        r.pipeline.triangles,
        r.geometry.chamfer,
        r.geometry.fscore_002,
        r.geometry.iou_64,
        r.texture_psnr_input_views,
        r.total_seconds
    );
    let out = args.out.display();
    println!("wrote {out}/spot.glb, {out}/views.png and {out}/report.json");
    Ok(())
}

/// The demo from a photo of spot, with the model of `--weights`.
#[cfg(feature = "diffusion")]
fn from_image(args: &DemoArgs, options: &DemoOptions) -> Result<wonder3d::demo::Demo> {
    // The small model samples as it scores best; a model given with `--weights` as its
    // authors sample it (a full-size model's generation takes minutes, and its guidance was
    // tuned for it).
    let (weights, defaults) = match &args.weights {
        Some(dir) => (dir.clone(), wonder3d::SampleOptions::default()),
        None => (small_model_dir()?, wonder3d::demo::small_model_sampling()),
    };
    let bar = progress::bar(args.quiet)?;
    bar.set_prefix("load");
    let generator = crate::generate::load(&weights, &args.sampling, &defaults, &bar)?;
    let demo = wonder3d::demo::run_demo_from_image(generator, options, &mut progress::follow(&bar))?;
    bar.finish_and_clear();
    Ok(demo)
}

/// `--from-image` in a binary without the model.
#[cfg(not(feature = "diffusion"))]
fn from_image(_: &DemoArgs, _: &DemoOptions) -> Result<wonder3d::demo::Demo> {
    Err(crate::generate::without_model())
}
