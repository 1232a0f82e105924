//! Wonder3D++'s multi-view enhancer: one joint img2img call that sharpens four views of an
//! object, colours and normals together (`docs/refinement.md` has the whole story).
//!
//! The four views (front, right, back, left) of each domain are laid out as a 2×2 grid of
//! tiles ([`make_grid`]: front | right over back | left), the colour grid and the normal grid
//! form one batch `[colour, normal]`, and the call is SDEdit: the grids are encoded by the
//! VAE, noised forward to the timestep `strength` selects and denoised with the UniPC
//! multistep solver ([`UniPcMultistepScheduler`]) by a frozen Stable Diffusion 1.5 UNet with
//! an IP-Adapter, driven by a ControlNet whose transformer blocks pair each colour row with
//! its normal row (cross-domain attention). The control image is the grid itself; the text
//! is one prompt per domain; classifier-free guidance runs the unconditional rows (empty
//! prompt, IP tokens of a zero embedding) beside the conditional ones.
//!
//! Batch orders. The UNet sees the guidance order `[colour uncond, normal uncond, colour cond,
//! normal cond]`; the ControlNet's cross-domain attention pairs row `i` with row `i + n/2`,
//! so it runs in the domain order `[colour uncond, colour cond, normal uncond, normal cond]`
//! and its residuals are put back into the guidance order. The authors' released pipeline
//! has two order bugs here (the ControlNet gets the text rows in guidance order, and the mid
//! residual's *channel* blocks are permuted instead of its rows); [`EnhancerOptions::
//! reproduce_upstream_cfg_bugs`] reproduces them for parity with that code, and the default
//! is the corrected order.

use std::path::Path;

use burn::tensor::{Device, Tensor, TensorData};
use w3d_core::{Error, Image};

use crate::compute;
use crate::loading::config::SchedulerConfig;
use crate::loading::weights::WeightStorage;
use crate::models::blocks::IpTokens;
use crate::models::clip::text::ClipText;
use crate::models::clip::tokenizer::ClipTokenizer;
use crate::models::clip::vision::{ClipVision, preprocess, preprocess_rescaled_twice};
use crate::models::controlnet::ControlNet;
use crate::models::ip_adapter::ImageProjection;
use crate::models::unet::{ControlResiduals, FeatureCache, UNet, UNetExtra};
use crate::models::vae::Vae;
use crate::pipelines::acceleration::Acceleration;
use crate::pipelines::guidance::{classifier_free_guidance, gaussian_noise};
use crate::schedulers::{UniPcMultistepScheduler, img2img_begin_index};

/// Views per grid: front, right, back, left.
pub const GRID_VIEWS: usize = 4;

/// Options of one enhancer call. The defaults are the authors' first iteration
/// ([`EnhancerOptions::for_iteration`] gives the later ones).
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct EnhancerOptions {
    /// Inference steps of the full schedule (the call runs the last `⌊steps·strength⌋`).
    pub steps: usize,
    /// SDEdit strength in (0, 1]: how far the grids are noised (0.2 → timestep 200).
    pub strength: f64,
    /// ControlNet conditioning scale (every residual is multiplied by it).
    pub control_scale: f32,
    /// Classifier-free guidance scale.
    pub guidance: f64,
    /// Scale of the IP-Adapter's image attention.
    pub ip_scale: f32,
    /// Seed of the posterior sample and the forward noise (this crate's generator, not
    /// torch's: the numbers differ from the authors' run for the same seed).
    pub seed: u64,
    /// Prompt of the colour grid.
    pub colour_prompt: String,
    /// Prompt of the normal grid.
    pub normal_prompt: String,
    /// Prompt of the unconditional rows (the authors' negative prompt never reaches their
    /// pipeline, so it is empty).
    pub negative_prompt: String,
    /// Reproduce the two batch-order bugs of the authors' released pipeline (see the module
    /// docs); off by default.
    pub reproduce_upstream_cfg_bugs: bool,
    /// Feed the IP-Adapter's image encoder the input image rescaled twice, as the authors'
    /// pipeline does (their `[0, 1]` image is divided by 255 again, so CLIP sees an almost
    /// black image — what their ControlNet was trained with); on by default.
    pub ip_image_rescaled_twice: bool,
    /// Training-free accelerations: guidance only inside an interval of noise levels (the
    /// other steps run the conditional rows alone), DeepCache over the UNet and the ControlNet
    /// together (a cached step runs both only as far as the cache depth's skip), bf16
    /// products, token merging. None by default.
    pub acceleration: Acceleration,
}

impl Default for EnhancerOptions {
    fn default() -> Self {
        EnhancerOptions {
            steps: 50,
            strength: 0.2,
            control_scale: 0.7,
            guidance: 3.0,
            ip_scale: 1.0,
            seed: 42,
            colour_prompt: "4views, multiview color".into(),
            normal_prompt: "4views, multiview normal map".into(),
            negative_prompt: String::new(),
            reproduce_upstream_cfg_bugs: false,
            ip_image_rescaled_twice: true,
            acceleration: Acceleration::default(),
        }
    }
}

impl EnhancerOptions {
    /// The authors' settings for refinement iteration `iteration` (from 0): strength 0.2 and
    /// ControlNet scale 0.7 first, then 0.1 and 1.0.
    pub fn for_iteration(iteration: usize) -> Self {
        if iteration == 0 { Self::default() } else { Self { strength: 0.1, control_scale: 1.0, ..Self::default() } }
    }

    w3d_core::setters! {
        with_strength(strength: f64);
        with_control_scale(control_scale: f32);
        with_steps(steps: usize);
        with_seed(seed: u64);
        /// These options with [`reproduce_upstream_cfg_bugs`](Self::reproduce_upstream_cfg_bugs)
        /// set to `value`.
        with_upstream_cfg_bugs(reproduce_upstream_cfg_bugs: bool);
        with_acceleration(acceleration: Acceleration);
    }
}

/// The text conditioning of one call, each `[1, tokens, width]`.
#[derive(Clone, Debug)]
pub struct PromptEmbeddings {
    /// The unconditional (negative) prompt.
    pub uncond: Tensor<3>,
    /// The colour prompt.
    pub colour: Tensor<3>,
    /// The normal prompt.
    pub normal: Tensor<3>,
}

/// The IP-Adapter tokens of one call, each `[1, tokens, cross_attention_dim]`.
#[derive(Clone, Debug)]
pub struct ImageTokens {
    /// Tokens of the unconditional rows (the projection of a zero embedding).
    pub uncond: Tensor<3>,
    /// Tokens of the conditional rows (the projection of the input image's embedding).
    pub cond: Tensor<3>,
}

/// The conditioning of one call: text and IP-Adapter tokens.
#[derive(Clone, Debug)]
pub struct EnhancerConditioning {
    /// The prompts' text tokens.
    pub prompts: PromptEmbeddings,
    /// The IP-Adapter tokens.
    pub image: ImageTokens,
}

/// The enhancer's models: SD1.5 UNet with IP-Adapter, the cross-domain ControlNet, the VAE,
/// the CLIP text encoder and tokenizer, the IP-Adapter's image encoder and projection, and
/// the scheduler config (see the module docs).
#[derive(Debug)]
pub struct EnhancerPipeline {
    unet: UNet,
    controlnet: ControlNet,
    vae: Vae,
    text_encoder: ClipText,
    tokenizer: ClipTokenizer,
    image_encoder: ClipVision,
    image_projection: ImageProjection,
    scheduler: SchedulerConfig,
}

/// The parts of an enhancer directory, for [`EnhancerPipeline::from_dir`] and its errors.
pub const ENHANCER_LAYOUT: &str = "unet/, vae/, text_encoder/, tokenizer/, scheduler/scheduler_config.json, \
     controlnet/, image_encoder/ and ip_adapter/ip-adapter_sd15.safetensors (docs/weights.md, \"The enhancer\")";

impl EnhancerPipeline {
    /// Assembles a pipeline, checking that the models fit together: the UNet has an
    /// IP-Adapter and no multi-view attention, the ControlNet has cross-domain attention, the
    /// latent channels agree, and the text width is the UNet's cross-attention width.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        unet: UNet,
        controlnet: ControlNet,
        vae: Vae,
        text_encoder: ClipText,
        tokenizer: ClipTokenizer,
        image_encoder: ClipVision,
        image_projection: ImageProjection,
        scheduler: SchedulerConfig,
    ) -> Result<Self, Error> {
        scheduler.validate()?;
        let u = unet.config();
        let latent = vae.config().latent_channels;
        if !unet.has_ip_adapter() {
            return Err(Error::invalid("enhancer unet", "a UNet with an IP-Adapter loaded"));
        }
        if u.num_views.is_some() || u.class_embed_type.is_some() {
            return Err(Error::invalid(
                "enhancer unet",
                "Stable Diffusion 1.5's UNet (no multi-view attention, no class embedding)",
            ));
        }
        if u.in_channels != latent || u.out_channels != latent {
            return Err(Error::invalid(
                "enhancer unet in_channels/out_channels",
                format!(
                    "{latent} and {latent} for a {latent}-channel VAE (found {}, {})",
                    u.in_channels, u.out_channels
                ),
            ));
        }
        if !controlnet.has_cross_domain_attention() {
            return Err(Error::invalid(
                "enhancer controlnet",
                "Wonder3D++'s ControlNet with cross-domain attention (attn_joint_mid keys)",
            ));
        }
        if text_encoder.config().hidden_size != u.cross_attention_dim {
            return Err(Error::invalid(
                "enhancer text_encoder hidden_size",
                format!(
                    "the UNet's cross_attention_dim {} (found {})",
                    u.cross_attention_dim,
                    text_encoder.config().hidden_size
                ),
            ));
        }
        if image_encoder.config().projection_dim != image_projection.embed_dim() {
            return Err(Error::invalid(
                "enhancer image_encoder projection_dim",
                format!(
                    "the IP-Adapter's embedding width {} (found {})",
                    image_projection.embed_dim(),
                    image_encoder.config().projection_dim
                ),
            ));
        }
        Ok(Self { unet, controlnet, vae, text_encoder, tokenizer, image_encoder, image_projection, scheduler })
    }

    /// Loads an enhancer directory laid out as [`ENHANCER_LAYOUT`] says.
    pub fn from_dir(dir: impl AsRef<Path>, device: &Device) -> Result<Self, Error> {
        Self::from_dir_with(dir, device, WeightStorage::F32)
    }

    /// [`EnhancerPipeline::from_dir`] with the weights held as `storage` says.
    pub fn from_dir_with(dir: impl AsRef<Path>, device: &Device, storage: WeightStorage) -> Result<Self, Error> {
        let dir = dir.as_ref();
        if !dir.is_dir() {
            return Err(Error::invalid(
                "enhancer weights",
                format!("a directory with {ENHANCER_LAYOUT} ({} is not a directory)", dir.display()),
            ));
        }
        check_enhancer_dir(dir)?;
        let require = |name: &str| dir.join(name);
        let mut unet = UNet::from_dir_with(require("unet"), device, storage)?;
        let image_projection = unet.load_ip_adapter(require("ip_adapter/ip-adapter_sd15.safetensors"))?;
        let controlnet = ControlNet::from_dir_with(require("controlnet"), device, storage)?;
        let vae = Vae::from_dir_with(require("vae"), device, storage)?;
        let text_encoder = ClipText::from_dir_with(require("text_encoder"), device, storage)?;
        let tokenizer = ClipTokenizer::from_dir(require("tokenizer"))?;
        let image_encoder = ClipVision::from_dir_with(require("image_encoder"), device, storage)?;
        let scheduler = unipc_scheduler_config(&require("scheduler/scheduler_config.json"))?;
        Self::new(unet, controlnet, vae, text_encoder, tokenizer, image_encoder, image_projection, scheduler)
    }

    /// The scheduler config (timestep spacing as UniPC reads it).
    pub fn scheduler(&self) -> &SchedulerConfig {
        &self.scheduler
    }

    /// The VAE.
    pub fn vae(&self) -> &Vae {
        &self.vae
    }

    /// The text conditioning of `options`' prompts.
    pub fn encode_prompts(&self, options: &EnhancerOptions) -> Result<PromptEmbeddings, Error> {
        let ids = [&options.negative_prompt, &options.colour_prompt, &options.normal_prompt]
            .iter()
            .map(|p| self.tokenizer.encode(p))
            .collect::<Result<Vec<_>, _>>()?;
        let all = self.text_encoder.encode(&ids)?;
        let [_, t, w] = all.dims();
        let row = |i: usize| all.clone().slice([i..i + 1, 0..t, 0..w]);
        Ok(PromptEmbeddings { uncond: row(0), colour: row(1), normal: row(2) })
    }

    /// The IP-Adapter tokens for `image` (RGB or RGBA in `[0, 1]`, composited over white):
    /// CLIP image embedding → projection for the conditional rows, the projection of zeros
    /// for the unconditional ones. With [`EnhancerOptions::ip_image_rescaled_twice`] the
    /// image is divided by 255 once more before the CLIP preprocessing, as in the authors'
    /// pipeline.
    pub fn image_tokens(
        &self,
        image: &Image,
        options: &EnhancerOptions,
        device: &Device,
    ) -> Result<ImageTokens, Error> {
        let rgb = composite_over_white(image)?;
        let size = self.image_encoder.config().image_size;
        let (w, h) = (rgb.width() as usize, rgb.height() as usize);
        let pixels = if options.ip_image_rescaled_twice {
            preprocess_rescaled_twice(rgb.data(), w, h, size)?
        } else {
            let levels: Vec<f32> = rgb.data().iter().map(|v| v * 255.0).collect();
            preprocess(&levels, w, h, size)?
        };
        let pixels: Tensor<4> = Tensor::from_data(TensorData::new(pixels, [1, 3, size, size]), device);
        let embeds = self.image_encoder.image_embeds(pixels)?;
        let zeros = Tensor::zeros(embeds.dims(), device);
        Ok(ImageTokens { uncond: self.image_projection.forward(zeros)?, cond: self.image_projection.forward(embeds)? })
    }

    /// The SDEdit start: scaled latents `[2, c, h, w]` of the grids `[colour, normal]`
    /// (`[2, 3, H, W]` in `[0, 1]`), a sample of the VAE posterior with `posterior_noise`
    /// (standard normal, the latents' shape).
    pub fn encode_grids(&self, grids: Tensor<4>, posterior_noise: Tensor<4>) -> Result<Tensor<4>, Error> {
        let (mean, logvar) = self.vae.encode_moments(grids * 2.0 - 1.0)?;
        if posterior_noise.dims() != mean.dims() {
            return Err(Error::invalid(
                "posterior_noise",
                format!("the latents' shape {:?} (found {:?})", mean.dims(), posterior_noise.dims()),
            ));
        }
        let sample = mean + (logvar * 0.5).exp() * posterior_noise;
        Ok(sample * self.vae.config().scaling_factor)
    }

    /// Decodes scaled latents `[2, c, h, w]` into grids `[2, 3, H, W]` in `[0, 1]`.
    pub fn decode_grids(&self, latents: Tensor<4>) -> Result<Tensor<4>, Error> {
        let [n, c, h, w] = latents.dims();
        let scaled = latents / self.vae.config().scaling_factor;
        let mut images = Vec::with_capacity(n);
        for i in 0..n {
            let decoded = self.vae.decode(scaled.clone().slice([i..i + 1, 0..c, 0..h, 0..w]))?;
            images.push((decoded * 0.5 + 0.5).clamp(0.0, 1.0));
        }
        Ok(Tensor::cat(images, 0))
    }

    /// The denoising part of the call: SDEdit from `init` (scaled latents `[2, c, h, w]`,
    /// rows colour and normal) with `noise` (its shape) to the timestep `options.strength`
    /// selects, then UniPC steps with guidance, the ControlNet driven by `control`
    /// (`[2, 3, H, W]` in `[0, 1]`, rows colour and normal). Returns the final latents.
    /// `progress(done, total)` is called after every step.
    pub fn denoise(
        &self,
        init: Tensor<4>,
        noise: Tensor<4>,
        control: Tensor<4>,
        conditioning: &EnhancerConditioning,
        options: &EnhancerOptions,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Tensor<4>, Error> {
        let [n, c, h, w] = init.dims();
        if n != 2 {
            return Err(Error::invalid("init latents", format!("2 rows, colour and normal (found {n})")));
        }
        if noise.dims() != init.dims() {
            return Err(Error::invalid(
                "noise",
                format!("the latents' shape {:?} (found {:?})", init.dims(), noise.dims()),
            ));
        }
        let [cn, cc, ch, cw] = control.dims();
        if cn != 2 || cc != 3 {
            return Err(Error::invalid("control", format!("[2, 3, H, W] (found {:?})", control.dims())));
        }
        let mut scheduler = UniPcMultistepScheduler::new(self.scheduler.clone(), options.steps)?;
        let begin = img2img_begin_index(options.steps, options.strength)?;
        scheduler.set_begin_index(begin)?;
        let timesteps: Vec<usize> = scheduler.run_timesteps().to_vec();
        let mut latents = scheduler.add_noise(init, noise)?;

        // Guidance order [c_uc, n_uc, c_cond, n_cond]; domain order [c_uc, c_cond, n_uc, n_cond].
        let cat = |rows: [&Tensor<3>; 4]| Tensor::cat(rows.iter().map(|t| (*t).clone()).collect(), 0);
        let p = &conditioning.prompts;
        let unet_text = cat([&p.uncond, &p.uncond, &p.colour, &p.normal]);
        let control_text = if options.reproduce_upstream_cfg_bugs {
            unet_text.clone()
        } else {
            cat([&p.uncond, &p.colour, &p.uncond, &p.normal])
        };
        let it = &conditioning.image;
        let ip = IpTokens { tokens: cat([&it.uncond, &it.uncond, &it.cond, &it.cond]), scale: options.ip_scale };
        let colour_control = control.clone().slice([0..1, 0..3, 0..ch, 0..cw]);
        let normal_control = control.slice([1..2, 0..3, 0..ch, 0..cw]);
        let control_rows =
            Tensor::cat(vec![colour_control.clone(), colour_control, normal_control.clone(), normal_control], 0);

        let accel = &options.acceleration;
        accel.validate()?;
        let skips = self.unet.skip_count();
        if accel.cache_interval > 1 && accel.cache_depth >= skips {
            return Err(Error::invalid(
                "cache_depth",
                format!("a skip of the UNet, 0..{skips} (found {})", accel.cache_depth),
            ));
        }
        // The conditional rows alone, for steps outside the guidance interval: colour and
        // normal, in both the UNet's and the ControlNet's order.
        let cond_rows = |t: &Tensor<3>, rows: [usize; 2]| {
            let [_, tokens, width] = t.dims();
            Tensor::cat(rows.iter().map(|&r| t.clone().slice([r..r + 1, 0..tokens, 0..width])).collect(), 0)
        };
        let cond_text = cond_rows(&unet_text, [2, 3]);
        let cond_ip = IpTokens { tokens: cond_rows(&ip.tokens, [2, 3]), scale: ip.scale };
        let cond_control = {
            let [_, cc, ch, cw] = control_rows.dims();
            Tensor::cat(
                vec![
                    control_rows.clone().slice([1..2, 0..cc, 0..ch, 0..cw]),
                    control_rows.clone().slice([3..4, 0..cc, 0..ch, 0..cw]),
                ],
                0,
            )
        };
        let mut cache = FeatureCache::new(accel.cache_depth);
        let mut last_full = None;
        let train_timesteps = self.scheduler.num_train_timesteps;

        let total = timesteps.len();
        for (done, &t) in timesteps.iter().enumerate() {
            let guided = accel.guided_at(t, train_timesteps);
            let rows = if guided { 4 } else { 2 };
            // DeepCache: a step that is not a multiple of the interval reuses the deep features
            // of the last full pass, if that pass had the same rows.
            let reuse = cache.batch() == Some(rows) && accel.reuses_cache(done, last_full);
            let colour = latents.clone().slice([0..1, 0..c, 0..h, 0..w]);
            let normal = latents.clone().slice([1..2, 0..c, 0..h, 0..w]);
            let tf = [t as f32];
            let eps = compute::with_settings(accel.pass, || -> Result<Tensor<4>, Error> {
                let (unet_rows, domain_rows, text, control_text, control_rows, ip) = if guided {
                    let guidance_rows =
                        Tensor::cat(vec![colour.clone(), normal.clone(), colour.clone(), normal.clone()], 0);
                    let domain_rows = Tensor::cat(vec![colour.clone(), colour, normal.clone(), normal], 0);
                    (guidance_rows, domain_rows, &unet_text, &control_text, &control_rows, &ip)
                } else {
                    let both = Tensor::cat(vec![colour, normal], 0);
                    (both.clone(), both, &cond_text, &cond_text, &cond_control, &cond_ip)
                };
                let residuals = if reuse {
                    self.controlnet.forward_shallow(
                        domain_rows,
                        &tf,
                        control_text.clone(),
                        control_rows.clone(),
                        options.control_scale,
                        accel.cache_depth,
                    )?
                } else {
                    self.controlnet.forward(
                        domain_rows,
                        &tf,
                        control_text.clone(),
                        control_rows.clone(),
                        options.control_scale,
                    )?
                };
                // Two conditional rows are in the same order for both models.
                let residuals =
                    if guided { to_guidance_order(residuals, options.reproduce_upstream_cfg_bugs) } else { residuals };
                let extra = UNetExtra { control: Some(residuals), ip: Some(ip.clone()) };
                let out = if accel.cache_interval > 1 {
                    self.unet.forward_cached(unet_rows, &tf, text.clone(), None, &extra, &mut cache, reuse)?
                } else {
                    self.unet.forward_with(unet_rows, &tf, text.clone(), None, &extra)?
                };
                if !guided {
                    return Ok(out);
                }
                let uncond = out.clone().slice([0..2, 0..c, 0..h, 0..w]);
                let cond = out.slice([2..4, 0..c, 0..h, 0..w]);
                Ok(classifier_free_guidance(uncond, cond, options.guidance))
            })?;
            if !reuse {
                last_full = Some(done);
            }
            latents = scheduler.step(eps, t, latents)?;
            progress(done + 1, total);
        }
        Ok(latents)
    }

    /// One whole enhancer call on grids (`[2, 3, H, W]` in `[0, 1]`: colour, normal), which
    /// are both the init and the control images, with `image_tokens` from
    /// [`EnhancerPipeline::image_tokens`]. Returns the enhanced grids `[2, 3, H, W]`.
    pub fn enhance_grids(
        &self,
        grids: Tensor<4>,
        image_tokens: &ImageTokens,
        options: &EnhancerOptions,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Tensor<4>, Error> {
        let device = grids.device();
        let [n, c, gh, gw] = grids.dims();
        let m = self.vae.config().downscale();
        if n != 2 || c != 3 || gh == 0 || gw == 0 || !gh.is_multiple_of(m) || !gw.is_multiple_of(m) {
            return Err(Error::invalid(
                "grids",
                format!("[2, 3, H, W] with H and W multiples of {m} (found {:?})", grids.dims()),
            ));
        }
        let conditioning = EnhancerConditioning { prompts: self.encode_prompts(options)?, image: image_tokens.clone() };
        let latent_shape = [2, self.vae.config().latent_channels, gh / m, gw / m];
        let posterior = gaussian_noise(latent_shape, options.seed, &device);
        let noise = gaussian_noise(latent_shape, options.seed.wrapping_add(1), &device);
        // The VAE's products as the denoising's (bf16 where asked).
        let pass = options.acceleration.pass;
        let init = compute::with_settings(pass, || self.encode_grids(grids.clone(), posterior))?;
        let latents = self.denoise(init, noise, grids, &conditioning, options, progress)?;
        compute::with_settings(pass, || self.decode_grids(latents))
    }
}

/// Puts the ControlNet's residuals (rows in domain order) into the UNet's guidance order.
/// With `upstream_bugs`, the down residuals are reordered as the authors' code does, and the
/// mid residual keeps its rows while its four channel blocks are permuted (their loop ran
/// over the batch size of a single tensor).
fn to_guidance_order(residuals: ControlResiduals, upstream_bugs: bool) -> ControlResiduals {
    let rows = |t: Tensor<4>| {
        let [n, c, h, w] = t.dims();
        let q = n / 4;
        let part = |i: usize| t.clone().slice([i * q..(i + 1) * q, 0..c, 0..h, 0..w]);
        Tensor::cat(vec![part(0), part(2), part(1), part(3)], 0)
    };
    let down = residuals.down.into_iter().map(rows).collect();
    let mid = if upstream_bugs {
        let [n, c, h, w] = residuals.mid.dims();
        let q = c / 4;
        let t = residuals.mid;
        let part = |i: usize| t.clone().slice([0..n, i * q..(i + 1) * q, 0..h, 0..w]);
        Tensor::cat(vec![part(0), part(2), part(1), part(3)], 1)
    } else {
        rows(residuals.mid)
    };
    ControlResiduals { down, mid }
}

/// The files [`EnhancerPipeline::from_dir`] reads, as (folder, names): one of the names must
/// be in the folder (the first is preferred; weights as safetensors only). `wonder3d`'s Hub
/// download fetches exactly these.
pub const ENHANCER_FILES: [(&str, &[&str]); 14] = [
    ("unet", &["config.json"]),
    ("unet", &["diffusion_pytorch_model.safetensors", "diffusion_pytorch_model.fp16.safetensors"]),
    ("controlnet", &["config.json"]),
    ("controlnet", &["diffusion_pytorch_model.safetensors", "diffusion_pytorch_model.fp16.safetensors"]),
    ("vae", &["config.json"]),
    ("vae", &["diffusion_pytorch_model.safetensors", "diffusion_pytorch_model.fp16.safetensors"]),
    ("text_encoder", &["config.json"]),
    ("text_encoder", &["model.safetensors", "model.fp16.safetensors"]),
    ("image_encoder", &["config.json"]),
    ("image_encoder", &["model.safetensors", "model.fp16.safetensors"]),
    ("ip_adapter", &["ip-adapter_sd15.safetensors"]),
    ("tokenizer", &["vocab.json"]),
    ("tokenizer", &["merges.txt"]),
    ("scheduler", &["scheduler_config.json"]),
];

/// Fails naming the first file of an enhancer directory that is missing (and where the
/// directory's layout is documented), before any weight is read.
pub fn check_enhancer_dir(dir: &Path) -> Result<(), Error> {
    for (folder, names) in ENHANCER_FILES {
        if !names.iter().any(|name| dir.join(folder).join(name).is_file()) {
            return Err(Error::invalid(
                "enhancer weights",
                format!(
                    "{} (missing; an enhancer directory holds {ENHANCER_LAYOUT})",
                    dir.join(folder).join(names.join(" or ")).display()
                ),
            ));
        }
    }
    Ok(())
}

/// Reads an SD1.5 `scheduler_config.json` for UniPC: a file without `timestep_spacing` gets
/// UniPC's own default, `linspace` (diffusers drops keys the file lacks when it builds
/// UniPC from another scheduler's config), not the DDIM default this crate's
/// [`SchedulerConfig`] fills in.
pub fn unipc_scheduler_config(path: &Path) -> Result<SchedulerConfig, Error> {
    let mut config = SchedulerConfig::from_file(path)?;
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| Error::format(path, "scheduler config", format!("JSON ({e})")))?;
    if value.get("timestep_spacing").is_none() {
        config.timestep_spacing = "linspace".into();
    }
    Ok(config)
}

/// `image` (RGB, or RGBA composited over white) as RGB.
fn composite_over_white(image: &Image) -> Result<Image, Error> {
    match image.channels() {
        3 => Ok(image.clone()),
        4 => {
            let data = image
                .data()
                .chunks_exact(4)
                .flat_map(|p| {
                    let a = p[3];
                    [p[0] * a + 1.0 - a, p[1] * a + 1.0 - a, p[2] * a + 1.0 - a]
                })
                .collect();
            Image::new(image.width(), image.height(), 3, data)
        }
        c => Err(Error::invalid("image", format!("3 or 4 channels (found {c})"))),
    }
}

/// Lays out four equally sized tiles (front, right, back, left) as a 2×2 grid: front | right
/// on top, back | left below (row-major, as the authors' `make_grid(nrow=2)`).
pub fn make_grid(tiles: &[Image]) -> Result<Image, Error> {
    if tiles.len() != GRID_VIEWS {
        return Err(Error::invalid("tiles", format!("{GRID_VIEWS} images (found {})", tiles.len())));
    }
    let (w, h, ch) = (tiles[0].width(), tiles[0].height(), tiles[0].channels());
    for (i, tile) in tiles.iter().enumerate() {
        tile.expect_shape(&format!("tile {i}"), w, h, ch)?;
    }
    let (gw, gh) = (2 * w as usize, 2 * h as usize);
    let c = ch as usize;
    let mut data = vec![0.0; gw * gh * c];
    for (i, tile) in tiles.iter().enumerate() {
        let (ox, oy) = ((i % 2) * w as usize, (i / 2) * h as usize);
        for (y, row) in tile.data().chunks_exact(w as usize * c).enumerate() {
            let start = ((oy + y) * gw + ox) * c;
            data[start..start + row.len()].copy_from_slice(row);
        }
    }
    Image::new(gw as u32, gh as u32, ch, data)
}

/// The inverse of [`make_grid`]: the four tiles of a 2×2 grid (even width and height).
pub fn split_grid(grid: &Image) -> Result<Vec<Image>, Error> {
    let (gw, gh, c) = (grid.width() as usize, grid.height() as usize, grid.channels() as usize);
    if gw == 0 || gh == 0 || gw % 2 != 0 || gh % 2 != 0 {
        return Err(Error::invalid("grid", format!("an even, non-zero width and height (found {gw}x{gh})")));
    }
    let (w, h) = (gw / 2, gh / 2);
    (0..GRID_VIEWS)
        .map(|i| {
            let (ox, oy) = ((i % 2) * w, (i / 2) * h);
            let mut data = Vec::with_capacity(w * h * c);
            for y in 0..h {
                let start = ((oy + y) * gw + ox) * c;
                data.extend_from_slice(&grid.data()[start..start + w * c]);
            }
            Image::new(w as u32, h as u32, c as u32, data)
        })
        .collect()
}

/// Images `[h, w, 3]` (all the same size) as a batch `[n, 3, h, w]`.
pub fn images_to_tensor(images: &[&Image], device: &Device) -> Result<Tensor<4>, Error> {
    let first = images.first().ok_or_else(|| Error::invalid("images", "at least one image"))?;
    let (w, h) = (first.width(), first.height());
    let mut values = Vec::with_capacity(images.len() * (w * h * 3) as usize);
    for (i, image) in images.iter().enumerate() {
        image.expect_shape(&format!("image {i}"), w, h, 3)?;
        values.extend_from_slice(image.data());
    }
    let hwc: Tensor<4> = Tensor::from_data(TensorData::new(values, [images.len(), h as usize, w as usize, 3]), device);
    Ok(hwc.permute([0, 3, 1, 2]))
}

/// A batch `[n, 3, h, w]` as `n` RGB images.
pub fn tensor_to_images(batch: Tensor<4>) -> Result<Vec<Image>, Error> {
    let [n, c, h, w] = batch.dims();
    if c != 3 {
        return Err(Error::invalid("batch", format!("3 channels (found {c})")));
    }
    let values = batch
        .permute([0, 2, 3, 1])
        .into_data()
        .try_to_vec::<f32>()
        .map_err(|e| Error::invalid("batch", format!("f32 values ({e:?})")))?;
    values
        .chunks_exact(h * w * 3)
        .map(|v| Image::new(w as u32, h as u32, 3, v.to_vec()))
        .collect::<Result<_, _>>()
        .and_then(
            |images: Vec<Image>| {
                if images.len() == n { Ok(images) } else { Err(Error::invalid("batch", format!("{n} images"))) }
            },
        )
}

/// `image` (3 channels in `[0, 1]`) resized to `width × height` with PIL's bicubic filter on
/// 8-bit values (what the authors' data loader does to bring their saved 256² generated
/// views to the 512² tiles), back in `[0, 1]`.
pub fn resize_bicubic(image: &Image, width: u32, height: u32) -> Result<Image, Error> {
    image.expect_shape("image", image.width(), image.height(), 3)?;
    if width == 0 || height == 0 {
        return Err(Error::invalid("size", format!("a non-zero size (found {width}x{height})")));
    }
    if (image.width(), image.height()) == (width, height) {
        return Ok(image.clone());
    }
    let bytes: Vec<f32> = image.data().iter().map(|v| (v * 255.0).round().clamp(0.0, 255.0)).collect();
    let mut data = crate::models::clip::vision::resize_bicubic(
        &bytes,
        image.width() as usize,
        image.height() as usize,
        width as usize,
        height as usize,
    );
    data.iter_mut().for_each(|v| *v /= 255.0);
    Image::new(width, height, 3, data)
}
