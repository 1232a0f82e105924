//! A training step of the multi-view UNet as Wonder3D++ trains it (`docs/training.md`): the
//! objective ([`crate::train::objective`]) with Min-SNR-γ weighting, condition dropout "as a
//! whole" for classifier-free guidance, and AdamW ([`crate::train::optim`]) with the
//! class-embedding parameter group, warm-up, gradient-norm clipping and gradient accumulation;
//! the trainer's state files for resuming.

use std::collections::HashMap;

use burn::module::{Module, ModuleVisitor, Param, ParamId};
use burn::tensor::{Device, Tensor, TensorData};
use rayon::prelude::*;
use w3d_core::Error;

use crate::loading::config::SchedulerConfig;
use crate::loading::weights::{NamedValues, Precision};
use crate::models::unet::UNet;
use crate::pipelines::guidance::gaussian_noise;
use crate::train::objective::*;
use crate::train::optim::*;
use crate::train::options::*;

/// What one [`Trainer::step`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct StepLog {
    /// Optimizer steps taken so far (after this micro-batch).
    pub step: usize,
    /// The micro-batch's loss.
    pub loss: f32,
    /// Whether this micro-batch completed an optimizer step.
    pub updated: bool,
    /// The global gradient norm before clipping (on optimizer steps).
    pub grad_norm: Option<f32>,
    /// The base learning rate used (on optimizer steps).
    pub learning_rate: Option<f64>,
}

/// A UNet being trained: the model on an autodiff device, the objective, AdamW state and the
/// random draws.
#[derive(Debug)]
pub struct Trainer {
    unet: UNet,
    objective: DiffusionObjective,
    options: TrainOptions,
    /// Trainable parameters: key and whether it is in the class-embedding group.
    trainable: HashMap<ParamId, (String, bool)>,
    moments: HashMap<ParamId, Moments>,
    accumulated: HashMap<ParamId, Tensor<1>>,
    /// The moving average of each trainable parameter, flattened (with `ema_decay`).
    ema: HashMap<ParamId, Tensor<1>>,
    micro_batches: usize,
    step: usize,
    rng: u64,
}

impl Trainer {
    /// Prepares `unet` for training with `options` on the noise schedule `scheduler`: freezes
    /// what the stage does not train and moves the model to the autodiff version of its device.
    pub fn new(unet: UNet, scheduler: SchedulerConfig, options: TrainOptions) -> Result<Self, Error> {
        options.validate()?;
        let objective = DiffusionObjective::new(scheduler, options.min_snr_gamma)?;
        let mut trainable = HashMap::new();
        for named in unet.named_parameters() {
            if options.train_all || options.stage.trains(&named.key) {
                trainable.insert(named.id, (named.key.clone(), named.key.starts_with("class_embedding.")));
            }
        }
        if trainable.is_empty() {
            return Err(Error::invalid(
                "stage",
                format!(
                    "a model with parameters stage {} trains (cross-domain stage: `cd_attention_mid`)",
                    options.stage.number()
                ),
            ));
        }
        let checkpointing = options.gradient_checkpointing;
        let unet = unet.map(&mut RequireGrad { trainable: &trainable, checkpointing }).train();
        let rng = options.seed ^ 0x9E37_79B9_7F4A_7C15;
        Ok(Self {
            unet,
            objective,
            options,
            trainable,
            moments: HashMap::new(),
            accumulated: HashMap::new(),
            ema: HashMap::new(),
            micro_batches: 0,
            step: 0,
            rng,
        })
    }

    /// The autodiff device the model trains on (create batches on it).
    pub fn device(&self) -> Device {
        self.unet.devices().into_iter().next().unwrap_or_default()
    }

    /// The model being trained (on the autodiff device).
    pub fn unet(&self) -> &UNet {
        &self.unet
    }

    /// The trained model for inference (autodiff off).
    pub fn inference_unet(&self) -> UNet {
        self.unet.valid()
    }

    /// The model for inference with the moving average of the trainable weights in place of
    /// their current values (`None` without [`TrainOptions::ema_decay`]; before the first
    /// optimizer step, the current weights). What diffusers' scripts save at the end of an
    /// EMA run.
    pub fn ema_unet(&self) -> Option<UNet> {
        self.options.ema_decay?;
        let unet = self.unet.valid();
        Some(unet.map(&mut SetValues { values: &self.ema }))
    }

    /// The decay applied at the `k`-th optimizer step (1-based): 0 at the first (a copy), then
    /// `min(decay, (1 + s) / (10 + s))` with `s = k − 1`, as diffusers' `EMAModel`.
    fn ema_decay_at(&self, k: usize) -> f64 {
        let s = k.saturating_sub(1);
        match self.options.ema_decay {
            Some(decay) if s > 0 => decay.min((1.0 + s as f64) / (10.0 + s as f64)),
            _ => 0.0,
        }
    }

    fn update_ema(&mut self) {
        if self.options.ema_decay.is_none() {
            return;
        }
        let decay = self.ema_decay_at(self.step);
        let mut current = CollectValues { trainable: &self.trainable, out: Vec::new() };
        self.unet.visit(&mut current);
        // In parallel over the parameters, as AdamW's step (`AdamW::into_updates`).
        let work: Vec<(ParamId, Tensor<1>, Option<Tensor<1>>)> =
            current.out.into_iter().map(|(id, value)| (id, value, self.ema.remove(&id))).collect();
        let averaged: Vec<(ParamId, Tensor<1>)> = work
            .into_par_iter()
            .map(|(id, value, ema)| match ema {
                Some(ema) if decay > 0.0 => (id, ema * decay + value * (1.0 - decay)),
                _ => (id, value),
            })
            .collect();
        self.ema.extend(averaged);
    }

    /// The objective.
    pub fn objective(&self) -> &DiffusionObjective {
        &self.objective
    }

    /// The options.
    pub fn options(&self) -> &TrainOptions {
        &self.options
    }

    /// Optimizer steps taken.
    pub fn steps(&self) -> usize {
        self.step
    }

    /// Number of trainable parameter tensors.
    pub fn trainable_tensors(&self) -> usize {
        self.trainable.len()
    }

    fn next_u64(&mut self) -> u64 {
        splitmix64(&mut self.rng)
    }

    fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Draws the timesteps, noise and condition dropout of the next step for `batch`.
    pub fn draw(&mut self, batch: &TrainBatch) -> StepDraws {
        let dims = batch.latents.dims();
        let views = self.unet.config().views();
        let groups = dims[0] / views;
        let objects = groups / batch.domains.max(1);
        let t_max = self.objective.train_timesteps() as u64;
        let timesteps = (0..groups).map(|_| (self.next_u64() % t_max) as usize).collect();
        let condition_drops = (0..objects)
            .map(|_| {
                let u = self.uniform();
                ConditionDrop::from_uniform(u, self.options.condition_drop_rate)
            })
            .collect();
        let seed = self.next_u64();
        let noise = gaussian_noise(dims, seed, &batch.latents.device());
        StepDraws { timesteps, noise, condition_drops }
    }

    /// One micro-batch with the trainer's own random draws; see [`Trainer::step_with`].
    pub fn step(&mut self, batch: &TrainBatch) -> Result<StepLog, Error> {
        let draws = self.draw(batch);
        self.step_with(batch, &draws)
    }

    /// One micro-batch with given draws: forward, backward, gradients accumulated; every
    /// `gradient_accumulation` micro-batches an AdamW step (clipped, warmed-up). The step runs
    /// on a worker of rayon's pool, which the CPU kernels share (see `cpu_pool`).
    pub fn step_with(&mut self, batch: &TrainBatch, draws: &StepDraws) -> Result<StepLog, Error> {
        crate::kernels::pool::on_pool(|| self.step_on_pool(batch, draws))
    }

    /// The body of [`Trainer::step_with`], run on a worker of the pool.
    fn step_on_pool(&mut self, batch: &TrainBatch, draws: &StepDraws) -> Result<StepLog, Error> {
        let loss = self.objective.loss(&self.unet, batch, draws)?;
        let loss_value = loss
            .clone()
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .map_err(|e| Error::invalid("loss", format!("a readable f32 scalar ({e:?})")))?[0];
        if !loss_value.is_finite() {
            return Err(Error::invalid(
                "loss",
                format!("a finite value (found {loss_value}); lower the learning rate"),
            ));
        }
        let grads = loss.backward();
        let scale = 1.0 / self.options.gradient_accumulation as f64;
        let mut collect = CollectGrads { grads: &grads, trainable: &self.trainable, out: Vec::new() };
        self.unet.visit(&mut collect);
        for (id, _, g) in collect.out {
            // Scaling by 1 would be a pass over every gradient that changes no bit.
            let g = if scale == 1.0 { g } else { g * scale };
            let sum = match self.accumulated.remove(&id) {
                Some(acc) => acc + g,
                None => g,
            };
            self.accumulated.insert(id, sum);
        }
        self.micro_batches += 1;
        if self.micro_batches < self.options.gradient_accumulation {
            return Ok(StepLog {
                step: self.step,
                loss: loss_value,
                updated: false,
                grad_norm: None,
                learning_rate: None,
            });
        }
        self.micro_batches = 0;
        let grads = std::mem::take(&mut self.accumulated);
        let (grad_norm, lr) = self.apply(grads)?;
        Ok(StepLog {
            step: self.step,
            loss: loss_value,
            updated: true,
            grad_norm: Some(grad_norm),
            learning_rate: Some(lr),
        })
    }

    /// The loss and the gradient of every trainable parameter for `batch` under `draws`, under
    /// their checkpoint keys in PyTorch layout, without updating anything (for inspection and
    /// parity checks against a PyTorch training step).
    pub fn gradients(&self, batch: &TrainBatch, draws: &StepDraws) -> Result<(f32, Vec<NamedValues>), Error> {
        let loss = self.objective.loss(&self.unet, batch, draws)?;
        let loss_value = scalar(&loss)?;
        let grads = loss.backward();
        let mut collect = CollectGrads { grads: &grads, trainable: &self.trainable, out: Vec::new() };
        self.unet.visit(&mut collect);
        let mut by_id: HashMap<ParamId, (Vec<usize>, Tensor<1>)> =
            collect.out.into_iter().map(|(id, dims, g)| (id, (dims, g))).collect();
        let mut named = Vec::new();
        for param in self.unet.named_parameters() {
            let Some((dims, g)) = by_id.remove(&param.id) else { continue };
            let values = g.into_data().convert::<f32>().try_to_vec::<f32>().unwrap_or_default();
            named.push(NamedValues::from_param(param, dims, values)?);
        }
        Ok((loss_value, named))
    }

    /// The factor of the peak learning rate at optimizer step `step` (0-based): the warm-up,
    /// then [`TrainOptions::lr_schedule`].
    pub fn lr_factor(&self, step: usize) -> f64 {
        self.options.lr_schedule.factor(step, self.options.warmup_steps)
    }

    fn apply(&mut self, grads: HashMap<ParamId, Tensor<1>>) -> Result<(f32, f64), Error> {
        let (norm, clip) = clip_factor(&grads, self.options.max_grad_norm)?;
        let lr = self.options.learning_rate * self.lr_factor(self.step);
        self.step += 1;
        let o = &self.options;
        let trainable = &self.trainable;
        let lr_of = |id: ParamId| match trainable.get(&id) {
            Some((_, true)) => lr * o.class_embedding_lr_mult,
            _ => lr,
        };
        let mut update = AdamW {
            grads,
            moments: &mut self.moments,
            lr_of: &lr_of,
            clip,
            betas: o.betas,
            weight_decay: o.weight_decay,
            epsilon: o.epsilon,
            step: self.step,
        }
        .into_updates();
        let unet = self.unet.clone().map(&mut update);
        self.unet = unet;
        self.update_ema();
        Ok((norm as f32, lr))
    }
}

/// The trainer-state file of a checkpoint folder (step, RNG, options).
pub const STATE_FILE: &str = "trainer_state.json";
/// The optimizer-moment file of a checkpoint folder.
pub const OPTIMIZER_FILE: &str = "optimizer.safetensors";
pub(crate) const STATE_FORMAT: &str = "wonder3d-rs trainer state";

#[derive(serde::Serialize, serde::Deserialize)]
pub(crate) struct SavedState {
    format: String,
    version: u32,
    step: usize,
    rng: u64,
    stage: u8,
    learning_rate: f64,
    seed: u64,
}

impl Trainer {
    /// Writes the optimizer moments ([`OPTIMIZER_FILE`]: `exp_avg.<key>` and
    /// `exp_avg_sq.<key>`, flattened in the model's own layout, and `ema.<key>` with
    /// [`TrainOptions::ema_decay`]) and the step, RNG and stage
    /// ([`STATE_FILE`]) into the existing folder `dir`. Only between optimizer steps (not in
    /// the middle of gradient accumulation).
    pub fn write_state(&self, dir: &std::path::Path) -> Result<(), Error> {
        if self.micro_batches != 0 {
            return Err(Error::invalid(
                "trainer state",
                "a save between optimizer steps (micro-batches of an accumulated step are pending)",
            ));
        }
        let mut tensors = Vec::with_capacity(2 * self.moments.len());
        let mut keys: Vec<(&String, &ParamId)> = self.trainable.iter().map(|(id, (key, _))| (key, id)).collect();
        keys.sort();
        for (key, id) in keys {
            let Some(m) = self.moments.get(id) else { continue };
            let ema = self.ema.get(id).map(|t| ("ema", t));
            for (prefix, t) in [("exp_avg", &m.first), ("exp_avg_sq", &m.second)].into_iter().chain(ema) {
                let values = t.clone().into_data().convert::<f32>().try_to_vec::<f32>().unwrap_or_default();
                tensors.push(NamedValues { key: format!("{prefix}.{key}"), shape: vec![values.len()], values });
            }
        }
        let state = SavedState {
            format: STATE_FORMAT.into(),
            version: 1,
            step: self.step,
            rng: self.rng,
            stage: self.options.stage.number(),
            learning_rate: self.options.learning_rate,
            seed: self.options.seed,
        };
        let json = serde_json::to_value(&state).map_err(|e| Error::invalid("trainer state", e.to_string()))?;
        crate::loading::weights::write_checkpoint_named(
            dir,
            OPTIMIZER_FILE,
            &tensors,
            STATE_FILE,
            &json,
            Precision::F32,
        )
    }

    /// Restores what [`Trainer::write_state`] wrote in `dir`: step, RNG and the moments of
    /// every trainable parameter (a missing or misshaped moment, or a state of another
    /// stage, is an error naming it).
    pub fn load_state(&mut self, dir: &std::path::Path) -> Result<(), Error> {
        let path = dir.join(STATE_FILE);
        let text = std::fs::read(&path).map_err(|e| Error::io(&path, e))?;
        let state: SavedState = serde_json::from_slice(&text)
            .map_err(|e| Error::format(&path, STATE_FILE, format!("a trainer state ({e})")))?;
        if state.format != STATE_FORMAT || state.version != 1 {
            return Err(Error::format(&path, "format", format!("{STATE_FORMAT:?} version 1")));
        }
        if state.stage != self.options.stage.number() {
            return Err(Error::format(
                &path,
                "stage",
                format!(
                    "stage {} as this run (found {}; start a new run to change stage)",
                    self.options.stage.number(),
                    state.stage
                ),
            ));
        }
        let mut numel = HashMap::new();
        struct Sizes<'a>(&'a mut HashMap<ParamId, usize>);
        impl ModuleVisitor for Sizes<'_> {
            fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
                self.0.insert(param.id, param.val().shape().num_elements());
            }
        }
        self.unet.visit(&mut Sizes(&mut numel));
        let opt_path = dir.join(OPTIMIZER_FILE);
        let mut file = crate::loading::weights::SafetensorsFile::open(&opt_path)?;
        let device = self.device().inner();
        let mut moments = HashMap::new();
        let mut ema = HashMap::new();
        if state.step > 0 {
            for (id, (key, _)) in &self.trainable {
                let n = numel.get(id).copied().unwrap_or(0);
                let mut read = |prefix: &str| -> Result<Tensor<1>, Error> {
                    let name = format!("{prefix}.{key}");
                    let (values, _) = file.read_f32(&name)?;
                    if values.len() != n {
                        return Err(Error::format(&opt_path, name, format!("{n} values (found {})", values.len())));
                    }
                    Ok(Tensor::from_data(TensorData::new(values, [n]), &device))
                };
                moments.insert(*id, Moments { first: read("exp_avg")?, second: read("exp_avg_sq")? });
                if self.options.ema_decay.is_some() {
                    ema.insert(*id, read("ema")?);
                }
            }
        }
        self.moments = moments;
        self.ema = ema;
        self.accumulated.clear();
        self.micro_batches = 0;
        self.step = state.step;
        self.rng = state.rng;
        Ok(())
    }

    /// A uniform index below `n` from the trainer's random stream (sample and domain choices
    /// of a run, so a resumed run draws what the uninterrupted one would).
    pub fn draw_index(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }
}
