//! diffusers building blocks: ResNet block with time embedding, down/up-sampling, the
//! attention layer, the spatial transformer (`Transformer2DModel`) with self-attention,
//! cross-attention and GEGLU feed-forward, and the timestep embedding MLP.

use burn::module::Module;
use burn::tensor::Tensor;
use burn::tensor::activation::silu;

use crate::loading::weights::{Init, ParamSource};
use crate::nn::{Conv2d, GroupNorm, LayerNorm, Linear, multi_head_attention};

/// `ResnetBlock2D`: GroupNorm → SiLU → conv → (+ time embedding) → GroupNorm → SiLU → conv,
/// plus a (1x1-projected) skip connection, divided by `output_scale`.
#[derive(Module, Debug)]
pub struct ResnetBlock {
    norm1: GroupNorm,
    conv1: Conv2d,
    time_emb_proj: Option<Linear>,
    norm2: GroupNorm,
    conv2: Conv2d,
    conv_shortcut: Option<Conv2d>,
    output_scale: f64,
}

/// Shape of a ResNet block.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ResnetShape {
    pub c_in: usize,
    pub c_out: usize,
    pub temb: Option<usize>,
    pub groups: usize,
    pub eps: f64,
    pub output_scale: f64,
}

impl ResnetBlock {
    pub(crate) fn load(p: &mut ParamSource, key: &str, s: ResnetShape) -> Self {
        Self {
            norm1: GroupNorm::load(p, &format!("{key}.norm1"), s.groups, s.c_in, s.eps),
            conv1: Conv2d::load(p, &format!("{key}.conv1"), s.c_in, s.c_out, 3, 1, 1, true),
            time_emb_proj: s.temb.map(|t| Linear::load(p, &format!("{key}.time_emb_proj"), t, s.c_out, true)),
            norm2: GroupNorm::load(p, &format!("{key}.norm2"), s.groups, s.c_out, s.eps),
            conv2: Conv2d::load(p, &format!("{key}.conv2"), s.c_out, s.c_out, 3, 1, 1, true),
            conv_shortcut: (s.c_in != s.c_out)
                .then(|| Conv2d::load(p, &format!("{key}.conv_shortcut"), s.c_in, s.c_out, 1, 1, 0, true)),
            output_scale: s.output_scale,
        }
    }

    /// `x [n, c_in, h, w]`, `temb_silu` = SiLU of the time embedding `[n, temb]`.
    pub fn forward(&self, x: Tensor<4>, temb_silu: Option<&Tensor<2>>) -> Tensor<4> {
        crate::compute::record(crate::compute::WorkKind::ResnetBlock, 1);
        let mut h = self.conv1.forward(self.norm1.forward_silu(x.clone()));
        if let (Some(proj), Some(t)) = (&self.time_emb_proj, temb_silu) {
            let t = proj.forward(t.clone());
            let [n, c] = t.dims();
            h = h + t.reshape([n, c, 1, 1]);
        }
        let h = self.conv2.forward(self.norm2.forward_silu(h));
        let skip = match &self.conv_shortcut {
            Some(conv) => conv.forward(x),
            None => x,
        };
        let out = skip + h;
        if self.output_scale == 1.0 { out } else { out / self.output_scale }
    }
}

/// `Downsample2D` with a stride-2 3x3 convolution (`padding = 0` pads right/bottom by one,
/// as diffusers does).
#[derive(Module, Debug)]
pub struct Downsample {
    conv: Conv2d,
    pad_right_bottom: bool,
}

impl Downsample {
    pub(crate) fn load(p: &mut ParamSource, key: &str, channels: usize, padding: usize) -> Self {
        Self {
            conv: Conv2d::load(p, &format!("{key}.conv"), channels, channels, 3, 2, padding, true),
            pad_right_bottom: padding == 0,
        }
    }

    /// Halves the spatial size.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let x = if self.pad_right_bottom { x.pad((0, 1, 0, 1), burn::tensor::ops::PadMode::Constant(0.0)) } else { x };
        self.conv.forward(x)
    }
}

/// `Upsample2D`: nearest-neighbour ×2 then a 3x3 convolution.
#[derive(Module, Debug)]
pub struct Upsample {
    conv: Conv2d,
}

impl Upsample {
    pub(crate) fn load(p: &mut ParamSource, key: &str, channels: usize) -> Self {
        Self { conv: Conv2d::load(p, &format!("{key}.conv"), channels, channels, 3, 1, 1, true) }
    }

    /// Doubles the spatial size.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.conv.forward(upsample_nearest2x(x))
    }
}

/// Nearest-neighbour ×2 up-sampling of `[n, c, h, w]`.
pub fn upsample_nearest2x(x: Tensor<4>) -> Tensor<4> {
    let [n, c, h, w] = x.dims();
    let x: Tensor<6> = x.reshape([n, c, h, 1, w, 1]);
    x.expand([n, c, h, 2, w, 2]).reshape([n, c, 2 * h, 2 * w])
}

/// IP tokens for one UNet call: `[n, tokens, cross_attention_dim]`, one row per UNet batch row,
/// and the scale of the image attention (1.0 in the authors' run; 0 leaves the UNet's output
/// exactly as without tokens).
#[derive(Clone, Debug)]
pub struct IpTokens {
    /// Image tokens `[n, tokens, cross_attention_dim]` (row `i` conditions UNet row `i`).
    pub tokens: Tensor<3>,
    /// Weight of the image attention added to the text attention.
    pub scale: f32,
}

/// diffusers `Attention` on token sequences: q/k/v projections, multi-head SDPA, output
/// projection (`to_out.0`); as a UNet cross-attention (`attn2`) it may carry an IP-Adapter's
/// image keys and values (see [`Attention::forward_with_ip`]).
#[derive(Module, Debug)]
pub struct Attention {
    to_q: Linear,
    to_k: Linear,
    to_v: Linear,
    to_out: Linear,
    heads: usize,
    /// The IP-Adapter's `to_k_ip` / `to_v_ip` (cross-attention layers with an adapter loaded).
    ip: Option<IpKeyValue>,
}

/// An IP-Adapter's projections of the image tokens to keys and values of one cross-attention
/// layer: `to_k_ip`, `to_v_ip`, Linear(cross_attention_dim → layer width, no bias).
#[derive(Module, Debug)]
pub(crate) struct IpKeyValue {
    pub(crate) to_k_ip: Linear,
    pub(crate) to_v_ip: Linear,
}

impl Attention {
    /// `dim` query width, `context_dim` key/value input width, `bias` on q/k/v.
    pub(crate) fn load(
        p: &mut ParamSource,
        key: &str,
        dim: usize,
        context_dim: usize,
        heads: usize,
        bias: bool,
    ) -> Self {
        Self::load_with_out_init(p, key, dim, context_dim, heads, bias, Init::Uniform { fan_in: dim })
    }

    /// As `load`, with `out_init` for the output projection's weight when the model is
    /// randomly initialised (zeros for Wonder3D's fresh cross-domain attention).
    fn load_with_out_init(
        p: &mut ParamSource,
        key: &str,
        dim: usize,
        context_dim: usize,
        heads: usize,
        bias: bool,
        out_init: Init,
    ) -> Self {
        Self {
            to_q: Linear::load(p, &format!("{key}.to_q"), dim, dim, bias),
            to_k: Linear::load(p, &format!("{key}.to_k"), context_dim, dim, bias),
            to_v: Linear::load(p, &format!("{key}.to_v"), context_dim, dim, bias),
            to_out: Linear::load_init(p, &format!("{key}.to_out.0"), dim, dim, true, out_init),
            heads,
            ip: None,
        }
    }

    /// The layer's width (query, output and IP key/value width).
    pub(crate) fn width(&self) -> usize {
        self.to_q.weight.dims()[1]
    }

    /// Whether the layer has an IP-Adapter's image keys and values.
    pub(crate) fn has_ip(&self) -> bool {
        self.ip.is_some()
    }

    /// Gives the layer an IP-Adapter's image key / value projections.
    pub(crate) fn set_ip(&mut self, ip: IpKeyValue) {
        self.ip = Some(ip);
    }

    /// `x [b, t, dim]` attends to `context [b, s, context_dim]` (or to itself).
    pub fn forward(&self, x: Tensor<3>, context: Option<&Tensor<3>>) -> Tensor<3> {
        let context = context.cloned().unwrap_or_else(|| x.clone());
        let q = self.to_q.forward(x);
        let k = self.to_k.forward(context.clone());
        let v = self.to_v.forward(context);
        self.to_out.forward(multi_head_attention(q, k, v, self.heads))
    }

    /// The cross-attention of `x [b, t, dim]` to `context [b, s, context_dim]` with the
    /// IP-Adapter's decoupled image attention (docs/weights.md, "IP-Adapter"):
    /// `to_out(SDPA(q, K_text, V_text) + scale · SDPA(q, to_k_ip(ip), to_v_ip(ip)))`, the same
    /// queries and heads for both, no mask; `ip.tokens` is `[b, n_ip, context_dim]`. Without
    /// tokens, without an adapter in this layer or at scale 0 it is exactly
    /// [`Attention::forward`] (as diffusers, which skips the image attention at scale 0).
    pub fn forward_with_ip(&self, x: Tensor<3>, context: &Tensor<3>, ip: Option<&IpTokens>) -> Tensor<3> {
        let (Some(ip), Some(kv)) = (ip, &self.ip) else {
            return self.forward(x, Some(context));
        };
        if ip.scale == 0.0 {
            return self.forward(x, Some(context));
        }
        let q = self.to_q.forward(x);
        let k = self.to_k.forward(context.clone());
        let v = self.to_v.forward(context.clone());
        let text = multi_head_attention(q.clone(), k, v, self.heads);
        let k_ip = kv.to_k_ip.forward(ip.tokens.clone());
        let v_ip = kv.to_v_ip.forward(ip.tokens.clone());
        let image = multi_head_attention(q, k_ip, v_ip, self.heads);
        self.to_out.forward(text + image * ip.scale)
    }
}

/// `BasicTransformerBlock`: pre-norm self-attention, cross-attention and GEGLU feed-forward,
/// each with a residual connection; as Wonder3D's `BasicMVTransformerBlock` (see the
/// [`crate::models::unet`] module docs) the self-attention may be multi-view, a cross-domain attention
/// (`attn_joint_mid`) may follow it and another (`attn_joint_last`) may follow the
/// feed-forward.
#[derive(Module, Debug)]
pub struct TransformerBlock {
    norm1: LayerNorm,
    attn1: Attention,
    norm_joint_mid: Option<LayerNorm>,
    attn_joint_mid: Option<Attention>,
    norm_joint_last: Option<LayerNorm>,
    attn_joint_last: Option<Attention>,
    norm2: LayerNorm,
    attn2: Attention,
    norm3: LayerNorm,
    ff_proj: Linear,
    ff_out: Linear,
    /// Images per multi-view group (1: plain self-attention).
    views: usize,
    /// Whether the block sits at the model's highest-resolution level, where its multi-view
    /// self-attention may run on merged tokens ([`crate::compute::PassSettings::token_merge`]).
    first_level: bool,
}

impl TransformerBlock {
    fn load(p: &mut ParamSource, key: &str, s: &TransformerShape) -> Self {
        let (dim, heads) = (s.channels, s.heads);
        let inner = 4 * dim;
        let norm1 = LayerNorm::load(p, &format!("{key}.norm1"), dim, 1e-5);
        let attn1 = Attention::load(p, &format!("{key}.attn1"), dim, dim, heads, false);
        // Wonder3D: a fresh cross-domain attention has a zero output weight, so it adds only
        // its output bias (the same for every token): it starts without cross-domain mixing.
        let joint = |p: &mut ParamSource, name: &str| {
            let norm = LayerNorm::load(p, &format!("{key}.norm_joint_{name}"), dim, 1e-5);
            let attn = Attention::load_with_out_init(
                p,
                &format!("{key}.attn_joint_{name}"),
                dim,
                dim,
                heads,
                false,
                Init::Zeros,
            );
            (Some(norm), Some(attn))
        };
        let (norm_joint_mid, attn_joint_mid) = if s.cross_domain_mid { joint(p, "mid") } else { (None, None) };
        let norm2 = LayerNorm::load(p, &format!("{key}.norm2"), dim, 1e-5);
        let attn2 = Attention::load(p, &format!("{key}.attn2"), dim, s.cross_dim, heads, false);
        let norm3 = LayerNorm::load(p, &format!("{key}.norm3"), dim, 1e-5);
        let ff_proj = Linear::load(p, &format!("{key}.ff.net.0.proj"), dim, 2 * inner, true);
        let ff_out = Linear::load(p, &format!("{key}.ff.net.2"), inner, dim, true);
        let (norm_joint_last, attn_joint_last) = if s.cross_domain_last { joint(p, "last") } else { (None, None) };
        Self {
            norm1,
            attn1,
            norm_joint_mid,
            attn_joint_mid,
            norm_joint_last,
            attn_joint_last,
            norm2,
            attn2,
            norm3,
            ff_proj,
            ff_out,
            views: s.views,
            first_level: s.first_level,
        }
    }

    /// `x [n, tokens, dim]` with `tokens = h·w` of an `(h, w)` latent grid; with multi-view
    /// attention `n` is a multiple of the view count, with cross-domain attention `n` is even
    /// (`[normal half, colour half]`); `ip` the IP-Adapter tokens of the cross-attention
    /// (`[n, n_ip, cross_dim]`), if any.
    fn forward(&self, x: Tensor<3>, context: &Tensor<3>, ip: Option<&IpTokens>, hw: (usize, usize)) -> Tensor<3> {
        crate::compute::record(crate::compute::WorkKind::TransformerBlock, 1);
        let attn1 = |t: Tensor<3>| self.attn1.forward(t, None);
        let normed = self.norm1.forward(x.clone());
        let x = match self.token_merge() {
            Some(ratio) => within_views(normed, self.views, |t| {
                crate::kernels::token_merge::with_merged_tokens(t, self.views, hw, ratio, attn1)
            }),
            None => within_views(normed, self.views, attn1),
        } + x;
        let x = joint_attention(x, self.norm_joint_mid.as_ref(), self.attn_joint_mid.as_ref());
        let x = self.attn2.forward_with_ip(self.norm2.forward(x.clone()), context, ip) + x;
        let x = self.feed_forward(self.norm3.forward(x.clone())) + x;
        joint_attention(x, self.norm_joint_last.as_ref(), self.attn_joint_last.as_ref())
    }

    /// The fraction of tokens merged before this block's self-attention: the pass's
    /// [`crate::compute::PassSettings::token_merge`] when it is positive and the block sits at
    /// the highest-resolution level, otherwise `None` (the plain attention). That level holds
    /// the most expensive self-attention of both models that run here: the multi-view
    /// attention over 6 × 1024 tokens of Wonder3D++'s UNet, and the enhancer's over 128² tokens
    /// per grid (ToMe for Stable Diffusion merges there too).
    fn token_merge(&self) -> Option<f32> {
        let ratio = crate::compute::settings().token_merge;
        (self.first_level && ratio > 0.0).then_some(ratio)
    }

    /// The GEGLU feed-forward `ff_out(hidden · gelu(gate))`, `[hidden, gate] = ff_proj(x)`,
    /// on groups of images small enough that the projection holds at most
    /// [`FEED_FORWARD_MAX_VALUES`] values at a time (tokens are independent here, so the
    /// numbers are the same as on the whole batch).
    fn feed_forward(&self, x: Tensor<3>) -> Tensor<3> {
        let t = x.dims()[1];
        let two_inner = self.ff_proj.weight.dims()[1];
        let group = (FEED_FORWARD_MAX_VALUES / (t * two_inner).max(1)).max(1);
        let geglu = |x: Tensor<3>| self.ff_out.forward(crate::nn::geglu(self.ff_proj.forward(x)));
        crate::nn::in_groups(x, group, geglu)
    }
}

/// Largest GEGLU projection (`images × tokens × 2·inner` values) a transformer block computes
/// at once. Without a bound, the 32×32 level of a guided multi-view step (24 images × 1024
/// tokens × 2560) holds 63 M values (252 MB) plus two products of half that size; in groups
/// of images below 8 M values the real-size step's peak memory drops by 0.1–0.2 GiB for the
/// same numbers (`docs/benchmarks.md`; a bound of 4 M saved nothing more).
pub const FEED_FORWARD_MAX_VALUES: usize = 1 << 23;

/// The residual cross-domain attention step `x + attn(norm(x))` (the attention joint over both
/// domains' tokens of a view, see [`across_domains`]), or `x` when the block has none there.
fn joint_attention(x: Tensor<3>, norm: Option<&LayerNorm>, attn: Option<&Attention>) -> Tensor<3> {
    match (norm, attn) {
        (Some(norm), Some(attn)) => across_domains(norm.forward(x.clone()), |t| attn.forward(t, None)) + x,
        _ => x,
    }
}

/// Applies the token-sequence map `f` to the tokens of each group of `views` consecutive
/// images as one sequence: `[n, t, c]` → `[n / views, views · t, c]` → back. With a
/// self-attention as `f`, every view's queries attend over the keys of all views of its group
/// (Wonder3D's multi-view attention, whose K/V are reshaped to the group and repeated per view).
fn within_views(x: Tensor<3>, views: usize, f: impl FnOnce(Tensor<3>) -> Tensor<3>) -> Tensor<3> {
    if views == 1 {
        return f(x);
    }
    let [n, t, c] = x.dims();
    f(x.reshape([n / views, views * t, c])).reshape([n, t, c])
}

/// Applies the token-sequence map `f` to the tokens of image `i` of the first half of the
/// batch and image `i` of the second half as one sequence (`[n, t, c]` → `[n / 2, 2t, c]` →
/// back). With a self-attention as `f`, both domains' queries attend over the concatenated
/// normal and colour tokens of the same view (Wonder3D's cross-domain attention).
fn across_domains(x: Tensor<3>, f: impl FnOnce(Tensor<3>) -> Tensor<3>) -> Tensor<3> {
    let [n, t, c] = x.dims();
    let half = n / 2;
    let paired: Tensor<4> = x.reshape([2, half, t, c]).swap_dims(0, 1);
    let out = f(paired.reshape([half, 2 * t, c]));
    let out: Tensor<4> = out.reshape([half, 2, t, c]).swap_dims(0, 1);
    out.reshape([n, t, c])
}

/// The transformer's in/out projection: a 1x1 convolution or a linear layer.
#[derive(Module, Debug)]
enum Projection {
    Conv(Conv2d),
    Linear(Linear),
}

/// `Transformer2DModel` (continuous input): GroupNorm → projection in → transformer blocks on
/// the `h·w` tokens → projection out, plus the input.
#[derive(Module, Debug)]
pub struct SpatialTransformer {
    norm: GroupNorm,
    proj_in: Projection,
    blocks: Vec<TransformerBlock>,
    proj_out: Projection,
}

/// Shape of a spatial transformer.
#[derive(Clone, Copy, Debug)]
pub(crate) struct TransformerShape {
    pub channels: usize,
    pub heads: usize,
    pub layers: usize,
    pub cross_dim: usize,
    pub groups: usize,
    pub linear_projection: bool,
    /// Images per multi-view attention group (1: plain self-attention).
    pub views: usize,
    /// Whether the blocks have the cross-domain attention after the self-attention
    /// (`attn_joint_mid`).
    pub cross_domain_mid: bool,
    /// Whether the blocks have the cross-domain attention after the feed-forward
    /// (`attn_joint_last`).
    pub cross_domain_last: bool,
    /// Whether the transformer sits at the model's highest-resolution level (level 0), the
    /// only level where [`crate::compute::PassSettings::token_merge`] applies.
    pub first_level: bool,
}

impl SpatialTransformer {
    pub(crate) fn load(p: &mut ParamSource, key: &str, s: TransformerShape) -> Self {
        let c = s.channels;
        let proj = |p: &mut ParamSource, name: &str| {
            let k = format!("{key}.{name}");
            if s.linear_projection {
                Projection::Linear(Linear::load(p, &k, c, c, true))
            } else {
                Projection::Conv(Conv2d::load(p, &k, c, c, 1, 1, 0, true))
            }
        };
        let norm = GroupNorm::load(p, &format!("{key}.norm"), s.groups, c, 1e-6);
        let proj_in = proj(p, "proj_in");
        let blocks =
            (0..s.layers).map(|l| TransformerBlock::load(p, &format!("{key}.transformer_blocks.{l}"), &s)).collect();
        let proj_out = proj(p, "proj_out");
        Self { norm, proj_in, blocks, proj_out }
    }

    /// `x [n, c, h, w]`, `context [n, s, cross_dim]`.
    pub fn forward(&self, x: Tensor<4>, context: &Tensor<3>) -> Tensor<4> {
        self.forward_with_ip(x, context, None)
    }

    /// [`SpatialTransformer::forward`] with IP-Adapter tokens `[n, n_ip, cross_dim]` for the
    /// cross-attentions (see [`Attention::forward_with_ip`]).
    pub fn forward_with_ip(&self, x: Tensor<4>, context: &Tensor<3>, ip: Option<&IpTokens>) -> Tensor<4> {
        let [n, c, h, w] = x.dims();
        let residual = x.clone();
        let x = self.norm.forward(x);
        let to_tokens = |x: Tensor<4>| x.reshape([n, c, h * w]).swap_dims(1, 2);
        let mut tokens = match &self.proj_in {
            Projection::Conv(conv) => to_tokens(conv.forward(x)),
            Projection::Linear(lin) => lin.forward(to_tokens(x)),
        };
        for block in &self.blocks {
            tokens = block.forward(tokens, context, ip, (h, w));
        }
        let to_image = |t: Tensor<3>| t.swap_dims(1, 2).reshape([n, c, h, w]);
        let out = match &self.proj_out {
            Projection::Conv(conv) => conv.forward(to_image(tokens)),
            Projection::Linear(lin) => to_image(lin.forward(tokens)),
        };
        out + residual
    }
}

impl SpatialTransformer {
    /// The cross-attention (`attn2`) of every transformer block, in block order.
    pub(crate) fn cross_attentions(&self) -> impl Iterator<Item = &Attention> {
        self.blocks.iter().map(|b| &b.attn2)
    }

    /// [`SpatialTransformer::cross_attentions`], mutable (to add an IP-Adapter).
    pub(crate) fn cross_attentions_mut(&mut self) -> impl Iterator<Item = &mut Attention> {
        self.blocks.iter_mut().map(|b| &mut b.attn2)
    }
}

/// `TimestepEmbedding`: linear → SiLU → linear.
#[derive(Module, Debug)]
pub struct TimestepEmbedding {
    linear_1: Linear,
    linear_2: Linear,
}

impl TimestepEmbedding {
    pub(crate) fn load(p: &mut ParamSource, key: &str, d_in: usize, d_out: usize) -> Self {
        Self {
            linear_1: Linear::load(p, &format!("{key}.linear_1"), d_in, d_out, true),
            linear_2: Linear::load(p, &format!("{key}.linear_2"), d_out, d_out, true),
        }
    }

    /// `[n, d_in] → [n, d_out]`.
    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        self.linear_2.forward(silu(self.linear_1.forward(x)))
    }
}
