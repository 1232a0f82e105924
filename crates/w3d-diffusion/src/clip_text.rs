//! CLIP text transformer (transformers `CLIPTextModel`): the text tower whose
//! `last_hidden_state` Stable Diffusion 1.5 — and the enhancer's UNet and ControlNet — take as
//! `encoder_hidden_states`.
//!
//! Token ids in (`[n][t]`, from [`crate::ClipTokenizer`]); out: `[n, t, hidden_size]`, the
//! hidden states after `final_layer_norm`, every position (no pooling, no attention mask, no
//! "clip skip": what the SD1.5 pipelines use, `docs/weights.md`). The layers are the vision
//! tower's ([`crate::ClipVision`]) with a causal mask: token `i` sees tokens `0..=i`.

use std::path::Path;
use std::sync::Arc;

use burn::module::{Module, Param};
use burn::tensor::{Device, Int, Tensor, TensorData};
use w3d_core::Error;

use crate::clip::EncoderLayer;
use crate::config::ClipTextConfig;
use crate::nn::LayerNorm;
use crate::weights::{Init, NamedParam, ParamSource, Precision, SafetensorsFile, WeightStorage};

/// The CLIP text encoder (see the module docs).
#[derive(Module, Debug)]
pub struct ClipText {
    /// Token embedding, `[vocab_size, hidden_size]`.
    token_embedding: Param<Tensor<2>>,
    /// Learnt absolute position embedding, `[max_position_embeddings, hidden_size]`.
    position_embedding: Param<Tensor<2>>,
    layers: Vec<EncoderLayer>,
    final_layer_norm: LayerNorm,
    #[module(skip)]
    config: ClipTextConfig,
    #[module(skip)]
    names: Arc<Vec<NamedParam>>,
}

impl ClipText {
    /// Loads `config` with the weights of a transformers `model.safetensors` (keys
    /// `text_model.…`; the `text_model.embeddings.position_ids` buffer older files hold is
    /// accepted and ignored).
    pub fn load(config: &ClipTextConfig, weights: impl AsRef<Path>, device: &Device) -> Result<Self, Error> {
        Self::load_stored(config, weights.as_ref(), device, WeightStorage::F32)
    }

    fn load_stored(
        config: &ClipTextConfig,
        weights: &Path,
        device: &Device,
        storage: WeightStorage,
    ) -> Result<Self, Error> {
        config.validate()?;
        let mut file = SafetensorsFile::open(weights)?;
        let mut p = ParamSource::from_file(&mut file, str::to_string, device).storing(storage);
        p.ignore(|k| k == "text_model.embeddings.position_ids");
        let mut model = Self::build(config, &mut p);
        model.names = Arc::new(p.take_names());
        p.finish()?;
        Ok(model)
    }

    /// Loads `config.json` and `model.safetensors` (or `model.fp16.safetensors`) from a
    /// `text_encoder/` folder.
    pub fn from_dir(dir: impl AsRef<Path>, device: &Device) -> Result<Self, Error> {
        Self::from_dir_with(dir, device, WeightStorage::F32)
    }

    /// [`ClipText::from_dir`] with the linear weights held in `storage` (embeddings and norms
    /// stay f32; arithmetic is f32 whatever the storage, see [`crate::UNet::from_dir_with`]).
    pub fn from_dir_with(dir: impl AsRef<Path>, device: &Device, storage: WeightStorage) -> Result<Self, Error> {
        let dir = dir.as_ref();
        let config = ClipTextConfig::from_file(dir.join("config.json"))?;
        Self::load_stored(&config, &crate::weights::find_weights(dir, "model")?, device, storage)
    }

    /// `config` with seeded random weights (same seed, same values): for shape, speed and
    /// memory checks at the real size without a checkpoint.
    pub fn random(config: &ClipTextConfig, seed: u64, device: &Device) -> Result<Self, Error> {
        config.validate()?;
        let mut p = ParamSource::random(seed, device);
        let mut model = Self::build(config, &mut p);
        model.names = Arc::new(p.take_names());
        Ok(model)
    }

    /// Writes `config.json` and `model.safetensors` (transformers keys) into `dir`, a
    /// `text_encoder/` folder ([`ClipText::from_dir`] reads it back).
    pub fn save(&self, dir: impl AsRef<Path>, precision: Precision) -> Result<(), Error> {
        let tensors = crate::weights::collect_named(self, &self.names)?;
        let config = crate::weights::config_json(
            &self.config,
            &[("model_type", "clip_text_model"), ("architectures", "CLIPTextModel")],
        )?;
        crate::weights::write_checkpoint(dir.as_ref(), "model.safetensors", &tensors, &config, precision)
    }

    /// The config this model was built from.
    pub fn config(&self) -> &ClipTextConfig {
        &self.config
    }

    fn build(c: &ClipTextConfig, p: &mut ParamSource) -> Self {
        let d = c.hidden_size;
        let init = Init::Uniform { fan_in: d };
        let token_embedding = p.param("text_model.embeddings.token_embedding.weight", [c.vocab_size, d], init);
        let position_embedding =
            p.param("text_model.embeddings.position_embedding.weight", [c.max_position_embeddings, d], init);
        let eps = c.layer_norm_eps;
        let layers = (0..c.num_hidden_layers)
            .map(|l| EncoderLayer::load(p, &format!("text_model.encoder.layers.{l}"), d, c.intermediate_size, eps))
            .collect();
        let final_layer_norm = LayerNorm::load(p, "text_model.final_layer_norm", d, eps);
        Self { token_embedding, position_embedding, layers, final_layer_norm, config: c.clone(), names: Arc::default() }
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
        let mut x = tokens + positions;
        for layer in &self.layers {
            x = layer.forward(x, c.num_attention_heads, &c.hidden_act, true);
        }
        Ok(self.final_layer_norm.forward(x))
    }
}
