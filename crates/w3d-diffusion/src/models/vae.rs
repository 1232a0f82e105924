//! `AutoencoderKL`: the Stable Diffusion VAE. Images are `[n, 3, H, W]` in `[-1, 1]`
//! (H, W multiples of the downscale `2^(levels-1)`); latents are `[n, latent_channels, H/8, W/8]`
//! *before* the scaling factor (the diffusion model sees `latent * scaling_factor`).

use std::sync::Arc;

use burn::module::Module;
use burn::tensor::Tensor;
use w3d_core::Error;

use crate::loading::checkpoint::{self, Checkpoint};
use crate::loading::config::VaeConfig;
use crate::loading::weights::{NamedParam, ParamSource};
use crate::models::blocks::{Downsample, ResnetBlock, ResnetShape, Upsample};
use crate::nn::{Conv2d, GroupNorm, Linear, multi_head_attention};

/// GroupNorm epsilon used everywhere in the VAE.
const VAE_EPS: f64 = 1e-6;

/// Single-head self-attention over the pixels of a feature map, with GroupNorm and residual.
#[derive(Module, Debug)]
struct PixelAttention {
    group_norm: GroupNorm,
    to_q: Linear,
    to_k: Linear,
    to_v: Linear,
    to_out: Linear,
}

impl PixelAttention {
    fn load(p: &mut ParamSource, key: &str, c: usize, groups: usize) -> Self {
        Self {
            group_norm: GroupNorm::load(p, &format!("{key}.group_norm"), groups, c, VAE_EPS),
            to_q: Linear::load(p, &format!("{key}.to_q"), c, c, true),
            to_k: Linear::load(p, &format!("{key}.to_k"), c, c, true),
            to_v: Linear::load(p, &format!("{key}.to_v"), c, c, true),
            to_out: Linear::load(p, &format!("{key}.to_out.0"), c, c, true),
        }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let [n, c, h, w] = x.dims();
        let tokens = self.group_norm.forward(x.clone()).reshape([n, c, h * w]).swap_dims(1, 2);
        let q = self.to_q.forward(tokens.clone());
        let k = self.to_k.forward(tokens.clone());
        let v = self.to_v.forward(tokens);
        let o = self.to_out.forward(multi_head_attention(q, k, v, 1));
        o.swap_dims(1, 2).reshape([n, c, h, w]) + x
    }
}

/// ResNet → attention → ResNet at the lowest resolution.
#[derive(Module, Debug)]
struct MidBlock {
    resnet_0: ResnetBlock,
    attention: PixelAttention,
    resnet_1: ResnetBlock,
}

impl MidBlock {
    fn load(p: &mut ParamSource, key: &str, c: usize, groups: usize) -> Self {
        let shape = ResnetShape { c_in: c, c_out: c, temb: None, groups, eps: VAE_EPS, output_scale: 1.0 };
        Self {
            resnet_0: ResnetBlock::load(p, &format!("{key}.resnets.0"), shape),
            attention: PixelAttention::load(p, &format!("{key}.attentions.0"), c, groups),
            resnet_1: ResnetBlock::load(p, &format!("{key}.resnets.1"), shape),
        }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        self.resnet_1.forward(self.attention.forward(self.resnet_0.forward(x, None)), None)
    }
}

#[derive(Module, Debug)]
struct EncoderBlock {
    resnets: Vec<ResnetBlock>,
    downsampler: Option<Downsample>,
}

#[derive(Module, Debug)]
struct DecoderBlock {
    resnets: Vec<ResnetBlock>,
    upsampler: Option<Upsample>,
}

/// The VAE (encoder + decoder); see the module docs for shapes and ranges.
#[derive(Module, Debug)]
pub struct Vae {
    encoder_conv_in: Conv2d,
    encoder_blocks: Vec<EncoderBlock>,
    encoder_mid: MidBlock,
    encoder_norm_out: GroupNorm,
    encoder_conv_out: Conv2d,
    quant_conv: Conv2d,
    post_quant_conv: Conv2d,
    decoder_conv_in: Conv2d,
    decoder_mid: MidBlock,
    decoder_blocks: Vec<DecoderBlock>,
    decoder_norm_out: GroupNorm,
    decoder_conv_out: Conv2d,
    #[module(skip)]
    config: VaeConfig,
    #[module(skip)]
    names: Arc<Vec<NamedParam>>,
}

impl Vae {
    checkpoint::checkpoint_methods!(VaeConfig, "vae/");

    fn build(c: &VaeConfig, p: &mut ParamSource) -> Self {
        let ch = &c.block_out_channels;
        let levels = ch.len();
        let g = c.norm_num_groups;
        let lat = c.latent_channels;
        let shape = |c_in, c_out| ResnetShape { c_in, c_out, temb: None, groups: g, eps: VAE_EPS, output_scale: 1.0 };

        let encoder_conv_in = Conv2d::load(p, "encoder.conv_in", c.in_channels, ch[0], 3, 1, 1, true);
        let mut encoder_blocks = Vec::new();
        let mut c_prev = ch[0];
        for (i, &c_out) in ch.iter().enumerate() {
            let key = format!("encoder.down_blocks.{i}");
            let resnets = (0..c.layers_per_block)
                .map(|j| {
                    let c_in = if j == 0 { c_prev } else { c_out };
                    ResnetBlock::load(p, &format!("{key}.resnets.{j}"), shape(c_in, c_out))
                })
                .collect();
            let downsampler = (i + 1 < levels).then(|| Downsample::load(p, &format!("{key}.downsamplers.0"), c_out, 0));
            encoder_blocks.push(EncoderBlock { resnets, downsampler });
            c_prev = c_out;
        }
        let top = ch[levels - 1];
        let encoder_mid = MidBlock::load(p, "encoder.mid_block", top, g);
        let encoder_norm_out = GroupNorm::load(p, "encoder.conv_norm_out", g, top, VAE_EPS);
        let encoder_conv_out = Conv2d::load(p, "encoder.conv_out", top, 2 * lat, 3, 1, 1, true);
        let quant_conv = Conv2d::load(p, "quant_conv", 2 * lat, 2 * lat, 1, 1, 0, true);
        let post_quant_conv = Conv2d::load(p, "post_quant_conv", lat, lat, 1, 1, 0, true);

        let decoder_conv_in = Conv2d::load(p, "decoder.conv_in", lat, top, 3, 1, 1, true);
        let decoder_mid = MidBlock::load(p, "decoder.mid_block", top, g);
        let mut decoder_blocks = Vec::new();
        let mut c_prev = top;
        for (i, &c_out) in ch.iter().rev().enumerate() {
            let key = format!("decoder.up_blocks.{i}");
            let resnets = (0..c.layers_per_block + 1)
                .map(|j| {
                    let c_in = if j == 0 { c_prev } else { c_out };
                    ResnetBlock::load(p, &format!("{key}.resnets.{j}"), shape(c_in, c_out))
                })
                .collect();
            let upsampler = (i + 1 < levels).then(|| Upsample::load(p, &format!("{key}.upsamplers.0"), c_out));
            decoder_blocks.push(DecoderBlock { resnets, upsampler });
            c_prev = c_out;
        }
        let decoder_norm_out = GroupNorm::load(p, "decoder.conv_norm_out", g, ch[0], VAE_EPS);
        let decoder_conv_out = Conv2d::load(p, "decoder.conv_out", ch[0], c.out_channels, 3, 1, 1, true);
        Self {
            encoder_conv_in,
            encoder_blocks,
            encoder_mid,
            encoder_norm_out,
            encoder_conv_out,
            quant_conv,
            post_quant_conv,
            decoder_conv_in,
            decoder_mid,
            decoder_blocks,
            decoder_norm_out,
            decoder_conv_out,
            config: c.clone(),
            names: Arc::default(),
        }
    }

    /// The mean (= mode) of the latent distribution of `image` (`[n, 3, H, W]` in `[-1, 1]`),
    /// unscaled: multiply by `scaling_factor` for the diffusion model.
    pub fn encode_mean(&self, image: Tensor<4>) -> Result<Tensor<4>, Error> {
        Ok(self.encode_moments(image)?.0)
    }

    /// Mean and log-variance of the diagonal Gaussian latent distribution of `image`
    /// (`[n, 3, H, W]` in `[-1, 1]`), each `[n, latent_channels, H / m, W / m]`, unscaled
    /// (the log-variance clamped to [−30, 20] as diffusers).
    pub fn encode_moments(&self, image: Tensor<4>) -> Result<(Tensor<4>, Tensor<4>), Error> {
        let [n, c, h, w] = image.dims();
        let m = self.config.downscale();
        if c != self.config.in_channels {
            return Err(Error::invalid("image", format!("{} channels (found {c})", self.config.in_channels)));
        }
        if h == 0 || w == 0 || !h.is_multiple_of(m) || !w.is_multiple_of(m) {
            return Err(Error::invalid("image", format!("height and width multiples of {m} (found {h}x{w})")));
        }
        let mut x = self.encoder_conv_in.forward(image);
        for block in &self.encoder_blocks {
            for resnet in &block.resnets {
                x = resnet.forward(x, None);
            }
            if let Some(down) = &block.downsampler {
                x = down.forward(x);
            }
        }
        x = self.encoder_mid.forward(x);
        x = self.encoder_conv_out.forward(self.encoder_norm_out.forward_silu(x));
        let moments = self.quant_conv.forward(x);
        let lat = self.config.latent_channels;
        let mean = moments.clone().slice([0..n, 0..lat, 0..h / m, 0..w / m]);
        let logvar = moments.slice([0..n, lat..2 * lat, 0..h / m, 0..w / m]).clamp(-30.0, 20.0);
        Ok((mean, logvar))
    }

    /// The parameters of the decoding half (`post_quant_conv` and `decoder.*`): what a
    /// decoder-only fine-tune trains, leaving the encoder and so the latent space alone.
    #[cfg(feature = "train")]
    pub(crate) fn decoder_param_ids(&self) -> Vec<burn::module::ParamId> {
        use crate::loading::weights::collect_named_ids;
        let mut ids = collect_named_ids(&self.post_quant_conv);
        ids.extend(collect_named_ids(&self.decoder_conv_in));
        ids.extend(collect_named_ids(&self.decoder_mid));
        ids.extend(collect_named_ids(&self.decoder_blocks));
        ids.extend(collect_named_ids(&self.decoder_norm_out));
        ids.extend(collect_named_ids(&self.decoder_conv_out));
        ids
    }

    /// This model with `scaling_factor` set (the factor that brings the latents of the
    /// training images to unit standard deviation for the diffusion model).
    pub fn with_scaling_factor(mut self, scaling_factor: f64) -> Self {
        self.config.scaling_factor = scaling_factor;
        self
    }

    /// Decodes unscaled latents `[n, latent_channels, h, w]` into images `[n, 3, h·8, w·8]`
    /// (nominally `[-1, 1]`, not clamped).
    pub fn decode(&self, latents: Tensor<4>) -> Result<Tensor<4>, Error> {
        let [_, c, h, w] = latents.dims();
        if c != self.config.latent_channels || h == 0 || w == 0 {
            return Err(Error::invalid(
                "latents",
                format!("{} channels (found {c}, {h}x{w})", self.config.latent_channels),
            ));
        }
        let mut x = self.decoder_conv_in.forward(self.post_quant_conv.forward(latents));
        x = self.decoder_mid.forward(x);
        for block in &self.decoder_blocks {
            for resnet in &block.resnets {
                x = resnet.forward(x, None);
            }
            if let Some(up) = &block.upsampler {
                x = up.forward(x);
            }
        }
        Ok(self.decoder_conv_out.forward(self.decoder_norm_out.forward_silu(x)))
    }
}

/// Renames the pre-0.14 diffusers attention keys to the current names.
fn rename_legacy_vae_key(key: &str) -> String {
    if !key.contains(".attentions.") {
        return key.to_string();
    }
    key.replace(".query.", ".to_q.")
        .replace(".key.", ".to_k.")
        .replace(".value.", ".to_v.")
        .replace(".proj_attn.", ".to_out.0.")
}

impl Checkpoint for Vae {
    type Config = VaeConfig;
    const WEIGHTS_STEM: &'static str = "diffusion_pytorch_model";

    fn model_key(file_key: &str) -> String {
        rename_legacy_vae_key(file_key)
    }

    fn build(config: &VaeConfig, p: &mut ParamSource) -> Result<Self, Error> {
        Ok(Vae::build(config, p))
    }

    fn set_names(&mut self, names: Vec<NamedParam>) {
        self.names = Arc::new(names);
    }

    fn names(&self) -> &[NamedParam] {
        &self.names
    }

    fn config(&self) -> &VaeConfig {
        &self.config
    }

    fn class_fields(&self) -> Vec<(&'static str, &'static str)> {
        vec![("_class_name", "AutoencoderKL")]
    }
}
