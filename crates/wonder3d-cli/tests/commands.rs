//! The CLI's commands other than generate, batch and dataset, one test binary for all (one
//! link instead of five): `info`, `render` / `eval` / `texture`, `prepare`, `reconstruct` and
//! `demo`, and hostile input to all of them.

mod common;

#[path = "commands/hostile.rs"]
mod hostile;
#[path = "commands/info.rs"]
mod info;
#[path = "commands/prepare.rs"]
mod prepare;
#[path = "commands/reconstruct.rs"]
mod reconstruct;
#[path = "commands/render_eval.rs"]
mod render_eval;
