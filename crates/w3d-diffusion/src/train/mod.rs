//! Training the multi-view UNet as Wonder3D++ does (`docs/training.md`), and fine-tuning the
//! VAE's decoder; on Burn's autodiff, on any device. Behind the `train` feature: an
//! inference-only build compiles neither this module nor Burn's autodiff.
//!
//! Layers, bottom up: what a run is ([`options`]); the objective, the training set and the
//! optimiser ([`objective`], [`data`], [`optim`]); a training step and its state ([`trainer`]); whole runs
//! ([`run`], [`vae`]).
//!
//! Batch layout (as inference, [`crate::pipelines::multiview`]): `n = domains · objects · views`
//! images, domain-major, then object, then view. Each group of `views` consecutive images (one
//! object, one domain) gets one timestep; the noise is independent per image; one
//! condition-dropout draw per object applies to all its images in every domain.
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

pub mod options;

pub mod data;
pub mod objective;
pub mod optim;

pub mod trainer;

pub mod run;
pub mod vae;

pub use data::{EncodedSet, TrainingSet};
pub use objective::DiffusionObjective;
pub use options::{ConditionDrop, LrSchedule, Stage, StepDraws, TrainBatch, TrainOptions};
pub use run::{CHECKPOINT_DIR, EMA_DIR, LOG_FILE, RunEvent, RunOptions, run_training, run_training_encoded};
pub use trainer::{OPTIMIZER_FILE, STATE_FILE, StepLog, Trainer};
pub use vae::{VaeTrainOptions, train_vae};
