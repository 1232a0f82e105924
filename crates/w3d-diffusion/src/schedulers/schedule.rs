//! The noise schedule every sampler shares: betas and ᾱ from a [`SchedulerConfig`], the
//! timestep spacings, the σ of the multistep solvers, and the checks they all make.
//!
//! Timesteps are integer training steps in `[0, T)` (T = `num_train_timesteps`). ᾱ_t
//! (`alphas_cumprod[t]`) is the signal fraction of the forward process
//! `x_t = √ᾱ_t·x_0 + √(1-ᾱ_t)·ε`.

use burn::tensor::Tensor;
use w3d_core::Error;

use crate::loading::config::SchedulerConfig;

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

/// The noise schedule every scheduler holds: its config, ᾱ for every training step and what
/// the model predicts.
#[derive(Clone, Debug)]
pub(crate) struct Schedule {
    pub(crate) config: SchedulerConfig,
    pub(crate) alphas_cumprod: Vec<f64>,
    pub(crate) prediction: Prediction,
}

impl Schedule {
    /// The schedule of `config` for a run of `steps` inference steps (checked against the
    /// training length).
    pub(crate) fn for_steps(config: SchedulerConfig, steps: usize) -> Result<Self, Error> {
        let schedule = Self::new(config)?;
        check_steps(steps, schedule.config.num_train_timesteps)?;
        Ok(schedule)
    }

    /// ᾱ one step before the first training step, where DDIM's last step (and the inversion's
    /// first) lands: 1 with `set_alpha_to_one`, else ᾱ₀.
    pub(crate) fn boundary_alpha_cumprod(&self) -> f64 {
        if self.config.set_alpha_to_one { 1.0 } else { self.alphas_cumprod[0] }
    }

    pub(crate) fn new(config: SchedulerConfig) -> Result<Self, Error> {
        config.validate()?;
        let t = config.num_train_timesteps;
        // Betas and ᾱ bit for bit as diffusers computes them in torch float32 (`torch.linspace`
        // and `torch.cumprod`, see `torch_linspace_f32`), then held in f64; the multistep
        // solvers' σ = √((1−ᾱ)/ᾱ) near t = 0 amplifies any last-bit difference of ᾱ.
        let betas: Vec<f32> = match (&config.trained_betas, config.beta_schedule.as_str()) {
            (Some(b), _) => b.iter().map(|&v| v as f32).collect(),
            (None, "linear") => torch_linspace_f32(config.beta_start, config.beta_end, t),
            (None, "scaled_linear") => torch_linspace_f32(config.beta_start.sqrt(), config.beta_end.sqrt(), t)
                .into_iter()
                .map(|b| b * b)
                .collect(),
            (None, _) => {
                // squaredcos_cap_v2: betas from the cosine ᾱ(t), capped at 0.999.
                let alpha_bar = |x: f64| ((x + 0.008) / 1.008 * std::f64::consts::FRAC_PI_2).cos().powi(2);
                (0..t)
                    .map(|i| {
                        let (t1, t2) = (i as f64 / t as f64, (i + 1) as f64 / t as f64);
                        (1.0 - alpha_bar(t2) / alpha_bar(t1)).min(0.999) as f32
                    })
                    .collect()
            }
        };
        // torch's CPU cumprod of float32 accumulates in double and rounds each output to f32.
        let mut alphas_cumprod = Vec::with_capacity(t);
        let mut acc = 1.0f64;
        for &b in &betas {
            acc *= f64::from(1.0 - b);
            alphas_cumprod.push(f64::from(acc as f32));
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

    pub(crate) fn alpha(&self, t: usize) -> Result<f64, Error> {
        self.alphas_cumprod.get(t).copied().ok_or_else(|| {
            Error::invalid("timestep", format!("a training step below {} (found {t})", self.alphas_cumprod.len()))
        })
    }

    /// (x₀, ε) from a model output at ᾱ_t.
    pub(crate) fn split<const D: usize>(
        &self,
        output: Tensor<D>,
        sample: Tensor<D>,
        alpha_t: f64,
    ) -> (Tensor<D>, Tensor<D>) {
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

    /// x₀ from the model output at the variance-preserving (α, σ) of a multistep solver
    /// (`convert_model_output` of DPM-Solver++ and UniPC with x₀ prediction).
    pub(crate) fn data_prediction(&self, output: Tensor<4>, sample: Tensor<4>, alpha: f64, sigma: f64) -> Tensor<4> {
        match self.prediction {
            Prediction::Epsilon => (sample - output * sigma) / alpha,
            Prediction::Sample => output,
            Prediction::VPrediction => sample * alpha - output * sigma,
        }
    }
}

/// `torch.linspace(start, end, n, dtype=float32)` on the CPU, bit for bit (checked on all
/// 1000 SD betas, torch 2.4.1): the endpoints and the step `(end − start)/(n − 1)` rounded to
/// f32, the first half of the points `start + step·i` and the second half
/// `end − step·(n − 1 − i)`, each evaluated exactly (f64) and rounded once to f32.
pub(crate) fn torch_linspace_f32(start: f64, end: f64, n: usize) -> Vec<f32> {
    let (start, end) = (start as f32, end as f32);
    if n == 1 {
        return vec![start];
    }
    let step = f64::from((end - start) / (n - 1) as f32);
    let (start, end) = (f64::from(start), f64::from(end));
    (0..n)
        .map(|i| if i < n / 2 { (start + step * i as f64) as f32 } else { (end - step * (n - 1 - i) as f64) as f32 })
        .collect()
}

pub(crate) fn linspace(start: f64, end: f64, n: usize) -> Vec<f64> {
    if n == 1 {
        return vec![start];
    }
    (0..n).map(|i| start + (end - start) * i as f64 / (n - 1) as f64).collect()
}

/// Lin et al. 2023, algorithm 1: shift and scale √ᾱ so the last step has zero SNR
/// (ᾱ is the square of the rescaled √ᾱ).
pub(crate) fn rescale_zero_terminal_snr(alphas_cumprod: &[f64]) -> Vec<f64> {
    let first = alphas_cumprod[0].sqrt();
    let last = alphas_cumprod[alphas_cumprod.len() - 1].sqrt();
    alphas_cumprod.iter().map(|a| ((a.sqrt() - last) * first / (first - last)).powi(2)).collect()
}

/// `trailing` spacing, descending: `round(arange(T, 0, -T/n)) - 1` (the same for every
/// diffusers scheduler).
pub(crate) fn trailing_timesteps(t: usize, n: usize) -> Vec<usize> {
    let ratio = t as f64 / n as f64;
    (0..n).map(|i| round_half_even(t as f64 - i as f64 * ratio) as usize - 1).collect()
}

/// Fails if a timestep (shifted by `steps_offset`) reaches the training length `t`.
pub(crate) fn check_below(timesteps: &[usize], t: usize) -> Result<(), Error> {
    match timesteps.iter().find(|&&s| s >= t) {
        Some(&bad) => Err(Error::invalid("steps_offset", format!("timesteps below {t} (found {bad})"))),
        None => Ok(()),
    }
}

/// Timesteps of diffusers' multistep solvers (`DPMSolverMultistepScheduler`,
/// `UniPCMultistepScheduler`), descending. They differ from DDIM's: `linspace` takes the first
/// `n` of `n + 1` points from T−1 down to 0 (so t = 0 is never run), `leading` divides by
/// `n + 1`; `trailing` is the common one.
pub(crate) fn multistep_timesteps(c: &SchedulerConfig, n: usize) -> Result<Vec<usize>, Error> {
    let t = c.num_train_timesteps;
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
    Ok(timesteps)
}

/// σ = √((1−ᾱ)/ᾱ) at each timestep (computed in f32, as diffusers stores it), then the final
/// σ = 0.
pub(crate) fn multistep_sigmas(schedule: &Schedule, timesteps: &[usize]) -> Vec<f64> {
    let mut sigmas: Vec<f64> = timesteps
        .iter()
        .map(|&s| {
            let mut a = schedule.alphas_cumprod[s] as f32;
            if a == 0.0 && schedule.config.rescale_betas_zero_snr {
                // diffusers' multistep solvers replace the zero terminal ᾱ by 2⁻²⁴ (f16's
                // smallest subnormal) so the first σ is finite.
                a = 2f32.powi(-24);
            }
            ((1.0 - a) / a).sqrt() as f64
        })
        .collect();
    sigmas.push(0.0);
    sigmas
}

/// Fails unless `timestep` is `timesteps[index]`, the step a multistep solver expects next.
pub(crate) fn check_next_timestep(timesteps: &[usize], index: usize, timestep: usize) -> Result<(), Error> {
    match timesteps.get(index) {
        Some(&expected) if expected == timestep => Ok(()),
        Some(&expected) => Err(Error::invalid(
            "timestep",
            format!("the scheduler's next timestep {expected} (step {index}), found {timestep}"),
        )),
        None => Err(Error::invalid(
            "timestep",
            format!("no timestep after the last of {} steps (call reset)", timesteps.len()),
        )),
    }
}

/// (α, σ) of the variance-preserving process x = α·x₀ + σ·ε from the variance-exploding
/// σ_VE = σ/α that the multistep solvers store: α = 1/√(σ_VE² + 1), σ = σ_VE·α.
pub(crate) fn vp_alpha_sigma(sigma_ve: f64) -> (f64, f64) {
    let alpha = 1.0 / (sigma_ve * sigma_ve + 1.0).sqrt();
    (alpha, sigma_ve * alpha)
}

pub(crate) fn check_steps(steps: usize, t: usize) -> Result<(), Error> {
    if steps == 0 || steps > t {
        return Err(Error::invalid("num_inference_steps", format!("1..={t} (found {steps})")));
    }
    Ok(())
}

/// numpy's `round` (half to even).
pub(crate) fn round_half_even(v: f64) -> f64 {
    let r = v.round();
    if (v - v.trunc()).abs() == 0.5 && r % 2.0 != 0.0 { r - v.signum() } else { r }
}
