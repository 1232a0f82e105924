//! The samplers, as diffusers': DDIM sampling and DDIM inversion ([`ddim`]), the multistep
//! solvers DPM-Solver++(2M) ([`dpm_solver`]) and UniPC with img2img's start index ([`unipc`]),
//! all on the noise schedule they share ([`schedule`]); [`SamplerKind`] names one.
//!
//! Timesteps are integer training steps in `[0, T)` (T = `num_train_timesteps`). ᾱ_t
//! (`alphas_cumprod[t]`) is the signal fraction of the forward process
//! `x_t = √ᾱ_t·x_0 + √(1-ᾱ_t)·ε`.

pub mod multistep;
pub mod schedule;

pub mod ddim;
pub mod dpm_solver;
pub mod kind;
pub mod unipc;

pub use ddim::{DdimInverseScheduler, DdimScheduler, ddim_invert, ddim_sample};
pub use dpm_solver::DpmSolverMultistepScheduler;
pub use kind::SamplerKind;
pub use multistep::MultistepScheduler;
pub use schedule::Prediction;
pub use unipc::{UniPcMultistepScheduler, img2img_begin_index};
