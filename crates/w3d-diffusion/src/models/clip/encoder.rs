//! The transformer encoder both CLIP towers share (transformers `CLIPEncoder`): a stack of
//! pre-LayerNorm layers. The vision tower ([`crate::ClipVision`]) attends over all tokens; the
//! text tower ([`crate::ClipText`]) masks its attention causally. Token sequences are
//! `[n, t, d]`.

use burn::module::Module;
use burn::tensor::Tensor;
use burn::tensor::activation::{gelu, sigmoid};

use crate::loading::weights::ParamSource;
use crate::nn::{LayerNorm, Linear, causal_multi_head_attention, multi_head_attention};

/// One pre-LayerNorm transformer layer of a CLIP tower (transformers `CLIPEncoderLayer`):
/// `x + out_proj(attention(layer_norm1(x)))`, then `x + fc2(act(fc1(layer_norm2(x))))`. Both
/// towers run it through [`ClipEncoder`].
#[derive(Module, Debug)]
pub(crate) struct EncoderLayer {
    layer_norm1: LayerNorm,
    q_proj: Linear,
    k_proj: Linear,
    v_proj: Linear,
    out_proj: Linear,
    layer_norm2: LayerNorm,
    fc1: Linear,
    fc2: Linear,
}

impl EncoderLayer {
    /// The layer under `prefix` (e.g. `text_model.encoder.layers.3`): width `d`, MLP width
    /// `inter`, LayerNorm epsilon `eps`.
    pub(crate) fn load(p: &mut ParamSource, prefix: &str, d: usize, inter: usize, eps: f64) -> Self {
        Self {
            layer_norm1: LayerNorm::load(p, &format!("{prefix}.layer_norm1"), d, eps),
            q_proj: Linear::load(p, &format!("{prefix}.self_attn.q_proj"), d, d, true),
            k_proj: Linear::load(p, &format!("{prefix}.self_attn.k_proj"), d, d, true),
            v_proj: Linear::load(p, &format!("{prefix}.self_attn.v_proj"), d, d, true),
            out_proj: Linear::load(p, &format!("{prefix}.self_attn.out_proj"), d, d, true),
            layer_norm2: LayerNorm::load(p, &format!("{prefix}.layer_norm2"), d, eps),
            fc1: Linear::load(p, &format!("{prefix}.mlp.fc1"), d, inter, true),
            fc2: Linear::load(p, &format!("{prefix}.mlp.fc2"), inter, d, true),
        }
    }

    /// The layer applied to tokens `x [n, t, d]` with `heads` attention heads and the MLP
    /// activation `hidden_act` (`quick_gelu`, else exact `gelu`; configs validate it); with
    /// `causal`, token `i` attends to tokens `0..=i` only.
    pub(crate) fn forward(&self, x: Tensor<3>, heads: usize, hidden_act: &str, causal: bool) -> Tensor<3> {
        let h = self.layer_norm1.forward(x.clone());
        let (q, k, v) = (self.q_proj.forward(h.clone()), self.k_proj.forward(h.clone()), self.v_proj.forward(h));
        let attn =
            if causal { causal_multi_head_attention(q, k, v, heads) } else { multi_head_attention(q, k, v, heads) };
        let x = x + self.out_proj.forward(attn);
        let h = self.fc1.forward(self.layer_norm2.forward(x.clone()));
        let h = if hidden_act == "quick_gelu" { h.clone() * sigmoid(h * 1.702) } else { gelu(h) };
        x + self.fc2.forward(h)
    }
}

/// The stack of [`EncoderLayer`]s of one CLIP tower (transformers `CLIPEncoder`), keys
/// `{prefix}.layers.{i}`.
#[derive(Module, Debug)]
pub(crate) struct ClipEncoder {
    layers: Vec<EncoderLayer>,
}

impl ClipEncoder {
    /// `count` layers under `prefix` (e.g. `text_model.encoder`): width `d`, MLP width `inter`,
    /// LayerNorm epsilon `eps`.
    pub(crate) fn load(p: &mut ParamSource, prefix: &str, count: usize, d: usize, inter: usize, eps: f64) -> Self {
        let layers =
            (0..count).map(|l| EncoderLayer::load(p, &format!("{prefix}.layers.{l}"), d, inter, eps)).collect();
        Self { layers }
    }

    /// The layers applied in turn to `x [n, t, d]` (see [`EncoderLayer::forward`]).
    pub(crate) fn forward(&self, mut x: Tensor<3>, heads: usize, hidden_act: &str, causal: bool) -> Tensor<3> {
        for layer in &self.layers {
            x = layer.forward(x, heads, hidden_act, causal);
        }
        x
    }
}
