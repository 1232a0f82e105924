//! The CLI's commands, one test binary for all (one link instead of nine): `info`, `render` /
//! `eval` / `texture`, `prepare`, `reconstruct` and `demo`, hostile input to all of them,
//! `generate` / `run` / `demo --from-image` with the tiny model (and by Hub id), their training-free
//! accelerations, `batch`, `dataset` and `train`. Run one group with `cargo test --release -p wonder3d-cli --test commands <group>::`.

mod common;

#[path = "commands/acceleration.rs"]
mod acceleration;
#[path = "commands/batch.rs"]
mod batch;
#[path = "commands/dataset.rs"]
mod dataset;
#[path = "commands/generate.rs"]
mod generate;
#[path = "commands/hostile.rs"]
mod hostile;
#[path = "commands/hub.rs"]
mod hub;
/// The Hugging Face Hub on loopback of the facade's tests.
#[cfg(feature = "diffusion")]
#[path = "../../wonder3d/tests/facade/hub_server.rs"]
mod hub_server;
#[path = "commands/info.rs"]
mod info;
#[path = "commands/prepare.rs"]
mod prepare;
#[path = "commands/reconstruct.rs"]
mod reconstruct;
#[path = "commands/render_eval.rs"]
mod render_eval;
#[path = "commands/train.rs"]
mod train;
