//! IP-Adapter (`h94/IP-Adapter`, `ip-adapter_sd15.safetensors` layout): an image prompt for a
//! Stable Diffusion 1.5 UNet, as the Wonder3D++ enhancer uses it (`docs/weights.md`,
//! "IP-Adapter (enhancer)").
//!
//! - The image encoder is a CLIP ViT-H/14 (`models/image_encoder`), run by
//!   [`crate::ClipVision`]; its `image_embeds` `[n, 1024]` are the adapter's input.
//! - [`ImageProjection`] turns each embedding into `tokens` (4) image tokens of the UNet's
//!   cross-attention width (768): Linear(embed → tokens · width) → reshape → LayerNorm.
//! - Every cross-attention (`attn2`) layer of the UNet gains `to_k_ip` / `to_v_ip`
//!   (Linear(width → layer width, no bias)) and adds a decoupled image attention to its text
//!   attention: `to_out(SDPA(q, K_text, V_text) + scale · SDPA(q, K_ip, V_ip))`
//!   ([`crate::models::blocks::Attention::forward_with_ip`]). Self-attention layers are unchanged.
//! - [`UNet::load_ip_adapter`] reads the file; [`IpTokens`] in [`crate::models::unet::UNetExtra`] pass the
//!   tokens of one call to [`UNet::forward_with`].
//!
//! Batches: one token row per UNet row. Under classifier-free guidance the unconditional rows
//! get the projection of a **zero** embedding (LayerNorm of the reshaped bias, not zero
//! tokens), see [`ImageProjection::guided`]. Repeating a row's tokens (the authors' pipeline
//! gives each row the tokens of two identical images, 8 tokens) does not change the softmax
//! attention, so 4 tokens per row give the same result.

use std::path::Path;

use burn::module::Module;
use burn::tensor::Tensor;
use w3d_core::Error;

use crate::loading::weights::{ParamSource, SafetensorsFile};
use crate::models::blocks::{IpKeyValue, IpTokens};
use crate::models::unet::UNet;
use crate::nn::{LayerNorm, Linear};

/// The image projection of an IP-Adapter file (`image_proj.proj`, `image_proj.norm`;
/// diffusers' `ImageProjection`): CLIP image embeddings `[n, embed_dim]` →
/// image tokens `[n, tokens, cross_dim]`.
#[derive(Module, Debug)]
pub struct ImageProjection {
    /// `image_proj.proj`: Linear(embed_dim → tokens · cross_dim, with bias).
    proj: Linear,
    /// `image_proj.norm`: LayerNorm(cross_dim, eps 1e-5) on each token.
    norm: LayerNorm,
    /// Tokens per embedding.
    tokens: usize,
}

impl ImageProjection {
    /// `key.proj` and `key.norm` with the given sizes.
    fn load(p: &mut ParamSource, key: &str, embed_dim: usize, tokens: usize, cross_dim: usize) -> Self {
        Self {
            proj: Linear::load(p, &format!("{key}.proj"), embed_dim, tokens * cross_dim, true),
            norm: LayerNorm::load(p, &format!("{key}.norm"), cross_dim, 1e-5),
            tokens,
        }
    }

    /// `[n, embed_dim]` → `[n, tokens, cross_dim]` (tokens = projection width / cross_dim):
    /// the projection, split into tokens, each layer-normalised.
    pub fn forward(&self, image_embeds: Tensor<2>) -> Result<Tensor<3>, Error> {
        let [n, d] = image_embeds.dims();
        if n == 0 || d != self.embed_dim() {
            return Err(Error::invalid(
                "image_embeds",
                format!("[n ≥ 1, {}] (found {:?})", self.embed_dim(), image_embeds.dims()),
            ));
        }
        let x = self.proj.forward(image_embeds).reshape([n, self.tokens, self.cross_dim()]);
        Ok(self.norm.forward(x))
    }

    /// The IP tokens of a classifier-free-guidance batch `[unconditional rows, conditional
    /// rows]` for `image_embeds [b, embed_dim]`: `[2b, tokens, cross_dim]`, the first `b` rows
    /// the projection of a zero embedding (as diffusers' pipelines build the unconditional
    /// half), the last `b` the projection of `image_embeds`; with the image-attention `scale`.
    pub fn guided(&self, image_embeds: Tensor<2>, scale: f32) -> Result<IpTokens, Error> {
        let zeros = image_embeds.zeros_like();
        let tokens = self.forward(Tensor::cat(vec![zeros, image_embeds], 0))?;
        Ok(IpTokens { tokens, scale })
    }

    /// Image tokens per embedding (4 for `ip-adapter_sd15`).
    pub fn tokens(&self) -> usize {
        self.tokens
    }

    /// Width of the image embeddings taken (1024 for `ip-adapter_sd15`).
    pub fn embed_dim(&self) -> usize {
        self.proj.weight.dims()[0]
    }

    /// Width of the tokens produced, the UNet's `cross_attention_dim` (768 for SD1.5).
    pub fn cross_dim(&self) -> usize {
        self.norm.weight.dims()[0]
    }
}

impl UNet {
    /// Loads an `ip-adapter_sd15.safetensors`-layout file (f32, f16 or bf16): adds `to_k_ip` /
    /// `to_v_ip` (`ip_adapter.{k}.to_{k,v}_ip.weight`, `[layer width, cross_attention_dim]`) to
    /// every cross-attention (`attn2`) layer, numbered as diffusers' loader does (k = 1, 3, 5, …
    /// over the cross-attentions of the down blocks, then the up blocks, then the mid block),
    /// and returns the image projection (`image_proj.proj.{weight,bias}`
    /// `[tokens · cross_attention_dim, embed_dim]`, `image_proj.norm.{weight,bias}`).
    ///
    /// The UNet is changed only on success. Errors name every missing, unexpected or
    /// misshaped key; it is an error if the UNet has an adapter already or has cross-domain
    /// attention (whose layers diffusers would number too). The adapter's weights are not
    /// part of [`UNet::named_parameters`], so [`UNet::save`] writes the UNet without them.
    pub fn load_ip_adapter(&mut self, file: impl AsRef<Path>) -> Result<ImageProjection, Error> {
        let path = file.as_ref();
        if self.has_ip_adapter() {
            return Err(Error::invalid("unet", "a model without an IP-Adapter (one is loaded already)"));
        }
        let config = self.config();
        if config.cd_attention_mid || config.cd_attention_last {
            return Err(Error::invalid(
                "unet cd_attention_mid / cd_attention_last",
                "false (IP-Adapter files number the cross-attention layers of a UNet without cross-domain attention)",
            ));
        }
        let cross = config.cross_attention_dim;
        let mut file = SafetensorsFile::open(path)?;
        let proj_key = "image_proj.proj.weight";
        let expected =
            format!("a tensor [tokens · {cross}, embed_dim] (tokens ≥ 1; {cross} = the UNet's cross_attention_dim)");
        let (out, embed_dim) = match file.shapes().find(|(k, _)| *k == proj_key).map(|(_, s)| s.to_vec()).as_deref() {
            Some(&[out, embed]) if out > 0 && embed > 0 && out.is_multiple_of(cross) => (out, embed),
            Some(shape) => return Err(Error::format(path, proj_key, format!("{expected} (found {shape:?})"))),
            None => return Err(Error::format(path, proj_key, expected)),
        };
        let widths: Vec<usize> = self.cross_attentions().map(|a| a.width()).collect();
        let device = self.devices().into_iter().next().unwrap_or_default();
        let mut p = ParamSource::from_file(&mut file, str::to_string, &device);
        let projection = ImageProjection::load(&mut p, "image_proj", embed_dim, out / cross, cross);
        let layers: Vec<IpKeyValue> = widths
            .iter()
            .enumerate()
            .map(|(i, &width)| {
                let key = format!("ip_adapter.{}", 2 * i + 1);
                IpKeyValue {
                    to_k_ip: Linear::load(&mut p, &format!("{key}.to_k_ip"), cross, width, false),
                    to_v_ip: Linear::load(&mut p, &format!("{key}.to_v_ip"), cross, width, false),
                }
            })
            .collect();
        p.finish()?;
        for (attention, ip) in self.cross_attentions_mut().zip(layers) {
            attention.set_ip(ip);
        }
        Ok(projection)
    }

    /// Whether the UNet's cross-attentions carry an IP-Adapter ([`UNet::load_ip_adapter`]).
    pub fn has_ip_adapter(&self) -> bool {
        self.cross_attentions().any(|a| a.has_ip())
    }
}
