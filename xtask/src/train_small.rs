//! `cargo xtask train-small`: the recipe of the small model shipped in `assets/model-small`
//! (`docs/training.md`; `cargo xtask ship-small` puts a trained model there in f16): a training set rendered from the CC0 / CC BY meshes, a small VAE
//! trained on its images, a frozen random CLIP image encoder, the multi-view UNet trained
//! through Wonder3D++'s three stages, then twice a joint phase on white backgrounds followed by
//! a cool-down (the learning rate falling to 0), each starting from the previous one, and, on a thread of
//! its own beside the UNet's phases, the VAE's decoder fine-tuned in two passes with its
//! encoder frozen.

use std::path::{Path, PathBuf};
use std::time::Instant;

use wonder3d::dataset::{Dataset, DatasetOptions};
use wonder3d::diffusion::train::data::{Background, EncodedSet, TrainingSet};
use wonder3d::diffusion::train::{
    CHECKPOINT_DIR, EMA_DIR, LrSchedule, RunEvent, RunOptions, STATE_FILE, Stage, TrainOptions, VaeTrainOptions,
    run_training_encoded, train_vae,
};
use wonder3d::diffusion::{
    ClipVision, ClipVisionConfig, MultiViewPipeline, SchedulerConfig, UNet, UNetConfig, Vae, VaeConfig,
};

/// The meshes the small model trains on (licences in `docs/training.md`), relative to the
/// workspace root; `torus` is held out.
pub(crate) const TRAIN_MESHES: &[&str] = &[
    "assets/spot.obj",
    "assets/bob_tri.obj",
    "../shared/data/meshes/boot.obj",
    "../shared/data/meshes/hammer.obj",
    "../shared/data/meshes/wingnut.obj",
    "../shared/data/meshes/plane.obj",
    "../shared/data/meshes/koala_low_resolution.obj",
];

/// The held-out mesh.
pub(crate) const HELD_OUT_MESH: &str = "assets/torus.obj";

/// The folder of a run's tuned VAE (written once its decoder's passes are complete).
const DECODER_DIR: &str = "decoder";

/// The file in which a run keeps its training time up to the last work a `--resume` keeps
/// (a checkpoint, a finished phase), summed over the processes that `--resume` joins: the
/// wall time of the uninterrupted run plus the resumes' reloading.
const CLOCK_FILE: &str = "clock.json";

/// A run's training time across processes (see [`CLOCK_FILE`]).
struct RunClock {
    /// Seconds of the earlier processes (`None`: a resumed run without a clock file).
    earlier: Option<f64>,
    started: Instant,
    path: PathBuf,
}

impl RunClock {
    /// This process's clock, counting from `started` (the process's start); a fresh run
    /// discards an earlier run's file.
    fn start(out: &Path, resume: bool, started: Instant) -> Result<Self, String> {
        let path = out.join(CLOCK_FILE);
        let earlier = if resume {
            let read = std::fs::read(&path).ok().and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok());
            read.and_then(|json| json["seconds"].as_f64())
        } else {
            match std::fs::remove_file(&path) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(format!("{}: {e}", path.display())),
                _ => Some(0.0),
            }
        };
        Ok(Self { earlier, started, path })
    }

    /// The run's seconds so far, over all its processes (`None` if the earlier ones are unknown).
    fn seconds(&self) -> Option<f64> {
        self.earlier.map(|e| e + self.started.elapsed().as_secs_f64())
    }

    /// Records the time so far, and returns it; called once work a resume keeps is on disk.
    fn save(&self) -> Result<Option<f64>, String> {
        let Some(seconds) = self.seconds() else { return Ok(None) };
        let bytes = serde_json::to_vec_pretty(&serde_json::json!({ "seconds": seconds })).map_err(err)?;
        wonder3d::core::io::write_atomic_all(&[(&self.path, &bytes)]).map_err(err)?;
        Ok(Some(seconds))
    }
}

/// The decoder's fine-tune: loaded from an earlier run, or training on its own thread.
enum DecoderTune {
    Done(Box<Vae>),
    Running(std::thread::JoinHandle<Result<Vae, String>>),
}

impl DecoderTune {
    /// Waits for the thread (if any) and returns the tuned VAE, or the thread's error.
    fn join(self) -> Result<Vae, String> {
        match self {
            DecoderTune::Done(vae) => Ok(*vae),
            DecoderTune::Running(handle) => handle.join().map_err(|_| "the decoder's thread panicked".to_string())?,
        }
    }

    /// Joins the thread if it has already finished, so that its failure stops the run at the
    /// next phase boundary instead of after every UNet phase (hours later).
    fn poll(self) -> Result<Self, String> {
        match self {
            DecoderTune::Running(handle) if handle.is_finished() => {
                Ok(DecoderTune::Done(Box::new(DecoderTune::Running(handle).join()?)))
            }
            other => Ok(other),
        }
    }
}

/// One phase of the UNet's training: its folder, the stage (the batch layout and, unless
/// `train_all`, the trainable set), whether every sample is composited on white, the seed of
/// its draws and the decay of its weights' moving average (`None`: no EMA).
struct Phase {
    dir: &'static str,
    stage: Stage,
    train_all: bool,
    white: bool,
    seed: u64,
    ema_decay: Option<f64>,
    /// The learning rate falls linearly to 0 over the phase after its warm-up (a cool-down)
    /// instead of staying at its peak.
    cool_down: bool,
}

impl Phase {
    /// One of Wonder3D++'s stages: its own trainable set, on the dataset's backgrounds.
    const fn stage(dir: &'static str, stage: Stage, seed: u64) -> Self {
        Self { dir, stage, train_all: false, white: false, seed, ema_decay: None, cool_down: false }
    }

    /// A joint phase: the whole UNet with the cross-domain attention, on white, at a constant
    /// learning rate.
    const fn joint(dir: &'static str, seed: u64, ema_decay: Option<f64>) -> Self {
        Self { dir, stage: Stage::CrossDomain, train_all: true, white: true, seed, ema_decay, cool_down: false }
    }

    /// A cool-down: a joint phase without EMA whose learning rate falls to 0.
    const fn cool_down(dir: &'static str, seed: u64) -> Self {
        Self { cool_down: true, ..Self::joint(dir, seed, None) }
    }
}

/// Wonder3D++'s three stages on the dataset's three backgrounds, then joint phases: the
/// whole UNet with the cross-domain attention (Wonder3D v1's joint training) on white, the
/// only background inference uses — a model this small generates garbage from an input on a
/// background other than the one its sample was trained on (docs/training.md). The second
/// joint phase continues the first with fresh optimizer moments and an EMA of the weights;
/// a cool-down starts from that average and brings the learning rate down to 0. The third
/// to seventh joint phases, each with its cool-down, repeat the last two from the cooled
/// model: the moving average alone scores no better than its start, the cool-down after
/// it does (docs/training.md).
const PHASES: [Phase; PHASE_COUNT] = [
    Phase::stage("stage1", Stage::MultiDomain, 10),
    Phase::stage("stage2", Stage::MixedDomain, 11),
    Phase::stage("stage3", Stage::CrossDomain, 12),
    Phase::joint("joint", 13, None),
    Phase::joint("joint2", 1, Some(0.999)),
    Phase::cool_down("cooldown", 2),
    Phase::joint("joint3", 3, Some(0.999)),
    Phase::cool_down("cooldown2", 4),
    Phase::joint("joint4", 5, Some(0.999)),
    Phase::cool_down("cooldown3", 6),
    Phase::joint("joint5", 7, Some(0.999)),
    Phase::cool_down("cooldown4", 8),
    Phase::joint("joint6", 14, Some(0.999)),
    Phase::cool_down("cooldown5", 15),
    Phase::joint("joint7", 16, Some(0.999)),
    Phase::cool_down("cooldown6", 17),
];

/// The number of UNet phases ([`PHASES`]).
pub(crate) const PHASE_COUNT: usize = 16;

/// The folder under `configs/small` of the recipe's UNet configuration: the half width
/// (`block_out_channels` [32, 64, 64], 1.45 M parameters), which learns more per hour of 2
/// cores than the full width of `configs/small/unet` and generates in half the time
/// (docs/training.md, items 11 and 16).
const RECIPE_UNET: &str = "unet-half";

/// The schedule of one run.
#[derive(Clone, Debug)]
pub(crate) struct Schedule {
    pub samples: usize,
    pub size: u32,
    pub vae_steps: usize,
    /// Steps of each phase: the three stages, then joint phases and cool-downs ([`PHASES`]).
    pub stage_steps: [usize; PHASE_COUNT],
    /// Warm-up steps of each phase.
    pub stage_warmup: [usize; PHASE_COUNT],
    pub stage_lr: [f64; PHASE_COUNT],
    /// Steps and learning rate of each pass of the decoder's fine-tune beside the UNet
    /// ([`tune_decoder`]; each pass starts with fresh optimizer moments).
    pub decoder_passes: Vec<(usize, f64)>,
    pub objects_per_batch: usize,
    /// Min-SNR γ of the UNet's loss (`None`: the plain MSE of the v-prediction).
    pub min_snr_gamma: Option<f64>,
}

impl Schedule {
    pub(crate) fn full() -> Self {
        Self {
            samples: 12,
            size: 64,
            vae_steps: 1200,
            // Seven joint phases, each but the first followed by a cool-down: every pair
            // lowered the generated normals' error of every training object, a long pair
            // more than a short one (docs/training.md, "Where the error comes from", items 6,
            // 11 and 16).
            stage_steps: [
                800, 4000, 1000, 3000, 16000, 2000, 8000, 2000, 7000, 2000, 4000, 2000, 4000, 2000, 14000, 2000,
            ],
            stage_warmup: [40, 300, 75, 50, 50, 50, 50, 50, 50, 50, 50, 50, 50, 50, 50, 50],
            stage_lr: [5e-4, 3e-4, 2e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4],
            // Each pass lowered the decoder's own error on the training views and passed part
            // of it on to the generated normals: the second 0.2–4.8°, the third 0.9–1.0°
            // (docs/training.md, item 14). They run beside the UNet's phases.
            decoder_passes: vec![(1500, 3e-4), (4500, 2e-4), (4500, 1e-4)],
            objects_per_batch: 1,
            // The small model predicts v and weighs every timestep alike in v (x₀ error
            // weighted by SNR + 1): with ε or Min-SNR weights (x₀ error weighted by
            // min(SNR, 5)) the noisiest timesteps weigh 1/600 of the clean ones, and the first
            // small model learned to ignore its input there (docs/training.md).
            min_snr_gamma: None,
        }
    }

    /// A few steps of everything, to check the recipe end to end and time its steps.
    pub(crate) fn quick() -> Self {
        Self {
            samples: 2,
            size: 64,
            vae_steps: 20,
            stage_steps: [10; PHASE_COUNT],
            stage_warmup: [1; PHASE_COUNT],
            decoder_passes: vec![(10, 3e-4), (10, 2e-4)],
            ..Self::full()
        }
    }
}

/// What `cargo xtask train-small` may change in the recipe (each `None`: the recipe's).
#[derive(Clone, Debug, Default)]
pub(crate) struct Overrides {
    /// Steps of the UNet phases in order (`--phase-steps`; see [`phase_steps_of`]).
    pub phase_steps: Option<Vec<usize>>,
    /// Steps and learning rate of each of the decoder's passes (`--decoder-passes`).
    pub decoder_passes: Option<Vec<(usize, f64)>>,
    /// The UNet's `config.json` (`--unet-config`; the recipe's is [`RECIPE_UNET`]'s).
    pub unet_config: Option<PathBuf>,
}

/// One `--decoder-passes` item, `STEPS:LR` (e.g. `4500:1e-4`).
pub(crate) fn parse_decoder_pass(text: &str) -> Result<(usize, f64), String> {
    let (steps, lr) = text.split_once(':').ok_or_else(|| format!("{text:?}: a pass is STEPS:LR, e.g. 4500:1e-4"))?;
    let steps = steps.trim().parse().map_err(|e| format!("{text:?}: steps {steps:?}: {e}"))?;
    let lr = lr.trim().parse().map_err(|e| format!("{text:?}: learning rate {lr:?}: {e}"))?;
    Ok((steps, lr))
}

/// The step counts of every UNet phase from `--phase-steps`: the first phases' counts, 0 for
/// the phases after them, so that a schedule written before later phases were added still
/// means the same run. The three stages need at least 1 step each.
fn phase_steps_of(steps: &[usize]) -> Result<[usize; PHASE_COUNT], String> {
    if !(3..=PHASE_COUNT).contains(&steps.len()) || steps[..3].contains(&0) {
        return Err(format!(
            "--phase-steps: 3 to {PHASE_COUNT} step counts (the phases after the last one are left out), \
             those of the three stages at least 1 (found {steps:?})"
        ));
    }
    let mut all = [0; PHASE_COUNT];
    all[..steps.len()].copy_from_slice(steps);
    Ok(all)
}

fn config_dir() -> PathBuf {
    crate::workspace::workspace_root().join("crates").join("w3d-diffusion").join("configs").join("small")
}

fn err(e: impl std::fmt::Display) -> String {
    e.to_string()
}

/// The optimizer step a stage folder's checkpoint reached (`None` without one).
fn checkpoint_step(stage_dir: &Path) -> Option<usize> {
    let path = stage_dir.join(CHECKPOINT_DIR).join(STATE_FILE);
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(path).ok()?).ok()?;
    json["step"].as_u64().map(|s| s as usize)
}

/// Runs the recipe into `out`. With `resume`, an earlier run there continues: the training
/// set and the VAE are reused, a stage whose checkpoint reached its step count is loaded, one
/// that stopped short resumes from its checkpoint (exactly, see `run_training`), and once a
/// stage has trained, the stages after it start afresh. The result is the uninterrupted
/// run's. `phase_steps` replaces the schedule's step counts of the first UNet phases (at least
/// the three stages'); a phase after the three stages with 0 steps, or after the last count, is
/// left out.
pub(crate) fn run(out: &Path, quick: bool, resume: bool, overrides: &Overrides) -> Result<(), String> {
    let mut schedule = if quick { Schedule::quick() } else { Schedule::full() };
    if let Some(steps) = &overrides.phase_steps {
        schedule.stage_steps = phase_steps_of(steps)?;
    }
    if let Some(passes) = &overrides.decoder_passes {
        if passes.is_empty() || passes.iter().any(|&(steps, lr)| steps == 0 || !(lr > 0.0 && lr.is_finite())) {
            return Err(format!(
                "--decoder-passes: one or more STEPS:LR pairs, each with at least 1 step and a positive \
                 learning rate (found {passes:?})"
            ));
        }
        schedule.decoder_passes = passes.clone();
    }
    let unet_config =
        overrides.unet_config.clone().unwrap_or_else(|| config_dir().join(RECIPE_UNET).join("config.json"));
    // Read now, so that a wrong path fails before the hours of training, not after the VAE.
    let unet_config = UNetConfig::from_file(&unet_config).map_err(|e| format!("--unet-config: {e}"))?;
    let root = crate::workspace::workspace_root();
    let started = Instant::now();
    let device = wonder3d::diffusion::default_device();
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let stage1 = out.join("stage1").join(CHECKPOINT_DIR);
    let resume = resume && stage1.join("model_index.json").is_file();
    let clock = RunClock::start(out, resume, started)?;

    // 1. The training set.
    let data = out.join("data");
    if !resume {
        let meshes: Vec<PathBuf> = TRAIN_MESHES.iter().map(|m| root.join(m)).collect();
        let options = DatasetOptions::default().with_samples(schedule.samples).with_size(schedule.size).with_seed(0);
        let dataset = Dataset::prepare(&meshes, &options).map_err(err)?;
        dataset.write(&data, &mut |_| {}).map_err(err)?;
    }
    let set = TrainingSet::open(&data).map_err(err)?;
    eprintln!("[{:6.0}s] training set: {} samples at {}²", started.elapsed().as_secs_f64(), set.len(), set.size());

    let scheduler =
        SchedulerConfig::from_file(config_dir().join("scheduler").join("scheduler_config.json")).map_err(err)?;
    let mut retrain = !resume;
    let mut pipeline = if resume {
        // The VAE and CLIP encoder of the earlier run (every checkpoint holds them).
        eprintln!(
            "[{:6.0}s] resuming: VAE and CLIP encoder from {}",
            started.elapsed().as_secs_f64(),
            stage1.display()
        );
        let earlier = MultiViewPipeline::from_dir(&stage1, &device).map_err(err)?;
        if earlier.scheduler() != &scheduler {
            // The noise schedule or the prediction changed: the UNet trains again from
            // stage 1 (the VAE does not depend on them).
            eprintln!("  the recipe's scheduler config changed: the UNet trains again from stage 1");
            retrain = true;
            let (_, vae, clip, _) = earlier.into_parts();
            let unet = UNet::random(&unet_config, 3, &device).map_err(err)?;
            MultiViewPipeline::new(unet, vae, clip, scheduler).map_err(err)?
        } else {
            earlier
        }
    } else {
        fresh_model(&set, &schedule, &unet_config, scheduler, &device, started)?
    };

    // 4. The decoder, sharpened on the latents of the frozen encoder, in passes. It
    // depends on the VAE alone, not on the UNet, so it trains on a thread of its own beside
    // the UNet's phases: the two share the cores, and each fills the other's serial gaps
    // (docs/training.md). Its result is written to `decoder/` once complete.
    let decoder_dir = out.join(DECODER_DIR);
    // Checked now rather than when the tune, an hour later, writes there.
    wonder3d::core::io::replaceable_folder(&decoder_dir).map_err(err)?;
    if !resume && decoder_dir.exists() {
        // An earlier run's decoder belongs to that run's VAE.
        std::fs::remove_dir_all(&decoder_dir).map_err(|e| format!("{}: {e}", decoder_dir.display()))?;
    }
    let mut decoder = if resume && decoder_dir.join("config.json").is_file() {
        eprintln!(
            "[{:6.0}s] decoder: tuned earlier, loaded from {}",
            started.elapsed().as_secs_f64(),
            decoder_dir.display()
        );
        DecoderTune::Done(Box::new(Vae::from_dir(&decoder_dir, &device).map_err(err)?))
    } else {
        let passes = schedule.decoder_passes.clone();
        let (vae, set) = (pipeline.vae().clone(), set.clone());
        let dir = decoder_dir.clone();
        DecoderTune::Running(
            std::thread::Builder::new()
                .name("decoder".into())
                .spawn(move || {
                    let t = Instant::now();
                    let vae = tune_decoder(vae, &set, &passes)?;
                    wonder3d::core::io::write_dir_atomic(&dir, "config.json", |staging| vae.save(staging))
                        .map_err(err)?;
                    eprintln!(
                        "[{:6.0}s] decoder tuned in {:.0} s",
                        started.elapsed().as_secs_f64(),
                        t.elapsed().as_secs_f64()
                    );
                    Ok(vae)
                })
                .map_err(err)?,
        )
    };

    // 5. The three stages, the joint phases and the cool-downs. The set is encoded once per
    // background (the stages' own, the joint phases' white) and shared by the phases on it:
    // training changes only the UNet, so each phase would encode it identically.
    let mut encodings: [Option<EncodedSet>; 2] = [None, None];
    for (i, phase) in PHASES.iter().enumerate() {
        decoder = decoder.poll()?;
        let stage = phase.stage;
        let steps = schedule.stage_steps[i];
        let stage_dir = out.join(phase.dir);
        if steps == 0 {
            // A phase of 0 steps (`--phase-steps`) is left out; a fresh run does not keep an
            // earlier run's folder of it beside its own phases.
            if !resume && stage_dir.exists() {
                std::fs::remove_dir_all(&stage_dir).map_err(|e| format!("{}: {e}", stage_dir.display()))?;
            }
            eprintln!("[{:6.0}s] {}: 0 steps, left out", started.elapsed().as_secs_f64(), phase.dir);
            continue;
        }
        let reached = if retrain { None } else { checkpoint_step(&stage_dir) };
        if let Some(s) = reached.filter(|&s| s > steps) {
            return Err(format!(
                "{}: its checkpoint reached step {s}, beyond this schedule's {steps} (resume with the same schedule, or use a new --out)",
                stage_dir.display()
            ));
        }
        if reached == Some(steps) {
            eprintln!(
                "[{:6.0}s] {}: checkpoint at its {steps} steps, loaded",
                started.elapsed().as_secs_f64(),
                phase.dir
            );
            pipeline = MultiViewPipeline::from_dir(stage_dir.join(CHECKPOINT_DIR), &device).map_err(err)?;
            if phase.ema_decay.is_some() {
                // The phase's result is its moving average, as `run_training` returns it.
                let (_, vae, clip, scheduler) = pipeline.into_parts();
                let unet = UNet::from_dir(stage_dir.join(CHECKPOINT_DIR).join(EMA_DIR), &device).map_err(err)?;
                pipeline = MultiViewPipeline::new(unet, vae, clip, scheduler).map_err(err)?;
            }
            continue;
        }
        // This stage trains: every later one starts afresh.
        retrain = true;
        let resume_stage = reached.is_some();
        if stage == Stage::CrossDomain && !pipeline.unet().config().cd_attention_mid && !resume_stage {
            let (unet, vae, clip, scheduler) = pipeline.into_parts();
            let unet = unet.with_cross_domain_attention(4).map_err(err)?;
            pipeline = MultiViewPipeline::new(unet, vae, clip, scheduler).map_err(err)?;
        }
        let options = TrainOptions::for_stage(stage)
            .with_learning_rate(schedule.stage_lr[i])
            .with_warmup_steps(schedule.stage_warmup[i])
            .with_min_snr_gamma(schedule.min_snr_gamma)
            .with_train_all(phase.train_all)
            .with_ema_decay(phase.ema_decay)
            .with_lr_schedule(if phase.cool_down {
                LrSchedule::LinearToZero { end: steps }
            } else {
                LrSchedule::Constant
            })
            .with_seed(phase.seed);
        let encoded = match &mut encodings[usize::from(phase.white)] {
            Some(encoded) => encoded,
            slot => {
                let set = set.clone().with_background(phase.white.then_some(Background::White));
                let t = Instant::now();
                let encoded = slot.insert(EncodedSet::encode(&pipeline, &set, &device, &mut |_, _| {}).map_err(err)?);
                eprintln!(
                    "[{:6.0}s] training set encoded{} in {:.0} s",
                    started.elapsed().as_secs_f64(),
                    if phase.white { " on white" } else { "" },
                    t.elapsed().as_secs_f64()
                );
                encoded
            }
        };
        let run = RunOptions::default()
            .with_steps(steps)
            .with_objects_per_batch(schedule.objects_per_batch)
            .with_checkpoint_every(500);
        if !resume_stage && stage_dir.exists() {
            std::fs::remove_dir_all(&stage_dir).map_err(|e| format!("{}: {e}", stage_dir.display()))?;
        }
        let t = Instant::now();
        let first = reached.unwrap_or(0);
        let mut clock_error = None;
        pipeline =
            run_training_encoded(
                pipeline,
                encoded,
                options,
                &run,
                &stage_dir,
                resume_stage,
                &mut |event| match event {
                    RunEvent::Step(log) if log.step % 50 == 0 || log.step == steps => eprintln!(
                        "  {} step {}/{steps}: loss {:.4} ({:.2} s/step)",
                        phase.dir,
                        log.step,
                        log.loss,
                        t.elapsed().as_secs_f64() / (log.step - first).max(1) as f64
                    ),
                    RunEvent::Checkpoint { .. } => {
                        if let Err(e) = clock.save() {
                            clock_error.get_or_insert(e);
                        }
                    }
                    _ => {}
                },
            )
            .map_err(err)?;
        if let Some(e) = clock_error {
            return Err(e);
        }
        clock.save()?;
        eprintln!("[{:6.0}s] {} done", started.elapsed().as_secs_f64(), phase.dir);
    }
    // 6. The trained UNet with the tuned decoder.
    let tuned = decoder.join()?;
    let (unet, _, clip, scheduler) = pipeline.into_parts();
    pipeline = MultiViewPipeline::new(unet, tuned, clip, scheduler).map_err(err)?;
    let model = out.join("model");
    pipeline.save(&model).map_err(err)?;
    let wall = started.elapsed().as_secs_f64();
    // Saved once, so that `clock.json` and `recipe.json` hold the same time.
    let run_seconds = clock.save()?;
    let record = serde_json::json!({
        "schedule": {
            "samples_per_mesh": schedule.samples, "size": schedule.size, "vae_steps": schedule.vae_steps,
            "stage_steps": schedule.stage_steps, "stage_warmup": schedule.stage_warmup, "stage_lr": schedule.stage_lr,
            "objects_per_batch": schedule.objects_per_batch,
            "decoder_steps": schedule.decoder_passes.iter().map(|p| p.0).collect::<Vec<_>>(),
            "decoder_lr": schedule.decoder_passes.iter().map(|p| p.1).collect::<Vec<_>>(),
            "min_snr_gamma": schedule.min_snr_gamma,
            "unet_block_out_channels": pipeline.unet().config().block_out_channels,
            "phases": PHASES.iter().map(|p| serde_json::json!({
                "dir": p.dir, "stage": p.stage.number(), "train_all": p.train_all, "white_background": p.white,
                "seed": p.seed, "ema_decay": p.ema_decay, "cool_down": p.cool_down,
            })).collect::<Vec<_>>(),
        },
        "meshes": TRAIN_MESHES, "held_out": HELD_OUT_MESH,
        "resumed": resume,
        "wall_seconds": wall,
        "run_seconds": run_seconds,
        "threads": std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
    });
    std::fs::write(out.join("recipe.json"), serde_json::to_vec_pretty(&record).map_err(err)?)
        .map_err(|e| format!("{}: {e}", out.display()))?;
    match run_seconds {
        Some(run) if resume => {
            eprintln!("[{wall:6.0}s] model written to {} ({run:.0} s over this run's processes)", model.display())
        }
        _ => eprintln!("[{wall:6.0}s] model written to {}", model.display()),
    }
    Ok(())
}

/// A new model for `set`: the VAE trained on every model image of the set, a frozen random
/// CLIP image encoder and a random UNet of the small configuration.
fn fresh_model(
    set: &TrainingSet,
    schedule: &Schedule,
    unet_config: &UNetConfig,
    scheduler: SchedulerConfig,
    device: &wonder3d::diffusion::Device,
    started: Instant,
) -> Result<MultiViewPipeline, String> {
    // 2. The VAE, trained on every model image of the set.
    let vae_config = VaeConfig::from_file(config_dir().join("vae").join("config.json")).map_err(err)?;
    let mut images = Vec::new();
    for i in 0..set.len() {
        images.extend(set.images(i).map_err(err)?.domains.into_iter().flatten());
    }
    let vae = Vae::random(&vae_config, 1, device).map_err(err)?;
    // The mean is decoded (see VaeTrainOptions::sample_posterior): with a few thousand steps a
    // sampled posterior stays as wide as the prior and the reconstruction does not improve.
    let vae_options = VaeTrainOptions::default()
        .with_steps(schedule.vae_steps)
        .with_batch(4)
        .with_learning_rate(1e-3)
        .with_sample_posterior(false);
    let t = Instant::now();
    let vae = train_vae(vae, &images, &vae_options, &mut |step, loss| {
        if step % 100 == 0 || step == schedule.vae_steps {
            eprintln!(
                "  vae step {step}/{}: loss {loss:.5} ({:.2} s/step)",
                schedule.vae_steps,
                t.elapsed().as_secs_f64() / step as f64
            );
        }
    })
    .map_err(err)?;
    eprintln!(
        "[{:6.0}s] VAE trained on {} images, scaling factor {:.4}",
        started.elapsed().as_secs_f64(),
        images.len(),
        vae.config().scaling_factor
    );

    // 3. The frozen CLIP image encoder (random weights, see docs/training.md) and the UNet.
    let clip_config =
        ClipVisionConfig::from_file(config_dir().join("image_encoder").join("config.json")).map_err(err)?;
    let clip = ClipVision::random(&clip_config, 2, device).map_err(err)?;
    let unet = UNet::random(unet_config, 3, device).map_err(err)?;
    MultiViewPipeline::new(unet, vae, clip, scheduler).map_err(err)
}

/// Fine-tunes the decoder of `vae` on the normal and colour views of `set` on white (what
/// inference decodes), the encoder frozen: the latent space the UNet was trained in stays
/// exactly as it was, and the decoder learns to draw it more sharply (docs/training.md, "The
/// decoder"). One pass per `(steps, learning rate)` of `passes`, each with fresh optimizer
/// moments; the set's images are read once for all of them.
pub(crate) fn tune_decoder(mut vae: Vae, set: &TrainingSet, passes: &[(usize, f64)]) -> Result<Vae, String> {
    let set = set.clone().with_background(Some(Background::White));
    let mut images = Vec::new();
    for i in 0..set.len() {
        let [normal, colour, _mask] = set.images(i).map_err(err)?.domains;
        images.extend(normal);
        images.extend(colour);
    }
    for &(steps, learning_rate) in passes {
        let options = VaeTrainOptions::default()
            .with_steps(steps)
            .with_batch(4)
            .with_learning_rate(learning_rate)
            .with_sample_posterior(false)
            .with_decoder_only(true)
            .with_seed(21);
        let t = Instant::now();
        let mut recent = Vec::new();
        vae = train_vae(vae, &images, &options, &mut |step, loss| {
            recent.push(loss);
            if step % 100 == 0 || step == steps {
                let mean = recent.iter().sum::<f32>() / recent.len() as f32;
                recent.clear();
                eprintln!(
                    "  decoder step {step}/{steps} (lr {learning_rate:e}): mean loss {mean:.5} ({:.2} s/step)",
                    t.elapsed().as_secs_f64() / step as f64
                );
            }
        })
        .map_err(err)?;
    }
    Ok(vae)
}

/// `cargo xtask tune-decoder`: [`tune_decoder`] from the model in `model` on the set in
/// `data`, the result written to `out` (checked first: it must not exist yet).
pub(crate) fn tune_decoder_command(model: &Path, data: &Path, out: &Path, steps: usize, lr: f64) -> Result<(), String> {
    if out.exists() {
        return Err(format!("{}: already exists (choose a new output folder)", out.display()));
    }
    let device = wonder3d::diffusion::default_device();
    let pipeline = MultiViewPipeline::from_dir(model, &device).map_err(err)?;
    let set = TrainingSet::open(data).map_err(err)?;
    if set.size() != pipeline.image_size() as u32 {
        return Err(format!(
            "{}: images of {}² (the model's size; found {}²)",
            data.display(),
            pipeline.image_size(),
            set.size()
        ));
    }
    let started = Instant::now();
    let (unet, vae, clip, scheduler) = pipeline.into_parts();
    let vae = tune_decoder(vae, &set, &[(steps, lr)])?;
    MultiViewPipeline::new(unet, vae, clip, scheduler).map_err(err)?.save(out).map_err(err)?;
    eprintln!("[{:6.0}s] model with the tuned decoder written to {}", started.elapsed().as_secs_f64(), out.display());
    Ok(())
}

/// Writes the model in `model` to `assets/model-small` with f16 weights (replacing the folder
/// whole), after checking that it loads.
pub(crate) fn ship(model: &Path) -> Result<(), String> {
    let device = wonder3d::diffusion::default_device();
    let pipeline = MultiViewPipeline::from_dir(model, &device).map_err(err)?;
    let out = crate::workspace::workspace_root().join("assets").join("model-small");
    pipeline.save_with(&out, wonder3d::diffusion::Precision::F16).map_err(err)?;
    let bytes: u64 = walk_sizes(&out);
    eprintln!("wrote {} ({:.1} MB, f16)", out.display(), bytes as f64 / 1e6);
    Ok(())
}

fn walk_sizes(dir: &Path) -> u64 {
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| {
            let path = e.path();
            if path.is_dir() { walk_sizes(&path) } else { e.metadata().map_or(0, |m| m.len()) }
        })
        .sum()
}
