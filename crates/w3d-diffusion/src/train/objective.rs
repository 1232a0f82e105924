//! The training objective: ε- (or v-) prediction with Min-SNR-γ weighting.

use burn::tensor::{Tensor, TensorData};
use w3d_core::Error;

use crate::loading::config::SchedulerConfig;
use crate::models::unet::UNet;
use crate::schedulers::{DdimScheduler, Prediction};
use crate::train::options::*;

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
