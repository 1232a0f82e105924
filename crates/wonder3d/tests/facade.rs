//! The facade's integration tests, in one test binary (one link instead of 3). Run one group with
//! `cargo test --release -p wonder3d --test facade <group>::`.

#[path = "facade/batch.rs"]
mod batch;
#[path = "facade/dataset.rs"]
mod dataset;
#[path = "facade/refine.rs"]
mod refine;
