//! Diffusion models of wonder3d-rs on Burn 0.22: Wonder3D++'s multi-view cross-domain UNet
//! (diffusers' `UNet2DConditionModel` / the authors' `UNetMV2DConditionModel`, with the
//! switchers' projection class embedding), the `AutoencoderKL` VAE, the CLIP vision and text
//! towers with the BPE tokenizer, and the refinement enhancer's ControlNet and IP-Adapter;
//! DDIM (with inversion), DPM-Solver++(2M) and UniPC sampling with classifier-free guidance,
//! exactly as diffusers; [`MultiViewPipeline`] turns one RGBA image into 6 views × {normal,
//! colour} and a `w3d_core::ViewSet`; with the `train` feature, Wonder3D++'s three training
//! stages.
//!
//! The crate is built in layers, each importing only from those below it
//! (`docs/architecture.md` draws them):
//!
//! | layer | what |
//! |---|---|
//! | `train` (feature `train`) | objective, AdamW, EMA, checkpoints, training sets, VAE fine-tuning |
//! | [`pipelines`] | guidance and noise, image → views ([`pipelines::multiview`]), the enhancer ([`pipelines::enhancer`]) |
//! | [`schedulers`] | DDIM and its inversion, DPM-Solver++(2M), UniPC, the schedule they share |
//! | [`models`] | UNet and its blocks, VAE, CLIP, ControlNet, IP-Adapter |
//! | [`nn`] | linear, convolution, norms, attention, GEGLU |
//! | kernels (private) | CPU kernels for Burn's flex backend, with their backward passes |
//! | [`loading`], [`device`], [`compute`] | configs, safetensors and key names; the compute device; pass settings and work counts |
//!
//! Configs deserialize the `config.json` files of a diffusers checkpoint as they are (a
//! multi-view `config.json` lacking a field the authors' inference passes explicitly gets
//! their value, see [`UNetConfig::from_value`]); weights load from f32, f16 or bf16
//! safetensors and every missing, unexpected or misshaped key is reported by name. Models run
//! on any Burn device: [`default_device`] is Burn's `flex` CPU backend; the `wgpu` feature adds
//! the GPU backend ([`ComputeDevice`] picks a device at run time, `docs/gpu.md`), and the
//! `ndarray` feature Burn's older CPU backend, a second backend for the parity tests
//! (`docs/testing.md`).
//!
//! ```
//! use w3d_diffusion::{DdimScheduler, SchedulerConfig, classifier_free_guidance, gaussian_noise};
//!
//! let device = w3d_diffusion::default_device();
//! let scheduler = DdimScheduler::new(SchedulerConfig::stable_diffusion(), 10).unwrap();
//! assert_eq!(scheduler.timesteps()[..3], [901, 801, 701]);
//! let mut latent = gaussian_noise([1, 4, 8, 8], 7, &device);
//! for &t in scheduler.timesteps() {
//!     // A stand-in for the UNet: predicts the sample itself as noise, with and without condition.
//!     let (uncond, cond) = (latent.clone() * 0.9, latent.clone());
//!     let eps = classifier_free_guidance(uncond, cond, 2.0);
//!     latent = scheduler.step(eps, t, latent, 0.0, None).unwrap();
//! }
//! assert_eq!(latent.dims(), [1, 4, 8, 8]);
//! ```

// The layers of the crate, bottom up: a module imports only from its own group or the groups
// declared before it (`cargo xtask layers` checks this; `docs/architecture.md` draws it).
//
// Foundations: the compute device; how passes compute and what they did (settings, work
// counts); reading checkpoints (configs, safetensors, key names).
pub mod compute;
pub mod device;
pub mod loading;

// CPU kernels for Burn's flex backend on plain slices, with their backward passes.
mod kernels;

// Neural-network layers: linear, convolution, norms, attention, GEGLU.
pub mod nn;

// The models: UNet and its blocks, VAE, CLIP towers and tokenizer, ControlNet, IP-Adapter.
pub mod models;

// The samplers and the schedule they share.
pub mod schedulers;

// Pipelines: image → six views × {normal, colour}; the refinement enhancer.
pub mod pipelines;

// Training (feature `train`).
#[cfg(feature = "train")]
pub mod train;

pub use burn::tensor::{Device, Tensor, TensorData};
#[cfg(feature = "wgpu")]
pub use device::gpu_device;
#[cfg(feature = "ndarray")]
pub use device::ndarray_device;
pub use device::{ComputeDevice, OpenedDevice, default_device};
pub use loading::config::{
    AUTHORS_INFERENCE_UNET_KWARGS, ClipTextConfig, ClipVisionConfig, ConfigDifference, ControlNetConfig,
    InferenceOverride, PerBlock, SchedulerConfig, UNetConfig, VaeConfig,
};
pub use loading::weights::{NamedParam, NamedValues, Precision, SafetensorsFile, WeightStorage};
pub use models::blocks::IpTokens;
pub use models::clip::text::ClipText;
pub use models::clip::tokenizer::ClipTokenizer;
pub use models::clip::vision::{
    CLIP_MEAN, CLIP_STD, ClipVision, preprocess as clip_preprocess,
    preprocess_rescaled_twice as clip_preprocess_rescaled_twice,
};
pub use models::controlnet::ControlNet;
pub use models::ip_adapter::ImageProjection;
pub use models::unet::{ControlResiduals, FeatureCache, UNet, UNetExtra};
pub use models::vae::Vae;
pub use pipelines::acceleration::Acceleration;
pub use pipelines::guidance::{classifier_free_guidance, gaussian_noise};
pub use pipelines::multiview::{
    CameraType, Conditioning, Domain, GeneratedViews, MultiViewPipeline, SampleOptions, prepare_input,
    prepare_input_on, quantize_u8, switcher_labels, task_labels,
};
pub use schedulers::{
    DdimInverseScheduler, DdimScheduler, DpmSolverMultistepScheduler, MultistepScheduler, Prediction, SamplerKind,
    UniPcMultistepScheduler, ddim_invert, ddim_sample, img2img_begin_index,
};
