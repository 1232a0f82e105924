//! CLIP text transformer (transformers `CLIPTextModel`): the text tower whose
//! `last_hidden_state` Stable Diffusion 1.5 — and the enhancer's UNet and ControlNet — take as
//! `encoder_hidden_states`.
//!
//! Token ids in (`[n][t]`, from [`crate::ClipTokenizer`]); out: `[n, t, hidden_size]`, the
//! hidden states after `final_layer_norm`, every position (no pooling, no attention mask, no
//! "clip skip": what the SD1.5 pipelines use, `docs/weights.md`). The layers are the vision
//! tower's ([`crate::ClipVision`]) with a causal mask: token `i` sees tokens `0..=i`.

use std::sync::Arc;

use burn::module::{Module, Param};
use burn::tensor::{Int, Tensor, TensorData};
use w3d_core::Error;

use crate::loading::checkpoint::{self, Checkpoint};
use crate::loading::config::ClipTextConfig;
use crate::loading::weights::{Init, NamedParam, ParamSource};
use crate::models::clip::encoder::ClipEncoder;
use crate::nn::LayerNorm;

/// The CLIP text encoder (see the module docs).
#[derive(Module, Debug)]
pub struct ClipText {
    /// Token embedding, `[vocab_size, hidden_size]`.
    token_embedding: Param<Tensor<2>>,
    /// Learnt absolute position embedding, `[max_position_embeddings, hidden_size]`.
    position_embedding: Param<Tensor<2>>,
    encoder: ClipEncoder,
    final_layer_norm: LayerNorm,
    #[module(skip)]
    config: ClipTextConfig,
    #[module(skip)]
    names: Arc<Vec<NamedParam>>,
}

impl ClipText {
    checkpoint::checkpoint_methods!(ClipTextConfig, "text_encoder/");

    fn build(c: &ClipTextConfig, p: &mut ParamSource) -> Self {
        let d = c.hidden_size;
        let init = Init::Uniform { fan_in: d };
        let token_embedding = p.param("text_model.embeddings.token_embedding.weight", [c.vocab_size, d], init);
        let position_embedding =
            p.param("text_model.embeddings.position_embedding.weight", [c.max_position_embeddings, d], init);
        let eps = c.layer_norm_eps;
        let encoder = ClipEncoder::load(p, "text_model.encoder", c.num_hidden_layers, d, c.intermediate_size, eps);
        let final_layer_norm = LayerNorm::load(p, "text_model.final_layer_norm", d, eps);
        Self {
            token_embedding,
            position_embedding,
            encoder,
            final_layer_norm,
            config: c.clone(),
            names: Arc::default(),
        }
    }

    /// `last_hidden_state` `[n, t, hidden_size]` (after `final_layer_norm`) of token ids
    /// `[n][t]`: every row the same length `t` with `1 <= t <= max_position_embeddings`, every
    /// id below `vocab_size`. For SD1.5 the rows are [`crate::ClipTokenizer::encode`]'s 77 ids
    /// and the result is the UNet's `encoder_hidden_states`. Position `i` depends only on ids
    /// `0..=i` (causal attention).
    pub fn encode(&self, token_ids: &[Vec<u32>]) -> Result<Tensor<3>, Error> {
        let c = &self.config;
        let n = token_ids.len();
        let t = token_ids.first().map_or(0, Vec::len);
        if n == 0 || t == 0 || t > c.max_position_embeddings {
            return Err(Error::invalid(
                "token_ids",
                format!(
                    "at least one row of 1..={} tokens (found {n} rows, the first of {t})",
                    c.max_position_embeddings
                ),
            ));
        }
        let mut flat = Vec::with_capacity(n * t);
        for (row, ids) in token_ids.iter().enumerate() {
            if ids.len() != t {
                return Err(Error::invalid(
                    format!("token_ids[{row}]"),
                    format!("{t} tokens like row 0 (found {})", ids.len()),
                ));
            }
            for (col, &id) in ids.iter().enumerate() {
                if id as usize >= c.vocab_size {
                    return Err(Error::invalid(
                        format!("token_ids[{row}][{col}]"),
                        format!("an id below vocab_size {} (found {id})", c.vocab_size),
                    ));
                }
                flat.push(i64::from(id));
            }
        }
        let d = c.hidden_size;
        let device = self.token_embedding.device();
        let ids = Tensor::<1, Int>::from_data(TensorData::new(flat, [n * t]), &device);
        let tokens: Tensor<3> = self.token_embedding.val().select(0, ids).reshape([n, t, d]);
        let positions = self.position_embedding.val().slice([0..t, 0..d]).unsqueeze::<3>();
        let x = self.encoder.forward(tokens + positions, c.num_attention_heads, &c.hidden_act, true);
        Ok(self.final_layer_norm.forward(x))
    }
}

impl Checkpoint for ClipText {
    type Config = ClipTextConfig;
    const WEIGHTS_STEM: &'static str = "model";

    fn is_buffer(key: &str) -> bool {
        key == "text_model.embeddings.position_ids"
    }

    fn build(config: &ClipTextConfig, p: &mut ParamSource) -> Result<Self, Error> {
        Ok(ClipText::build(config, p))
    }

    fn set_names(&mut self, names: Vec<NamedParam>) {
        self.names = Arc::new(names);
    }

    fn names(&self) -> &[NamedParam] {
        &self.names
    }

    fn config(&self) -> &ClipTextConfig {
        &self.config
    }

    fn class_fields(&self) -> Vec<(&'static str, &'static str)> {
        vec![("model_type", "clip_text_model"), ("architectures", "CLIPTextModel")]
    }
}
