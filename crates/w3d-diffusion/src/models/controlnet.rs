//! `ControlNetModel` (diffusers, Stable Diffusion 1.5 layout) with Wonder3D++'s cross-domain
//! ("joint") attention: the ControlNet of the refinement stage's enhancer
//! (`docs/weights.md`, "ControlNet (enhancer)").
//!
//! A ControlNet is the UNet's down half ([`crate::models::unet`]'s `conv_in`, time embedding, down
//! blocks and mid block, built by the same code) plus:
//! - `controlnet_cond_embedding`: the control image `[n, 3, 8h, 8w]` (in `[0, 1]`, not
//!   normalised) through a 3×3 convolution, then pairs of 3×3 convolutions (the second of each
//!   pair with stride 2), SiLU after each, and a last 3×3 convolution to the UNet's first
//!   width; added to `conv_in`'s output;
//! - `controlnet_down_blocks.{i}`: one 1×1 convolution per skip tensor of the down pass (the
//!   `conv_in` output, every ResNet (+ transformer) output, every down-sampler output: 12 for
//!   SD1.5, widths 320×4, 640×3, 1280×5), and `controlnet_mid_block` on the mid block's output.
//!   Fresh (diffusers `from_unet`) they are zero, so an untrained ControlNet changes nothing;
//! - the outputs times the conditioning scale are the residuals the UNet adds to its skips and
//!   to its mid block's output ([`crate::models::unet::UNetExtra`]).
//!
//! Wonder3D++'s MVControlNet adds, in every transformer block, a cross-domain attention after
//! the self-attention: `h += attn_joint_mid(norm_joint_mid(h))` (LayerNorm; attention with the
//! block's head count and head width, no q/k/v bias, output projection with bias), before the
//! cross-attention to the text and the feed-forward. The batch is `[domain A half, domain B
//! half]` (colour, then normal, in the enhancer) and row `i` of either half attends over the
//! concatenated tokens of rows `i` and `i + n/2`: the same layer and pairing as the multi-view
//! UNet's `cd_attention_mid` ([`crate::models::blocks`]), without multi-view attention.

use std::path::Path;
use std::sync::Arc;

use burn::module::Module;
use burn::tensor::activation::silu;
use burn::tensor::{Device, Tensor};
use w3d_core::Error;

use crate::loading::config::ControlNetConfig;
use crate::loading::weights::{Init, NamedParam, ParamSource, SafetensorsFile, WeightStorage};
use crate::models::blocks::TransformerShape;
use crate::models::unet::{ControlResiduals, DownPath, transformer_shape};
use crate::nn::Conv2d;

/// `ControlNetConditioningEmbedding`: the control image to the UNet's first width at the
/// latent's resolution.
#[derive(Module, Debug)]
struct CondEmbedding {
    conv_in: Conv2d,
    blocks: Vec<Conv2d>,
    conv_out: Conv2d,
}

impl CondEmbedding {
    /// `channels` of the control image, `widths` = `conditioning_embedding_out_channels`,
    /// `out` the UNet's first width.
    fn load(p: &mut ParamSource, channels: usize, widths: &[usize], out: usize) -> Self {
        let key = "controlnet_cond_embedding";
        let conv_in = Conv2d::load(p, &format!("{key}.conv_in"), channels, widths[0], 3, 1, 1, true);
        let mut blocks = Vec::with_capacity(2 * widths.len());
        for (i, pair) in widths.windows(2).enumerate() {
            let (c_in, c_out) = (pair[0], pair[1]);
            blocks.push(Conv2d::load(p, &format!("{key}.blocks.{}", 2 * i), c_in, c_in, 3, 1, 1, true));
            blocks.push(Conv2d::load(p, &format!("{key}.blocks.{}", 2 * i + 1), c_in, c_out, 3, 2, 1, true));
        }
        let last = widths[widths.len() - 1];
        let conv_out = zero_conv(p, &format!("{key}.conv_out"), last, out, 3, 1);
        Self { conv_in, blocks, conv_out }
    }

    /// `[n, channels, s·h, s·w]` → `[n, out, h, w]` (`s` = 2^(blocks/2)).
    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let mut x = silu(self.conv_in.forward(x));
        for block in &self.blocks {
            x = silu(block.forward(x));
        }
        self.conv_out.forward(x)
    }
}

/// A stride-1 convolution with bias that a randomly initialised model gets as zeros (diffusers'
/// `zero_module`: the zero convolutions and the condition embedding's output).
fn zero_conv(p: &mut ParamSource, key: &str, c_in: usize, c_out: usize, kernel: usize, padding: usize) -> Conv2d {
    Conv2d {
        weight: p.param(&format!("{key}.weight"), [c_out, c_in, kernel, kernel], Init::Zeros),
        bias: Some(p.param(&format!("{key}.bias"), [c_out], Init::Zeros)),
        stride: 1,
        padding,
    }
}

/// A ControlNet (see the module docs), optionally with the cross-domain attention.
#[derive(Module, Debug)]
pub struct ControlNet {
    down: DownPath,
    cond_embedding: CondEmbedding,
    zero_convs: Vec<Conv2d>,
    mid_zero_conv: Conv2d,
    #[module(skip)]
    config: ControlNetConfig,
    /// Whether the transformer blocks have the cross-domain attention.
    #[module(skip)]
    cross_domain: bool,
    /// The checkpoint key of every parameter.
    #[module(skip)]
    names: Arc<Vec<NamedParam>>,
}

impl ControlNet {
    /// Loads `config` with the weights of a diffusers `diffusion_pytorch_model.safetensors`
    /// (f32, f16 or bf16). The cross-domain attention is built iff the file has
    /// `…attn_joint_mid…` keys (Wonder3D++'s MVControlNet: 7 tensors per transformer block,
    /// 49 for SD1.5); a stock ControlNet loads too. Fails listing every missing, unexpected or
    /// misshaped key.
    pub fn load(config: &ControlNetConfig, weights: impl AsRef<Path>, device: &Device) -> Result<Self, Error> {
        Self::load_stored(config, weights.as_ref(), device, WeightStorage::F32)
    }

    fn load_stored(
        config: &ControlNetConfig,
        weights: &Path,
        device: &Device,
        storage: WeightStorage,
    ) -> Result<Self, Error> {
        config.validate()?;
        let mut file = SafetensorsFile::open(weights)?;
        let cross_domain = file.shapes().any(|(key, _)| key.contains(".attn_joint_mid."));
        let mut p = ParamSource::from_file(&mut file, |key: &str| key.to_owned(), device).storing(storage);
        let mut model = Self::build(config, cross_domain, &mut p)?;
        model.names = Arc::new(p.take_names());
        p.finish()?;
        Ok(model)
    }

    /// Loads `config.json` and `diffusion_pytorch_model.safetensors` (or its
    /// `.fp16.safetensors` variant) from a ControlNet folder (e.g. `mv_controlnet/`).
    pub fn from_dir(dir: impl AsRef<Path>, device: &Device) -> Result<Self, Error> {
        Self::from_dir_with(dir, device, WeightStorage::F32)
    }

    /// [`ControlNet::from_dir`] with the linear and convolution weights held as `storage`
    /// says ([`WeightStorage`]: f16 halves the memory; the arithmetic stays f32).
    pub fn from_dir_with(dir: impl AsRef<Path>, device: &Device, storage: WeightStorage) -> Result<Self, Error> {
        let dir = dir.as_ref();
        let config = ControlNetConfig::from_file(dir.join("config.json"))?;
        Self::load_stored(
            &config,
            &crate::loading::weights::find_weights(dir, "diffusion_pytorch_model")?,
            device,
            storage,
        )
    }

    /// `config` with seeded random weights, with the cross-domain attention when
    /// `cross_domain` (for shape, speed and memory checks at real sizes). Initialised as a
    /// fresh diffusers ControlNet: the zero convolutions, the condition embedding's output
    /// convolution and the cross-domain attention's output weight are zero, so the residuals
    /// are zero until the model is trained.
    pub fn random(config: &ControlNetConfig, cross_domain: bool, seed: u64, device: &Device) -> Result<Self, Error> {
        config.validate()?;
        let mut p = ParamSource::random(seed, device);
        let mut model = Self::build(config, cross_domain, &mut p)?;
        model.names = Arc::new(p.take_names());
        Ok(model)
    }

    fn build(config: &ControlNetConfig, cross_domain: bool, p: &mut ParamSource) -> Result<Self, Error> {
        let c = &config.unet;
        // The authors' block builds the joint attention with the block's own head count and
        // head width (8 heads of d/8 in SD1.5), so the UNet's shape rule applies as it is.
        let transformer = |channels, level, _multiview: bool| -> Result<TransformerShape, Error> {
            Ok(TransformerShape { cross_domain_mid: cross_domain, ..transformer_shape(c, channels, level, false)? })
        };
        let down = DownPath::load(c, p, &transformer)?;
        let cond_embedding = CondEmbedding::load(
            p,
            config.conditioning_channels,
            &config.conditioning_embedding_out_channels,
            c.block_out_channels[0],
        );
        // Only the channel count of each skip matters here.
        let zero_convs = DownPath::skip_shapes(c, 0, 0, 0)
            .iter()
            .enumerate()
            .map(|(i, &[_, ch, _, _])| zero_conv(p, &format!("controlnet_down_blocks.{i}"), ch, ch, 1, 0))
            .collect();
        let c_mid = c.block_out_channels[c.block_out_channels.len() - 1];
        let mid_zero_conv = zero_conv(p, "controlnet_mid_block", c_mid, c_mid, 1, 0);
        Ok(Self {
            down,
            cond_embedding,
            zero_convs,
            mid_zero_conv,
            config: config.clone(),
            cross_domain,
            names: Arc::default(),
        })
    }

    /// Whether the transformer blocks have Wonder3D++'s cross-domain attention (then the batch
    /// must be `[domain A half, domain B half]`).
    pub fn has_cross_domain_attention(&self) -> bool {
        self.cross_domain
    }

    /// The config this model was built from.
    pub fn config(&self) -> &ControlNetConfig {
        &self.config
    }

    /// The checkpoint key (diffusers `ControlNetModel` names) of every parameter, in build
    /// order.
    pub fn named_parameters(&self) -> &[NamedParam] {
        &self.names
    }

    /// The residuals for a UNet call on `sample [n, in_channels, h, w]` (latents; h, w
    /// multiples of `2^(levels-1)`) at `timesteps` (one per row, or one for all), with
    /// `context [n, tokens, cross_attention_dim]` (text tokens) and `control [n,
    /// conditioning_channels, s·h, s·w]` (`s` = [`ControlNetConfig::control_downscale`], 8 for
    /// SD1.5), the control image in `[0, 1]` as it is (no normalisation, like diffusers'
    /// control image processor). `scale` is the conditioning scale every residual is
    /// multiplied by. With the cross-domain attention `n` must be even: rows `i` and `i + n/2`
    /// are one pair (same object and guidance branch, the two domains).
    pub fn forward(
        &self,
        sample: Tensor<4>,
        timesteps: &[f32],
        context: Tensor<3>,
        control: Tensor<4>,
        scale: f32,
    ) -> Result<ControlResiduals, Error> {
        self.residuals(sample, timesteps, context, control, scale, None)
    }

    /// The residuals of skips `0..=depth` only, for the shallow branch of a cached UNet pass
    /// ([`crate::models::unet::UNet::forward_cached`], DeepCache): the ControlNet runs only
    /// as far as that skip. Arguments and errors as [`ControlNet::forward`]; the returned mid
    /// residual is a `[n, c, 1, 1]` zero stand-in (a shallow pass does not use it).
    pub fn forward_shallow(
        &self,
        sample: Tensor<4>,
        timesteps: &[f32],
        context: Tensor<3>,
        control: Tensor<4>,
        scale: f32,
        depth: usize,
    ) -> Result<ControlResiduals, Error> {
        let skips = self.zero_convs.len();
        if depth >= skips {
            return Err(Error::invalid("cache depth", format!("a skip index below {skips} (found {depth})")));
        }
        self.residuals(sample, timesteps, context, control, scale, Some(depth))
    }

    /// [`ControlNet::forward`], or up to skip `last_skip` only.
    fn residuals(
        &self,
        sample: Tensor<4>,
        timesteps: &[f32],
        context: Tensor<3>,
        control: Tensor<4>,
        scale: f32,
        last_skip: Option<usize>,
    ) -> Result<ControlResiduals, Error> {
        let c = &self.config.unet;
        let timesteps = DownPath::check_inputs(c, &sample, timesteps, &context)?;
        let [n, _, h, w] = sample.dims();
        if self.cross_domain && !n.is_multiple_of(2) {
            return Err(Error::invalid(
                "sample",
                format!("an even batch [domain A half, domain B half] for the cross-domain attention (found {n})"),
            ));
        }
        let s = self.config.control_downscale();
        let want = [n, self.config.conditioning_channels, s * h, s * w];
        if control.dims() != want {
            return Err(Error::invalid("control", format!("shape {want:?} (found {:?})", control.dims())));
        }
        if !scale.is_finite() {
            return Err(Error::invalid("scale", format!("a finite conditioning scale (found {scale})")));
        }
        let control = match self.config.controlnet_conditioning_channel_order.as_str() {
            "bgr" => control.flip([1]),
            _ => control,
        };
        let device = sample.device();
        let temb = self.down.embed_time(c, &timesteps, None, &device)?;
        let cond = self.cond_embedding.forward(control);
        let (skips, mid) = self.down.forward_until(c, sample, &temb, &context, Some(cond), None, last_skip);
        let down = skips.into_iter().zip(&self.zero_convs).map(|(skip, conv)| conv.forward(skip) * scale).collect();
        let mid = match mid {
            Some(mid) => self.mid_zero_conv.forward(mid) * scale,
            None => {
                let c_mid = c.block_out_channels[c.block_out_channels.len() - 1];
                Tensor::zeros([n, c_mid, 1, 1], &device)
            }
        };
        Ok(ControlResiduals { down, mid })
    }
}
