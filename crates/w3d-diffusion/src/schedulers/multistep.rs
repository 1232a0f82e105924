//! What the multistep solvers have in common for a sampling loop: they walk their timesteps in
//! order, each step taking the model output at the current sample and keeping the history the
//! next step needs.

use burn::tensor::Tensor;
use w3d_core::Error;

/// A sampler that steps through its timesteps one at a time, holding the history of earlier
/// steps ([`crate::DpmSolverMultistepScheduler`], [`crate::UniPcMultistepScheduler`]), so a
/// sampling loop can run either.
pub trait MultistepScheduler {
    /// The timesteps a run steps through, in sampling order (descending).
    fn run_timesteps(&self) -> &[usize];

    /// One step from `timestep` (the next of [`Self::run_timesteps`]) given the model output at
    /// `sample` (`[n, c, h, w]`); returns the sample at the following timestep.
    fn step(&mut self, model_output: Tensor<4>, timestep: usize, sample: Tensor<4>) -> Result<Tensor<4>, Error>;
}
