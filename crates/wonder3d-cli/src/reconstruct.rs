//! `wonder3d reconstruct VIEWS_DIR --out mesh.glb [--preset …] [--report report.json]
//! [--enhancer DIR [--refine N]]`.

use std::path::PathBuf;

use wonder3d::core::io::write_atomic;
use wonder3d::outputs::{check_distinct, check_outputs, mesh_output_files};
use wonder3d::{Error, Pipeline, Result, ViewSet};

use crate::args::PresetArg;
use crate::progress;

/// Arguments of `wonder3d reconstruct`.
#[derive(clap::Args)]
pub struct ReconstructArgs {
    /// View-set folder (`cameras.json`, `normal_<view>.png|exr`, `mask_<view>.png`), as
    /// written by `wonder3d render` or `wonder3d generate`.
    views: PathBuf,
    /// Output mesh (.glb, .obj or .ply), in the rig's world frame.
    #[arg(long)]
    out: PathBuf,
    /// Speed/accuracy preset.
    #[arg(long, value_enum, default_value_t = PresetArg::Default)]
    preset: PresetArg,
    /// Reconstructions tried, each with its own remesher seed; the one that fits the views
    /// best is kept. 1 suits rendered views; views from `wonder3d generate` disagree with
    /// each other and gain from 4 (docs/accuracy.md, "Several starts").
    #[arg(long, default_value_t = 1, allow_hyphen_values = true, value_parser = crate::args::starts)]
    starts: usize,
    /// Also write the reconstruction report (stage timings, losses, face counts, init choice) as JSON.
    #[arg(long)]
    report: Option<PathBuf>,
    #[command(flatten)]
    refinement: crate::refine::RefineAfterArgs,
    /// Texture width and height in texels of the refined mesh (with --enhancer; the coarse
    /// mesh is written untextured).
    #[arg(long, default_value_t = wonder3d::TextureOptions::default().size, allow_hyphen_values = true, value_parser = crate::args::texture_size)]
    texture_size: u32,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

/// Runs `wonder3d reconstruct`: the closed mesh, untextured (refined and textured with
/// `--enhancer`).
pub fn run(args: &ReconstructArgs) -> Result<()> {
    check_outputs(("--out", &args.out), args.report.as_deref().map(|r| ("--report", r)), None)?;
    let written = mesh_output_files(&args.out);
    let mut outputs: Vec<(&str, &std::path::Path)> = written.iter().map(|f| ("--out", f.as_path())).collect();
    outputs.extend(args.report.as_deref().map(|report| ("--report", report)));
    let view_files = ViewSet::input_files(&args.views);
    check_distinct(&outputs, &view_files.iter().map(|f| ("VIEWS", f.as_path())).collect::<Vec<_>>())?;
    let texture = wonder3d::TextureOptions::default().with_size(args.texture_size);
    texture.validate()?;
    let iterations = args.refinement.check(args.quiet)?;
    let views = ViewSet::load(&args.views)?;
    let bar = progress::bar(args.quiet)?;
    let output = Pipeline::new()
        .with_preset(args.preset.into())
        .with_starts(args.starts)
        .without_texture()
        .from_views(&views, &mut progress::follow(&bar))?;
    bar.finish_and_clear();
    match args.refinement.refine(&output.geometry, &views, None, iterations, texture, args.quiet)? {
        Some(refined) => {
            wonder3d::save_mesh(&args.out, &refined.mesh)?;
            println!("{}", crate::refine::summary(&refined.report));
        }
        None => output.save(&args.out)?,
    }
    if let Some(path) = &args.report {
        let json = serde_json::to_vec_pretty(&output.report.reconstruction)
            .map_err(|e| Error::invalid("report", e.to_string()))?;
        write_atomic(path, |w| std::io::Write::write_all(w, &json).map_err(|e| Error::io(path, e)))?;
    }
    let r = &output.report;
    println!(
        "reconstructed {} triangles in {:.1} s{} (init: {}) -> {}",
        r.triangles,
        r.seconds.reconstruct,
        crate::progress::starts_note(&r.reconstruction),
        r.reconstruction.init.reason,
        args.out.display()
    );
    if let Some(note) = crate::progress::disagreement_note(&r.reconstruction) {
        eprintln!("{note}");
    }
    Ok(())
}
