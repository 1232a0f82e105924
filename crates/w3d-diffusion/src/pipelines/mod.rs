//! Pipelines over the models and samplers: classifier-free guidance and seeded noise
//! ([`guidance`]), training-free accelerations of a sampling loop ([`acceleration`]), one RGBA image → six views × {normal, colour} ([`multiview`]), and the
//! refinement stage's enhancer ([`enhancer`]: one joint img2img call over 2×2 grids of views).

pub mod acceleration;
pub mod guidance;

pub mod multiview;

pub mod enhancer;
