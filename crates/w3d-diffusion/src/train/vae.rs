//! Fine-tuning the VAE's decoder on its frozen encoder's latents.

use std::collections::{HashMap, HashSet};

use burn::module::{Module, ModuleVisitor, Param, ParamId};
use burn::tensor::{Device, Gradients, Tensor, TensorData};
use w3d_core::Error;

use crate::pipelines::guidance::gaussian_noise;
use crate::train::optim::*;

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
    w3d_core::setters! {
        /// Sets the number of steps.
        with_steps(steps: usize);
        /// Sets the images per step.
        with_batch(batch: usize);
        /// Sets the learning rate.
        with_learning_rate(learning_rate: f64);
        /// Sets the seed.
        with_seed(seed: u64);
        /// Sets whether only the decoder trains ([`VaeTrainOptions::decoder_only`]).
        with_decoder_only(decoder_only: bool);
        /// Sets whether a posterior sample (true) or the mean (false) is decoded.
        with_sample_posterior(sample_posterior: bool);
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
    vae: crate::models::vae::Vae,
    images: &[w3d_core::Image],
    options: &VaeTrainOptions,
    on_step: &mut dyn FnMut(usize, f32),
) -> Result<crate::models::vae::Vae, Error> {
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
        crate::loading::weights::collect_named_ids(&vae).into_iter().collect()
    };
    let mut moments = HashMap::new();
    let mut rng = options.seed ^ 0xA076_1D64_78BD_642F;
    let mut next = move || splitmix64(&mut rng);
    let lr = options.learning_rate;
    let lr_of = |_: ParamId| lr;
    for step in 1..=options.steps {
        // The step runs on a worker of rayon's pool, which the CPU kernels share (see `cpu_pool`).
        let (updated, value) = crate::kernels::pool::on_pool(|| -> Result<(crate::models::vae::Vae, f32), Error> {
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
pub(crate) struct CollectAllGrads<'a> {
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
