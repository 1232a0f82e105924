//! `wonder3d reconstruct VIEWS_DIR --out mesh.glb [--preset …] [--report report.json]`.

use std::path::PathBuf;

use indicatif::{ProgressBar, ProgressStyle};
use w3d_core::{Error, Result, ViewSet, io::write_atomic, save_mesh};
use w3d_recon::{Preset, Progress, ReconOptions, Stage, reconstruct};

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
    let (views, rig) = ViewSet::load(&args.views)?;
    let bar = if args.quiet { ProgressBar::hidden() } else { ProgressBar::new(1) };
    bar.set_style(
        ProgressStyle::with_template("{prefix:>8} [{bar:40}] {pos}/{len} {msg} ({elapsed})")
            .map_err(|e| Error::invalid("progress template", e.to_string()))?
            .progress_chars("=> "),
    );
    let mut progress = |p: Progress| {
        match p.stage {
            Stage::Init => bar.set_prefix("init"),
            Stage::Coarse => bar.set_prefix("coarse"),
        }
        bar.set_length(p.total as u64);
        bar.set_position(p.done as u64);
        if let Some(loss) = p.loss {
            bar.set_message(format!("loss {loss:.5}"));
        }
    };
    let (mesh, report) = reconstruct(&views, &rig, &ReconOptions::preset(preset), &mut progress)?;
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
