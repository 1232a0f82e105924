//! `wonder3d run IMAGE --weights DIR --out mesh.glb [--enhancer DIR]`: prepare (background
//! removal, framing) → generate → reconstruct → texture (→ refine, with an enhancer).

use std::path::PathBuf;

use wonder3d::{Result, TextureOptions};

use crate::args::PresetArg;
use crate::generate::ModelArgs;

/// Arguments of `wonder3d run`.
#[derive(clap::Args)]
#[cfg_attr(not(feature = "diffusion"), allow(dead_code))]
pub struct RunArgs {
    /// Input image: a photo (JPEG, PNG or WebP; background removed automatically) or an RGBA
    /// image whose alpha masks the object.
    image: PathBuf,
    #[command(flatten)]
    model: ModelArgs,
    /// Output textured mesh: `.glb` (embedded texture) or `.obj` (+ `.mtl` + `.png`).
    #[arg(long)]
    out: PathBuf,
    /// Also keep the generated views in this folder (the `wonder3d generate` layout).
    #[arg(long)]
    views: Option<PathBuf>,
    /// Reconstruction preset.
    #[arg(long, value_enum, default_value_t = PresetArg::Default)]
    preset: PresetArg,
    /// Reconstructions tried from the generated views, each with its own remesher seed; the
    /// one that fits the views best is kept (generated views disagree, so one fit is a
    /// lottery: docs/accuracy.md, "Several starts"); one only when the
    /// first fit shows views no closed surface explains.
    #[arg(long, default_value_t = wonder3d::GENERATED_VIEW_STARTS, allow_hyphen_values = true, value_parser = crate::args::starts)]
    starts: usize,
    /// Side of the baked texture in texels.
    #[arg(long, default_value_t = TextureOptions::default().size, allow_hyphen_values = true, value_parser = crate::args::texture_size)]
    texture_size: u32,
    /// Also write the run's report (generation settings, stage timings, reconstruction and
    /// texture measurements) as JSON.
    #[arg(long)]
    report: Option<PathBuf>,
    #[command(flatten)]
    refinement: crate::refine::RefineAfterArgs,
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
}

/// Runs `wonder3d run`.
#[cfg(feature = "diffusion")]
pub fn run(args: &RunArgs) -> Result<()> {
    use wonder3d::core::io::write_atomic;
    use wonder3d::outputs::check_outputs;
    use wonder3d::{Error, Pipeline};

    use crate::{generate, progress};

    check_outputs(
        ("--out", &args.out),
        args.report.as_deref().map(|r| ("--report", r)),
        args.views.as_deref().map(|v| ("--views", v)),
    )?;
    if let Some(views) = &args.views {
        wonder3d::outputs::check_inputs_outside(("--views", views), &[("IMAGE", &args.image)])?;
    }
    let texture = TextureOptions::default().with_size(args.texture_size);
    texture.validate()?;
    let iterations = args.refinement.check(args.quiet)?;
    args.model.sampling.check()?;
    // Read and prepare the image before loading the weights: a refused photo fails fast.
    let prepared = wonder3d::prepare_image(&args.image, &args.model.sampling.prepare_options()?)?;
    if !args.quiet {
        eprintln!("{}", crate::prepare::describe(&args.image, &prepared));
    }
    let rgba = prepared.rgba;
    let bar = progress::bar(args.quiet)?;
    bar.set_prefix("load");
    let pipeline = Pipeline::new()
        .with_preset(args.preset.into())
        .with_generated_view_starts(args.starts)
        .with_texture_size(args.texture_size)
        .with_model(generate::load(
            &args.model.weights,
            &args.model.sampling,
            &wonder3d::SampleOptions::default(),
            &bar,
        )?);
    let output = pipeline.from_image(&rgba, &mut progress::follow(&bar))?;
    bar.finish_and_clear();
    if let (Some(dir), Some(input)) = (&args.views, &output.input) {
        wonder3d::Generated::new(output.views.clone(), input.clone()).save(dir)?;
    }
    let refined =
        args.refinement.refine(&output.geometry, &output.views, Some(&rgba), iterations, texture, args.quiet)?;
    match &refined {
        Some(refined) => wonder3d::save_mesh(&args.out, &refined.mesh)?,
        None => output.save(&args.out)?,
    }
    if let Some(path) = &args.report {
        let mut report = serde_json::to_value(&output.report).map_err(|e| Error::invalid("report", e.to_string()))?;
        if let (Some(refined), Some(object)) = (&refined, report.as_object_mut()) {
            let value = serde_json::to_value(&refined.report).map_err(|e| Error::invalid("report", e.to_string()))?;
            object.insert("refinement".into(), value);
        }
        let json = serde_json::to_string_pretty(&report).map_err(|e| Error::invalid("report", e.to_string()))?;
        write_atomic(path, |w| std::io::Write::write_all(w, json.as_bytes()).map_err(|e| Error::io(path, e)))?;
    }
    if let Some(refined) = &refined {
        println!("{}", crate::refine::summary(&refined.report));
    }
    let r = &output.report;
    let acceleration = r.generation.as_ref().map_or(String::new(), |g| crate::args::acceleration_note(&g.acceleration));
    println!(
        "{} -> {}: {} triangles (init: {}), {}×{} texture, {:.1} s generation{acceleration}, {:.1} s reconstruction{}",
        args.image.display(),
        args.out.display(),
        r.triangles,
        r.reconstruction.init.reason,
        args.texture_size,
        args.texture_size,
        r.seconds.generate,
        r.seconds.reconstruct,
        crate::progress::starts_note(&r.reconstruction)
    );
    if let Some(note) = crate::progress::disagreement_note(&r.reconstruction) {
        eprintln!("{note}");
    }
    Ok(())
}

/// Runs `wonder3d run` (this binary has no model).
#[cfg(not(feature = "diffusion"))]
pub fn run(_: &RunArgs) -> Result<()> {
    Err(crate::generate::without_model())
}
