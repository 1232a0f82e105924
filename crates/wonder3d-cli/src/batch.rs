//! `wonder3d batch MANIFEST --out DIR [--shard I/N] [--resume] [--jobs J] [--timeout S]
//! [--weights DIR …]`: many objects in one process, one output folder each, with a JSON-lines
//! report; shards default from Slurm job arrays and Kubernetes Indexed Jobs
//! (`docs/scale.md`).

use std::path::PathBuf;
use std::sync::Mutex;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};
use wonder3d::batch::{Batch, BatchEvent, BatchOptions, InputKind, ItemStatus, Manifest, Shard};
use wonder3d::{Error, Result, TextureOptions};

use crate::args::PresetArg;
use crate::generate::SamplingArgs;

/// Arguments of `wonder3d batch`.
#[derive(clap::Args)]
pub struct BatchArgs {
    /// Manifest: one item per line, an image file or a view-set folder (relative to the
    /// manifest's folder), or a JSON object {"input": …, "id": …, "preset": …, "seed": …}.
    manifest: PathBuf,
    /// Output folder: one folder per item (mesh.glb, report.json, done.json) and reports/.
    #[arg(long)]
    out: PathBuf,
    /// Run shard I of N (0-based): items I, I+N, I+2N, … Default: from SLURM_ARRAY_TASK_ID /
    /// SLURM_ARRAY_TASK_COUNT, or JOB_COMPLETION_INDEX / W3D_SHARD_COUNT, else the whole manifest.
    #[arg(long, allow_hyphen_values = true, value_parser = shard)]
    shard: Option<Shard>,
    /// Continue an earlier run into the same --out: skip items whose outputs are complete
    /// and valid, run the others again.
    #[arg(long)]
    resume: bool,
    /// Items at once in this process (reconstruction overlaps; generation is one at a time).
    #[arg(long, default_value_t = 1, allow_hyphen_values = true, value_parser = crate::args::jobs)]
    jobs: u16,
    /// Give up an item after this many seconds (checked at every optimisation or sampling step).
    #[arg(long, allow_hyphen_values = true, value_parser = seconds)]
    timeout: Option<f64>,
    /// Reconstruction preset of items that name none.
    #[arg(long, value_enum, default_value_t = PresetArg::Default)]
    preset: PresetArg,
    /// Texture side in texels of items that name none.
    #[arg(long, default_value_t = TextureOptions::default().size, allow_hyphen_values = true, value_parser = crate::args::texture_size)]
    texture_size: u32,
    /// Image items: reconstructions tried from the generated views, each with its own remesher
    /// seed; the one that fits the views best is kept (docs/accuracy.md, "Several starts"); one only when the
    /// first fit shows views no closed surface explains.
    #[arg(long, default_value_t = wonder3d::GENERATED_VIEW_STARTS, allow_hyphen_values = true, value_parser = crate::args::starts)]
    starts: usize,
    /// Write untextured meshes (geometry only; faster).
    #[arg(long)]
    no_texture: bool,
    /// Keep the generated views of image items in <out>/<id>/views/.
    #[arg(long)]
    keep_views: bool,
    /// Model directory or Hugging Face Hub id for image items (docs/weights.md); not needed
    /// when every item is a view-set folder. Loaded (and downloaded) once for the whole batch.
    #[arg(long, value_name = "DIR|HUB_ID")]
    weights: Option<PathBuf>,
    #[command(flatten)]
    sampling: SamplingArgs,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

fn shard(s: &str) -> std::result::Result<Shard, String> {
    Shard::parse(s).map_err(|e| e.to_string())
}

fn seconds(s: &str) -> std::result::Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v <= 1e7 => Ok(v),
        _ => Err(format!("a number of seconds in (0, 10000000], got {s:?}")),
    }
}

/// Runs `wonder3d batch`.
pub fn run(args: &BatchArgs) -> Result<()> {
    let shard = match args.shard {
        Some(s) => s,
        None => Shard::from_env()?.unwrap_or(Shard::ALL),
    };
    let options = BatchOptions::new(&args.out)
        .with_shard(shard)
        .with_resume(args.resume)
        .with_jobs(args.jobs.into())
        .with_timeout(args.timeout.map(Duration::from_secs_f64))
        .with_keep_views(args.keep_views)
        .with_preset(args.preset.into())
        .with_texture_size(args.texture_size)
        .with_texture(!args.no_texture)
        .with_generated_view_starts(args.starts);
    let manifest = Manifest::read(&args.manifest)?;
    // Everything checkable is checked before the weights load.
    let mine = Batch::check(&options, &manifest, args.weights.is_some())?;
    let acceleration = args.sampling.check()?;
    if !args.quiet {
        eprintln!(
            "{}: {} items, shard {} runs {} of them -> {}{}",
            args.manifest.display(),
            manifest.items.len(),
            shard,
            mine.len(),
            args.out.display(),
            if args.weights.is_some() { crate::args::acceleration_note(&acceleration) } else { String::new() }
        );
    }
    // A shard of view folders only needs no model: loading one would cost every task its time.
    let needs_model = mine.iter().any(|item| item.kind == InputKind::Image);
    if let Some(weights) = &args.weights
        && !needs_model
    {
        // Not loaded (nor downloaded), yet a typo must not pass: the folder must be there, or
        // the Hub id well-formed.
        check_weights(weights)?;
        if weights.is_dir() && !weights.join("unet").is_dir() {
            return Err(Error::invalid(
                "--weights",
                format!("a model folder with unet/, vae/, image_encoder/ (docs/weights.md), got {}", weights.display()),
            ));
        }
        if !args.quiet {
            eprintln!("note: --weights not loaded: this shard has no image items");
        }
    }
    let batch = if needs_model { with_model(Batch::new(options), args)? } else { Batch::new(options) };
    let bar = if args.quiet { ProgressBar::hidden() } else { ProgressBar::new(mine.len() as u64) };
    bar.set_style(
        ProgressStyle::with_template("{prefix:>8} [{bar:30}] {pos}/{len} {per_sec} ETA {eta} {msg}")
            .map_err(|e| Error::invalid("progress template", e.to_string()))?
            .progress_chars("=> "),
    );
    bar.set_prefix("items");
    bar.enable_steady_tick(Duration::from_millis(250));
    let failures = Mutex::new(Vec::new());
    let summary = batch.run(&manifest, &|event| match event {
        BatchEvent::Planned { total, skipped } => {
            bar.set_length(total as u64);
            if skipped > 0 {
                bar.println(format!("resume: {skipped} items already done"));
            }
        }
        BatchEvent::Started { id } => bar.set_message(id.to_string()),
        BatchEvent::Progress { id, progress } => {
            bar.set_message(format!("{id}: {} {}/{}", progress.stage.name(), progress.done, progress.total))
        }
        BatchEvent::Finished(record) => {
            if record.status != ItemStatus::Skipped {
                bar.inc(1);
            }
            if let Some(error) = &record.error {
                let line = format!("{} (line {}): {error}", record.id, record.line);
                bar.println(format!("failed: {line}"));
                failures.lock().unwrap_or_else(|e| e.into_inner()).push(line);
            }
        }
        _ => {}
    })?;
    bar.finish_and_clear();
    if args.quiet {
        for line in failures.into_inner().unwrap_or_else(|e| e.into_inner()) {
            eprintln!("failed: {line}");
        }
    }
    println!(
        "shard {}: {} ok, {} failed, {} timed out, {} skipped in {:.1} s ({:.0} items/h, {} jobs); report {}",
        summary.shard,
        summary.ok,
        summary.failed,
        summary.timed_out,
        summary.skipped,
        summary.seconds,
        summary.items_per_hour,
        summary.jobs,
        batch.options().report_path().display()
    );
    if summary.failed + summary.timed_out > 0 {
        return Err(Error::invalid(
            "batch",
            format!(
                "every item to succeed: {} failed or timed out (listed in {}); fix them and rerun with --resume",
                summary.failed + summary.timed_out,
                batch.options().report_path().display()
            ),
        ));
    }
    Ok(())
}

#[cfg(feature = "diffusion")]
fn with_model(batch: Batch, args: &BatchArgs) -> Result<Batch> {
    Ok(match &args.weights {
        Some(weights) => {
            let bar = crate::progress::download_bar(args.quiet);
            let model = crate::generate::load(weights, &args.sampling, &wonder3d::SampleOptions::default(), &bar)?;
            bar.finish_and_clear();
            batch.with_model(model)
        }
        None => batch,
    })
}

/// Fails unless `--weights` is an existing folder or a well-formed Hub id.
#[cfg(feature = "diffusion")]
fn check_weights(weights: &std::path::Path) -> Result<()> {
    crate::weights::check("--weights", weights)
}

/// Without the model (and so without Hub downloads) `--weights` must be a folder.
#[cfg(not(feature = "diffusion"))]
fn check_weights(weights: &std::path::Path) -> Result<()> {
    match weights.is_dir() {
        true => Ok(()),
        false => Err(Error::invalid(
            "--weights",
            format!("a model folder with unet/, vae/, image_encoder/ (docs/weights.md), got {}", weights.display()),
        )),
    }
}

#[cfg(not(feature = "diffusion"))]
fn with_model(batch: Batch, args: &BatchArgs) -> Result<Batch> {
    match args.weights {
        Some(_) => Err(crate::generate::without_model()),
        None => Ok(batch),
    }
}
