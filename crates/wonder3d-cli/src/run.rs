//! `wonder3d run IMAGE --weights DIR --out mesh.glb`: generate → reconstruct → texture.

use std::path::PathBuf;

use w3d_core::{Result, save_mesh};
use w3d_recon::{Preset, ReconOptions, reconstruct};
use w3d_texture::{TextureOptions, bake};

use crate::generate::{ModelArgs, generate_views};
use crate::progress::{recon_progress, stage_bar};

/// Arguments of `wonder3d run`.
#[derive(clap::Args)]
pub struct RunArgs {
    /// Input image: a PNG with an alpha channel masking the object (background removed).
    image: PathBuf,
    #[command(flatten)]
    model: ModelArgs,
    /// Output textured mesh: `.glb` (embedded texture) or `.obj` (+ `.mtl` + `.png`).
    #[arg(long)]
    out: PathBuf,
    /// Also keep the generated views in this folder (the `wonder3d generate` layout).
    #[arg(long)]
    views: Option<PathBuf>,
    /// Reconstruction preset: fast, default or quality.
    #[arg(long, default_value = "default")]
    preset: String,
    /// Side of the baked texture in texels.
    #[arg(long, default_value_t = TextureOptions::default().size)]
    texture_size: u32,
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
}

/// Runs `wonder3d run`.
pub fn run(args: &RunArgs) -> Result<()> {
    let preset: Preset = args.preset.parse()?;
    let generated = generate_views(&args.image, &args.model, args.quiet)?;
    if let Some(dir) = &args.views {
        generated.views.save(dir)?;
        generated.input.write_png(dir.join("input.png"))?;
    }
    let bar = stage_bar(args.quiet, "reconstruct")?;
    let (mesh, report) = reconstruct(&generated.views, &ReconOptions::preset(preset), &mut recon_progress(&bar))?;
    bar.finish_and_clear();
    let bar = stage_bar(args.quiet, "texture")?;
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    let options = TextureOptions::default().with_size(args.texture_size);
    let textured = bake(&mesh, &generated.views, &options)?;
    bar.finish_and_clear();
    save_mesh(&args.out, &textured.mesh)?;
    println!(
        "{} -> {}: {} triangles (init: {}), {}×{} texture, {:.1} s reconstruction",
        args.image.display(),
        args.out.display(),
        mesh.triangle_count(),
        report.init.reason,
        args.texture_size,
        args.texture_size,
        report.seconds
    );
    Ok(())
}
