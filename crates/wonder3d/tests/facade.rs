//! The facade's integration tests, in one test binary (one link instead of 4). Run one group with
//! `cargo test --release -p wonder3d --test facade <group>::`.

#[path = "facade/batch.rs"]
mod batch;
#[path = "facade/dataset.rs"]
mod dataset;
#[cfg(feature = "diffusion")]
#[path = "facade/generate.rs"]
mod generate;
#[path = "facade/refine.rs"]
mod refine;
