//! Diffusion models of wonder3d-rs on Burn 0.22: the Stable-Diffusion-image-variations UNet
//! (`UNet2DConditionModel`, with the projection class embedding Wonder3D's switchers use), the
//! `AutoencoderKL` VAE, the CLIP vision encoder with projection and its preprocessing, the CLIP
//! text encoder ([`ClipText`]) and its BPE tokenizer ([`ClipTokenizer`]), the IP-Adapter image
//! prompt ([`ip_adapter`]) and the ControlNet ([`controlnet`]) of Wonder3D++'s refinement enhancer
//! ([`enhancer`]: one joint img2img call over 2×2 grids of four views), DDIM, DPM-Solver++(2M) and UniPC sampling (UniPC
//! also as img2img / SDEdit) with classifier-free guidance and DDIM inversion (exactly as
//! diffusers), and
//! streaming `.safetensors` loading with the diffusers / transformers key names. The UNet is
//! also Wonder3D++'s multi-view cross-domain `UNetMV2DConditionModel` (config fields
//! `num_views`, `cd_attention_mid`, `cd_attention_last`; a multi-view `config.json` lacking a
//! field the authors' inference passes explicitly gets their value, see
//! [`UNetConfig::from_value`]), and [`MultiViewPipeline`] turns one RGBA image into 6 views
//! × {normal, colour} and a `w3d_core::ViewSet` ([`multiview`]). For the refinement stage's
//! enhancer, [`ControlNet`] is diffusers' `ControlNetModel` with Wonder3D++'s cross-domain
//! attention ([`controlnet`]); [`UNet::forward_with`] adds its residuals ([`UNetExtra`]).
//!
//! Configs deserialize the `config.json` files of a diffusers checkpoint directory as they are
//! (apart from those multi-view defaults);
//! weights load from f32, f16 or bf16 safetensors and every missing, unexpected or misshaped key
//! is reported by name. Models run on any Burn device: [`default_device`] is Burn's `flex` CPU
//! backend; the `wgpu` feature adds the GPU backend ([`ComputeDevice`] picks a device at run
//! time, `docs/gpu.md`), and the `ndarray` feature Burn's older
//! `ndarray` CPU backend (a second backend for the parity tests:
//! `CARGO_TARGET_DIR=target/ndarray cargo test --release -p w3d-diffusion --features ndarray`). Convolutions run as im2col + GEMM (see [`nn::ConvAlgorithm`]).
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

pub mod blocks;
pub mod clip;
pub mod clip_text;
pub mod config;
pub mod controlnet;
mod cpu_attention;
mod cpu_conv;
mod cpu_geglu;
mod cpu_gemm;
mod cpu_group_norm;
mod cpu_linear;
mod cpu_pool;
pub mod device;
pub mod enhancer;
mod flex_autodiff;
pub mod ip_adapter;
pub mod multiview;
pub mod nn;
pub mod scheduler;
pub mod tokenizer;
pub mod train;
pub mod training_set;
pub mod unet;
pub mod vae;
pub mod weights;

pub use burn::tensor::{Device, Tensor, TensorData};
pub use clip::{
    CLIP_MEAN, CLIP_STD, ClipVision, preprocess as clip_preprocess,
    preprocess_rescaled_twice as clip_preprocess_rescaled_twice,
};
pub use clip_text::ClipText;
pub use config::{
    AUTHORS_INFERENCE_UNET_KWARGS, ClipTextConfig, ClipVisionConfig, ConfigDifference, ControlNetConfig,
    InferenceOverride, PerBlock, SchedulerConfig, UNetConfig, VaeConfig,
};
pub use controlnet::{ControlNet, ControlResiduals};
#[cfg(feature = "wgpu")]
pub use device::gpu_device;
pub use device::{ComputeDevice, OpenedDevice};
pub use ip_adapter::{ImageProjection, IpTokens};
pub use multiview::{
    CameraType, Conditioning, Domain, GeneratedViews, MultiViewPipeline, SampleOptions, prepare_input,
    prepare_input_on, quantize_u8, switcher_labels, task_labels,
};
pub use scheduler::{
    DdimInverseScheduler, DdimScheduler, DpmSolverMultistepScheduler, Prediction, SamplerKind, UniPcMultistepScheduler,
    classifier_free_guidance, ddim_invert, ddim_sample, gaussian_noise, img2img_begin_index,
};
pub use tokenizer::ClipTokenizer;
pub use unet::{UNet, UNetExtra};
pub use vae::Vae;
pub use weights::{NamedParam, NamedValues, Precision, SafetensorsFile, WeightStorage};

/// The default CPU device: Burn's `flex` backend (gemm-crate matmul, rayon threads), measured
/// faster than `ndarray` on this crate's models (see `docs/benchmarks.md`).
pub fn default_device() -> Device {
    Device::flex()
}

/// Burn's `ndarray` CPU backend (feature `ndarray`; deprecated in Burn 0.22): the second CPU
/// backend the parity tests and benches run on when the feature is on.
#[cfg(feature = "ndarray")]
#[allow(deprecated)]
pub fn ndarray_device() -> Device {
    Device::ndarray()
}
