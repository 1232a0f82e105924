//! `wonder3d demo [--out DIR]`: the whole mesh-extraction pipeline on the bundled spot (CC0),
//! with no downloads (`wonder3d::demo`).

use std::path::PathBuf;

use wonder3d::demo::{DemoOptions, run_demo};
use wonder3d::{Result, check_out_folder};

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
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
}

/// Runs `wonder3d demo`.
pub fn run(args: &DemoArgs) -> Result<()> {
    check_out_folder(&args.out)?;
    wonder3d::TextureOptions::default().with_size(args.texture_size).validate()?;
    let options = DemoOptions::default()
        .with_preset(args.preset.into())
        .with_view_size(args.size)
        .with_texture_size(args.texture_size);
    let bar = progress::bar(args.quiet)?;
    let demo = run_demo(&options, &mut progress::follow(&bar))?;
    bar.finish_and_clear();
    demo.save(&args.out)?;
    let r = &demo.report;
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
