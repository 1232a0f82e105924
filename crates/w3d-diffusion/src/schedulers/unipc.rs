//! UniPC, as diffusers' `UniPCMultistepScheduler`, with img2img's start index.

use burn::tensor::Tensor;
use w3d_core::Error;

use crate::loading::config::SchedulerConfig;
use crate::schedulers::multistep::MultistepScheduler;
use crate::schedulers::schedule::*;

/// diffusers' `UniPCMultistepScheduler` with its defaults: UniPC-bh2 (Zhao et al. 2023) in
/// data (x₀) prediction, second order (`solver_order` 2), a first-order warm-up step, a
/// first-order last step (`lower_order_final`), final σ = 0 (`final_sigmas_type "zero"`), no
/// Karras σ, no dynamic thresholding. It is the sampler of Wonder3D++'s enhancer
/// (img2img / SDEdit at 10 or 5 steps, `docs/benchmarks.md`).
///
/// Each step first *corrects* the sample the previous step predicted (UniC, from the new
/// model output; not on the first step of a run) and then *predicts* the next sample (UniP)
/// from the last two x₀ predictions. The solver works in σ = √((1−ᾱ)/ᾱ) (σ_VE, the σ of
/// [`DpmSolverMultistepScheduler`](crate::DpmSolverMultistepScheduler)), in α = 1/√(σ²+1), σ·α and λ = −log σ; the schedule's
/// coefficients are computed in f64, the tensors in f32. The schedule (betas, ᾱ, prediction
/// type, spacing) comes from a [`SchedulerConfig`], as `UniPCMultistepScheduler.from_config`
/// does in diffusers; [`UniPcMultistepScheduler::stable_diffusion_config`] is the one the
/// authors' enhancer ends up with. The scheduler holds the multistep history: a run goes
/// through the timesteps from [`UniPcMultistepScheduler::begin_index`] in order, and
/// [`UniPcMultistepScheduler::reset`] (or [`UniPcMultistepScheduler::set_begin_index`])
/// starts a new one.
#[derive(Clone, Debug)]
pub struct UniPcMultistepScheduler {
    schedule: Schedule,
    timesteps: Vec<usize>,
    /// σ_VE at each inference timestep, then the final σ = 0 (f32 values, as diffusers stores them).
    sigmas: Vec<f64>,
    /// Index into `timesteps` of the first step of a run.
    begin_index: usize,
    /// Index into `timesteps` of the next step.
    step_index: usize,
    /// x₀ prediction of the previous step (the corrector's and the second-order predictor's m₀/m₁).
    x0_last: Option<Tensor<4>>,
    /// x₀ prediction of the step before the previous one.
    x0_before: Option<Tensor<4>>,
    /// The (corrected) sample the previous predictor started from.
    last_sample: Option<Tensor<4>>,
    /// Order of the previous predictor step, which the next corrector uses.
    last_order: usize,
}

/// diffusers' default `solver_order` of UniPC.
const UNIPC_ORDER: usize = 2;

impl UniPcMultistepScheduler {
    /// A scheduler for `num_inference_steps` steps, the run starting at the first timestep.
    ///
    /// `config.timestep_spacing` is used as given (`linspace`, `leading` or `trailing`, the
    /// same timesteps as [`DpmSolverMultistepScheduler`](crate::DpmSolverMultistepScheduler), which differ from DDIM's);
    /// `steps_offset` applies to `leading` only. DDIM's `clip_sample`, `clip_sample_range` and
    /// `set_alpha_to_one` do not apply to UniPC and are ignored, as in diffusers. Errors on an
    /// invalid config, a step count outside `1..=num_train_timesteps`, or a count whose
    /// timesteps are not all distinct (the solver divides by λ differences).
    pub fn new(config: SchedulerConfig, num_inference_steps: usize) -> Result<Self, Error> {
        let schedule = Schedule::for_steps(config, num_inference_steps)?;
        let c = &schedule.config;
        let timesteps = multistep_timesteps(c, num_inference_steps)?;
        if let Some(w) = timesteps.windows(2).find(|w| w[0] <= w[1]) {
            return Err(Error::invalid(
                "num_inference_steps",
                format!(
                    "a count with distinct {} spacing timesteps (found {num_inference_steps}, which repeats t = {})",
                    c.timestep_spacing, w[1]
                ),
            ));
        }
        let sigmas = multistep_sigmas(&schedule, &timesteps);
        Ok(Self {
            schedule,
            timesteps,
            sigmas,
            begin_index: 0,
            step_index: 0,
            x0_last: None,
            x0_before: None,
            last_sample: None,
            last_order: 0,
        })
    }

    /// The config `UniPCMultistepScheduler.from_config` makes of Stable Diffusion 1.5's
    /// `scheduler_config.json` (a PNDM config, as Wonder3D++'s enhancer loads it): scaled-linear
    /// betas 0.00085 → 0.012 over 1000 steps, ε prediction, and UniPC's own default `linspace`
    /// spacing, because the file has no `timestep_spacing` key (so `steps_offset` 1 is
    /// unused). 50 steps then run t = 999, 979, …, 20.
    pub fn stable_diffusion_config() -> SchedulerConfig {
        SchedulerConfig { timestep_spacing: "linspace".into(), ..SchedulerConfig::stable_diffusion() }
    }

    /// All inference timesteps, in sampling order (descending), whatever the begin index.
    pub fn timesteps(&self) -> &[usize] {
        &self.timesteps
    }

    /// The timesteps a run steps through: [`Self::timesteps`] from [`Self::begin_index`] on.
    pub fn run_timesteps(&self) -> &[usize] {
        &self.timesteps[self.begin_index..]
    }

    /// σ_VE = √((1−ᾱ)/ᾱ) at each inference timestep, followed by the final σ = 0 (one more
    /// value than [`Self::timesteps`]).
    pub fn sigmas(&self) -> &[f64] {
        &self.sigmas
    }

    /// Index into [`Self::timesteps`] of the first step of a run (0 unless set by
    /// [`Self::set_begin_index`]).
    pub fn begin_index(&self) -> usize {
        self.begin_index
    }

    /// img2img: runs start at `timesteps()[index]` instead of the first timestep (diffusers'
    /// `set_begin_index`, with `index` from [`img2img_begin_index`]). Forgets the multistep
    /// history, so the next step is a first-order warm-up without correction, as in a fresh
    /// diffusers pipeline call. Errors if `index` is not below the number of timesteps.
    pub fn set_begin_index(&mut self, index: usize) -> Result<(), Error> {
        if index >= self.timesteps.len() {
            return Err(Error::invalid(
                "begin_index",
                format!("an index below the {} timesteps (found {index})", self.timesteps.len()),
            ));
        }
        self.begin_index = index;
        self.reset();
        Ok(())
    }

    /// Forgets the multistep history; the next step is the first of a new run, at
    /// `timesteps()[begin_index()]`.
    pub fn reset(&mut self) {
        self.step_index = self.begin_index;
        self.x0_last = None;
        self.x0_before = None;
        self.last_sample = None;
        self.last_order = 0;
    }

    /// SDEdit's forward noising to the σ of the next step (the begin index before a run):
    /// `α·original + σ·noise` with α = 1/√(σ_VE²+1), σ = σ_VE·α, i.e. √ᾱ_t·x₀ + √(1−ᾱ_t)·ε,
    /// exactly diffusers' `add_noise` for UniPC in an img2img pipeline. `original` (clean
    /// latents) and `noise` (standard normal) must have the same shape.
    pub fn add_noise(&self, original: Tensor<4>, noise: Tensor<4>) -> Result<Tensor<4>, Error> {
        if noise.dims() != original.dims() {
            return Err(Error::invalid(
                "noise",
                format!("the shape of the original samples {:?} (found {:?})", original.dims(), noise.dims()),
            ));
        }
        let (alpha, sigma) = vp_alpha_sigma(self.sigmas[self.step_index]);
        Ok(original * alpha + noise * sigma)
    }

    /// One step from `timestep` (which must be the next of [`Self::run_timesteps`]) to the
    /// following one, given the model output (ε, x₀ or v per the config) at `sample`
    /// (`[batch, channels, height, width]`, the shape of every step of the run). Corrects
    /// `sample` with this output (UniC, of the previous step's order; not on a run's first
    /// step), then predicts the next sample (UniP): first order on the first and the last
    /// step, second order otherwise. The last step (to σ = 0) returns the x₀ prediction
    /// itself. Errors on an unexpected timestep or a shape that differs from `sample`'s or the
    /// run's.
    pub fn step(&mut self, model_output: Tensor<4>, timestep: usize, sample: Tensor<4>) -> Result<Tensor<4>, Error> {
        let i = self.step_index;
        check_next_timestep(&self.timesteps, i, timestep)?;
        let dims = sample.dims();
        if model_output.dims() != dims {
            return Err(Error::invalid(
                "model_output",
                format!("the sample's shape {dims:?} (found {:?})", model_output.dims()),
            ));
        }
        if let Some(previous) = &self.x0_last
            && previous.dims() != dims
        {
            return Err(Error::invalid(
                "sample",
                format!("the shape of the run's previous steps {:?} (found {dims:?}; call reset)", previous.dims()),
            ));
        }
        let (alpha_s0, sigma_s0) = vp_alpha_sigma(self.sigmas[i]);
        let x0 = self.schedule.data_prediction(model_output, sample.clone(), alpha_s0, sigma_s0);
        let sample = match (self.last_sample.take(), &self.x0_last) {
            (Some(last_sample), Some(m0)) => self.corrected(&x0, m0, last_sample, i),
            _ => sample,
        };
        self.x0_before = self.x0_last.replace(x0.clone());
        // Second order once two x₀ are known, first order on the last step.
        let done = i - self.begin_index;
        let order = UNIPC_ORDER.min(self.timesteps.len() - i).min(done + 1);
        self.last_sample = Some(sample.clone());
        self.last_order = order;
        self.step_index += 1;
        let sigma_next = self.sigmas[i + 1];
        if sigma_next == 0.0 {
            // λ = ∞: σ_next/σ = 0, α_next = 1, B(h) = −1, so UniP-1 lands on x₀ exactly.
            return Ok(x0);
        }
        let (alpha_t, sigma_t) = vp_alpha_sigma(sigma_next);
        let h = self.lambda(i + 1) - self.lambda(i);
        let b_h = (-h).exp_m1();
        let first_order = sample * (sigma_t / sigma_s0) - x0.clone() * (alpha_t * b_h);
        Ok(match (&self.x0_before, order) {
            (Some(m1), 2) => {
                // D₁ = (m₁ − m₀)/r with r = (λ_prev − λ_cur)/h; UniP-2 of bh2 weighs it by ½.
                let r = (self.lambda(i - 1) - self.lambda(i)) / h;
                first_order - (m1.clone() - x0) * (alpha_t * b_h * 0.5 / r)
            }
            _ => first_order,
        })
    }

    /// λ = log α − log σ = −log σ_VE at `sigmas[index]`.
    fn lambda(&self, index: usize) -> f64 {
        -self.sigmas[index].ln()
    }

    /// UniC: re-takes the previous step (from `last_sample` at `sigmas[i−1]` to `sigmas[i]`)
    /// with the x₀ prediction `x0` now known at `sigmas[i]`, using the previous step's order:
    /// order 1 weighs the new difference by ρ = ½, order 2 solves the 2×2 system R·ρ = b of
    /// the bh2 variant for the weights of the older and the new difference.
    fn corrected(&self, x0: &Tensor<4>, m0: &Tensor<4>, last_sample: Tensor<4>, i: usize) -> Tensor<4> {
        let (alpha_t, sigma_t) = vp_alpha_sigma(self.sigmas[i]);
        let (_, sigma_s0) = vp_alpha_sigma(self.sigmas[i - 1]);
        let h = self.lambda(i) - self.lambda(i - 1);
        let b_h = (-h).exp_m1();
        let base = last_sample * (sigma_t / sigma_s0) - m0.clone() * (alpha_t * b_h);
        let new_difference = x0.clone() - m0.clone();
        let correction = match (&self.x0_before, self.last_order) {
            (Some(m1), 2) => {
                let r = (self.lambda(i - 2) - self.lambda(i - 1)) / h;
                let (rho_old, rho_new) = unic2_weights(h, r);
                (m1.clone() - m0.clone()) * (rho_old / r) + new_difference * rho_new
            }
            _ => new_difference * 0.5,
        };
        base - correction * (alpha_t * b_h)
    }
}

/// The weights (ρ_old, ρ_new) of UniC-2 (bh2, x₀ prediction) for the step `h` (in λ) and
/// r = (λ_prev − λ_s0)/h: the solution of `[[1, 1], [r, 1]]·ρ = b` with B = e^{−h} − 1,
/// φ₁ = B/(−h) − 1, φ₂ = φ₁/(−h) − ½, b = (φ₁/B, 2φ₂/B) (the UniPC paper's bh2 system, in
/// closed form; the determinant 1 − r is above 1 since r < 0).
fn unic2_weights(h: f64, r: f64) -> (f64, f64) {
    let hh = -h;
    let b_h = hh.exp_m1();
    let phi1 = b_h / hh - 1.0;
    let b1 = phi1 / b_h;
    let phi2 = phi1 / hh - 0.5;
    let b2 = 2.0 * phi2 / b_h;
    let rho_old = (b1 - b2) / (1.0 - r);
    (rho_old, b1 - rho_old)
}

/// diffusers img2img `get_timesteps` (for a scheduler of order 1, such as UniPC): the index
/// of the first timestep run at `strength` ∈ (0, 1], `steps − ⌊steps·strength⌋`; the run
/// then takes `⌊steps·strength⌋` steps. Strength 0.2 at 50 steps gives 40 (10 steps,
/// t = 200 … 20 with linspace spacing), 0.1 gives 45 (5 steps). Errors on a strength outside
/// (0, 1], zero steps, or a strength that leaves no step.
pub fn img2img_begin_index(num_inference_steps: usize, strength: f64) -> Result<usize, Error> {
    if !(strength > 0.0 && strength <= 1.0) {
        return Err(Error::invalid("strength", format!("a value in (0, 1] (found {strength})")));
    }
    if num_inference_steps == 0 {
        return Err(Error::invalid("num_inference_steps", "at least 1 (found 0)"));
    }
    let run = ((num_inference_steps as f64 * strength).floor() as usize).min(num_inference_steps);
    if run == 0 {
        return Err(Error::invalid(
            "strength",
            format!("a value leaving at least one of the {num_inference_steps} steps (found {strength})"),
        ));
    }
    Ok(num_inference_steps - run)
}

impl MultistepScheduler for UniPcMultistepScheduler {
    fn run_timesteps(&self) -> &[usize] {
        UniPcMultistepScheduler::run_timesteps(self)
    }

    fn step(&mut self, model_output: Tensor<4>, timestep: usize, sample: Tensor<4>) -> Result<Tensor<4>, Error> {
        UniPcMultistepScheduler::step(self, model_output, timestep, sample)
    }
}
