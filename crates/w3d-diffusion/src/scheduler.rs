//! DDIM sampling and DDIM inversion, as diffusers' `DDIMScheduler` and `DDIMInverseScheduler`,
//! plus classifier-free guidance and seeded Gaussian noise.
//!
//! Timesteps are integer training steps in `[0, T)` (T = `num_train_timesteps`). ᾱ_t
//! (`alphas_cumprod[t]`) is the signal fraction of the forward process
//! `x_t = √ᾱ_t·x_0 + √(1-ᾱ_t)·ε`.

use burn::tensor::{Device, Tensor, TensorData};
use w3d_core::Error;

use crate::config::SchedulerConfig;

/// What the model predicts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Prediction {
    /// The added noise ε.
    Epsilon,
    /// The clean sample x₀.
    Sample,
    /// v = √ᾱ·ε − √(1−ᾱ)·x₀.
    VPrediction,
}

/// The noise schedule shared by both schedulers.
#[derive(Clone, Debug)]
struct Schedule {
    config: SchedulerConfig,
    alphas_cumprod: Vec<f64>,
    prediction: Prediction,
}

impl Schedule {
    fn new(config: SchedulerConfig) -> Result<Self, Error> {
        config.validate()?;
        let t = config.num_train_timesteps;
        let mut betas: Vec<f64> = match (&config.trained_betas, config.beta_schedule.as_str()) {
            (Some(b), _) => b.clone(),
            (None, "linear") => linspace(config.beta_start, config.beta_end, t),
            (None, "scaled_linear") => {
                linspace(config.beta_start.sqrt(), config.beta_end.sqrt(), t).into_iter().map(|b| b * b).collect()
            }
            (None, _) => {
                // squaredcos_cap_v2: betas from the cosine ᾱ(t), capped at 0.999.
                let alpha_bar = |x: f64| ((x + 0.008) / 1.008 * std::f64::consts::FRAC_PI_2).cos().powi(2);
                (0..t)
                    .map(|i| {
                        let (t1, t2) = (i as f64 / t as f64, (i + 1) as f64 / t as f64);
                        (1.0 - alpha_bar(t2) / alpha_bar(t1)).min(0.999)
                    })
                    .collect()
            }
        };
        // The schedule is computed in f32 like diffusers (torch float32), then held in f64.
        betas.iter_mut().for_each(|b| *b = *b as f32 as f64);
        let mut alphas_cumprod = Vec::with_capacity(t);
        let mut acc = 1.0f32;
        for b in &betas {
            acc *= 1.0 - *b as f32;
            alphas_cumprod.push(acc as f64);
        }
        if config.rescale_betas_zero_snr {
            alphas_cumprod = rescale_zero_terminal_snr(&alphas_cumprod);
        }
        let prediction = match config.prediction_type.as_str() {
            "epsilon" => Prediction::Epsilon,
            "sample" => Prediction::Sample,
            _ => Prediction::VPrediction,
        };
        Ok(Self { config, alphas_cumprod, prediction })
    }

    fn alpha(&self, t: usize) -> Result<f64, Error> {
        self.alphas_cumprod.get(t).copied().ok_or_else(|| {
            Error::invalid("timestep", format!("a training step below {} (found {t})", self.alphas_cumprod.len()))
        })
    }

    /// (x₀, ε) from a model output at ᾱ_t.
    fn split<const D: usize>(&self, output: Tensor<D>, sample: Tensor<D>, alpha_t: f64) -> (Tensor<D>, Tensor<D>) {
        let beta_t = 1.0 - alpha_t;
        let (sa, sb) = (alpha_t.sqrt(), beta_t.sqrt());
        let (mut x0, eps) = match self.prediction {
            Prediction::Epsilon => ((sample.clone() - output.clone() * sb) / sa, output),
            Prediction::Sample => (output.clone(), (sample - output * sa) / sb),
            Prediction::VPrediction => (sample.clone() * sa - output.clone() * sb, output * sa + sample * sb),
        };
        if self.config.clip_sample {
            let r = self.config.clip_sample_range;
            x0 = x0.clamp(-r, r);
        }
        (x0, eps)
    }
}

fn linspace(start: f64, end: f64, n: usize) -> Vec<f64> {
    if n == 1 {
        return vec![start];
    }
    (0..n).map(|i| start + (end - start) * i as f64 / (n - 1) as f64).collect()
}

/// Lin et al. 2023, algorithm 1: shift and scale √ᾱ so the last step has zero SNR
/// (ᾱ is the square of the rescaled √ᾱ).
fn rescale_zero_terminal_snr(alphas_cumprod: &[f64]) -> Vec<f64> {
    let first = alphas_cumprod[0].sqrt();
    let last = alphas_cumprod[alphas_cumprod.len() - 1].sqrt();
    alphas_cumprod.iter().map(|a| ((a.sqrt() - last) * first / (first - last)).powi(2)).collect()
}

/// `trailing` spacing, descending: `round(arange(T, 0, -T/n)) - 1` (the same for every
/// diffusers scheduler).
fn trailing_timesteps(t: usize, n: usize) -> Vec<usize> {
    let ratio = t as f64 / n as f64;
    (0..n).map(|i| round_half_even(t as f64 - i as f64 * ratio) as usize - 1).collect()
}

/// Fails if a timestep (shifted by `steps_offset`) reaches the training length `t`.
fn check_below(timesteps: &[usize], t: usize) -> Result<(), Error> {
    match timesteps.iter().find(|&&s| s >= t) {
        Some(&bad) => Err(Error::invalid("steps_offset", format!("timesteps below {t} (found {bad})"))),
        None => Ok(()),
    }
}

fn check_steps(steps: usize, t: usize) -> Result<(), Error> {
    if steps == 0 || steps > t {
        return Err(Error::invalid("num_inference_steps", format!("1..={t} (found {steps})")));
    }
    Ok(())
}

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
        let schedule = Schedule::new(config)?;
        let c = &schedule.config;
        let t = c.num_train_timesteps;
        check_steps(num_inference_steps, t)?;
        let n = num_inference_steps;
        let timesteps: Vec<usize> = match c.timestep_spacing.as_str() {
            "linspace" => {
                linspace(0.0, (t - 1) as f64, n).into_iter().rev().map(|v| round_half_even(v) as usize).collect()
            }
            "leading" => (0..n).rev().map(|i| i * (t / n) + c.steps_offset).collect(),
            _ => trailing_timesteps(t, n),
        };
        check_below(&timesteps, t)?;
        let final_alpha_cumprod = if c.set_alpha_to_one { 1.0 } else { schedule.alphas_cumprod[0] };
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
        let schedule = Schedule::new(config)?;
        let c = &schedule.config;
        let t = c.num_train_timesteps;
        check_steps(num_inference_steps, t)?;
        let n = num_inference_steps;
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
        let initial_alpha_cumprod = if c.set_alpha_to_one { 1.0 } else { schedule.alphas_cumprod[0] };
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

/// numpy's `round` (half to even).
fn round_half_even(v: f64) -> f64 {
    let r = v.round();
    if (v - v.trunc()).abs() == 0.5 && r % 2.0 != 0.0 { r - v.signum() } else { r }
}

/// Classifier-free guidance: `uncond + scale · (cond − uncond)`.
pub fn classifier_free_guidance<const D: usize>(uncond: Tensor<D>, cond: Tensor<D>, scale: f64) -> Tensor<D> {
    uncond.clone() + (cond - uncond) * scale
}

/// Standard-normal noise of `shape` from `seed` (SplitMix64 + Box–Muller): the same seed gives
/// the same values on every backend.
pub fn gaussian_noise<const D: usize>(shape: [usize; D], seed: u64, device: &Device) -> Tensor<D> {
    let n: usize = shape.iter().product();
    let mut state = seed;
    let mut next = move || {
        state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let mut values = Vec::with_capacity(n);
    while values.len() < n {
        let (u1, u2) = (next(), next());
        let r = (-2.0 * u1.ln()).sqrt();
        let a = std::f64::consts::TAU * u2;
        values.push((r * a.cos()) as f32);
        if values.len() < n {
            values.push((r * a.sin()) as f32);
        }
    }
    Tensor::from_data(TensorData::new(values, shape), device)
}

/// diffusers' `DPMSolverMultistepScheduler` with its defaults: DPM-Solver++ (data prediction),
/// second order with the midpoint update (“2M”), first order on the first step and on the
/// last (the final σ is zero), deterministic. Lu et al. 2022 show it reaches DDIM's quality
/// at 50 steps in about 20, so one generation needs fewer UNet evaluations.
///
/// The schedule (betas, ᾱ) and the timestep spacing come from the same [`SchedulerConfig`] as
/// [`DdimScheduler`], as `DPMSolverMultistepScheduler.from_config(ddim.config)` does in
/// diffusers. The solver works in σ = √((1−ᾱ)/ᾱ) and λ = log(α/σ); each step needs the
/// previous step's x₀ prediction, so the scheduler holds that state: make a new one (or call
/// [`DpmSolverMultistepScheduler::reset`]) for every sampling run.
#[derive(Clone, Debug)]
pub struct DpmSolverMultistepScheduler {
    schedule: Schedule,
    timesteps: Vec<usize>,
    /// σ at each inference timestep, then the final σ = 0 (f32, as diffusers stores them).
    sigmas: Vec<f64>,
    /// The x₀ prediction of the previous step.
    previous: Option<Tensor<4>>,
    step_index: usize,
}

impl DpmSolverMultistepScheduler {
    /// A scheduler for `num_inference_steps` steps. `linspace`, `leading` and `trailing`
    /// spacing follow diffusers' `DPMSolverMultistepScheduler.set_timesteps` (which differs
    /// from DDIM's: `leading` divides by `steps + 1`). DDIM's `clip_sample`,
    /// `clip_sample_range` and `set_alpha_to_one` do not apply to this solver and are ignored,
    /// as in diffusers.
    pub fn new(config: SchedulerConfig, num_inference_steps: usize) -> Result<Self, Error> {
        let schedule = Schedule::new(config)?;
        let c = &schedule.config;
        let t = c.num_train_timesteps;
        check_steps(num_inference_steps, t)?;
        let n = num_inference_steps;
        let timesteps: Vec<usize> = match c.timestep_spacing.as_str() {
            "linspace" => linspace(0.0, (t - 1) as f64, n + 1)
                .into_iter()
                .rev()
                .take(n)
                .map(|v| round_half_even(v) as usize)
                .collect(),
            "leading" => {
                let ratio = t / (n + 1);
                (1..=n).rev().map(|i| i * ratio + c.steps_offset).collect()
            }
            _ => trailing_timesteps(t, n),
        };
        check_below(&timesteps, t)?;
        let mut sigmas: Vec<f64> = timesteps
            .iter()
            .map(|&s| {
                let a = schedule.alphas_cumprod[s] as f32;
                ((1.0 - a) / a).sqrt() as f64
            })
            .collect();
        sigmas.push(0.0);
        Ok(Self { schedule, timesteps, sigmas, previous: None, step_index: 0 })
    }

    /// Inference timesteps, in sampling order (descending).
    pub fn timesteps(&self) -> &[usize] {
        &self.timesteps
    }

    /// σ = √((1−ᾱ)/ᾱ) at each inference timestep, followed by the final σ = 0.
    pub fn sigmas(&self) -> &[f64] {
        &self.sigmas
    }

    /// Forgets the previous step, ready for a new sampling run.
    pub fn reset(&mut self) {
        self.previous = None;
        self.step_index = 0;
    }

    /// One step from `timestep` (which must be the next of [`Self::timesteps`]) to the
    /// following one, given the model output (ε, x₀ or v per the config) at `sample`. Steps
    /// are second order but for the first and the last, which are first order.
    pub fn step(&mut self, model_output: Tensor<4>, timestep: usize, sample: Tensor<4>) -> Result<Tensor<4>, Error> {
        let i = self.step_index;
        match self.timesteps.get(i) {
            Some(&expected) if expected == timestep => {}
            Some(&expected) => {
                return Err(Error::invalid(
                    "timestep",
                    format!("the scheduler's next timestep {expected} (step {i}), found {timestep}"),
                ));
            }
            None => {
                return Err(Error::invalid(
                    "timestep",
                    format!("no timestep after the last of {} steps (call reset)", self.timesteps.len()),
                ));
            }
        }
        // α, σ of the variance-preserving process from σ_VE = σ/α.
        let alpha_sigma = |s: f64| {
            let alpha = 1.0 / (s * s + 1.0).sqrt();
            (alpha, s * alpha)
        };
        let (alpha_s0, sigma_s0) = alpha_sigma(self.sigmas[i]);
        let (alpha_t, sigma_t) = alpha_sigma(self.sigmas[i + 1]);
        let lambda = |alpha: f64, sigma: f64| alpha.ln() - sigma.ln();
        let x0 = self.data_prediction(model_output, sample.clone(), alpha_s0, sigma_s0);
        let h = lambda(alpha_t, sigma_t) - lambda(alpha_s0, sigma_s0);
        // exp(−h) − 1, which is −1 at the final σ = 0 (h = ∞).
        let phi = (-h).exp() - 1.0;
        let last = i + 1 == self.timesteps.len();
        // First order (DPM-Solver++ 1 = DDIM in λ); the second-order correction uses the
        // previous x₀ except on the last step, which diffusers keeps first order.
        let first_order = sample * (sigma_t / sigma_s0) - x0.clone() * (alpha_t * phi);
        let prev = match (&self.previous, last) {
            (Some(previous_x0), false) => {
                let (alpha_s1, sigma_s1) = alpha_sigma(self.sigmas[i - 1]);
                let r0 = (lambda(alpha_s0, sigma_s0) - lambda(alpha_s1, sigma_s1)) / h;
                let d1 = (x0.clone() - previous_x0.clone()) * (1.0 / r0);
                first_order - d1 * (0.5 * alpha_t * phi)
            }
            _ => first_order,
        };
        self.previous = Some(x0);
        self.step_index += 1;
        Ok(prev)
    }

    /// x₀ from the model output at (α, σ), as `convert_model_output` for DPM-Solver++.
    fn data_prediction(&self, output: Tensor<4>, sample: Tensor<4>, alpha: f64, sigma: f64) -> Tensor<4> {
        match self.schedule.prediction {
            Prediction::Epsilon => (sample - output * sigma) / alpha,
            Prediction::Sample => output,
            Prediction::VPrediction => sample * alpha - output * sigma,
        }
    }
}

/// The sampling algorithm of a generation run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum SamplerKind {
    /// DDIM ([`DdimScheduler`]), the authors' choice: 50 steps, eta 1.
    #[default]
    Ddim,
    /// DPM-Solver++(2M) ([`DpmSolverMultistepScheduler`]): deterministic, about 20 steps.
    DpmSolverPlusPlus2M,
}

impl SamplerKind {
    /// The name used on the command line and in reports: `ddim` or `dpmpp-2m`.
    pub fn name(self) -> &'static str {
        match self {
            SamplerKind::Ddim => "ddim",
            SamplerKind::DpmSolverPlusPlus2M => "dpmpp-2m",
        }
    }
}

impl std::fmt::Display for SamplerKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for SamplerKind {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self, Error> {
        match s {
            "ddim" => Ok(SamplerKind::Ddim),
            "dpmpp-2m" | "dpm++2m" | "dpmsolver++" => Ok(SamplerKind::DpmSolverPlusPlus2M),
            other => Err(Error::invalid("scheduler", format!("ddim or dpmpp-2m (found {other:?})"))),
        }
    }
}
