//! DDIM sampling and DDIM inversion, as diffusers' `DDIMScheduler` and `DDIMInverseScheduler`.

use burn::tensor::Tensor;
use w3d_core::Error;

use crate::loading::config::SchedulerConfig;
use crate::schedulers::schedule::*;

/// diffusers' `DDIMScheduler`: deterministic (eta = 0) or stochastic DDIM sampling.
#[derive(Clone, Debug)]
pub struct DdimScheduler {
    schedule: Schedule,
    final_alpha_cumprod: f64,
    timesteps: Vec<usize>,
    num_inference_steps: usize,
}

impl DdimScheduler {
    /// A scheduler for `num_inference_steps` steps.
    pub fn new(config: SchedulerConfig, num_inference_steps: usize) -> Result<Self, Error> {
        let schedule = Schedule::for_steps(config, num_inference_steps)?;
        let c = &schedule.config;
        let (t, n) = (c.num_train_timesteps, num_inference_steps);
        let timesteps: Vec<usize> = match c.timestep_spacing.as_str() {
            "linspace" => {
                linspace(0.0, (t - 1) as f64, n).into_iter().rev().map(|v| round_half_even(v) as usize).collect()
            }
            "leading" => (0..n).rev().map(|i| i * (t / n) + c.steps_offset).collect(),
            _ => trailing_timesteps(t, n),
        };
        check_below(&timesteps, t)?;
        let final_alpha_cumprod = schedule.boundary_alpha_cumprod();
        Ok(Self { schedule, final_alpha_cumprod, timesteps, num_inference_steps: n })
    }

    /// Inference timesteps, in sampling order (descending).
    pub fn timesteps(&self) -> &[usize] {
        &self.timesteps
    }

    /// ᾱ_t for every training step.
    pub fn alphas_cumprod(&self) -> &[f64] {
        &self.schedule.alphas_cumprod
    }

    /// What the model predicts.
    pub fn prediction(&self) -> Prediction {
        self.schedule.prediction
    }

    /// One DDIM step from `timestep` to the previous inference timestep.
    ///
    /// `eta` scales the added noise (0 = deterministic DDIM, 1 = DDPM-like); when `eta > 0`,
    /// `variance_noise` (standard normal, same shape as `sample`) must be given.
    pub fn step<const D: usize>(
        &self,
        model_output: Tensor<D>,
        timestep: usize,
        sample: Tensor<D>,
        eta: f64,
        variance_noise: Option<Tensor<D>>,
    ) -> Result<Tensor<D>, Error> {
        if !(eta >= 0.0 && eta.is_finite()) {
            return Err(Error::invalid("eta", format!("a finite value >= 0 (found {eta})")));
        }
        let ratio = self.schedule.config.num_train_timesteps / self.num_inference_steps;
        let alpha_t = self.schedule.alpha(timestep)?;
        let alpha_prev = match timestep.checked_sub(ratio) {
            Some(prev) => self.schedule.alpha(prev)?,
            None => self.final_alpha_cumprod,
        };
        let (x0, eps) = self.schedule.split(model_output, sample, alpha_t);
        let variance = (1.0 - alpha_prev) / (1.0 - alpha_t) * (1.0 - alpha_t / alpha_prev);
        let std_dev = eta * variance.sqrt();
        let direction = eps * (1.0 - alpha_prev - std_dev * std_dev).max(0.0).sqrt();
        let prev = x0 * alpha_prev.sqrt() + direction;
        if eta > 0.0 {
            let noise =
                variance_noise.ok_or_else(|| Error::invalid("variance_noise", "a noise tensor when eta > 0"))?;
            if noise.dims() != prev.dims() {
                return Err(Error::invalid("variance_noise", format!("shape {:?}", prev.dims())));
            }
            return Ok(prev + noise * std_dev);
        }
        Ok(prev)
    }

    /// The forward process: `√ᾱ_t·x₀ + √(1−ᾱ_t)·noise`.
    pub fn add_noise<const D: usize>(
        &self,
        original: Tensor<D>,
        noise: Tensor<D>,
        timestep: usize,
    ) -> Result<Tensor<D>, Error> {
        let a = self.schedule.alpha(timestep)?;
        Ok(original * a.sqrt() + noise * (1.0 - a).sqrt())
    }
}

/// diffusers' `DDIMInverseScheduler`: the deterministic DDIM process run backwards (clean →
/// noisy), used to find the noise that regenerates a given latent.
#[derive(Clone, Debug)]
pub struct DdimInverseScheduler {
    schedule: Schedule,
    initial_alpha_cumprod: f64,
    timesteps: Vec<usize>,
    num_inference_steps: usize,
}

impl DdimInverseScheduler {
    /// An inverse scheduler for `num_inference_steps` steps (`leading` or `trailing` spacing).
    pub fn new(config: SchedulerConfig, num_inference_steps: usize) -> Result<Self, Error> {
        let schedule = Schedule::for_steps(config, num_inference_steps)?;
        let c = &schedule.config;
        let (t, n) = (c.num_train_timesteps, num_inference_steps);
        let timesteps: Vec<usize> = match c.timestep_spacing.as_str() {
            "leading" => (0..n).map(|i| i * (t / n) + c.steps_offset).collect(),
            "trailing" => trailing_timesteps(t, n).into_iter().rev().collect(),
            other => {
                return Err(Error::invalid(
                    "timestep_spacing",
                    format!("leading or trailing for inversion (found {other})"),
                ));
            }
        };
        check_below(&timesteps, t)?;
        let initial_alpha_cumprod = schedule.boundary_alpha_cumprod();
        Ok(Self { schedule, initial_alpha_cumprod, timesteps, num_inference_steps: n })
    }

    /// Inversion timesteps, in inversion order (ascending).
    pub fn timesteps(&self) -> &[usize] {
        &self.timesteps
    }

    /// One inverse step to `timestep` from the previous (lower) inversion timestep; the model
    /// output is evaluated on `sample` at `timestep`.
    pub fn step<const D: usize>(
        &self,
        model_output: Tensor<D>,
        timestep: usize,
        sample: Tensor<D>,
    ) -> Result<Tensor<D>, Error> {
        let t = self.schedule.config.num_train_timesteps;
        let ratio = t / self.num_inference_steps;
        let alpha_next = self.schedule.alpha(timestep)?;
        let current = timestep as i64 - ratio as i64;
        let current = current.min(t as i64 - 1);
        let alpha_t = if current >= 0 { self.schedule.alpha(current as usize)? } else { self.initial_alpha_cumprod };
        let (x0, eps) = self.schedule.split(model_output, sample, alpha_t);
        Ok(x0 * alpha_next.sqrt() + eps * (1.0 - alpha_next).sqrt())
    }
}

/// Inverts `latent` (clean, t = 0) to the noise at the last inversion timestep.
///
/// `model(x, t)` returns the model output (ε, v or x₀ per the config) for `x` at `t`. With
/// `refinements = 0` each step is diffusers' `DDIMInverseScheduler.step` with the output
/// evaluated at the previous (less noisy) latent. Each refinement re-evaluates the output at
/// the current estimate of the noisier latent and repeats the step (fixed-point iteration on
/// `x_t = inverse_step(model(x_t, t), x_prev)`), which makes the inversion the exact inverse of
/// deterministic DDIM sampling as the iteration converges.
pub fn ddim_invert<const D: usize, F>(
    inverse: &DdimInverseScheduler,
    latent: Tensor<D>,
    refinements: usize,
    mut model: F,
) -> Result<Tensor<D>, Error>
where
    F: FnMut(Tensor<D>, usize) -> Result<Tensor<D>, Error>,
{
    let mut x = latent;
    for &t in inverse.timesteps() {
        let prev = x.clone();
        x = inverse.step(model(x, t)?, t, prev.clone())?;
        for _ in 0..refinements {
            x = inverse.step(model(x, t)?, t, prev.clone())?;
        }
    }
    Ok(x)
}

/// Deterministic DDIM sampling (eta = 0) from `latent` at the first timestep down to t = 0;
/// `model(x, t)` as in [`ddim_invert`] (apply classifier-free guidance inside it).
pub fn ddim_sample<const D: usize, F>(
    scheduler: &DdimScheduler,
    latent: Tensor<D>,
    mut model: F,
) -> Result<Tensor<D>, Error>
where
    F: FnMut(Tensor<D>, usize) -> Result<Tensor<D>, Error>,
{
    let mut x = latent;
    for &t in scheduler.timesteps() {
        x = scheduler.step(model(x.clone(), t)?, t, x, 0.0, None)?;
    }
    Ok(x)
}
