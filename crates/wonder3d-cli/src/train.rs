//! `wonder3d train --stage 1|2|3 --data DIR --init MODEL --out DIR [--steps N] [--lr LR]
//! [--lr-schedule constant|linear] [--objects-per-batch B] [--accumulate K]
//! [--checkpoint-every C] [--seed S] [--resume]`:
//! trains the multi-view UNet of a model directory on a training set written by `wonder3d
//! dataset`, one Wonder3D++ stage at a time (`docs/training.md`).

use std::path::PathBuf;

use wonder3d::Result;

use crate::args::{DeviceArg, MinSnrGamma};

/// `--background` of `wonder3d train`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum BackgroundArg {
    /// The background each sample records in `dataset.json`.
    Dataset,
    /// White (inference's).
    White,
    /// Black.
    Black,
    /// Grey (0.5).
    Grey,
}

/// `--lr-schedule` of `wonder3d train`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LrScheduleArg {
    /// Constant after the warm-up (the authors').
    Constant,
    /// Linearly down to 0 at `--steps`.
    Linear,
}

/// Arguments of `wonder3d train`.
#[derive(clap::Args)]
#[cfg_attr(not(feature = "diffusion"), allow(dead_code))]
pub struct TrainArgs {
    /// Stage: 1 multi-domain pre-training (no switcher), 2 mixed-domain with the domain
    /// switcher, 3 cross-domain alignment (only the joint attention trains; added to a model
    /// that lacks it).
    #[arg(long, allow_hyphen_values = true, value_parser = clap::value_parser!(u8).range(1..=3))]
    pub stage: u8,
    /// Training set folder (`wonder3d dataset`), at the model's image size.
    #[arg(long)]
    pub data: PathBuf,
    /// Model directory to start from (unet/, vae/, image_encoder/, scheduler/), or a Hugging
    /// Face Hub id owner/name[@revision][:sub/folder] of one (downloaded once into the Hugging
    /// Face cache; docs/weights.md); the VAE and CLIP encoder stay frozen.
    #[arg(long, value_name = "DIR|HUB_ID")]
    pub init: PathBuf,
    /// Output folder: `checkpoint/` (a model directory plus the optimizer state) and
    /// `train_log.jsonl`.
    #[arg(long)]
    pub out: PathBuf,
    /// Optimizer steps to reach (with `--resume`, counting the steps already done).
    #[arg(long, default_value_t = 1000, allow_hyphen_values = true, value_parser = clap::value_parser!(u64).range(1..=10_000_000))]
    pub steps: u64,
    /// Peak learning rate (default: the stage's, 1e-4 / 5e-5 / 2e-5).
    #[arg(long, allow_hyphen_values = true, value_parser = crate::args::learning_rate)]
    pub lr: Option<f64>,
    /// Linear warm-up in optimizer steps.
    #[arg(long, default_value_t = 100, allow_hyphen_values = true, value_parser = clap::value_parser!(u64).range(0..=10_000_000))]
    pub warmup: u64,
    /// The learning rate after the warm-up: `constant` (the authors') or `linear`, from the
    /// peak down to 0 at `--steps` (a cool-down; keep `--steps` when resuming).
    #[arg(long, value_enum, default_value_t = LrScheduleArg::Constant)]
    pub lr_schedule: LrScheduleArg,
    /// Objects per micro-batch (each 6 views, or 12 in stage 3).
    #[arg(long, default_value_t = 1, allow_hyphen_values = true, value_parser = clap::value_parser!(u64).range(1..=1024))]
    pub objects_per_batch: u64,
    /// Micro-batches accumulated into one optimizer step.
    #[arg(long, default_value_t = 1, allow_hyphen_values = true, value_parser = clap::value_parser!(u64).range(1..=1024))]
    pub accumulate: u64,
    /// Write a checkpoint every this many optimizer steps (and at the end).
    #[arg(long, default_value_t = 100, allow_hyphen_values = true, value_parser = clap::value_parser!(u64).range(1..=10_000_000))]
    pub checkpoint_every: u64,
    /// Seed of the sample, domain, timestep, noise and dropout draws.
    #[arg(long, default_value_t = 0, allow_hyphen_values = true, value_parser = crate::args::seed)]
    pub seed: u64,
    /// Keep an exponential moving average of the trained weights with this maximum decay
    /// (e.g. 0.999; diffusers' warm-up `min(decay, (1 + s) / (10 + s))`): checkpoints hold it
    /// in `unet_ema/`, and the end of the run writes the whole model with it to
    /// `OUT/model-ema` (the model to generate with).
    #[arg(long, allow_hyphen_values = true, value_parser = crate::args::ema_decay)]
    pub ema_decay: Option<f64>,
    /// Min-SNR-γ loss weighting: a number (the authors' 5, the default) or `none` for the
    /// plain MSE of the model's prediction type (the small model's recipe, `docs/training.md`).
    #[arg(long, default_value = "5", allow_hyphen_values = true, value_parser = crate::args::min_snr_gamma)]
    pub min_snr_gamma: MinSnrGamma,
    /// Train the whole UNet whatever the stage (in stage 3: Wonder3D v1's joint training
    /// instead of the joint attention alone).
    #[arg(long)]
    pub train_all: bool,
    /// Recompute the memory-bound activations (element-wise operations, normalisations) in
    /// the backward pass instead of keeping them: less memory, more time per step
    /// (docs/training.md, "Gradient checkpointing").
    #[arg(long)]
    pub gradient_checkpointing: bool,
    /// Composite every sample on this background instead of the one `dataset.json` records
    /// (`dataset`: the recorded one; inference always uses white).
    #[arg(long, value_enum, default_value_t = BackgroundArg::Dataset)]
    pub background: BackgroundArg,
    /// Continue the run in `--out` from its checkpoint (bit-identical to an uninterrupted run).
    #[arg(long)]
    pub resume: bool,
    /// Where the model trains: `cpu` (all cores) or `wgpu` (the GPU; a build with the `wgpu`
    /// feature, docs/gpu.md). The data is encoded on the same device.
    #[arg(long, value_enum, default_value_t = DeviceArg::Cpu)]
    pub device: DeviceArg,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// Runs `wonder3d train`.
#[cfg(feature = "diffusion")]
pub fn run(args: &TrainArgs) -> Result<()> {
    use indicatif::{ProgressBar, ProgressStyle};
    use wonder3d::Error;
    use wonder3d::diffusion::MultiViewPipeline;
    use wonder3d::diffusion::train::data::TrainingSet;
    use wonder3d::diffusion::train::{LrSchedule, RunEvent, RunOptions, Stage, TrainOptions, run_training};

    let stage = Stage::from_number(args.stage)?;
    // Everything cheap is checked before the model loads: the set's index, the output folder.
    use wonder3d::diffusion::train::data::Background;
    let background = match args.background {
        BackgroundArg::Dataset => None,
        BackgroundArg::White => Some(Background::White),
        BackgroundArg::Black => Some(Background::Black),
        BackgroundArg::Grey => Some(Background::Grey),
    };
    wonder3d::outputs::check_folder_outside_inputs(
        ("--out", &args.out),
        &[("--data", args.data.as_path()), ("--init", args.init.as_path())],
    )?;
    let set = TrainingSet::open(&args.data)?.with_background(background);
    let checkpoint = args.out.join(wonder3d::diffusion::train::CHECKPOINT_DIR);
    if !args.resume && checkpoint.exists() {
        return Err(Error::invalid(
            "--out",
            format!(
                "a folder without a run ({} exists: pass --resume, or choose another folder)",
                checkpoint.display()
            ),
        ));
    }
    let opened = args.device.compute_device().open()?;
    if opened.kind != wonder3d::ComputeDevice::Cpu {
        eprintln!("device: {}", opened.description);
    }
    let init = {
        let bar = crate::progress::download_bar(args.quiet);
        let dir = crate::weights::resolve("--init", &args.init, wonder3d::weights::Layout::MultiView, &bar)?;
        bar.finish_and_clear();
        dir
    };
    let mut pipeline = MultiViewPipeline::from_dir(&init, &opened.device)?;
    if stage != Stage::CrossDomain && pipeline.unet().config().cd_attention_mid {
        return Err(Error::invalid(
            "--stage",
            format!(
                "3 for {} (its UNet has cross-domain attention, which pairs each image with its other \
                 domain; stages 1 and 2 train the model before that attention exists)",
                args.init.display()
            ),
        ));
    }
    if stage == Stage::CrossDomain && !pipeline.unet().config().cd_attention_mid && !args.resume {
        eprintln!(
            "note: {} has no cross-domain attention; adding it (zero-initialised output) for stage 3",
            args.init.display()
        );
        let (unet, vae, clip, scheduler) = pipeline.into_parts();
        pipeline = MultiViewPipeline::new(unet.with_cross_domain_attention(args.seed)?, vae, clip, scheduler)?;
    }
    let lr_schedule = match args.lr_schedule {
        LrScheduleArg::Constant => LrSchedule::Constant,
        LrScheduleArg::Linear => LrSchedule::LinearToZero { end: args.steps as usize },
    };
    let mut options = TrainOptions::for_stage(stage)
        .with_warmup_steps(args.warmup as usize)
        .with_lr_schedule(lr_schedule)
        .with_gradient_accumulation(args.accumulate as usize)
        .with_seed(args.seed)
        .with_ema_decay(args.ema_decay)
        .with_min_snr_gamma(args.min_snr_gamma.0)
        .with_train_all(args.train_all)
        .with_gradient_checkpointing(args.gradient_checkpointing);
    if let Some(lr) = args.lr {
        options = options.with_learning_rate(lr);
    }
    let run = RunOptions::default()
        .with_steps(args.steps as usize)
        .with_objects_per_batch(args.objects_per_batch as usize)
        .with_checkpoint_every(args.checkpoint_every as usize);
    let bar = if args.quiet { ProgressBar::hidden() } else { ProgressBar::new(set.len() as u64) };
    bar.set_style(
        ProgressStyle::with_template("{prefix:>8} [{bar:40}] {pos}/{len} {msg} ({elapsed}, eta {eta})")
            .map_err(|e| Error::invalid("progress template", e.to_string()))?
            .progress_chars("=> "),
    );
    bar.set_prefix("encode");
    let mut last_checkpoint = None;
    let trained = run_training(pipeline, &set, options, &run, &args.out, args.resume, &mut |event| match event {
        RunEvent::Encoded { done, total } => {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        }
        RunEvent::Resumed { step } => {
            bar.println(format!("resumed at step {step}"));
            bar.set_position(step as u64);
        }
        RunEvent::Step(log) => {
            if bar.prefix() != "train" {
                bar.set_prefix("train");
                bar.set_length(args.steps);
                bar.reset_eta();
            }
            bar.set_position(log.step as u64);
            bar.set_message(format!("loss {:.4}", log.loss));
        }
        RunEvent::Checkpoint { step } => last_checkpoint = Some(step),
    })?;
    bar.finish_and_clear();
    println!(
        "stage {} trained to step {} -> {} (log: {})",
        stage.number(),
        last_checkpoint.unwrap_or(args.steps as usize),
        checkpoint.display(),
        args.out.join(wonder3d::diffusion::train::LOG_FILE).display()
    );
    if args.ema_decay.is_some() {
        // The moving-average weights as a model directory of their own, for generate / run.
        let ema_model = args.out.join("model-ema");
        trained.save(&ema_model)?;
        println!("moving-average model -> {}", ema_model.display());
    }
    Ok(())
}

/// Runs `wonder3d train` (this binary has no model).
#[cfg(not(feature = "diffusion"))]
pub fn run(_: &TrainArgs) -> Result<()> {
    Err(crate::generate::without_model())
}
