//! `UNet2DConditionModel`: the denoiser of Stable Diffusion (image variations), with the
//! projection class embedding Wonder3D uses for its domain / camera switchers.
//!
//! Input: latents `[n, in_channels, h, w]` (h, w multiples of `2^(levels-1)`), one timestep
//! per image, conditioning tokens `[n, tokens, cross_attention_dim]` and, with
//! `class_embed_type = "projection"`, class labels `[n, projection_class_embeddings_input_dim]`.
//! Output: the prediction `[n, out_channels, h, w]`. [`UNet::forward_with`] also adds a
//! ControlNet's residuals ([`UNetExtra`], [`crate::models::controlnet`]) to the skip connections and
//! the mid block's output.
//!
//! Wonder3D's `UNetMV2DConditionModel` is the same network with multi-view block types
//! (`CrossAttnDownBlockMV2D`, `UNetMidBlockMV2DCrossAttn`, `CrossAttnUpBlockMV2D`) and the
//! config fields `num_views`, `cd_attention_mid` and `cd_attention_last` (`docs/weights.md`
//! lists the fields and weight keys):
//! - batch layout: `[normal half, colour half]` with a cross-domain attention, each half made
//!   of groups of `num_views` consecutive images (one object, views in rig order);
//! - multi-view attention: each image's self-attention attends over the tokens of all images
//!   of its group (no new weights);
//! - cross-domain attention (`attn_joint_mid`, `norm_joint_mid`, with `cd_attention_mid`):
//!   after the self-attention of every multi-view transformer block, image `i` of each half
//!   attends over the tokens of image `i` of both halves (pre-norm, residual). Random
//!   (fresh-training) initialisation zeroes its output projection's weight, so it starts
//!   without cross-domain mixing (it adds only its output bias; the identity when that bias
//!   is zero too);
//! - with `cd_attention_last` the same layer (`attn_joint_last`, `norm_joint_last`) follows
//!   the feed-forward of every multi-view transformer block as well (off in every shipped
//!   Wonder3D config; older checkpoints name it `attn_joint` / `norm_joint`);
//! - the domain / camera switchers enter as the projection class embedding (see
//!   [`crate::pipelines::multiview::switcher_labels`]).

use std::path::Path;
use std::sync::Arc;

use burn::module::Module;
use burn::tensor::activation::silu;
use burn::tensor::{Device, Tensor, TensorData};
use w3d_core::Error;

use crate::loading::checkpoint::{self, Checkpoint};
use crate::loading::config::UNetConfig;
use crate::loading::weights::{NamedParam, ParamSource, SafetensorsFile};
use crate::models::blocks::{
    Attention, Downsample, IpTokens, ResnetBlock, ResnetShape, SpatialTransformer, TimestepEmbedding, TransformerShape,
    Upsample,
};
use crate::nn::{Conv2d, GroupNorm};

/// One down level: ResNets (each optionally followed by a transformer) and a down-sampler.
#[derive(Module, Debug)]
struct DownBlock {
    resnets: Vec<ResnetBlock>,
    attentions: Vec<SpatialTransformer>,
    downsampler: Option<Downsample>,
}

/// One up level: ResNets on the concatenated skip (each optionally followed by a
/// transformer) and an up-sampler.
#[derive(Module, Debug)]
struct UpBlock {
    resnets: Vec<ResnetBlock>,
    attentions: Vec<SpatialTransformer>,
    upsampler: Option<Upsample>,
}

/// The input convolution, time (and class) embedding, down blocks and mid block: the part of
/// the UNet that a ControlNet copies (`ControlNetModel.from_unet`), built and run by one
/// implementation for both ([`UNet`], [`crate::models::controlnet::ControlNet`]).
#[derive(Module, Debug)]
pub(crate) struct DownPath {
    conv_in: Conv2d,
    time_embedding: TimestepEmbedding,
    class_embedding: Option<TimestepEmbedding>,
    down_blocks: Vec<DownBlock>,
    mid_resnets: Vec<ResnetBlock>,
    mid_attention: SpatialTransformer,
}

/// The shape of the spatial transformers of down level `level` (the mid block's is the last
/// level's) with `channels` channels; `multiview` for Wonder3D's multi-view block kinds, whose
/// transformers get the multi-view and cross-domain attention the config asks for.
pub(crate) fn transformer_shape(
    c: &UNetConfig,
    channels: usize,
    level: usize,
    multiview: bool,
) -> Result<TransformerShape, Error> {
    Ok(TransformerShape {
        channels,
        heads: c.heads(level)?,
        layers: c.transformer_layers(level)?,
        cross_dim: c.cross_attention_dim,
        groups: c.norm_num_groups,
        linear_projection: c.use_linear_projection,
        views: if multiview && c.multiview_attention { c.views() } else { 1 },
        cross_domain_mid: multiview && c.cd_attention_mid,
        cross_domain_last: multiview && c.cd_attention_last,
        first_level: level == 0,
    })
}

impl DownPath {
    /// Builds the down path of `c` (keys `conv_in`, `time_embedding`, `class_embedding`,
    /// `down_blocks.*`, `mid_block.*`); `transformer(channels, level, multiview)` gives the
    /// shape of each spatial transformer.
    pub(crate) fn load(
        c: &UNetConfig,
        p: &mut ParamSource,
        transformer: &dyn Fn(usize, usize, bool) -> Result<TransformerShape, Error>,
    ) -> Result<Self, Error> {
        let ch = &c.block_out_channels;
        let levels = ch.len();
        let temb = c.time_embed_dim();
        let (groups, eps) = (c.norm_num_groups, c.norm_eps);
        let resnet =
            |c_in, c_out, scale| ResnetShape { c_in, c_out, temb: Some(temb), groups, eps, output_scale: scale };
        let conv_in = Conv2d::load(p, "conv_in", c.in_channels, ch[0], 3, 1, 1, true);
        let time_embedding = TimestepEmbedding::load(p, "time_embedding", ch[0], temb);
        let class_embedding = match (c.class_embed_type.as_deref(), c.projection_class_embeddings_input_dim) {
            (Some("projection"), Some(d)) => Some(TimestepEmbedding::load(p, "class_embedding", d, temb)),
            _ => None,
        };

        let mut down_blocks = Vec::with_capacity(levels);
        let mut c_prev = ch[0];
        for (i, kind) in c.down_block_types.iter().enumerate() {
            let c_out = ch[i];
            let key = format!("down_blocks.{i}");
            let mut resnets = Vec::new();
            let mut attentions = Vec::new();
            for j in 0..c.layers_per_block {
                let c_in = if j == 0 { c_prev } else { c_out };
                resnets.push(ResnetBlock::load(p, &format!("{key}.resnets.{j}"), resnet(c_in, c_out, 1.0)));
                if kind.starts_with("CrossAttn") {
                    attentions.push(SpatialTransformer::load(
                        p,
                        &format!("{key}.attentions.{j}"),
                        transformer(c_out, i, UNetConfig::is_multiview_block(kind))?,
                    ));
                }
            }
            let downsampler = (i + 1 < levels)
                .then(|| Downsample::load(p, &format!("{key}.downsamplers.0"), c_out, c.downsample_padding));
            down_blocks.push(DownBlock { resnets, attentions, downsampler });
            c_prev = c_out;
        }

        let c_mid = ch[levels - 1];
        let scale = c.mid_block_scale_factor;
        let mid_resnets = vec![
            ResnetBlock::load(p, "mid_block.resnets.0", resnet(c_mid, c_mid, scale)),
            ResnetBlock::load(p, "mid_block.resnets.1", resnet(c_mid, c_mid, scale)),
        ];
        let mid_attention = SpatialTransformer::load(
            p,
            "mid_block.attentions.0",
            transformer(c_mid, levels - 1, c.multiview_mid_block())?,
        );
        Ok(Self { conv_in, time_embedding, class_embedding, down_blocks, mid_resnets, mid_attention })
    }

    /// Checks `sample [n, in_channels, h, w]` (h, w non-zero multiples of `2^(levels-1)`),
    /// `context [n, tokens, cross_attention_dim]` and `timesteps` (one per image or one for
    /// all); returns one timestep per image.
    pub(crate) fn check_inputs(
        c: &UNetConfig,
        sample: &Tensor<4>,
        timesteps: &[f32],
        context: &Tensor<3>,
    ) -> Result<Vec<f32>, Error> {
        let [n, channels, h, w] = sample.dims();
        if channels != c.in_channels {
            return Err(Error::invalid("sample", format!("{} channels (found {channels})", c.in_channels)));
        }
        let multiple = 1 << (c.block_out_channels.len() - 1);
        if h == 0 || w == 0 || !h.is_multiple_of(multiple) || !w.is_multiple_of(multiple) {
            return Err(Error::invalid("sample", format!("height and width multiples of {multiple} (found {h}x{w})")));
        }
        let [cn, _, cw] = context.dims();
        if cn != n || cw != c.cross_attention_dim {
            return Err(Error::invalid(
                "context",
                format!("[{n}, tokens, {}] (found {:?})", c.cross_attention_dim, context.dims()),
            ));
        }
        match timesteps.len() {
            1 => Ok(vec![timesteps[0]; n]),
            len if len == n => Ok(timesteps.to_vec()),
            len => Err(Error::invalid("timesteps", format!("1 or {n} values (found {len})"))),
        }
    }

    /// The shapes of the skip tensors [`DownPath::forward_until`] returns for an `[n, _, h, w]`
    /// sample, in order: the `conv_in` output, then per level every ResNet (+ transformer)
    /// output and the down-sampler's output (12 for Stable Diffusion 1.5). These are the
    /// shapes of a ControlNet's down residuals.
    pub(crate) fn skip_shapes(c: &UNetConfig, n: usize, h: usize, w: usize) -> Vec<[usize; 4]> {
        let ch = &c.block_out_channels;
        let mut shapes = vec![[n, ch[0], h, w]];
        let (mut h, mut w) = (h, w);
        for (i, &c_out) in ch.iter().enumerate() {
            shapes.extend(std::iter::repeat_n([n, c_out, h, w], c.layers_per_block));
            if i + 1 < ch.len() {
                (h, w) = (h / 2, w / 2);
                shapes.push([n, c_out, h, w]);
            }
        }
        shapes
    }

    /// SiLU of the time embedding `[n, time_embed_dim]` of one timestep per image, plus the
    /// class embedding of `class_labels` `[n, projection_class_embeddings_input_dim]` when the
    /// model has one (then the labels are required; without one they are refused).
    pub(crate) fn embed_time(
        &self,
        c: &UNetConfig,
        timesteps: &[f32],
        class_labels: Option<Tensor<2>>,
        device: &Device,
    ) -> Result<Tensor<2>, Error> {
        let n = timesteps.len();
        let mut temb = self.time_embedding.forward(timestep_features(c, timesteps, device));
        match (&self.class_embedding, class_labels) {
            (Some(embedding), Some(labels)) => {
                let want = c.projection_class_embeddings_input_dim.unwrap_or(0);
                if labels.dims() != [n, want] {
                    return Err(Error::invalid("class_labels", format!("[{n}, {want}] (found {:?})", labels.dims())));
                }
                temb = temb + embedding.forward(labels);
            }
            (Some(_), None) => return Err(Error::invalid("class_labels", "labels for class_embed_type projection")),
            (None, Some(_)) => return Err(Error::invalid("class_labels", "none (the model has no class embedding)")),
            (None, None) => {}
        }
        Ok(silu(temb))
    }

    /// Runs `conv_in` on `sample` (checked by [`DownPath::check_inputs`]), adds `added` (a
    /// ControlNet's condition embedding, `[n, block_out_channels[0], h, w]`), then the down
    /// blocks and the mid block with `temb_silu` ([`DownPath::embed_time`]) and `context`.
    /// Returns the skip tensors (shapes: [`DownPath::skip_shapes`]) and the mid block's
    /// output; with `last_skip = Some(d)` it stops after skip `d` and returns the skips
    /// `0..=d` and no mid block output (the shallow branch of a cached pass, [`FeatureCache`]).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn forward_until(
        &self,
        c: &UNetConfig,
        sample: Tensor<4>,
        temb_silu: &Tensor<2>,
        context: &Tensor<3>,
        added: Option<Tensor<4>>,
        ip: Option<&IpTokens>,
        last_skip: Option<usize>,
    ) -> (Vec<Tensor<4>>, Option<Tensor<4>>) {
        let temb = temb_silu;
        let done = |skips: &Vec<Tensor<4>>| last_skip.is_some_and(|d| skips.len() > d);
        let mut x = if c.center_input_sample { sample * 2.0 - 1.0 } else { sample };
        x = self.conv_in.forward(x);
        if let Some(added) = added {
            x = x + added;
        }
        let mut skips = vec![x.clone()];
        for block in &self.down_blocks {
            for (j, resnet) in block.resnets.iter().enumerate() {
                if done(&skips) {
                    return (skips, None);
                }
                x = resnet.forward(x, Some(temb));
                if let Some(attn) = block.attentions.get(j) {
                    x = attn.forward_with_ip(x, context, ip);
                }
                skips.push(x.clone());
            }
            if let Some(down) = &block.downsampler {
                if done(&skips) {
                    return (skips, None);
                }
                x = down.forward(x);
                skips.push(x.clone());
            }
        }
        if done(&skips) {
            return (skips, None);
        }
        x = self.mid_resnets[0].forward(x, Some(temb));
        x = self.mid_attention.forward_with_ip(x, context, ip);
        x = self.mid_resnets[1].forward(x, Some(temb));
        (skips, Some(x))
    }
}

/// The feature one branch of the sampling loop keeps between UNet passes for DeepCache (Ma
/// et al. 2023, "DeepCache: Accelerating Diffusion Models for Free"): the input of the up
/// path's layer that consumes skip `depth`, from the last full pass. The deep part of the
/// UNet changes slowly from one denoising step to the next, so the passes between two full
/// ones ([`UNet::forward_cached`] with `reuse`) compute only the shallow branch — `conv_in`,
/// the down layers up to skip `depth` and the last `depth + 1` up layers — and take the deep
/// part's contribution from here.
///
/// Skips are numbered as [`UNet`]'s down path produces them: 0 is `conv_in`'s output, then
/// every down layer's output and every down-sampler's (12 in Stable Diffusion 1.5, whose
/// first level gives skips 1 and 2; the shipped small model has 6). Depth 0 recomputes only
/// `conv_in` and the last up layer.
#[derive(Clone, Debug)]
pub struct FeatureCache {
    depth: usize,
    feature: Option<Tensor<4>>,
}

impl FeatureCache {
    /// An empty cache for the branch at skip `depth`.
    pub fn new(depth: usize) -> Self {
        Self { depth, feature: None }
    }

    /// The skip the cached branch starts at.
    pub fn depth(&self) -> usize {
        self.depth
    }

    /// Whether a full pass has filled the cache.
    pub fn is_filled(&self) -> bool {
        self.feature.is_some()
    }

    /// The batch size of the cached feature (a cached pass needs the same), if filled.
    pub fn batch(&self) -> Option<usize> {
        self.feature.as_ref().map(|f| f.dims()[0])
    }

    /// Forgets the cached feature (the next pass is a full one).
    pub fn clear(&mut self) {
        self.feature = None;
    }
}

/// A ControlNet's residuals for one UNet call: the down residuals in the UNet's skip order (12
/// for SD1.5; residual `i` has the shape of skip `i`, `[n, c_i, h_i, w_i]`) and the mid
/// residual (the mid block output's shape), already multiplied by the conditioning scale.
#[derive(Clone, Debug)]
pub struct ControlResiduals {
    /// One per skip connection of the UNet's down pass, in order.
    pub down: Vec<Tensor<4>>,
    /// Added to the UNet's mid block output.
    pub mid: Tensor<4>,
}

/// Extra conditioning of one UNet call, beyond the tokens and class labels (Default: none).
#[derive(Clone, Debug, Default)]
pub struct UNetExtra {
    /// ControlNet residuals added to the skip connections and the mid-block output
    /// ([`crate::models::controlnet::ControlNet::forward`]; their shapes must be the UNet's skips').
    pub control: Option<ControlResiduals>,
    /// IP-Adapter image tokens and scale for the decoupled cross-attention (needs a UNet with
    /// an adapter, [`UNet::load_ip_adapter`]).
    pub ip: Option<IpTokens>,
}

/// The conditional UNet (see the module docs for shapes).
#[derive(Module, Debug)]
pub struct UNet {
    down: DownPath,
    up_blocks: Vec<UpBlock>,
    conv_norm_out: GroupNorm,
    conv_out: Conv2d,
    #[module(skip)]
    config: UNetConfig,
    /// The checkpoint key of every parameter (ids survive `Module::map`, so they stay valid
    /// for a trained copy of this model).
    #[module(skip)]
    names: Arc<Vec<NamedParam>>,
}

impl UNet {
    checkpoint::checkpoint_methods!(UNetConfig, "unet/");

    /// This model with cross-domain attention added (`cd_attention_mid`, the start of stage
    /// 3): every parameter is copied, and `attn_joint_mid` / `norm_joint_mid` are new —
    /// seeded default initialisation with the output projection's weight zeroed, so the
    /// model computes what it computed before apart from the new output bias.
    pub fn with_cross_domain_attention(&self, seed: u64) -> Result<Self, Error> {
        if self.config.cd_attention_mid {
            return Err(Error::invalid(
                "unet cd_attention_mid",
                "false (the model has cross-domain attention already)",
            ));
        }
        let mut config = self.config.clone();
        config.cd_attention_mid = true;
        let device = self.devices().into_iter().next().unwrap_or_default();
        let values = crate::loading::weights::collect_named(self, &self.names)?
            .into_iter()
            .map(|t| (t.key, (t.shape, t.values)))
            .collect();
        let p = ParamSource::from_values(values, &device).with_fresh(seed, |key| key.contains("joint_mid."));
        checkpoint::build_checked(&config, p)
    }

    /// Wonder3D's `from_pretrained_2d`: the multi-view model `config` (8 input channels,
    /// projection class embedding, multi-view blocks, optionally cross-domain attention) from
    /// a single-view Stable-Diffusion-image-variations UNet's weights (`diffusion_pytorch_model
    /// .safetensors` of a diffusers `unet/` folder): `conv_in` keeps the 4 latent channels'
    /// weights and gets zeros for the 4 image-latent channels; the class embedding and any
    /// cross-domain attention are new (seeded default initialisation, the joint attention's
    /// output weight zeroed); every other parameter must be in the file (the multi-view
    /// attention reuses `attn1`).
    pub fn from_pretrained_2d(
        config: &UNetConfig,
        weights: impl AsRef<Path>,
        seed: u64,
        device: &Device,
    ) -> Result<Self, Error> {
        config.validate()?;
        let mut file = SafetensorsFile::open(weights)?;
        let p = ParamSource::from_file(&mut file, rename_legacy_unet_key, device)
            .with_fresh(seed, |key| {
                key.starts_with("class_embedding.") || key.contains("joint_mid.") || key.contains("joint_last.")
            })
            .widening_conv_in();
        checkpoint::build_checked(config, p)
    }

    fn build(c: &UNetConfig, p: &mut ParamSource) -> Result<Self, Error> {
        let ch = &c.block_out_channels;
        let levels = ch.len();
        let temb = c.time_embed_dim();
        let (groups, eps) = (c.norm_num_groups, c.norm_eps);
        let resnet =
            |c_in, c_out, scale| ResnetShape { c_in, c_out, temb: Some(temb), groups, eps, output_scale: scale };
        let transformer = |channels, level: usize, multiview: bool| transformer_shape(c, channels, level, multiview);
        let down = DownPath::load(c, p, &transformer)?;

        let mut up_blocks = Vec::with_capacity(levels);
        let reversed: Vec<usize> = ch.iter().rev().copied().collect();
        let mut c_prev_out = reversed[0];
        for (i, kind) in c.up_block_types.iter().enumerate() {
            let c_out = reversed[i];
            let c_skip_in = reversed[(i + 1).min(levels - 1)];
            let key = format!("up_blocks.{i}");
            let layers = c.layers_per_block + 1;
            let mut resnets = Vec::new();
            let mut attentions = Vec::new();
            for j in 0..layers {
                let skip = if j + 1 == layers { c_skip_in } else { c_out };
                let c_in = if j == 0 { c_prev_out } else { c_out };
                resnets.push(ResnetBlock::load(p, &format!("{key}.resnets.{j}"), resnet(c_in + skip, c_out, 1.0)));
                if kind.starts_with("CrossAttn") {
                    let level = levels - 1 - i;
                    attentions.push(SpatialTransformer::load(
                        p,
                        &format!("{key}.attentions.{j}"),
                        transformer(c_out, level, UNetConfig::is_multiview_block(kind))?,
                    ));
                }
            }
            let upsampler = (i + 1 < levels).then(|| Upsample::load(p, &format!("{key}.upsamplers.0"), c_out));
            up_blocks.push(UpBlock { resnets, attentions, upsampler });
            c_prev_out = c_out;
        }

        let conv_norm_out = GroupNorm::load(p, "conv_norm_out", groups, ch[0], eps);
        let conv_out = Conv2d::load(p, "conv_out", ch[0], c.out_channels, 3, 1, 1, true);
        Ok(Self { down, up_blocks, conv_norm_out, conv_out, config: c.clone(), names: Arc::default() })
    }

    /// Sinusoidal timestep features `[n, block_out_channels[0]]` (diffusers
    /// `get_timestep_embedding`, computed in f32 like diffusers).
    pub fn timestep_features(&self, timesteps: &[f32], device: &Device) -> Tensor<2> {
        timestep_features(&self.config, timesteps, device)
    }

    /// Predicts noise (or v / x₀, per the scheduler) for `sample` at `timesteps` (one per image,
    /// or one for all), conditioned on `context` and `class_labels`.
    pub fn forward(
        &self,
        sample: Tensor<4>,
        timesteps: &[f32],
        context: Tensor<3>,
        class_labels: Option<Tensor<2>>,
    ) -> Result<Tensor<4>, Error> {
        self.forward_with(sample, timesteps, context, class_labels, &UNetExtra::default())
    }

    /// [`UNet::forward`] with extra conditioning (validated: shapes, and that the model has
    /// what `extra` needs). ControlNet residuals (`extra.control`, diffusers'
    /// `down_block_additional_residuals` / `mid_block_additional_residual`): residual `i` is
    /// added to skip tensor `i` after the down pass, before the up blocks consume it, and the
    /// mid residual to the mid block's output; their count and shapes must be those of the
    /// skips for this `sample` (`[n, c, h, w]` per skip: 12 down residuals and a mid one for
    /// Stable Diffusion 1.5).
    pub fn forward_with(
        &self,
        sample: Tensor<4>,
        timesteps: &[f32],
        context: Tensor<3>,
        class_labels: Option<Tensor<2>>,
        extra: &UNetExtra,
    ) -> Result<Tensor<4>, Error> {
        self.run(sample, timesteps, context, class_labels, extra, Pass::Full(None))
    }

    /// [`UNet::forward_with`] with DeepCache ([`FeatureCache`]): with `reuse` false, or
    /// while `cache` holds no feature for a batch of this size, a full pass that fills
    /// `cache`; with `reuse`, only the shallow branch, the deep part's contribution taken
    /// from `cache`. A ControlNet's residuals may then be all of them or only those of the
    /// skips `0..=depth` ([`crate::models::controlnet::ControlNet::forward_shallow`]); the
    /// mid residual is not used.
    ///
    /// Errors: as [`UNet::forward_with`], and a depth beyond the last skip.
    #[allow(clippy::too_many_arguments)]
    pub fn forward_cached(
        &self,
        sample: Tensor<4>,
        timesteps: &[f32],
        context: Tensor<3>,
        class_labels: Option<Tensor<2>>,
        extra: &UNetExtra,
        cache: &mut FeatureCache,
        reuse: bool,
    ) -> Result<Tensor<4>, Error> {
        let skips = self.skip_count();
        if cache.depth >= skips {
            return Err(Error::invalid(
                "cache depth",
                format!("a skip index below {skips}, the UNet's skip count (found {})", cache.depth),
            ));
        }
        let n = sample.dims()[0];
        match &cache.feature {
            Some(feature) if reuse && feature.dims()[0] == n => {
                let feature = feature.clone();
                self.run(sample, timesteps, context, class_labels, extra, Pass::Shallow(Box::new(feature), cache.depth))
            }
            _ => self.run(sample, timesteps, context, class_labels, extra, Pass::Full(Some(cache))),
        }
    }

    /// The UNet pass behind [`UNet::forward_with`] and [`UNet::forward_cached`].
    fn run(
        &self,
        sample: Tensor<4>,
        timesteps: &[f32],
        context: Tensor<3>,
        class_labels: Option<Tensor<2>>,
        extra: &UNetExtra,
        pass: Pass<'_>,
    ) -> Result<Tensor<4>, Error> {
        let c = &self.config;
        let timesteps = DownPath::check_inputs(c, &sample, timesteps, &context)?;
        let [n, _, h, w] = sample.dims();
        let views = if c.multiview_attention { c.views() } else { 1 };
        let group = if c.cross_domain() { 2 * views } else { views };
        if !n.is_multiple_of(group) {
            return Err(Error::invalid(
                "sample",
                format!(
                    "a batch of whole groups of {group} images ({}{views} views each; found {n})",
                    if c.cross_domain() { "normal and colour halves of " } else { "" }
                ),
            ));
        }
        let shallow_depth = match &pass {
            Pass::Shallow(_, depth) => Some(*depth),
            Pass::Full(_) => None,
        };
        if let Some(control) = &extra.control {
            check_residuals(c, control, n, h, w, shallow_depth)?;
        }
        let ip = extra.ip.as_ref();
        if let Some(ip) = ip {
            self.check_ip_tokens(ip, n)?;
        }
        crate::compute::record(crate::compute::WorkKind::UNetPass, 1);
        let device = sample.device();
        let temb = self.down.embed_time(c, &timesteps, class_labels, &device)?;

        let (mut skips, mid) = self.down.forward_until(c, sample, &temb, &context, None, ip, shallow_depth);
        if let Some(control) = &extra.control {
            skips = skips.into_iter().zip(&control.down).map(|(skip, r)| skip + r.clone()).collect();
        }
        // The up path's layers in order; layer `k` consumes skip `skip_count - 1 - k`.
        let skip_count = DownPath::skip_shapes(c, n, h, w).len();
        let (mut x, first_layer, mut store) = match pass {
            Pass::Full(store) => {
                let mut x = mid.ok_or_else(|| Error::invalid("unet", "a mid block output after the down path"))?;
                if let Some(control) = &extra.control {
                    x = x + control.mid.clone();
                }
                (x, 0, store)
            }
            Pass::Shallow(feature, depth) => (*feature, skip_count - 1 - depth, None),
        };
        let mut layer = 0;
        for block in &self.up_blocks {
            for (j, resnet) in block.resnets.iter().enumerate() {
                if layer >= first_layer {
                    if let Some(cache) = store.as_deref_mut().filter(|cache| skip_count - 1 - layer == cache.depth) {
                        cache.feature = Some(x.clone());
                    }
                    let skip = skips.pop().ok_or_else(|| Error::invalid("unet", "a skip connection per up ResNet"))?;
                    x = resnet.forward(Tensor::cat(vec![x, skip], 1), Some(&temb));
                    if let Some(attn) = block.attentions.get(j) {
                        x = attn.forward_with_ip(x, &context, ip);
                    }
                }
                layer += 1;
            }
            if let Some(up) = &block.upsampler
                && layer > first_layer
            {
                x = up.forward(x);
            }
        }
        Ok(self.conv_out.forward(self.conv_norm_out.forward_silu(x)))
    }

    /// The number of skip connections (the first is `conv_in`'s output): the DeepCache depths
    /// are `0..skip_count()`.
    pub fn skip_count(&self) -> usize {
        DownPath::skip_shapes(&self.config, 1, 0, 0).len()
    }

    /// Checks IP-Adapter tokens for a batch of `n` rows against this model.
    fn check_ip_tokens(&self, ip: &IpTokens, n: usize) -> Result<(), Error> {
        if !self.has_ip_adapter() {
            return Err(Error::invalid("ip", "none (the UNet has no IP-Adapter; load one with UNet::load_ip_adapter)"));
        }
        let [rows, tokens, width] = ip.tokens.dims();
        let cross = self.config.cross_attention_dim;
        if rows != n || tokens == 0 || width != cross {
            return Err(Error::invalid(
                "ip.tokens",
                format!("[{n}, tokens ≥ 1, {cross}], one row per sample row (found {:?})", ip.tokens.dims()),
            ));
        }
        if !ip.scale.is_finite() {
            return Err(Error::invalid("ip.scale", format!("a finite number (found {})", ip.scale)));
        }
        Ok(())
    }

    /// The cross-attention (`attn2`) layers in diffusers' module order (down blocks, up
    /// blocks, then the mid block; blocks, transformers and transformer blocks in index
    /// order): the order in which an IP-Adapter file numbers them.
    pub(crate) fn cross_attentions(&self) -> impl Iterator<Item = &Attention> {
        let down = self.down.down_blocks.iter().flat_map(|b| b.attentions.iter());
        let up = self.up_blocks.iter().flat_map(|b| b.attentions.iter());
        down.chain(up).chain(std::iter::once(&self.down.mid_attention)).flat_map(SpatialTransformer::cross_attentions)
    }

    /// [`UNet::cross_attentions`], mutable.
    pub(crate) fn cross_attentions_mut(&mut self) -> impl Iterator<Item = &mut Attention> {
        let down = self.down.down_blocks.iter_mut().flat_map(|b| b.attentions.iter_mut());
        let up = self.up_blocks.iter_mut().flat_map(|b| b.attentions.iter_mut());
        down.chain(up)
            .chain(std::iter::once(&mut self.down.mid_attention))
            .flat_map(SpatialTransformer::cross_attentions_mut)
    }
}

/// How [`UNet::run`] evaluates: the whole UNet (filling a DeepCache feature cache if given), or
/// only the shallow branch from skip `depth`, the deep part's contribution given.
enum Pass<'a> {
    Full(Option<&'a mut FeatureCache>),
    Shallow(Box<Tensor<4>>, usize),
}

/// Sinusoidal timestep features `[n, block_out_channels[0]]` of `c` (see
/// [`UNet::timestep_features`]).
pub(crate) fn timestep_features(c: &UNetConfig, timesteps: &[f32], device: &Device) -> Tensor<2> {
    let dim = c.block_out_channels[0];
    let half = dim / 2;
    let shift = c.freq_shift as f32;
    let ln = -(10000f64.ln()) as f32;
    let freqs: Vec<f32> = (0..half).map(|i| ((ln * i as f32) / (half as f32 - shift)).exp()).collect();
    let mut values = Vec::with_capacity(timesteps.len() * dim);
    for &t in timesteps {
        let args: Vec<f32> = freqs.iter().map(|f| t * f).collect();
        let sin = args.iter().map(|a| a.sin());
        let cos = args.iter().map(|a| a.cos());
        if c.flip_sin_to_cos {
            values.extend(cos.chain(sin));
        } else {
            values.extend(sin.chain(cos));
        }
        if dim % 2 == 1 {
            values.push(0.0);
        }
    }
    Tensor::from_data(TensorData::new(values, [timesteps.len(), dim]), device)
}

/// Checks ControlNet residuals against the skips of an `[n, _, h, w]` sample of `c`: one per
/// skip with its exact shape, and a mid residual of the mid block's output shape; for the
/// shallow branch of a cached pass (`shallow_depth = Some(d)`) the residuals of skips `0..=d`
/// are enough (more are ignored) and the mid residual is not used.
fn check_residuals(
    c: &UNetConfig,
    control: &ControlResiduals,
    n: usize,
    h: usize,
    w: usize,
    shallow_depth: Option<usize>,
) -> Result<(), Error> {
    let mut shapes = DownPath::skip_shapes(c, n, h, w);
    if let Some(d) = shallow_depth
        && control.down.len() < shapes.len()
    {
        shapes.truncate(d + 1);
        if control.down.len() != shapes.len() {
            return Err(Error::invalid(
                "control.down",
                format!(
                    "{} residuals for a cached pass from skip {d}, or one per skip connection (found {})",
                    shapes.len(),
                    control.down.len()
                ),
            ));
        }
    }
    if control.down.len() != shapes.len() {
        return Err(Error::invalid(
            "control.down",
            format!("{} residuals, one per skip connection (found {})", shapes.len(), control.down.len()),
        ));
    }
    for (i, (r, want)) in control.down.iter().zip(&shapes).enumerate() {
        if r.dims() != *want {
            return Err(Error::invalid(format!("control.down[{i}]"), format!("shape {want:?} (found {:?})", r.dims())));
        }
    }
    let levels = c.block_out_channels.len();
    let side = 1 << (levels - 1);
    let want = [n, c.block_out_channels[levels - 1], h / side, w / side];
    // A shallow pass never reaches the mid block, so its mid residual is not looked at.
    if shallow_depth.is_none() && control.mid.dims() != want {
        return Err(Error::invalid("control.mid", format!("shape {want:?} (found {:?})", control.mid.dims())));
    }
    Ok(())
}

/// Renames keys of older Wonder3D checkpoints to the current names, as the authors' loader
/// does: `attn_joint` / `norm_joint` were the cross-domain attention after the feed-forward
/// (now `…_last`), `attn_joint_twice` / `norm_joint_twice` the one after the self-attention
/// (now `…_mid`).
fn rename_legacy_unet_key(key: &str) -> String {
    key.replace(".attn_joint_twice.", ".attn_joint_mid.")
        .replace(".norm_joint_twice.", ".norm_joint_mid.")
        .replace(".attn_joint.", ".attn_joint_last.")
        .replace(".norm_joint.", ".norm_joint_last.")
}

impl Checkpoint for UNet {
    type Config = UNetConfig;
    const WEIGHTS_STEM: &'static str = "diffusion_pytorch_model";

    fn model_key(file_key: &str) -> String {
        rename_legacy_unet_key(file_key)
    }

    fn build(config: &UNetConfig, p: &mut ParamSource) -> Result<Self, Error> {
        UNet::build(config, p)
    }

    fn set_names(&mut self, names: Vec<NamedParam>) {
        self.names = Arc::new(names);
    }

    fn names(&self) -> &[NamedParam] {
        &self.names
    }

    fn config(&self) -> &UNetConfig {
        &self.config
    }

    fn class_fields(&self) -> Vec<(&'static str, &'static str)> {
        let class = if self.config.num_views.is_some() { "UNetMV2DConditionModel" } else { "UNet2DConditionModel" };
        vec![("_class_name", class)]
    }
}
