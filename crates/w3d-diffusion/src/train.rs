//! Training the multi-view UNet as Wonder3D++ does (`docs/training.md`): the ε-prediction
//! objective with Min-SNR-γ weighting, condition dropout "as a whole" for classifier-free
//! guidance, the three stage presets, and AdamW with the class-embedding parameter group,
//! warm-up, gradient-norm clipping and gradient accumulation — on Burn's autodiff, on any
//! device.
//!
//! Batch layout (as inference, [`crate::multiview`]): `n = domains · objects · views` images,
//! domain-major, then object, then view. Each group of `views` consecutive images (one object,
//! one domain) gets one timestep; the noise is independent per image; one condition-dropout
//! draw per object applies to all its images in every domain.
//!
//! ```
//! use w3d_diffusion::train::{Stage, TrainBatch, TrainOptions, Trainer};
//! use w3d_diffusion::{SchedulerConfig, Tensor, UNet, UNetConfig, gaussian_noise};
//!
//! let device = w3d_diffusion::default_device();
//! let config = UNetConfig::from_file("tests/fixtures/wonder3d_tiny/unet/config.json").unwrap();
//! let unet = UNet::random(&config, 1, &device).unwrap();
//! let options = TrainOptions::for_stage(Stage::CrossDomain).with_warmup_steps(0);
//! let mut trainer = Trainer::new(unet, SchedulerConfig::stable_diffusion(), options).unwrap();
//! let device = trainer.device();
//! // One object, both domains, 6 views of 8×8 latents (already VAE-encoded and scaled).
//! let batch = TrainBatch {
//!     latents: gaussian_noise([12, 4, 8, 8], 2, &device),
//!     condition_latents: gaussian_noise([12, 4, 8, 8], 3, &device),
//!     image_embeddings: Tensor::ones([12, 1, 16], &device),
//!     class_labels: Some(Tensor::zeros([12, 14], &device)),
//!     domains: 2,
//! };
//! let log = trainer.step(&batch).unwrap();
//! assert!(log.loss.is_finite() && log.updated);
//! ```

use std::collections::{HashMap, HashSet};

use burn::module::{Module, ModuleMapper, ModuleVisitor, Param, ParamId};
use burn::tensor::{Device, GradientCheckpointingStrategy, Gradients, Tensor, TensorData};
use rayon::prelude::*;
use w3d_core::Error;

use crate::config::SchedulerConfig;
use crate::scheduler::{DdimScheduler, Prediction, gaussian_noise};
use crate::unet::UNet;
use crate::weights::{NamedValues, Precision};

/// The training stages of Wonder3D++ (`docs/training.md`; the authors' config file names do
/// not match the paper's stage names).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Stage {
    /// 1: multi-domain pre-training without switchers (task label `[0, 0]`), whole UNet,
    /// learning rate 1e-4.
    MultiDomain,
    /// 2: mixed-domain fine-tuning with the domain switcher, whole UNet, learning rate 5e-5.
    MixedDomain,
    /// 3: cross-domain alignment (`cd_attention_mid`): only `attn_joint_mid` and
    /// `norm_joint_mid` train, learning rate 2e-5; everything else stays bit-identical.
    CrossDomain,
}

impl Stage {
    /// The stage's number in the paper (1, 2 or 3).
    pub fn number(self) -> u8 {
        match self {
            Stage::MultiDomain => 1,
            Stage::MixedDomain => 2,
            Stage::CrossDomain => 3,
        }
    }

    /// The stage with that number.
    pub fn from_number(n: u8) -> Result<Self, Error> {
        match n {
            1 => Ok(Stage::MultiDomain),
            2 => Ok(Stage::MixedDomain),
            3 => Ok(Stage::CrossDomain),
            _ => Err(Error::invalid("stage", format!("1, 2 or 3 (found {n})"))),
        }
    }

    /// The authors' learning rate for the stage.
    pub fn learning_rate(self) -> f64 {
        match self {
            Stage::MultiDomain => 1e-4,
            Stage::MixedDomain => 5e-5,
            Stage::CrossDomain => 2e-5,
        }
    }

    /// Whether the parameter with checkpoint key `key` trains in this stage (stage 3: the
    /// modules whose name ends in `joint_mid`, as the authors' `trainable_modules`).
    pub fn trains(self, key: &str) -> bool {
        match self {
            Stage::MultiDomain | Stage::MixedDomain => true,
            Stage::CrossDomain => key.split('.').any(|module| module.ends_with("joint_mid")),
        }
    }
}

/// How the learning rate moves after the warm-up ([`TrainOptions::lr_schedule`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum LrSchedule {
    /// Constant at the peak: diffusers' `constant_with_warmup`, the authors' schedule.
    Constant,
    /// Linearly from the peak at the end of the warm-up down to 0 at optimizer step `end`,
    /// and 0 after (diffusers' `linear` with `num_training_steps = end`): a cool-down, which
    /// lowers the loss a constant rate leaves on a plateau (`docs/training.md`).
    LinearToZero {
        /// The optimizer step (0-based) at which the learning rate reaches 0.
        end: usize,
    },
}

impl LrSchedule {
    /// The factor of the peak learning rate at optimizer step `step` (0-based) after a
    /// linear warm-up of `warmup` steps.
    ///
    /// ```
    /// use w3d_diffusion::train::LrSchedule;
    /// assert_eq!(LrSchedule::Constant.factor(5, 10), 0.5);
    /// assert_eq!(LrSchedule::Constant.factor(50, 10), 1.0);
    /// let linear = LrSchedule::LinearToZero { end: 110 };
    /// assert_eq!(linear.factor(10, 10), 1.0);
    /// assert_eq!(linear.factor(60, 10), 0.5);
    /// assert_eq!(linear.factor(120, 10), 0.0);
    /// ```
    pub fn factor(&self, step: usize, warmup: usize) -> f64 {
        if step < warmup {
            return step as f64 / warmup as f64;
        }
        match *self {
            LrSchedule::Constant => 1.0,
            LrSchedule::LinearToZero { end } => {
                end.saturating_sub(step) as f64 / end.saturating_sub(warmup).max(1) as f64
            }
        }
    }
}

/// Hyper-parameters of a training run; [`TrainOptions::for_stage`] gives the authors' values.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct TrainOptions {
    /// Which stage (trainable set).
    pub stage: Stage,
    /// Peak learning rate.
    pub learning_rate: f64,
    /// Learning-rate multiplier of the `class_embedding.*` parameters (the switchers' MLP): 10.
    pub class_embedding_lr_mult: f64,
    /// AdamW β₁, β₂: 0.9, 0.999.
    pub betas: (f64, f64),
    /// AdamW decoupled weight decay: 1e-2.
    pub weight_decay: f64,
    /// AdamW ε: 1e-8.
    pub epsilon: f64,
    /// Linear warm-up length in optimizer steps: 100. The factor at optimizer step `s`
    /// (0-based) is `s / warmup` below `warmup` — so with warm-up the first step has learning
    /// rate 0, as with diffusers' schedulers — then as [`lr_schedule`](Self::lr_schedule) says.
    pub warmup_steps: usize,
    /// The learning rate after the warm-up: [`LrSchedule::Constant`] (the authors').
    pub lr_schedule: LrSchedule,
    /// Clip the global gradient norm to this (1.0); `None` disables clipping.
    pub max_grad_norm: Option<f64>,
    /// Micro-batches whose gradients are averaged into one optimizer step: 1.
    pub gradient_accumulation: usize,
    /// Min-SNR-γ loss weighting (5); `None` weighs every timestep equally.
    pub min_snr_gamma: Option<f64>,
    /// Condition-dropout rate p (0.05): per object, u < p drops CLIP, p ≤ u < 2p CLIP and
    /// the image latent, 2p ≤ u < 3p the image latent.
    pub condition_drop_rate: f64,
    /// Seed of the timestep, noise and dropout draws.
    pub seed: u64,
    /// Exponential moving average of the trainable weights (off by default): the maximum
    /// decay, reached through diffusers' `EMAModel` warm-up `min(decay, (1 + s) / (10 + s))`
    /// at the (s + 1)-th optimizer step (the first step copies the weights). See
    /// [`Trainer::ema_unet`].
    pub ema_decay: Option<f64>,
    /// Train every parameter whatever the stage (off: the stage's set, [`Stage::trains`]).
    /// In stage 3 this is Wonder3D (v1)'s joint training, where the whole UNet learns with
    /// the cross-domain attention; the small model's last phase uses it (`docs/training.md`).
    pub train_all: bool,
    /// Gradient checkpointing (off): the model trains on an autodiff device with Burn's
    /// balanced checkpointing strategy, which keeps the outputs of compute-bound operations
    /// (matrix products, convolutions) and recomputes the memory-bound ones (element-wise
    /// operations, normalisations, activations) during the backward pass. Same loss and
    /// gradients to rounding; lower peak memory for more time per step
    /// (`docs/training.md`, "Gradient checkpointing", has both measured).
    pub gradient_checkpointing: bool,
}

impl TrainOptions {
    /// The authors' hyper-parameters for `stage`.
    pub fn for_stage(stage: Stage) -> Self {
        Self {
            stage,
            learning_rate: stage.learning_rate(),
            class_embedding_lr_mult: 10.0,
            betas: (0.9, 0.999),
            weight_decay: 1e-2,
            epsilon: 1e-8,
            warmup_steps: 100,
            lr_schedule: LrSchedule::Constant,
            max_grad_norm: Some(1.0),
            gradient_accumulation: 1,
            min_snr_gamma: Some(5.0),
            condition_drop_rate: 0.05,
            seed: 0,
            ema_decay: None,
            train_all: false,
            gradient_checkpointing: false,
        }
    }

    /// Trains every parameter whatever the stage (see [`TrainOptions::train_all`]).
    pub fn with_train_all(mut self, train_all: bool) -> Self {
        self.train_all = train_all;
        self
    }

    /// Turns gradient checkpointing on or off (see [`TrainOptions::gradient_checkpointing`]).
    pub fn with_gradient_checkpointing(mut self, on: bool) -> Self {
        self.gradient_checkpointing = on;
        self
    }

    /// Keeps an exponential moving average of the trainable weights with maximum decay
    /// `decay` (`None`: off; diffusers' training scripts use 0.9999 with `--use_ema`).
    pub fn with_ema_decay(mut self, decay: Option<f64>) -> Self {
        self.ema_decay = decay;
        self
    }

    /// Sets the learning rate.
    pub fn with_learning_rate(mut self, lr: f64) -> Self {
        self.learning_rate = lr;
        self
    }

    /// Sets the warm-up length.
    pub fn with_warmup_steps(mut self, steps: usize) -> Self {
        self.warmup_steps = steps;
        self
    }

    /// Sets the learning rate's course after the warm-up.
    pub fn with_lr_schedule(mut self, schedule: LrSchedule) -> Self {
        self.lr_schedule = schedule;
        self
    }

    /// Sets the number of accumulated micro-batches per optimizer step.
    pub fn with_gradient_accumulation(mut self, micro_batches: usize) -> Self {
        self.gradient_accumulation = micro_batches;
        self
    }

    /// Sets the gradient-norm clip (`None`: off).
    pub fn with_max_grad_norm(mut self, norm: Option<f64>) -> Self {
        self.max_grad_norm = norm;
        self
    }

    /// Sets the condition-dropout rate.
    pub fn with_condition_drop_rate(mut self, p: f64) -> Self {
        self.condition_drop_rate = p;
        self
    }

    /// Sets the Min-SNR γ (`None`: every timestep weighs the same in the prediction's own
    /// MSE).
    pub fn with_min_snr_gamma(mut self, gamma: Option<f64>) -> Self {
        self.min_snr_gamma = gamma;
        self
    }

    /// Sets the seed of the random draws.
    pub fn with_seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }

    fn validate(&self) -> Result<(), Error> {
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(Error::invalid(name, format!("a finite value ≥ 0 (found {v})")))
            }
        };
        positive("learning_rate", self.learning_rate)?;
        positive("class_embedding_lr_mult", self.class_embedding_lr_mult)?;
        if let LrSchedule::LinearToZero { end } = self.lr_schedule
            && end <= self.warmup_steps
        {
            return Err(Error::invalid(
                "lr_schedule",
                format!("a linear decay that ends after the {}-step warm-up (found end {end})", self.warmup_steps),
            ));
        }
        positive("weight_decay", self.weight_decay)?;
        if !(self.epsilon.is_finite() && self.epsilon > 0.0) {
            return Err(Error::invalid("epsilon", format!("a finite value > 0 (found {})", self.epsilon)));
        }
        for (name, b) in [("betas.0", self.betas.0), ("betas.1", self.betas.1)] {
            if !(0.0..1.0).contains(&b) {
                return Err(Error::invalid(name, format!("a value in [0, 1) (found {b})")));
            }
        }
        for (name, value) in [("max_grad_norm", self.max_grad_norm), ("min_snr_gamma", self.min_snr_gamma)] {
            if let Some(v) = value.filter(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(Error::invalid(name, format!("a finite value > 0 (found {v})")));
            }
        }
        if self.gradient_accumulation == 0 {
            return Err(Error::invalid("gradient_accumulation", "at least 1 micro-batch"));
        }
        if let Some(d) = self.ema_decay.filter(|d| !(0.0..1.0).contains(d)) {
            return Err(Error::invalid("ema_decay", format!("a decay in [0, 1) (found {d})")));
        }
        if !(0.0..=1.0 / 3.0).contains(&self.condition_drop_rate) {
            return Err(Error::invalid(
                "condition_drop_rate",
                format!("a rate in [0, 1/3] (three cases of p each; found {})", self.condition_drop_rate),
            ));
        }
        Ok(())
    }
}

/// One batch of encoded training data (see the module docs for the layout).
#[derive(Clone, Debug)]
pub struct TrainBatch {
    /// Clean target latents `[n, c, h, w]` (VAE latents × scaling factor).
    pub latents: Tensor<4>,
    /// The condition image's latent for every image `[n, c, h, w]` (concatenated to the noisy
    /// latent; `c + c` = the UNet's input channels).
    pub condition_latents: Tensor<4>,
    /// CLIP image embeddings for every image `[n, tokens, cross_attention_dim]`.
    pub image_embeddings: Tensor<3>,
    /// Switcher labels `[n, projection_class_embeddings_input_dim]` (models with a
    /// projection class embedding).
    pub class_labels: Option<Tensor<2>>,
    /// Domains in the batch: 1 (stages 1 and 2) or 2 (stage 3: normal half, colour half).
    pub domains: usize,
}

/// What condition dropout removes from one object's inputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConditionDrop {
    /// Nothing.
    Keep,
    /// The CLIP embedding (u < p).
    Clip,
    /// The CLIP embedding and the image latent (p ≤ u < 2p).
    ClipAndImage,
    /// The image latent (2p ≤ u < 3p).
    Image,
}

impl ConditionDrop {
    /// The case for a uniform draw `u` in [0, 1) at rate `p`, as the authors' `drop_as_a_whole`.
    pub fn from_uniform(u: f64, p: f64) -> Self {
        if u < p {
            ConditionDrop::Clip
        } else if u < 2.0 * p {
            ConditionDrop::ClipAndImage
        } else if u < 3.0 * p {
            ConditionDrop::Image
        } else {
            ConditionDrop::Keep
        }
    }

    fn keeps_clip(self) -> bool {
        matches!(self, ConditionDrop::Keep | ConditionDrop::Image)
    }

    fn keeps_image(self) -> bool {
        matches!(self, ConditionDrop::Keep | ConditionDrop::Clip)
    }
}

/// The random draws of one training step: one timestep per group of views, the noise per
/// image, one condition dropout per object.
#[derive(Clone, Debug)]
pub struct StepDraws {
    /// Timesteps in `[0, T)`, one per group (`domains · objects`).
    pub timesteps: Vec<usize>,
    /// Gaussian noise `[n, c, h, w]`.
    pub noise: Tensor<4>,
    /// One per object.
    pub condition_drops: Vec<ConditionDrop>,
}

/// The objective: noise the latents at each group's timestep, predict with the UNet, and
/// take the (Min-SNR-weighted) mean squared error against ε (or v / x₀ for models trained
/// to predict those).
#[derive(Clone, Debug)]
pub struct DiffusionObjective {
    alphas_cumprod: Vec<f64>,
    prediction: Prediction,
    min_snr_gamma: Option<f64>,
}

impl DiffusionObjective {
    /// The objective for the noise schedule of `scheduler` (the checkpoint's
    /// `scheduler_config.json`) and the Min-SNR γ (`None`: unweighted).
    pub fn new(scheduler: SchedulerConfig, min_snr_gamma: Option<f64>) -> Result<Self, Error> {
        let ddim = DdimScheduler::new(scheduler, 1)?;
        Ok(Self { alphas_cumprod: ddim.alphas_cumprod().to_vec(), prediction: ddim.prediction(), min_snr_gamma })
    }

    /// Training timesteps T.
    pub fn train_timesteps(&self) -> usize {
        self.alphas_cumprod.len()
    }

    /// The loss weight of timestep `t`: `min(SNR, γ) / SNR` for ε-prediction,
    /// `min(SNR, γ) / (SNR + 1)` for v-prediction, `min(SNR, γ)` for x₀-prediction, with
    /// SNR = ᾱ / (1 − ᾱ); 1 without γ.
    pub fn weight(&self, t: usize) -> f64 {
        let Some(gamma) = self.min_snr_gamma else { return 1.0 };
        let a = self.alphas_cumprod[t];
        // As the authors (f32 schedule): SNR = (√ᾱ / √(1−ᾱ))².
        let (sa, sb) = ((a as f32).sqrt(), ((1.0 - a) as f32).sqrt());
        let snr = ((sa / sb) * (sa / sb)) as f64;
        let clipped = snr.min(gamma);
        match self.prediction {
            Prediction::Epsilon => clipped / snr,
            Prediction::VPrediction => clipped / (snr + 1.0),
            Prediction::Sample => clipped,
        }
    }

    /// The per-image weighted losses' mean for `batch` under `draws`: a scalar tensor `[1]`
    /// that carries the autodiff graph when `unet` is on an autodiff device.
    pub fn loss(&self, unet: &UNet, batch: &TrainBatch, draws: &StepDraws) -> Result<Tensor<1>, Error> {
        let [n, c, h, w] = batch.latents.dims();
        let views = unet.config().views();
        let domains = batch.domains;
        if domains == 0 || domains > 2 {
            return Err(Error::invalid("batch.domains", format!("1 or 2 (found {domains})")));
        }
        if n == 0 || n % (views * domains) != 0 {
            return Err(Error::invalid(
                "batch.latents",
                format!("a batch of domains × objects × {views} views (found {n} images for {domains} domains)"),
            ));
        }
        if unet.config().cd_attention_mid && domains != 2 {
            return Err(Error::invalid(
                "batch.domains",
                "2 for a UNet with cross-domain attention (cd_attention_mid: it pairs the normal and colour halves)",
            ));
        }
        let groups = n / views;
        let objects = groups / domains;
        if batch.condition_latents.dims() != [n, c, h, w] {
            return Err(Error::invalid(
                "batch.condition_latents",
                format!("shape {:?} (found {:?})", [n, c, h, w], batch.condition_latents.dims()),
            ));
        }
        let [en, tokens, dim] = batch.image_embeddings.dims();
        if en != n {
            return Err(Error::invalid("batch.image_embeddings", format!("{n} rows (found {en})")));
        }
        if draws.timesteps.len() != groups {
            return Err(Error::invalid(
                "draws.timesteps",
                format!("one per group of views ({groups}, found {})", draws.timesteps.len()),
            ));
        }
        if let Some(&t) = draws.timesteps.iter().find(|&&t| t >= self.train_timesteps()) {
            return Err(Error::invalid(
                "draws.timesteps",
                format!("steps below {} (found {t})", self.train_timesteps()),
            ));
        }
        if draws.noise.dims() != [n, c, h, w] {
            return Err(Error::invalid(
                "draws.noise",
                format!("shape {:?} (found {:?})", [n, c, h, w], draws.noise.dims()),
            ));
        }
        if draws.condition_drops.len() != objects {
            return Err(Error::invalid(
                "draws.condition_drops",
                format!("one per object ({objects}, found {})", draws.condition_drops.len()),
            ));
        }
        let device = batch.latents.device();
        let per_image = |f: &dyn Fn(usize, usize) -> f32| -> Vec<f32> {
            (0..n).map(|i| f(i / views, (i / views) % objects)).collect()
        };
        let column = |values: Vec<f32>| Tensor::<4>::from_data(TensorData::new(values, [n, 1, 1, 1]), &device);
        let alpha = |g: usize| self.alphas_cumprod[draws.timesteps[g]];
        let signal = column(per_image(&|g, _| alpha(g).sqrt() as f32));
        let noise_level = column(per_image(&|g, _| (1.0 - alpha(g)).sqrt() as f32));
        let keep_image = column(per_image(&|_, o| f32::from(u8::from(draws.condition_drops[o].keeps_image()))));
        let keep_clip: Tensor<3> = Tensor::from_data(
            TensorData::new(per_image(&|_, o| f32::from(u8::from(draws.condition_drops[o].keeps_clip()))), [n, 1, 1]),
            &device,
        );
        let x0 = batch.latents.clone();
        let noisy = x0.clone() * signal.clone() + draws.noise.clone() * noise_level.clone();
        let target = match self.prediction {
            Prediction::Epsilon => draws.noise.clone(),
            Prediction::VPrediction => draws.noise.clone() * signal - x0 * noise_level,
            Prediction::Sample => x0,
        };
        let input = Tensor::cat(vec![noisy, batch.condition_latents.clone() * keep_image], 1);
        let context = batch.image_embeddings.clone() * keep_clip.expand([n, tokens, dim]);
        let t: Vec<f32> = (0..n).map(|i| draws.timesteps[i / views] as f32).collect();
        let prediction = unet.forward(input, &t, context, batch.class_labels.clone())?;
        let diff = prediction - target;
        let mse: Tensor<1> = (diff.clone() * diff).reshape([n, c * h * w]).mean_dim(1).reshape([n]);
        let weights: Vec<f32> = (0..n).map(|i| self.weight(draws.timesteps[i / views]) as f32).collect();
        let weights = Tensor::<1>::from_data(TensorData::new(weights, [n]), &device);
        Ok((mse * weights).mean())
    }
}

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

/// AdamW moments of one parameter, flattened.
#[derive(Clone, Debug)]
struct Moments {
    first: Tensor<1>,
    second: Tensor<1>,
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
        crate::cpu_pool::on_pool(|| self.step_on_pool(batch, draws))
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

/// The global gradient norm (f64 over the per-tensor sums of squares, as PyTorch's
/// `clip_grad_norm_`) and the factor `min(1, max / (norm + 1e-6))` the gradients are scaled
/// by (1 without a maximum). A non-finite norm is an error.
fn clip_factor(grads: &HashMap<ParamId, Tensor<1>>, max: Option<f64>) -> Result<(f64, f64), Error> {
    // The per-tensor sums in parallel, added up in the map's order as before.
    let tensors: Vec<&Tensor<1>> = grads.values().collect();
    let squares: Vec<f32> = tensors.into_par_iter().map(|g| (g.clone() * g.clone()).sum().into_scalar()).collect();
    let total: f64 = squares.into_iter().fold(0.0, |total, sq| total + sq as f64);
    let norm = total.sqrt();
    if !norm.is_finite() {
        return Err(Error::invalid("gradients", format!("a finite norm (found {norm}); lower the learning rate")));
    }
    Ok((norm, max.map_or(1.0, |max| (max / (norm + 1e-6)).min(1.0))))
}

/// The next output of the SplitMix64 generator whose state is `state` (advanced): the random
/// stream of training draws, a plain `u64` so a checkpoint can store and restore it.
fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The value of a one-element loss, refused when not finite.
fn scalar(loss: &Tensor<1>) -> Result<f32, Error> {
    let values = loss
        .clone()
        .into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .map_err(|e| Error::invalid("loss", format!("a readable f32 scalar ({e:?})")))?;
    match values.first() {
        Some(v) if v.is_finite() => Ok(*v),
        v => Err(Error::invalid("loss", format!("a finite value (found {v:?}); lower the learning rate"))),
    }
}

/// Sets `require_grad` on the trainable parameters only.
struct RequireGrad<'a> {
    trainable: &'a HashMap<ParamId, (String, bool)>,
    /// Put every parameter on autodiff with Burn's balanced checkpointing strategy (the
    /// trainer's device, and so every tensor made on it, then carries the strategy too:
    /// operands must share one).
    checkpointing: bool,
}

impl ModuleMapper for RequireGrad<'_> {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let trains = self.trainable.contains_key(&param.id);
        let param = if self.checkpointing {
            param.map(|t| t.autodiff().with_gradient_checkpointing_strategy(GradientCheckpointingStrategy::Balanced))
        } else {
            param
        };
        param.set_require_grad(trains)
    }
}

/// Gradients of the trainable parameters, flattened, on the inner (non-autodiff) device.
struct CollectGrads<'a> {
    grads: &'a Gradients,
    trainable: &'a HashMap<ParamId, (String, bool)>,
    /// Id, the parameter's dims, the flattened gradient.
    out: Vec<(ParamId, Vec<usize>, Tensor<1>)>,
}

impl ModuleVisitor for CollectGrads<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if !self.trainable.contains_key(&param.id) {
            return;
        }
        if let Some(g) = param.val().grad(self.grads) {
            let dims = g.dims().to_vec();
            let n = g.shape().num_elements();
            self.out.push((param.id, dims, g.reshape([n])));
        }
    }
}

/// The current values of the trainable parameters, flattened, on the inner device.
struct CollectValues<'a> {
    trainable: &'a HashMap<ParamId, (String, bool)>,
    out: Vec<(ParamId, Tensor<1>)>,
}

impl ModuleVisitor for CollectValues<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if self.trainable.contains_key(&param.id) {
            let value = param.val().inner();
            let n = value.shape().num_elements();
            self.out.push((param.id, value.reshape([n])));
        }
    }
}

/// Replaces the parameters found in `values` (flattened) by those values.
struct SetValues<'a> {
    values: &'a HashMap<ParamId, Tensor<1>>,
}

impl ModuleMapper for SetValues<'_> {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let Some(value) = self.values.get(&param.id) else { return param };
        param.map(|tensor| {
            let dims = tensor.dims();
            value.clone().reshape(dims)
        })
    }
}

/// PyTorch's AdamW (decoupled weight decay, bias-corrected moments) on clipped gradients;
/// [`AdamW::into_updates`] computes the step.
struct AdamW<'a> {
    grads: HashMap<ParamId, Tensor<1>>,
    moments: &'a mut HashMap<ParamId, Moments>,
    /// The learning rate of each parameter (its group's).
    lr_of: &'a dyn Fn(ParamId) -> f64,
    clip: f64,
    betas: (f64, f64),
    weight_decay: f64,
    epsilon: f64,
    step: usize,
}

impl AdamW<'_> {
    /// Every parameter's new moments (stored) and update, computed in parallel over the
    /// parameters. Each parameter gets the same tensor operations as one after the other, so
    /// the same bits; in sequence, on one core, they were about a tenth of the small UNet's
    /// training step (`docs/benchmarks.md`, "Training step").
    fn into_updates(self) -> AdamWUpdates {
        let work: Vec<(ParamId, Tensor<1>, Option<Moments>, f64)> =
            self.grads.into_iter().map(|(id, grad)| (id, grad, self.moments.remove(&id), (self.lr_of)(id))).collect();
        let (b1, b2) = self.betas;
        let bias1 = 1.0 - b1.powi(self.step as i32);
        let bias2 = 1.0 - b2.powi(self.step as i32);
        let (clip, epsilon, weight_decay) = (self.clip, self.epsilon, self.weight_decay);
        let done: Vec<(ParamId, Moments, Tensor<1>, f64)> = work
            .into_par_iter()
            .map(|(id, grad, moments, lr)| {
                let grad = grad * clip;
                let moments = match moments {
                    Some(m) => Moments {
                        first: m.first * b1 + grad.clone() * (1.0 - b1),
                        second: m.second * b2 + grad.clone() * grad * (1.0 - b2),
                    },
                    None => Moments { first: grad.clone() * (1.0 - b1), second: grad.clone() * grad * (1.0 - b2) },
                };
                let denom = moments.second.clone().sqrt() / bias2.sqrt() + epsilon;
                let delta = moments.first.clone() / denom * (lr / bias1);
                (id, moments, delta, 1.0 - lr * weight_decay)
            })
            .collect();
        let mut updates = HashMap::with_capacity(done.len());
        for (id, moments, delta, decay) in done {
            self.moments.insert(id, moments);
            updates.insert(id, (delta, decay));
        }
        AdamWUpdates { updates }
    }
}

/// The parameters' AdamW updates ([`AdamW::into_updates`]); mapping a module by them applies
/// them.
struct AdamWUpdates {
    /// Per parameter: the step to subtract and the decoupled weight decay's factor
    /// `1 − lr·λ`.
    updates: HashMap<ParamId, (Tensor<1>, f64)>,
}

impl ModuleMapper for AdamWUpdates {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let Some((delta, weight_decay)) = self.updates.remove(&param.id) else { return param };
        param.map(|tensor| {
            let dims = tensor.dims();
            // The updated weight keeps the checkpointing strategy the trainer put it on.
            let strategy = tensor.gradient_checkpointing_strategy();
            let inner = tensor.inner();
            let n = inner.shape().num_elements();
            let updated = Tensor::from_inner((inner.reshape([n]) * weight_decay - delta).reshape(dims));
            match strategy {
                Some(strategy) => updated.with_gradient_checkpointing_strategy(strategy),
                None => updated,
            }
            .require_grad()
        })
    }
}

/// The trainer-state file of a checkpoint folder (step, RNG, options).
pub const STATE_FILE: &str = "trainer_state.json";
/// The optimizer-moment file of a checkpoint folder.
pub const OPTIMIZER_FILE: &str = "optimizer.safetensors";
const STATE_FORMAT: &str = "wonder3d-rs trainer state";

#[derive(serde::Serialize, serde::Deserialize)]
struct SavedState {
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
        crate::weights::write_checkpoint_named(dir, OPTIMIZER_FILE, &tensors, STATE_FILE, &json, Precision::F32)
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
        let mut file = crate::weights::SafetensorsFile::open(&opt_path)?;
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
    /// Sets the number of optimizer steps.
    pub fn with_steps(mut self, steps: usize) -> Self {
        self.steps = steps;
        self
    }

    /// Sets the objects per micro-batch.
    pub fn with_objects_per_batch(mut self, objects: usize) -> Self {
        self.objects_per_batch = objects;
        self
    }

    /// Sets the checkpoint interval.
    pub fn with_checkpoint_every(mut self, steps: usize) -> Self {
        self.checkpoint_every = steps;
        self
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
/// ([`crate::MultiViewPipeline::from_dir`]) plus [`STATE_FILE`] and [`OPTIMIZER_FILE`].
pub const CHECKPOINT_DIR: &str = "checkpoint";
/// With [`TrainOptions::ema_decay`], the checkpoint also holds the moving-average UNet in this
/// sub-folder (diffusers' `unet_ema` layout: `config.json` + safetensors); the checkpoint's
/// `unet/` keeps the current weights, which a resumed run continues from.
pub const EMA_DIR: &str = "unet_ema";
/// The run's log: one JSON object per optimizer step (`step`, `loss`, `grad_norm`, `lr`,
/// `seconds`).
pub const LOG_FILE: &str = "train_log.jsonl";

/// Trains the UNet of `pipeline` on `set` (`crate::training_set`), writing
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
    pipeline: crate::MultiViewPipeline,
    set: &crate::training_set::TrainingSet,
    options: TrainOptions,
    run: &RunOptions,
    out: &std::path::Path,
    resume: bool,
    on_event: &mut dyn FnMut(RunEvent),
) -> Result<crate::MultiViewPipeline, Error> {
    crate::training_set::check_set_size(set.dir(), set.size(), &pipeline)?;
    check_run(&options, run, out, resume)?;
    let device = pipeline.unet().devices().into_iter().next().unwrap_or_default();
    let encoded = crate::training_set::EncodedSet::encode(&pipeline, set, &device, &mut |done, total| {
        on_event(RunEvent::Encoded { done, total })
    })?;
    run_training_encoded(pipeline, &encoded, options, run, out, resume, on_event)
}

/// Refuses a run's bad options and folders before any work: 0 steps, objects or checkpoint
/// interval, a resume without a checkpoint, a fresh run into a folder holding one.
fn check_run(options: &TrainOptions, run: &RunOptions, out: &std::path::Path, resume: bool) -> Result<(), Error> {
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
/// [`EncodedSet`](crate::training_set::EncodedSet) per background). The result is the same
/// as `run_training` on the set the encoding came from.
pub fn run_training_encoded(
    pipeline: crate::MultiViewPipeline,
    encoded: &crate::training_set::EncodedSet,
    options: TrainOptions,
    run: &RunOptions,
    out: &std::path::Path,
    resume: bool,
    on_event: &mut dyn FnMut(RunEvent),
) -> Result<crate::MultiViewPipeline, Error> {
    use std::io::Write;

    use crate::training_set::{EncodedSample, TrainDomain, assemble_batch};

    crate::training_set::check_set_size(encoded.dir(), encoded.size(), &pipeline)?;
    check_run(&options, run, out, resume)?;
    let checkpoint = out.join(CHECKPOINT_DIR);
    let log_path = out.join(LOG_FILE);
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let device = pipeline.unet().devices().into_iter().next().unwrap_or_default();
    let (unet, vae, clip, scheduler) = pipeline.into_parts();
    let unet = if resume { crate::UNet::from_dir(checkpoint.join("unet"), &device)? } else { unet };
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
        let pipeline =
            crate::MultiViewPipeline::new(trainer.inference_unet(), vae.clone(), clip.clone(), scheduler.clone())?;
        w3d_core::io::write_dir_atomic(&checkpoint, |staging| {
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
    crate::MultiViewPipeline::new(unet, vae, clip, scheduler)
}

/// Options of [`train_vae`].
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct VaeTrainOptions {
    /// Optimizer steps.
    pub steps: usize,
    /// Images per step.
    pub batch: usize,
    /// AdamW learning rate (constant; no weight decay).
    pub learning_rate: f64,
    /// Weight of the KL term against the standard normal prior (per latent value, beside
    /// the per-pixel squared error).
    pub kl_weight: f64,
    /// Gradient-norm clip.
    pub max_grad_norm: Option<f64>,
    /// Decode a sample of the posterior (a VAE) rather than its mean (an autoencoder whose
    /// latents the KL term keeps near the unit scale). The diffusion model sees the mean
    /// either way; with few steps the mean trains much faster, since a fresh encoder's
    /// posterior is as wide as the prior and drowns the image in noise.
    pub sample_posterior: bool,
    /// Train only the decoder (`post_quant_conv` and `decoder.*`) on the latents of the
    /// frozen encoder. The encoder, the latent space and the scaling factor stay exactly as
    /// they were, so a diffusion model trained on this VAE's latents keeps working while the
    /// decoder learns to draw them more sharply. The KL term, which only shapes the encoder,
    /// drops out of the loss.
    pub decoder_only: bool,
    /// Seed of the batch and posterior-sample draws.
    pub seed: u64,
}

impl Default for VaeTrainOptions {
    fn default() -> Self {
        Self {
            steps: 2000,
            batch: 8,
            learning_rate: 1e-3,
            kl_weight: 1e-6,
            max_grad_norm: Some(1.0),
            sample_posterior: true,
            decoder_only: false,
            seed: 0,
        }
    }
}

impl VaeTrainOptions {
    /// Sets the number of steps.
    pub fn with_steps(mut self, steps: usize) -> Self {
        self.steps = steps;
        self
    }

    /// Sets the images per step.
    pub fn with_batch(mut self, batch: usize) -> Self {
        self.batch = batch;
        self
    }

    /// Sets the learning rate.
    pub fn with_learning_rate(mut self, lr: f64) -> Self {
        self.learning_rate = lr;
        self
    }

    /// Sets the seed.
    pub fn with_seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }

    /// Sets whether only the decoder trains ([`VaeTrainOptions::decoder_only`]).
    pub fn with_decoder_only(mut self, decoder_only: bool) -> Self {
        self.decoder_only = decoder_only;
        self
    }

    /// Sets whether a posterior sample (true) or the mean (false) is decoded.
    pub fn with_sample_posterior(mut self, sample: bool) -> Self {
        self.sample_posterior = sample;
        self
    }
}

/// Trains `vae` as the variational autoencoder of `images` (3 channels, values in `[0, 1]`,
/// sides a multiple of the VAE's downscale): per step, a random batch is encoded, a latent
/// is sampled from the posterior (or its mean taken, [`VaeTrainOptions::sample_posterior`]),
/// decoded, and the mean squared error against the image in
/// `[-1, 1]` plus `kl_weight` × the mean KL divergence to N(0, I) is minimised with AdamW.
/// Afterwards `scaling_factor` is set to 1 / the standard deviation of the latent means over
/// `images`, so the diffusion model sees unit-variance latents (Stable Diffusion's 0.18215
/// was found the same way). With [`VaeTrainOptions::decoder_only`] the encoder is frozen and
/// the scaling factor kept. `on_step(step, loss)` reports each step.
pub fn train_vae(
    vae: crate::Vae,
    images: &[w3d_core::Image],
    options: &VaeTrainOptions,
    on_step: &mut dyn FnMut(usize, f32),
) -> Result<crate::Vae, Error> {
    if images.is_empty() || options.batch == 0 {
        return Err(Error::invalid("images", "at least one image and a batch of at least 1"));
    }
    let (w, h) = (images[0].width(), images[0].height());
    for (i, image) in images.iter().enumerate() {
        image.expect_shape(&format!("images[{i}]"), w, h, 3)?;
    }
    let device = vae.devices().into_iter().next().unwrap_or_default();
    let ad = device.clone().autodiff();
    let to_tensor = |image: &w3d_core::Image, device: &Device| -> Tensor<4> {
        let (w, h) = (image.width() as usize, image.height() as usize);
        let t: Tensor<3> = Tensor::from_data(TensorData::new(image.data().to_vec(), [h, w, 3]), device);
        t.permute([2, 0, 1]).reshape([1, 3, h, w]) * 2.0 - 1.0
    };
    // Decoder-only: the frozen encoder's moments of every image, computed once outside the
    // autodiff graph (an encoder pass on tracked weights would grow a graph no backward
    // pass consumes).
    let frozen: Vec<(TensorData, TensorData)> = if options.decoder_only {
        images
            .iter()
            .map(|image| {
                let (mean, logvar) = vae.encode_moments(to_tensor(image, &device))?;
                Ok((mean.into_data(), logvar.into_data()))
            })
            .collect::<Result<_, Error>>()?
    } else {
        Vec::new()
    };
    let mut vae = vae.train();
    let ids: HashSet<ParamId> = if options.decoder_only {
        vae.decoder_param_ids().into_iter().collect()
    } else {
        crate::weights::collect_named_ids(&vae).into_iter().collect()
    };
    let mut moments = HashMap::new();
    let mut rng = options.seed ^ 0xA076_1D64_78BD_642F;
    let mut next = move || splitmix64(&mut rng);
    let lr = options.learning_rate;
    let lr_of = |_: ParamId| lr;
    for step in 1..=options.steps {
        // The step runs on a worker of rayon's pool, which the CPU kernels share (see `cpu_pool`).
        let (updated, value) = crate::cpu_pool::on_pool(|| -> Result<(crate::Vae, f32), Error> {
            let picks: Vec<usize> = (0..options.batch).map(|_| (next() % images.len() as u64) as usize).collect();
            let x = Tensor::cat(picks.iter().map(|&i| to_tensor(&images[i], &ad)).collect(), 0);
            let (mean, logvar) = if options.decoder_only {
                let stack = |part: fn(&(TensorData, TensorData)) -> &TensorData| {
                    Tensor::cat(
                        picks.iter().map(|&i| Tensor::<4>::from_data(part(&frozen[i]).clone(), &ad)).collect(),
                        0,
                    )
                };
                (stack(|m| &m.0), stack(|m| &m.1))
            } else {
                vae.encode_moments(x.clone())?
            };
            let z = if options.sample_posterior {
                let eps = gaussian_noise(mean.dims(), next(), &ad);
                mean.clone() + (logvar.clone() * 0.5).exp() * eps
            } else {
                mean.clone()
            };
            let recon = vae.decode(z)?;
            let diff = recon - x;
            let mse = (diff.clone() * diff).mean();
            let loss = if options.decoder_only {
                mse
            } else {
                let kl = ((mean.clone() * mean + logvar.clone().exp() - logvar - 1.0) * 0.5).mean();
                mse + kl * options.kl_weight
            };
            let value = scalar(&loss)?;
            let grads = loss.backward();
            let mut collect = CollectAllGrads { grads: &grads, ids: &ids, out: HashMap::new() };
            vae.visit(&mut collect);
            let (_, clip) = clip_factor(&collect.out, options.max_grad_norm)?;
            let mut update = AdamW {
                grads: collect.out,
                moments: &mut moments,
                lr_of: &lr_of,
                clip,
                betas: (0.9, 0.999),
                weight_decay: 0.0,
                epsilon: 1e-8,
                step,
            }
            .into_updates();
            Ok((vae.map(&mut update), value))
        })?;
        vae = updated;
        on_step(step, value);
    }
    let vae = vae.valid();
    if options.decoder_only {
        return Ok(vae);
    }
    let mut sum = 0.0f64;
    let mut sum_sq = 0.0f64;
    let mut count = 0usize;
    for image in images {
        let mean = vae.encode_mean(to_tensor(image, &device))?;
        for v in mean.into_data().convert::<f32>().try_to_vec::<f32>().unwrap_or_default() {
            sum += v as f64;
            sum_sq += (v as f64) * (v as f64);
            count += 1;
        }
    }
    let mean = sum / count.max(1) as f64;
    let std = (sum_sq / count.max(1) as f64 - mean * mean).max(0.0).sqrt();
    if !(std.is_finite() && std > 0.0) {
        return Err(Error::invalid("vae latents", format!("a positive finite spread after training (found {std})")));
    }
    Ok(vae.with_scaling_factor(1.0 / std))
}

/// Gradients of every parameter in `ids`, flattened.
struct CollectAllGrads<'a> {
    grads: &'a Gradients,
    ids: &'a HashSet<ParamId>,
    out: HashMap<ParamId, Tensor<1>>,
}

impl ModuleVisitor for CollectAllGrads<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if !self.ids.contains(&param.id) {
            return;
        }
        if let Some(g) = param.val().grad(self.grads) {
            let n = g.shape().num_elements();
            self.out.insert(param.id, g.reshape([n]));
        }
    }
}
