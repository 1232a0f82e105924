//! CLIP vision transformer with projection (transformers `CLIPVisionModelWithProjection`) and
//! the `CLIPImageProcessor` preprocessing.
//!
//! Pixels in: `[n, 3, image_size, image_size]`, normalised with [`CLIP_MEAN`] / [`CLIP_STD`].
//! Out: image embeddings `[n, projection_dim]` (the projected, post-LayerNorm class token).

use std::sync::Arc;

use burn::module::Module;
use burn::tensor::Tensor;
use w3d_core::Error;

use crate::loading::checkpoint::{self, Checkpoint};
use crate::loading::config::ClipVisionConfig;
use crate::loading::weights::{Init, NamedParam, ParamSource};
use crate::models::clip::encoder::ClipEncoder;
use crate::nn::{LayerNorm, Linear};

/// Per-channel RGB mean of CLIP's normalisation (pixels in `[0, 1]`).
#[allow(clippy::excessive_precision)] // the published constants, digit for digit
pub const CLIP_MEAN: [f32; 3] = [0.481_454_66, 0.457_827_5, 0.408_210_73];
/// Per-channel RGB standard deviation of CLIP's normalisation.
#[allow(clippy::excessive_precision)] // the published constants, digit for digit
pub const CLIP_STD: [f32; 3] = [0.268_629_54, 0.261_302_58, 0.275_777_11];

/// The CLIP image encoder (see the module docs).
#[derive(Module, Debug)]
pub struct ClipVision {
    class_embedding: burn::module::Param<Tensor<1>>,
    /// Patch embedding as a linear map of flattened `[c, p, p]` patches: `[c·p·p, hidden]`.
    patch_embedding: Linear,
    position_embedding: burn::module::Param<Tensor<2>>,
    pre_layrnorm: LayerNorm,
    encoder: ClipEncoder,
    post_layernorm: LayerNorm,
    visual_projection: Linear,
    #[module(skip)]
    config: ClipVisionConfig,
    #[module(skip)]
    names: Arc<Vec<NamedParam>>,
}

impl ClipVision {
    checkpoint::checkpoint_methods!(ClipVisionConfig, "image_encoder/");

    fn build(c: &ClipVisionConfig, p: &mut ParamSource) -> Self {
        let d = c.hidden_size;
        let patch = c.patch_size;
        let patch_in = c.num_channels * patch * patch;
        let tokens = c.patches_per_side().pow(2) + 1;
        let class_embedding = p.param("vision_model.embeddings.class_embedding", [d], Init::Uniform { fan_in: d });
        let patch_embedding = Linear {
            weight: p.transposed_weight(
                "vision_model.embeddings.patch_embedding.weight",
                d,
                &[c.num_channels, patch, patch],
                Init::Uniform { fan_in: patch_in },
            ),
            bias: None,
        };
        let position_embedding =
            p.param("vision_model.embeddings.position_embedding.weight", [tokens, d], Init::Uniform { fan_in: d });
        let eps = c.layer_norm_eps;
        let pre_layrnorm = LayerNorm::load(p, "vision_model.pre_layrnorm", d, eps);
        let encoder = ClipEncoder::load(p, "vision_model.encoder", c.num_hidden_layers, d, c.intermediate_size, eps);
        let post_layernorm = LayerNorm::load(p, "vision_model.post_layernorm", d, eps);
        let visual_projection = Linear::load(p, "visual_projection", d, c.projection_dim, false);
        Self {
            class_embedding,
            patch_embedding,
            position_embedding,
            pre_layrnorm,
            encoder,
            post_layernorm,
            visual_projection,
            config: c.clone(),
            names: Arc::default(),
        }
    }

    /// Image embeddings `[n, projection_dim]` of normalised pixels `[n, 3, S, S]`
    /// (S = `image_size`).
    pub fn image_embeds(&self, pixels: Tensor<4>) -> Result<Tensor<2>, Error> {
        let c = &self.config;
        let [n, ch, h, w] = pixels.dims();
        if ch != c.num_channels || h != c.image_size || w != c.image_size {
            return Err(Error::invalid(
                "pixels",
                format!("[n, {}, {}, {}] (found {:?})", c.num_channels, c.image_size, c.image_size, pixels.dims()),
            ));
        }
        let (p, g, d) = (c.patch_size, c.patches_per_side(), c.hidden_size);
        // Non-overlapping patches → tokens [n, g·g, c·p·p] (channel-major like the conv weight).
        let patches: Tensor<6> = pixels.reshape([n, ch, g, p, g, p]);
        let patches = patches.permute([0, 2, 4, 1, 3, 5]).reshape([n, g * g, ch * p * p]);
        let tokens = self.patch_embedding.forward(patches);
        let class = self.class_embedding.val().reshape([1, 1, d]).expand([n, 1, d]);
        let x = Tensor::cat(vec![class, tokens], 1) + self.position_embedding.val().unsqueeze::<3>();
        let x = self.pre_layrnorm.forward(x);
        let x = self.encoder.forward(x, c.num_attention_heads, &c.hidden_act, false);
        let pooled = x.slice([0..n, 0..1, 0..d]).reshape([n, d]);
        Ok(self.visual_projection.forward(self.post_layernorm.forward(pooled)))
    }
}

impl Checkpoint for ClipVision {
    type Config = ClipVisionConfig;
    const WEIGHTS_STEM: &'static str = "model";

    fn is_buffer(key: &str) -> bool {
        key == "vision_model.embeddings.position_ids"
    }

    fn build(config: &ClipVisionConfig, p: &mut ParamSource) -> Result<Self, Error> {
        Ok(ClipVision::build(config, p))
    }

    fn set_names(&mut self, names: Vec<NamedParam>) {
        self.names = Arc::new(names);
    }

    fn names(&self) -> &[NamedParam] {
        &self.names
    }

    fn config(&self) -> &ClipVisionConfig {
        &self.config
    }

    fn class_fields(&self) -> Vec<(&'static str, &'static str)> {
        vec![("model_type", "clip_vision_model"), ("architectures", "CLIPVisionModelWithProjection")]
    }
}

/// `CLIPImageProcessor`: resize the shorter side to `size` (bicubic, antialiased like PIL),
/// centre-crop `size²`, scale to `[0, 1]` and normalise with [`CLIP_MEAN`] / [`CLIP_STD`].
///
/// `rgb` is `[height][width][3]` row-major with values in `[0, 255]` (8-bit sample values,
/// as f32). Returns `[3, size, size]` channel-major.
pub fn preprocess(rgb: &[f32], width: usize, height: usize, size: usize) -> Result<Vec<f32>, Error> {
    resize_crop_normalize(rgb, width, height, size, |v| v / 255.0)
}

/// The Wonder3D++ authors' IP-Adapter preprocessing (`docs/weights.md`, "IP-Adapter
/// (enhancer)"): `CLIPImageProcessor` fed a float image already in `[0, 1]`, which it rescales
/// by 1/255 a second time, so CLIP sees an almost black image (≈ −mean/std per channel; the
/// image survives with an amplitude of at most 1/255 before normalisation).
///
/// `rgb` is `[height][width][3]` row-major with values in `[0, 1]`; returns `[3, size, size]`
/// channel-major like [`preprocess`]. As transformers: the floats become 8-bit levels
/// `trunc(255·v)` for PIL's bicubic resize (an image holding only 0s and 1s is taken as
/// 8-bit levels 0 and 1 instead, unscaled), the resized levels are divided by 255 (not for
/// such a 0/1 image), centre-cropped, divided by 255 again and normalised with [`CLIP_MEAN`] /
/// [`CLIP_STD`]. Values outside `[0, 1]` (or NaN) are an error, as in transformers. The
/// resize is [`preprocess`]'s (f64 per pass, rounded to 8 bits like PIL, which works in fixed
/// point): where a value sits at a rounding edge a level may differ by one, 1/255²/std ≈ 6e-5
/// here (none did on the parity fixture).
pub fn preprocess_rescaled_twice(rgb: &[f32], width: usize, height: usize, size: usize) -> Result<Vec<f32>, Error> {
    if let Some(v) = rgb.iter().find(|v| !(0.0..=1.0).contains(*v)) {
        return Err(Error::invalid("image", format!("values in [0, 1] (found {v})")));
    }
    // transformers' `_rescale_for_pil_conversion`: values `np.allclose` to their integer
    // truncation (in [0, 1]: ≤ 1e-8 or exactly 1) are 8-bit levels already.
    let levels_already = rgb.iter().all(|&v| v <= 1e-8 || v == 1.0);
    let levels: Vec<f32> = if levels_already {
        rgb.iter().map(|v| v.trunc()).collect()
    } else {
        rgb.iter().map(|v| (v * 255.0).trunc()).collect()
    };
    let rescale = |v: f32| (f64::from(v) / 255.0) as f32;
    resize_crop_normalize(&levels, width, height, size, |v| {
        let v = if levels_already { v } else { rescale(v) };
        rescale(v)
    })
}

/// Bicubic resize of the shorter side to `size` and centre crop of 8-bit levels `rgb`
/// (`[height][width][3]`), each level mapped by `scale` into `[0, 1]`-ish values and
/// normalised with [`CLIP_MEAN`] / [`CLIP_STD`]: `[3, size, size]`.
fn resize_crop_normalize(
    rgb: &[f32],
    width: usize,
    height: usize,
    size: usize,
    scale: impl Fn(f32) -> f32,
) -> Result<Vec<f32>, Error> {
    if width == 0 || height == 0 || rgb.len() != width * height * 3 {
        return Err(Error::invalid(
            "image",
            format!("{width}x{height}x3 = {} values (found {})", width * height * 3, rgb.len()),
        ));
    }
    if size == 0 {
        return Err(Error::invalid("size", "at least 1"));
    }
    // transformers: the shorter side becomes `size`, the other int(size * long / short).
    let (new_w, new_h) = if width <= height {
        (size, (size as f64 * height as f64 / width as f64) as usize)
    } else {
        ((size as f64 * width as f64 / height as f64) as usize, size)
    };
    let resized = resize_bicubic(rgb, width, height, new_w, new_h);
    let top = (new_h - size) / 2;
    let left = (new_w - size) / 2;
    let mut out = vec![0.0f32; 3 * size * size];
    for ch in 0..3 {
        for y in 0..size {
            for x in 0..size {
                let v = scale(resized[((top + y) * new_w + left + x) * 3 + ch]);
                out[(ch * size + y) * size + x] = (v - CLIP_MEAN[ch]) / CLIP_STD[ch];
            }
        }
    }
    Ok(out)
}

/// Keys' bicubic kernel with a = -0.5 (PIL's `BICUBIC`).
fn bicubic(x: f64) -> f64 {
    let a = -0.5;
    let x = x.abs();
    if x < 1.0 {
        ((a + 2.0) * x - (a + 3.0)) * x * x + 1.0
    } else if x < 2.0 {
        (((x - 5.0) * x + 8.0) * x - 4.0) * a
    } else {
        0.0
    }
}

/// Separable resampling weights of PIL's `ImagingResample` (support scaled when shrinking).
fn resample_weights(src: usize, dst: usize) -> Vec<(usize, Vec<f64>)> {
    let scale = src as f64 / dst as f64;
    let filter_scale = scale.max(1.0);
    let support = 2.0 * filter_scale;
    (0..dst)
        .map(|i| {
            let center = (i as f64 + 0.5) * scale;
            let xmin = ((center - support + 0.5).floor().max(0.0)) as usize;
            let xmax = ((center + support + 0.5).floor() as usize).min(src);
            let mut w: Vec<f64> = (xmin..xmax).map(|x| bicubic((x as f64 - center + 0.5) / filter_scale)).collect();
            let total: f64 = w.iter().sum();
            if total != 0.0 {
                w.iter_mut().for_each(|v| *v /= total);
            }
            (xmin, w)
        })
        .collect()
}

/// Bicubic resize of `[h][w][3]`, horizontal then vertical pass, each rounded and clamped to
/// `[0, 255]` as PIL does on 8-bit images.
pub(crate) fn resize_bicubic(rgb: &[f32], w: usize, h: usize, new_w: usize, new_h: usize) -> Vec<f32> {
    let round = |v: f64| v.round().clamp(0.0, 255.0) as f32;
    let horizontal = resample_weights(w, new_w);
    let mut tmp = vec![0.0f32; h * new_w * 3];
    for y in 0..h {
        for (x, (start, weights)) in horizontal.iter().enumerate() {
            for ch in 0..3 {
                let v: f64 =
                    weights.iter().enumerate().map(|(k, wt)| wt * rgb[(y * w + start + k) * 3 + ch] as f64).sum();
                tmp[(y * new_w + x) * 3 + ch] = round(v);
            }
        }
    }
    let vertical = resample_weights(h, new_h);
    let mut out = vec![0.0f32; new_h * new_w * 3];
    for (y, (start, weights)) in vertical.iter().enumerate() {
        for x in 0..new_w {
            for ch in 0..3 {
                let v: f64 =
                    weights.iter().enumerate().map(|(k, wt)| wt * tmp[((start + k) * new_w + x) * 3 + ch] as f64).sum();
                out[(y * new_w + x) * 3 + ch] = round(v);
            }
        }
    }
    out
}
