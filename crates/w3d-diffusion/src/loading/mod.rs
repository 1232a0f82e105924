//! Reading and writing checkpoints: the models' `config.json` files as diffusers and
//! transformers write them ([`config`]), `.safetensors` weights with the diffusers key names,
//! loaded streaming, stored in f32, f16 or bf16 ([`weights`]), and what every model's loading
//! and saving shares (`checkpoint`).

pub mod config;
pub mod weights;

pub(crate) mod checkpoint;
