//! `wonder3d reconstruct VIEWS_DIR --out mesh.glb [--preset …] [--report report.json]`.

use std::path::PathBuf;

use w3d_core::{Error, Result, ViewSet, io::write_atomic, save_mesh};
use w3d_recon::{Preset, ReconOptions, reconstruct};

use crate::progress::{recon_progress, stage_bar};

/// Arguments of `wonder3d reconstruct`.
#[derive(clap::Args)]
pub struct ReconstructArgs {
    /// View-set folder (`cameras.json`, `normal_<view>.png|exr`, `mask_<view>.png`), as
    /// written by `wonder3d render` or `wonder3d generate`.
    views: PathBuf,
    /// Output mesh (.glb, .obj or .ply), in the rig's world frame.
    #[arg(long)]
    out: PathBuf,
    /// Speed/accuracy preset: fast, default or quality.
    #[arg(long, default_value = "default")]
    preset: String,
    /// Also write the reconstruction report (stage timings, losses, face counts, init choice) as JSON.
    #[arg(long)]
    report: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

/// Runs `wonder3d reconstruct`.
pub fn run(args: &ReconstructArgs) -> Result<()> {
    let preset: Preset = args.preset.parse()?;
    let views = ViewSet::load(&args.views)?;
    let bar = stage_bar(args.quiet, "reconstruct")?;
    let (mesh, report) = reconstruct(&views, &ReconOptions::preset(preset), &mut recon_progress(&bar))?;
    bar.finish_and_clear();
    save_mesh(&args.out, &mesh)?;
    if let Some(path) = &args.report {
        let json = serde_json::to_vec_pretty(&report).map_err(|e| Error::invalid("report", e.to_string()))?;
        write_atomic(path, |w| std::io::Write::write_all(w, &json).map_err(|e| Error::io(path, e)))?;
    }
    println!(
        "reconstructed {} triangles in {:.1} s (init: {}) -> {}",
        mesh.triangle_count(),
        report.seconds,
        report.init.reason,
        args.out.display()
    );
    Ok(())
}
