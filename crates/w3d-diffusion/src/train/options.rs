//! What a training run is: the stages, the learning-rate schedule, the options, one batch and
//! its condition-dropout and noise draws.

use burn::tensor::Tensor;
use w3d_core::Error;

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
    /// [`Trainer::ema_unet`](crate::train::Trainer::ema_unet).
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

    w3d_core::setters! {
        /// Trains every parameter whatever the stage (see [`TrainOptions::train_all`]).
        with_train_all(train_all: bool);
        /// Turns gradient checkpointing on or off (see [`TrainOptions::gradient_checkpointing`]).
        with_gradient_checkpointing(gradient_checkpointing: bool);
        /// Keeps an exponential moving average of the trainable weights with maximum decay
        /// `value` (`None`: off; diffusers' training scripts use 0.9999 with `--use_ema`).
        with_ema_decay(ema_decay: Option<f64>);
        /// Sets the learning rate.
        with_learning_rate(learning_rate: f64);
        /// Sets the warm-up length.
        with_warmup_steps(warmup_steps: usize);
        /// Sets the learning rate's course after the warm-up.
        with_lr_schedule(lr_schedule: LrSchedule);
        /// Sets the number of accumulated micro-batches per optimizer step.
        with_gradient_accumulation(gradient_accumulation: usize);
        /// Sets the gradient-norm clip (`None`: off).
        with_max_grad_norm(max_grad_norm: Option<f64>);
        /// Sets the condition-dropout rate.
        with_condition_drop_rate(condition_drop_rate: f64);
        /// Sets the Min-SNR γ (`None`: every timestep weighs the same in the prediction's own
        /// MSE).
        with_min_snr_gamma(min_snr_gamma: Option<f64>);
        /// Sets the seed of the random draws.
        with_seed(seed: u64);
    }

    pub(crate) fn validate(&self) -> Result<(), Error> {
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

    pub(crate) fn keeps_clip(self) -> bool {
        matches!(self, ConditionDrop::Keep | ConditionDrop::Image)
    }

    pub(crate) fn keeps_image(self) -> bool {
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
