//! Pipelines over the models and samplers: classifier-free guidance and seeded noise
//! ([`guidance`]), one RGBA image → six views × {normal, colour} ([`multiview`]), and the
//! refinement stage's enhancer ([`enhancer`]: one joint img2img call over 2×2 grids of views).

pub mod guidance;

pub mod multiview;

pub mod enhancer;
