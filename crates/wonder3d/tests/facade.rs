//! The facade's integration tests, in one test binary (one link instead of 5). Run one group with
//! `cargo test --release -p wonder3d --test facade <group>::`.

#[path = "facade/batch.rs"]
mod batch;
#[path = "facade/dataset.rs"]
mod dataset;
#[cfg(feature = "diffusion")]
#[path = "facade/generate.rs"]
mod generate;
#[cfg(feature = "diffusion")]
#[path = "facade/hub.rs"]
mod hub;
#[cfg(feature = "diffusion")]
#[path = "facade/hub_server.rs"]
mod hub_server;
#[path = "facade/refine.rs"]
mod refine;
