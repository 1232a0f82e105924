//! A whole training run: the steps, checkpoints, the moving average and the loss log in an
//! output folder, resumable.

use burn::module::Module;
use w3d_core::Error;

use crate::loading::weights::Precision;
use crate::pipelines::multiview::MultiViewPipeline;
use crate::train::data::{EncodedSample, EncodedSet, TrainDomain, TrainingSet, assemble_batch, check_set_size};
use crate::train::options::*;
use crate::train::trainer::*;

/// Length and shape of a training run ([`run_training`]).
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct RunOptions {
    /// Optimizer steps to reach (counting steps done before a resume).
    pub steps: usize,
    /// Objects per micro-batch.
    pub objects_per_batch: usize,
    /// Write a checkpoint every this many optimizer steps (and at the end).
    pub checkpoint_every: usize,
}

impl Default for RunOptions {
    fn default() -> Self {
        Self { steps: 1000, objects_per_batch: 1, checkpoint_every: 100 }
    }
}

impl RunOptions {
    w3d_core::setters! {
        /// Sets the number of optimizer steps.
        with_steps(steps: usize);
        /// Sets the objects per micro-batch.
        with_objects_per_batch(objects_per_batch: usize);
        /// Sets the checkpoint interval.
        with_checkpoint_every(checkpoint_every: usize);
    }
}

/// What a training run reports as it goes.
#[derive(Clone, Debug)]
pub enum RunEvent {
    /// Samples encoded so far, of the total.
    Encoded {
        /// Done.
        done: usize,
        /// All.
        total: usize,
    },
    /// A run picked up from its checkpoint at this optimizer step.
    Resumed {
        /// The step.
        step: usize,
    },
    /// An optimizer step finished.
    Step(StepLog),
    /// A checkpoint was written after this optimizer step.
    Checkpoint {
        /// The step.
        step: usize,
    },
}

/// The checkpoint folder of a run's output folder: a model directory
/// ([`MultiViewPipeline::from_dir`]) plus [`STATE_FILE`] and [`OPTIMIZER_FILE`].
pub const CHECKPOINT_DIR: &str = "checkpoint";
/// With [`TrainOptions::ema_decay`], the checkpoint also holds the moving-average UNet in this
/// sub-folder (diffusers' `unet_ema` layout: `config.json` + safetensors); the checkpoint's
/// `unet/` keeps the current weights, which a resumed run continues from.
pub const EMA_DIR: &str = "unet_ema";
/// The run's log: one JSON object per optimizer step (`step`, `loss`, `grad_norm`, `lr`,
/// `seconds`).
pub const LOG_FILE: &str = "train_log.jsonl";

/// Trains the UNet of `pipeline` on `set` (`crate::train::data`), writing
/// `out/checkpoint/` every `run.checkpoint_every` steps and at the end (atomically, model and
/// optimizer state together) and one log line per optimizer step to `out/train_log.jsonl`.
/// With `resume`, `out/checkpoint/` must exist: its model replaces `pipeline`'s UNet and its
/// state the optimizer's, and the log keeps the lines up to its step; without, `out` must not
/// hold a run already. Returns the trained pipeline (with the moving-average weights when
/// `options` keeps an EMA).
///
/// The set is encoded first by the pipeline's frozen VAE and CLIP encoder
/// ([`RunEvent::Encoded`]); bad options and folders are refused before that.
/// [`run_training_encoded`] trains on a set encoded once for several runs.
pub fn run_training(
    pipeline: MultiViewPipeline,
    set: &TrainingSet,
    options: TrainOptions,
    run: &RunOptions,
    out: &std::path::Path,
    resume: bool,
    on_event: &mut dyn FnMut(RunEvent),
) -> Result<MultiViewPipeline, Error> {
    check_set_size(set.dir(), set.size(), &pipeline)?;
    check_run(&options, run, out, resume)?;
    let device = pipeline.unet().devices().into_iter().next().unwrap_or_default();
    let encoded =
        EncodedSet::encode(&pipeline, set, &device, &mut |done, total| on_event(RunEvent::Encoded { done, total }))?;
    run_training_encoded(pipeline, &encoded, options, run, out, resume, on_event)
}

/// Refuses a run's bad options and folders before any work: 0 steps, objects or checkpoint
/// interval, a resume without a checkpoint, a fresh run into a folder holding one.
pub(crate) fn check_run(
    options: &TrainOptions,
    run: &RunOptions,
    out: &std::path::Path,
    resume: bool,
) -> Result<(), Error> {
    if run.steps == 0 || run.objects_per_batch == 0 || run.checkpoint_every == 0 {
        return Err(Error::invalid("run", "steps, objects_per_batch and checkpoint_every of at least 1"));
    }
    let checkpoint = out.join(CHECKPOINT_DIR);
    if resume && !checkpoint.join(STATE_FILE).is_file() {
        return Err(Error::invalid(
            "resume",
            format!("a checkpoint to resume from ({} is missing)", checkpoint.join(STATE_FILE).display()),
        ));
    }
    if !resume && (checkpoint.exists() || out.join(LOG_FILE).exists()) {
        return Err(Error::invalid(
            "out",
            format!("a folder without a run in it ({} has one: resume it, or choose another folder)", out.display()),
        ));
    }
    options.validate()
}

/// [`run_training`] on a set already encoded by `pipeline`'s VAE and CLIP encoder (or by
/// identical ones: training changes only the UNet, so the phases of a recipe can share one
/// [`EncodedSet`] per background). The result is the same
/// as `run_training` on the set the encoding came from.
pub fn run_training_encoded(
    pipeline: MultiViewPipeline,
    encoded: &EncodedSet,
    options: TrainOptions,
    run: &RunOptions,
    out: &std::path::Path,
    resume: bool,
    on_event: &mut dyn FnMut(RunEvent),
) -> Result<MultiViewPipeline, Error> {
    use std::io::Write;

    check_set_size(encoded.dir(), encoded.size(), &pipeline)?;
    check_run(&options, run, out, resume)?;
    let checkpoint = out.join(CHECKPOINT_DIR);
    let log_path = out.join(LOG_FILE);
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let device = pipeline.unet().devices().into_iter().next().unwrap_or_default();
    let (unet, vae, clip, scheduler) = pipeline.into_parts();
    let unet = if resume { crate::models::unet::UNet::from_dir(checkpoint.join("unet"), &device)? } else { unet };
    let class_dim = unet.config().projection_class_embeddings_input_dim.unwrap_or(0);
    let mut trainer = Trainer::new(unet, scheduler.clone(), options)?;
    let mut kept_log = Vec::new();
    if resume {
        trainer.load_state(&checkpoint)?;
        if let Ok(text) = std::fs::read_to_string(&log_path) {
            for line in text.lines() {
                let step = serde_json::from_str::<serde_json::Value>(line)
                    .ok()
                    .and_then(|v| v.get("step").and_then(|s| s.as_u64()));
                if step.is_some_and(|s| s as usize <= trainer.steps()) {
                    kept_log.push(line.to_string());
                }
            }
        }
        on_event(RunEvent::Resumed { step: trainer.steps() });
    }
    let mut log_text = kept_log.join("\n");
    if !log_text.is_empty() {
        log_text.push('\n');
    }
    w3d_core::io::write_atomic_all(&[(&log_path, log_text.as_bytes())])?;
    let mut log = std::fs::OpenOptions::new().append(true).open(&log_path).map_err(|e| Error::io(&log_path, e))?;
    let train_device = trainer.device();
    let encoded: Vec<EncodedSample> = encoded.samples().iter().map(|s| s.to_device(&train_device)).collect();
    let stage = trainer.options().stage;
    let started = std::time::Instant::now();
    let save = |trainer: &Trainer| -> Result<(), Error> {
        let pipeline = MultiViewPipeline::new(trainer.inference_unet(), vae.clone(), clip.clone(), scheduler.clone())?;
        w3d_core::io::write_dir_atomic(&checkpoint, STATE_FILE, |staging| {
            pipeline.write_into(staging, Precision::F32)?;
            if let Some(ema) = trainer.ema_unet() {
                ema.save(staging.join(EMA_DIR))?;
            }
            trainer.write_state(staging)
        })
    };
    while trainer.steps() < run.steps {
        let picked: Vec<usize> = (0..run.objects_per_batch).map(|_| trainer.draw_index(encoded.len())).collect();
        let domains: Vec<TrainDomain> = picked
            .iter()
            .map(|_| match stage {
                Stage::MultiDomain => {
                    [TrainDomain::Normal, TrainDomain::Colour, TrainDomain::Mask][trainer.draw_index(3)]
                }
                _ => [TrainDomain::Normal, TrainDomain::Colour][trainer.draw_index(2)],
            })
            .collect();
        let samples: Vec<&EncodedSample> = picked.iter().map(|&i| &encoded[i]).collect();
        let batch = assemble_batch(stage, &samples, &domains, class_dim)?;
        let step = trainer.step(&batch)?;
        if !step.updated {
            continue;
        }
        let line = serde_json::json!({
            "step": step.step,
            "loss": step.loss,
            "grad_norm": step.grad_norm,
            "lr": step.learning_rate,
            "seconds": started.elapsed().as_secs_f64(),
        });
        writeln!(log, "{line}").map_err(|e| Error::io(&log_path, e))?;
        let at = step.step;
        on_event(RunEvent::Step(step));
        if at % run.checkpoint_every == 0 || at == run.steps {
            save(&trainer)?;
            on_event(RunEvent::Checkpoint { step: at });
        }
    }
    let unet = trainer.ema_unet().unwrap_or_else(|| trainer.inference_unet());
    MultiViewPipeline::new(unet, vae, clip, scheduler)
}
