//! Model configurations that deserialize the diffusers / transformers `config.json` files as
//! they are shipped in a checkpoint directory (`unet/`, `vae/`, `image_encoder/`, `scheduler/`).
//!
//! Fields a file omits take the default value of the Python class constructor (that is what
//! diffusers does too), except that a multi-view UNet config lacking a field the authors'
//! inference script passes explicitly gets the authors' value ([`AUTHORS_INFERENCE_UNET_KWARGS`],
//! reported on stderr and in [`UNetConfig::applied_overrides`]). Values this implementation does not support are rejected by
//! `validate` with an error naming the field, never silently ignored.

use std::path::Path;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use w3d_core::Error;

/// The widest channel count, hidden size or attention width a config may ask for. A config is
/// a claim that the weights are checked against only later: these bounds, far above every
/// Stable-Diffusion-family model (widths up to 1280, CLIP-H MLP 5120), stop a damaged or
/// hostile `config.json` from asking for terabytes or for hours of layer building first.
pub const MAX_WIDTH: usize = 8192;
/// The most layers a block (ResNets, transformer layers, CLIP encoder layers) may have.
pub const MAX_LAYERS: usize = 128;
/// The most resolution levels (down blocks) of a UNet or VAE.
pub const MAX_LEVELS: usize = 8;
/// The largest image side (pixels) a CLIP config may declare.
pub const MAX_IMAGE_SIDE: usize = 4096;

/// Fails unless `1 <= value <= max`, naming `field`.
fn in_range(field: &str, value: usize, max: usize) -> Result<(), Error> {
    if (1..=max).contains(&value) {
        Ok(())
    } else {
        Err(Error::invalid(field, format!("a value in 1..={max}, found {value}")))
    }
}

/// [`in_range`] for every entry of a per-block list.
fn all_in_range(field: &str, values: &[usize], max: usize) -> Result<(), Error> {
    values.iter().enumerate().try_for_each(|(i, &v)| in_range(&format!("{field}[{i}]"), v, max))
}

/// [`in_range`] for a `PerBlock` value.
fn per_block_in_range(field: &str, value: &Option<PerBlock>, max: usize) -> Result<(), Error> {
    match value {
        None => Ok(()),
        Some(PerBlock::All(v)) => in_range(field, *v, max),
        Some(PerBlock::Each(v)) => all_in_range(field, v, max),
    }
}

/// Reads and parses a JSON config file.
fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T, Error> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut json = serde_json::Deserializer::from_str(&text);
    serde_path_to_error::deserialize(&mut json).map_err(|e| {
        let key = e.path().to_string();
        let field = if key == "." { "json".to_string() } else { format!("json {key}") };
        Error::format(path, field, format!("a valid config ({})", e.inner()))
    })
}

/// `value` as the config `T`; a value of the wrong type is named by its key
/// (`config layers_per_block: expected a valid UNet config (invalid type: …)`).
fn parse_config<T: DeserializeOwned>(value: serde_json::Value, what: &str) -> Result<T, Error> {
    serde_path_to_error::deserialize(value).map_err(|e| {
        let key = e.path().to_string();
        let field = if key == "." { "config".to_string() } else { format!("config {key}") };
        Error::invalid(field, format!("a valid {what} ({})", e.inner()))
    })
}

/// A value that is either one number for every block or one number per block (diffusers
/// accepts both for `attention_head_dim`, `num_attention_heads`, `transformer_layers_per_block`).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(untagged)]
pub enum PerBlock {
    /// The same value for every block.
    All(usize),
    /// One value per down block (up blocks use the list reversed).
    Each(Vec<usize>),
}

impl PerBlock {
    /// The value for block `index` of `count` blocks.
    fn get(&self, field: &str, index: usize, count: usize) -> Result<usize, Error> {
        match self {
            PerBlock::All(v) => Ok(*v),
            PerBlock::Each(v) if v.len() == count => Ok(v[index]),
            PerBlock::Each(v) => Err(Error::invalid(field, format!("{count} values, found {}", v.len()))),
        }
    }
}

fn default_true() -> bool {
    true
}
fn default_silu() -> String {
    "silu".into()
}
fn default_groups() -> usize {
    32
}
fn default_in_out4() -> usize {
    4
}
fn default_layers() -> usize {
    2
}
fn default_one() -> f64 {
    1.0
}
fn default_one_usize() -> usize {
    1
}
fn default_eps5() -> f64 {
    1e-5
}

/// `UNet2DConditionModel` config (diffusers `unet/config.json`). Channel counts are feature
/// channels; `sample_size` is the latent side in pixels (image side / 8).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
pub struct UNetConfig {
    /// Latent channels in (4 for SD, 8 for Wonder3D: noisy latent + condition latent).
    #[serde(default = "default_in_out4")]
    pub in_channels: usize,
    /// Latent channels out (the predicted noise / v).
    #[serde(default = "default_in_out4")]
    pub out_channels: usize,
    /// Latent side the model was trained at (informational).
    #[serde(default)]
    pub sample_size: Option<usize>,
    /// Whether the input is mapped `x -> 2x - 1` first.
    #[serde(default)]
    pub center_input_sample: bool,
    /// Sinusoidal timestep embedding puts cos before sin.
    #[serde(default = "default_true")]
    pub flip_sin_to_cos: bool,
    /// `downscale_freq_shift` of the timestep embedding.
    #[serde(default)]
    pub freq_shift: f64,
    /// Down block kinds: `CrossAttnDownBlock2D`, Wonder3D's multi-view
    /// `CrossAttnDownBlockMV2D`, or `DownBlock2D` (no attention).
    pub down_block_types: Vec<String>,
    /// Mid block kind: `UNetMidBlock2DCrossAttn` or the multi-view `UNetMidBlockMV2DCrossAttn`
    /// (absent: multi-view when the down blocks are, as Wonder3D's `UNetMV2DConditionModel`).
    #[serde(default)]
    pub mid_block_type: Option<String>,
    /// Up block kinds: `CrossAttnUpBlock2D`, the multi-view `CrossAttnUpBlockMV2D`, or
    /// `UpBlock2D`.
    pub up_block_types: Vec<String>,
    /// Output channels of each down level.
    pub block_out_channels: Vec<usize>,
    /// ResNet layers per down block (up blocks have one more).
    #[serde(default = "default_layers")]
    pub layers_per_block: usize,
    /// Padding of the stride-2 down-sampling convolutions.
    #[serde(default = "default_one_usize")]
    pub downsample_padding: usize,
    /// Output scale of the mid block's ResNets.
    #[serde(default = "default_one")]
    pub mid_block_scale_factor: f64,
    /// Activation (`silu`).
    #[serde(default = "default_silu")]
    pub act_fn: String,
    /// GroupNorm groups.
    #[serde(default = "default_groups")]
    pub norm_num_groups: usize,
    /// GroupNorm epsilon of the ResNets and the output norm.
    #[serde(default = "default_eps5")]
    pub norm_eps: f64,
    /// Width of the conditioning tokens (768 for the CLIP image embedding).
    pub cross_attention_dim: usize,
    /// Transformer layers per attention block.
    #[serde(default)]
    pub transformer_layers_per_block: Option<PerBlock>,
    /// diffusers quirk: when `num_attention_heads` is absent this is the number of **heads**.
    #[serde(default)]
    pub attention_head_dim: Option<PerBlock>,
    /// Number of attention heads (overrides `attention_head_dim` when present).
    #[serde(default)]
    pub num_attention_heads: Option<PerBlock>,
    /// Linear (instead of 1x1 conv) transformer in/out projections.
    #[serde(default)]
    pub use_linear_projection: bool,
    /// Class embedding kind: absent or `projection`.
    #[serde(default)]
    pub class_embed_type: Option<String>,
    /// Input width of the `projection` class embedding.
    #[serde(default)]
    pub projection_class_embeddings_input_dim: Option<usize>,
    /// Concatenate instead of add the class embedding (unsupported: must be false).
    #[serde(default)]
    pub class_embeddings_concat: bool,
    /// `default` only.
    #[serde(default)]
    pub resnet_time_scale_shift: Option<String>,
    /// `positional` only.
    #[serde(default)]
    pub time_embedding_type: Option<String>,
    /// Unsupported when true.
    #[serde(default)]
    pub dual_cross_attention: bool,
    /// Unsupported when true.
    #[serde(default)]
    pub only_cross_attention: Option<serde_json::Value>,
    /// Unsupported when set.
    #[serde(default)]
    pub addition_embed_type: Option<String>,
    /// Unsupported when set.
    #[serde(default)]
    pub encoder_hid_dim: Option<usize>,
    /// Unsupported when set.
    #[serde(default)]
    pub time_cond_proj_dim: Option<usize>,
    /// Kernel of `conv_in` (3).
    #[serde(default)]
    pub conv_in_kernel: Option<usize>,
    /// Kernel of `conv_out` (3).
    #[serde(default)]
    pub conv_out_kernel: Option<usize>,
    /// Only `false`/absent supported (f32 attention is already full precision).
    #[serde(default)]
    pub upcast_attention: Option<bool>,
    /// Wonder3D: views per object in the batch (absent: 1). In the multi-view blocks every
    /// group of `num_views` consecutive images is one object (and one domain), and the
    /// self-attention of each image attends over the tokens of its whole group.
    #[serde(default)]
    pub num_views: Option<usize>,
    /// Wonder3D: multi-view self-attention in the multi-view blocks (absent: true, the
    /// `UNetMV2DConditionModel` default).
    #[serde(default = "default_true")]
    pub multiview_attention: bool,
    /// Wonder3D: the cross-domain attention (`attn_joint_mid` after the self-attention) in
    /// every multi-view transformer block. The batch is then `[normal half, colour half]`.
    #[serde(default)]
    pub cd_attention_mid: bool,
    /// Wonder3D: a second cross-domain attention (`attn_joint_last`, `norm_joint_last`) after
    /// the feed-forward of every multi-view transformer block, the same layer as
    /// `cd_attention_mid`'s (absent: false, the `UNetMV2DConditionModel` default; false in every
    /// shipped config, and the authors' inference script does not set it). The batch is then
    /// `[normal half, colour half]`.
    #[serde(default)]
    pub cd_attention_last: bool,
    /// Wonder3D: sparse multi-view attention (unsupported: off in every shipped config).
    #[serde(default)]
    pub sparse_mv_attention: bool,
    /// Wonder3D: joint multi-view + cross-domain attention (unsupported: off in every shipped
    /// config).
    #[serde(default)]
    pub mvcd_attention: bool,
    /// Options this implementation only supports at their diffusers default (`null`, `false`,
    /// `1.0` or `"default"`): `time_embedding_dim`, `time_embedding_act_fn`, `timestep_post_act`,
    /// `num_class_embeds`, `attention_type`, `resnet_skip_time_act`, `resnet_out_scale_factor`,
    /// `cross_attention_norm`, `mid_block_only_cross_attention`,
    /// `reverse_transformer_layers_per_block`.
    #[serde(flatten)]
    pub other: serde_json::Map<String, serde_json::Value>,
    /// Fields the multi-view `config.json` lacked (absent or `null`) and that
    /// [`UNetConfig::from_value`] filled with the authors' inference value
    /// ([`AUTHORS_INFERENCE_UNET_KWARGS`]), in that table's order. Empty for a single-view
    /// config or one that states every such field.
    #[serde(skip)]
    pub applied_overrides: Vec<InferenceOverride>,
    /// Fields the multi-view `config.json` sets to another value than the authors' inference
    /// script passes: kept as written, and reported because the authors' run uses their value.
    #[serde(skip)]
    pub differs_from_authors: Vec<ConfigDifference>,
}

/// The UNet keyword arguments of the authors' inference config (Wonder3D++
/// `configs/mvdiffusion-joint.yaml`, `unet_from_pretrained_kwargs`) that shape the network,
/// as JSON text. `run_mv_prediction.py` passes them to `UNetMV2DConditionModel.from_pretrained`
/// on top of the checkpoint's `config.json`, so the model the authors run has these values
/// whatever the file says. The same kwargs also hold `camera_embedding_type: e_de_da_sincos`
/// (the switcher encoding, fixed in [`crate::pipelines::multiview::switcher_labels`]) and
/// `zero_init_conv_in` / `zero_init_camera_projection: false` (initialisation only, void
/// when weights are loaded); `cd_attention_last` is not among them, so it keeps its class
/// default, false.
pub const AUTHORS_INFERENCE_UNET_KWARGS: &[(&str, &str)] = &[
    ("num_views", "6"),
    ("sample_size", "32"),
    ("projection_class_embeddings_input_dim", "14"),
    ("cd_attention_mid", "true"),
    ("multiview_attention", "true"),
    ("sparse_mv_attention", "false"),
    ("mvcd_attention", "false"),
];

/// A field of a multi-view UNet `config.json` filled with the authors' inference value
/// because the file lacked it (see [`UNetConfig::applied_overrides`]).
#[derive(Clone, Debug, PartialEq)]
pub struct InferenceOverride {
    /// The config field, e.g. `num_views`.
    pub field: &'static str,
    /// The value used.
    pub value: serde_json::Value,
}

/// A field of a multi-view UNet `config.json` whose value differs from the authors' inference
/// value (see [`UNetConfig::differs_from_authors`]).
#[derive(Clone, Debug, PartialEq)]
pub struct ConfigDifference {
    /// The config field.
    pub field: &'static str,
    /// The value in the file (the one used).
    pub file: serde_json::Value,
    /// The value the authors' inference script passes.
    pub authors: serde_json::Value,
}

/// Options of `UNet2DConditionModel` that must keep their default value, with the accepted values.
const UNET_DEFAULT_ONLY: &[(&str, &[&str])] = &[
    ("time_embedding_dim", &["null"]),
    ("time_embedding_act_fn", &["null"]),
    ("timestep_post_act", &["null"]),
    ("num_class_embeds", &["null"]),
    ("attention_type", &["\"default\""]),
    ("resnet_skip_time_act", &["false"]),
    ("resnet_out_scale_factor", &["1.0", "1"]),
    ("cross_attention_norm", &["null"]),
    ("mid_block_only_cross_attention", &["null", "false"]),
    ("reverse_transformer_layers_per_block", &["null"]),
];

fn unsupported(field: &str, value: impl std::fmt::Debug, expected: &str) -> Error {
    Error::invalid(field, format!("{expected} (found {value:?})"))
}

impl UNetConfig {
    /// Parses `unet/config.json` ([`UNetConfig::from_value`]) and, for a multi-view config
    /// whose file lacks some of the authors' inference values or states others, prints one
    /// line per kind to stderr naming the fields and values ([`UNetConfig::override_notes`]):
    /// a checkpoint's `config.json` alone does not describe the model the authors run.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self, Error> {
        let path = path.as_ref();
        let value: serde_json::Value = read_json(path)?;
        let config = Self::from_value(value).map_err(|e| e.in_file(path))?;
        for line in config.override_notes(&path.display().to_string()) {
            eprintln!("{line}");
        }
        Ok(config)
    }

    /// Parses and validates a UNet config. A multi-view config (`_class_name`
    /// `UNetMV2DConditionModel` or a multi-view block type) gets every field of
    /// [`AUTHORS_INFERENCE_UNET_KWARGS`] it lacks (absent or `null`) set to the authors' value,
    /// recorded in [`UNetConfig::applied_overrides`]; a field it states is kept as written and,
    /// when it differs from the authors' value, recorded in
    /// [`UNetConfig::differs_from_authors`]. A single-view config is parsed as it is.
    pub fn from_value(mut value: serde_json::Value) -> Result<Self, Error> {
        let object = value.as_object_mut().ok_or_else(|| Error::invalid("config", "a JSON object"))?;
        let mut applied = Vec::new();
        let mut differs = Vec::new();
        if json_is_multiview(object) {
            for &(field, text) in AUTHORS_INFERENCE_UNET_KWARGS {
                let authors: serde_json::Value = serde_json::from_str(text)
                    .map_err(|e| Error::invalid(field, format!("a JSON value in the override table ({e})")))?;
                match object.get(field) {
                    None | Some(serde_json::Value::Null) => {
                        object.insert(field.to_string(), authors.clone());
                        applied.push(InferenceOverride { field, value: authors });
                    }
                    Some(file) if !json_equal(file, &authors) => {
                        differs.push(ConfigDifference { field, file: file.clone(), authors });
                    }
                    Some(_) => {}
                }
            }
        }
        let mut config: Self = parse_config(value, "UNet config")?;
        config.applied_overrides = applied;
        config.differs_from_authors = differs;
        config.validate()?;
        Ok(config)
    }

    /// The stderr lines [`UNetConfig::from_file`] prints for `source` (the file's name): one
    /// for the fields filled with the authors' inference values, one for the fields whose
    /// value differs from theirs; none when there is nothing to say.
    pub fn override_notes(&self, source: &str) -> Vec<String> {
        let mut notes = Vec::new();
        if !self.applied_overrides.is_empty() {
            let fields: Vec<&str> = self.applied_overrides.iter().map(|o| o.field).collect();
            let values: Vec<String> = self.applied_overrides.iter().map(|o| o.value.to_string()).collect();
            notes.push(format!(
                "w3d-diffusion: {source} lacks {}: using the authors' inference values {}",
                fields.join(", "),
                values.join(", ")
            ));
        }
        if !self.differs_from_authors.is_empty() {
            let items: Vec<String> = self
                .differs_from_authors
                .iter()
                .map(|d| format!("{} = {} (authors' inference: {})", d.field, d.file, d.authors))
                .collect();
            notes.push(format!(
                "w3d-diffusion: {source} sets {}: keeping the file's values, so this model differs from the authors' run",
                items.join(", ")
            ));
        }
        notes
    }

    /// Checks that every field holds a supported value.
    pub fn validate(&self) -> Result<(), Error> {
        let n = self.block_out_channels.len();
        in_range("block_out_channels (levels)", n, MAX_LEVELS)?;
        all_in_range("block_out_channels", &self.block_out_channels, MAX_WIDTH)?;
        in_range("in_channels", self.in_channels, MAX_WIDTH)?;
        in_range("out_channels", self.out_channels, MAX_WIDTH)?;
        in_range("layers_per_block", self.layers_per_block, MAX_LAYERS)?;
        in_range("norm_num_groups", self.norm_num_groups, MAX_WIDTH)?;
        in_range("cross_attention_dim", self.cross_attention_dim, MAX_WIDTH)?;
        per_block_in_range("transformer_layers_per_block", &self.transformer_layers_per_block, MAX_LAYERS)?;
        per_block_in_range("attention_head_dim", &self.attention_head_dim, MAX_WIDTH)?;
        per_block_in_range("num_attention_heads", &self.num_attention_heads, MAX_WIDTH)?;
        if let Some(d) = self.projection_class_embeddings_input_dim {
            in_range("projection_class_embeddings_input_dim", d, MAX_WIDTH)?;
        }
        if let Some(v) = self.num_views {
            in_range("num_views", v, 64)?;
        }
        if let Some(side) = self.sample_size {
            in_range("sample_size", side, MAX_WIDTH)?;
        }
        if self.down_block_types.len() != n || self.up_block_types.len() != n {
            return Err(Error::invalid(
                "down_block_types/up_block_types",
                format!("one entry per block_out_channels entry ({n})"),
            ));
        }
        for (i, t) in self.down_block_types.iter().enumerate() {
            if !matches!(t.as_str(), "CrossAttnDownBlock2D" | "CrossAttnDownBlockMV2D" | "DownBlock2D") {
                return Err(unsupported(
                    &format!("down_block_types[{i}]"),
                    t,
                    "CrossAttnDownBlock2D, CrossAttnDownBlockMV2D or DownBlock2D",
                ));
            }
        }
        for (i, t) in self.up_block_types.iter().enumerate() {
            if !matches!(t.as_str(), "CrossAttnUpBlock2D" | "CrossAttnUpBlockMV2D" | "UpBlock2D") {
                return Err(unsupported(
                    &format!("up_block_types[{i}]"),
                    t,
                    "CrossAttnUpBlock2D, CrossAttnUpBlockMV2D or UpBlock2D",
                ));
            }
        }
        if let Some(m) = &self.mid_block_type
            && m != "UNetMidBlock2DCrossAttn"
            && m != "UNetMidBlockMV2DCrossAttn"
        {
            return Err(unsupported("mid_block_type", m, "UNetMidBlock2DCrossAttn or UNetMidBlockMV2DCrossAttn"));
        }
        if self.num_views == Some(0) {
            return Err(Error::invalid("num_views", "at least 1"));
        }
        for (field, on) in [("sparse_mv_attention", self.sparse_mv_attention), ("mvcd_attention", self.mvcd_attention)]
        {
            if on {
                return Err(unsupported(field, true, "false"));
            }
        }
        if self.act_fn != "silu" {
            return Err(unsupported("act_fn", &self.act_fn, "silu"));
        }
        if self.block_out_channels.iter().any(|c| !c.is_multiple_of(self.norm_num_groups)) {
            return Err(Error::invalid("block_out_channels", "multiples of norm_num_groups"));
        }
        match (self.class_embed_type.as_deref(), self.projection_class_embeddings_input_dim) {
            (None, _) | (Some("projection"), Some(_)) => {}
            (Some("projection"), None) => {
                return Err(Error::invalid(
                    "projection_class_embeddings_input_dim",
                    "a value for class_embed_type projection",
                ));
            }
            (Some(other), _) => return Err(unsupported("class_embed_type", other, "absent or projection")),
        }
        if self.class_embeddings_concat {
            return Err(unsupported("class_embeddings_concat", true, "false"));
        }
        if let Some(s) = &self.resnet_time_scale_shift
            && s != "default"
        {
            return Err(unsupported("resnet_time_scale_shift", s, "default"));
        }
        if let Some(s) = &self.time_embedding_type
            && s != "positional"
        {
            return Err(unsupported("time_embedding_type", s, "positional"));
        }
        if self.dual_cross_attention {
            return Err(unsupported("dual_cross_attention", true, "false"));
        }
        match &self.only_cross_attention {
            None | Some(serde_json::Value::Bool(false)) => {}
            Some(v) => return Err(unsupported("only_cross_attention", v, "false")),
        }
        if let Some(v) = &self.addition_embed_type {
            return Err(unsupported("addition_embed_type", v, "absent"));
        }
        if let Some(v) = self.encoder_hid_dim {
            return Err(unsupported("encoder_hid_dim", v, "absent"));
        }
        if let Some(v) = self.time_cond_proj_dim {
            return Err(unsupported("time_cond_proj_dim", v, "absent"));
        }
        for (field, k) in [("conv_in_kernel", self.conv_in_kernel), ("conv_out_kernel", self.conv_out_kernel)] {
            if let Some(k) = k
                && k != 3
            {
                return Err(unsupported(field, k, "3"));
            }
        }
        for (field, accepted) in UNET_DEFAULT_ONLY {
            if let Some(v) = self.other.get(*field)
                && !accepted.contains(&v.to_string().as_str())
            {
                return Err(unsupported(field, v, &accepted.join(" or ")));
            }
        }
        for b in 0..n {
            let heads = self.heads(b)?;
            if heads == 0 || !self.block_out_channels[b].is_multiple_of(heads) {
                return Err(Error::invalid(
                    "attention_head_dim",
                    format!("a head count dividing block_out_channels[{b}] = {}", self.block_out_channels[b]),
                ));
            }
            self.transformer_layers(b)?;
        }
        Ok(())
    }

    /// Attention heads of down block `index` (diffusers: `num_attention_heads or attention_head_dim`).
    pub fn heads(&self, index: usize) -> Result<usize, Error> {
        let n = self.block_out_channels.len();
        match (&self.num_attention_heads, &self.attention_head_dim) {
            (Some(h), _) => h.get("num_attention_heads", index, n),
            (None, Some(h)) => h.get("attention_head_dim", index, n),
            (None, None) => Ok(8),
        }
    }

    /// Transformer layers of down block `index`.
    pub fn transformer_layers(&self, index: usize) -> Result<usize, Error> {
        match &self.transformer_layers_per_block {
            None => Ok(1),
            Some(t) => t.get("transformer_layers_per_block", index, self.block_out_channels.len()),
        }
    }

    /// Whether the multi-view blocks have a cross-domain attention (`cd_attention_mid` or
    /// `cd_attention_last`), so that the batch is `[normal half, colour half]`.
    pub fn cross_domain(&self) -> bool {
        self.cd_attention_mid || self.cd_attention_last
    }

    /// Views per object in the batch (`num_views`, 1 when absent).
    pub fn views(&self) -> usize {
        self.num_views.unwrap_or(1)
    }

    /// Whether block kind `kind` (a down, mid or up block type) is one of Wonder3D's
    /// multi-view variants.
    pub fn is_multiview_block(kind: &str) -> bool {
        kind.contains("MV2D")
    }

    /// Whether the mid block is the multi-view variant (see `mid_block_type`).
    pub fn multiview_mid_block(&self) -> bool {
        match &self.mid_block_type {
            Some(kind) => Self::is_multiview_block(kind),
            None => self.down_block_types.iter().any(|k| Self::is_multiview_block(k)),
        }
    }

    /// Width of the time embedding (4 × the first block's channels).
    pub fn time_embed_dim(&self) -> usize {
        self.block_out_channels[0] * 4
    }
}

/// Whether a UNet config object describes Wonder3D's multi-view `UNetMV2DConditionModel`:
/// its class name, or any block type that is a multi-view variant.
fn json_is_multiview(object: &serde_json::Map<String, serde_json::Value>) -> bool {
    if object.get("_class_name").and_then(|v| v.as_str()) == Some("UNetMV2DConditionModel") {
        return true;
    }
    ["down_block_types", "up_block_types"]
        .iter()
        .filter_map(|k| object.get(*k).and_then(|v| v.as_array()))
        .flatten()
        .chain(object.get("mid_block_type"))
        .any(|v| v.as_str().is_some_and(UNetConfig::is_multiview_block))
}

/// JSON equality that treats numbers by value (`32` equals `32.0`, as Python's would).
fn json_equal(a: &serde_json::Value, b: &serde_json::Value) -> bool {
    match (a.as_f64(), b.as_f64()) {
        (Some(x), Some(y)) => x == y,
        _ => a == b,
    }
}

fn default_cond_embedding_channels() -> Vec<usize> {
    vec![16, 32, 96, 256]
}
fn default_rgb() -> String {
    "rgb".into()
}

/// `ControlNetModel` config (the `config.json` of a diffusers ControlNet folder, e.g.
/// Wonder3D++'s `mv_controlnet/`, `docs/weights.md`). A ControlNet is the down half of the UNet
/// it was made from (`ControlNetModel.from_unet` copies the config fields and the weights of
/// `conv_in`, the time embedding, the down blocks and the mid block) plus a condition
/// embedding and zero convolutions, so those fields are held as that UNet's [`UNetConfig`] and
/// read and checked by the same rules. Nothing here records Wonder3D++'s cross-domain
/// attention: a ControlNet has it when its weights do.
#[derive(Clone, Debug, PartialEq)]
pub struct ControlNetConfig {
    /// The fields shared with the UNet (`in_channels`, `block_out_channels`,
    /// `down_block_types`, heads, norms, …). Its `up_block_types` mirror the down blocks
    /// (`CrossAttnUpBlock2D` / `UpBlock2D`, unused: a ControlNet has no up path) and
    /// `out_channels` keeps its default.
    pub unet: UNetConfig,
    /// Channels of the control image (3).
    pub conditioning_channels: usize,
    /// Channels of the condition embedding's convolutions (`[16, 32, 96, 256]` for SD1.5):
    /// every entry after the first halves the side, so the control image is
    /// [`ControlNetConfig::control_downscale`] times the latent's side.
    pub conditioning_embedding_out_channels: Vec<usize>,
    /// `rgb`, or `bgr` (the control image's channels are then reversed first, as diffusers).
    pub controlnet_conditioning_channel_order: String,
    /// Must be false: mean-pooled residuals (diffusers' shuffle ControlNets) are not supported.
    pub global_pool_conditions: bool,
}

/// The ControlNet-only fields of its `config.json`, with the `ControlNetModel` defaults.
#[derive(Deserialize)]
struct ControlNetFields {
    #[serde(default = "default_three")]
    conditioning_channels: usize,
    #[serde(default = "default_cond_embedding_channels")]
    conditioning_embedding_out_channels: Vec<usize>,
    #[serde(default = "default_rgb")]
    controlnet_conditioning_channel_order: String,
    #[serde(default)]
    global_pool_conditions: bool,
}

/// `ControlNetModel` options that must keep their default (`null`), beyond the UNet's.
const CONTROLNET_DEFAULT_ONLY: &[&str] = &["encoder_hid_dim_type", "addition_time_embed_dim"];

impl ControlNetConfig {
    /// Parses and validates a ControlNet `config.json`.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self, Error> {
        let path = path.as_ref();
        let value: serde_json::Value = read_json(path)?;
        Self::from_value(value).map_err(|e| e.in_file(path))
    }

    /// Parses and validates a ControlNet config (a JSON object as diffusers writes it).
    pub fn from_value(mut value: serde_json::Value) -> Result<Self, Error> {
        let fields: ControlNetFields = parse_config(value.clone(), "ControlNet config")?;
        let object = value.as_object_mut().ok_or_else(|| Error::invalid("config", "a JSON object"))?;
        if let Some(class) = object.get("_class_name")
            && class.as_str() != Some("ControlNetModel")
        {
            return Err(unsupported("_class_name", class, "ControlNetModel"));
        }
        for key in [
            "conditioning_channels",
            "conditioning_embedding_out_channels",
            "controlnet_conditioning_channel_order",
            "global_pool_conditions",
        ] {
            object.remove(key);
        }
        let up: Vec<serde_json::Value> = match object.get("down_block_types").and_then(|v| v.as_array()) {
            Some(down) => down
                .iter()
                .rev()
                .map(|kind| match kind.as_str() {
                    Some(k) if k.starts_with("CrossAttn") => "CrossAttnUpBlock2D".into(),
                    _ => "UpBlock2D".into(),
                })
                .collect(),
            None => return Err(Error::invalid("down_block_types", "a list of down block kinds")),
        };
        object.insert("up_block_types".into(), serde_json::Value::Array(up));
        let config = Self {
            unet: UNetConfig::from_value(value)?,
            conditioning_channels: fields.conditioning_channels,
            conditioning_embedding_out_channels: fields.conditioning_embedding_out_channels,
            controlnet_conditioning_channel_order: fields.controlnet_conditioning_channel_order,
            global_pool_conditions: fields.global_pool_conditions,
        };
        config.validate()?;
        Ok(config)
    }

    /// Checks that every field holds a supported value: the UNet fields as
    /// [`UNetConfig::validate`], single-view Stable Diffusion blocks only
    /// (`CrossAttnDownBlock2D` / `DownBlock2D`, `UNetMidBlock2DCrossAttn`), no class or
    /// addition embedding (the enhancer's ControlNet is conditioned on text tokens only).
    pub fn validate(&self) -> Result<(), Error> {
        let u = &self.unet;
        u.validate()?;
        for (i, t) in u.down_block_types.iter().enumerate() {
            if !matches!(t.as_str(), "CrossAttnDownBlock2D" | "DownBlock2D") {
                return Err(unsupported(&format!("down_block_types[{i}]"), t, "CrossAttnDownBlock2D or DownBlock2D"));
            }
        }
        if let Some(m) = &u.mid_block_type
            && m != "UNetMidBlock2DCrossAttn"
        {
            return Err(unsupported("mid_block_type", m, "UNetMidBlock2DCrossAttn"));
        }
        if let Some(t) = &u.class_embed_type {
            return Err(unsupported("class_embed_type", t, "absent (a ControlNet without class labels)"));
        }
        if u.num_views.is_some() || u.cross_domain() {
            return Err(Error::invalid("num_views/cd_attention_mid/cd_attention_last", "absent (not UNet fields)"));
        }
        for field in CONTROLNET_DEFAULT_ONLY {
            if let Some(v) = u.other.get(*field)
                && !v.is_null()
            {
                return Err(unsupported(field, v, "null"));
            }
        }
        in_range("conditioning_channels", self.conditioning_channels, MAX_WIDTH)?;
        in_range(
            "conditioning_embedding_out_channels (levels)",
            self.conditioning_embedding_out_channels.len(),
            MAX_LEVELS,
        )?;
        all_in_range("conditioning_embedding_out_channels", &self.conditioning_embedding_out_channels, MAX_WIDTH)?;
        if !matches!(self.controlnet_conditioning_channel_order.as_str(), "rgb" | "bgr") {
            return Err(unsupported(
                "controlnet_conditioning_channel_order",
                &self.controlnet_conditioning_channel_order,
                "rgb or bgr",
            ));
        }
        if self.global_pool_conditions {
            return Err(unsupported("global_pool_conditions", true, "false"));
        }
        Ok(())
    }

    /// Ratio of the control image's side to the latent's side: `2^(len - 1)` of
    /// `conditioning_embedding_out_channels` (8 for SD1.5, whose control image is the
    /// 512² or 1024² picture of a 64² or 128² latent).
    pub fn control_downscale(&self) -> usize {
        1 << self.conditioning_embedding_out_channels.len().saturating_sub(1)
    }
}

fn default_scaling() -> f64 {
    0.18215
}
fn default_vae_channels() -> Vec<usize> {
    vec![64]
}
fn default_vae_down() -> Vec<String> {
    vec!["DownEncoderBlock2D".into()]
}
fn default_vae_up() -> Vec<String> {
    vec!["UpDecoderBlock2D".into()]
}
fn default_three() -> usize {
    3
}

/// `AutoencoderKL` config (diffusers `vae/config.json`). Images are `[-1, 1]`, latents are
/// `latent_channels` wide and `2^(levels-1)` times smaller.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
pub struct VaeConfig {
    /// Image channels in (3).
    #[serde(default = "default_three")]
    pub in_channels: usize,
    /// Image channels out (3).
    #[serde(default = "default_three")]
    pub out_channels: usize,
    /// Encoder block kinds: `DownEncoderBlock2D`.
    #[serde(default = "default_vae_down")]
    pub down_block_types: Vec<String>,
    /// Decoder block kinds: `UpDecoderBlock2D`.
    #[serde(default = "default_vae_up")]
    pub up_block_types: Vec<String>,
    /// Channels of each encoder level.
    #[serde(default = "default_vae_channels")]
    pub block_out_channels: Vec<usize>,
    /// ResNets per encoder block (decoder blocks have one more).
    #[serde(default = "default_one_usize")]
    pub layers_per_block: usize,
    /// Activation (`silu`).
    #[serde(default = "default_silu")]
    pub act_fn: String,
    /// Latent channels (4).
    #[serde(default = "default_in_out4")]
    pub latent_channels: usize,
    /// GroupNorm groups.
    #[serde(default = "default_groups")]
    pub norm_num_groups: usize,
    /// Image side the model was trained at (informational).
    #[serde(default)]
    pub sample_size: Option<usize>,
    /// Latent scaling factor: the diffusion model sees `mean * scaling_factor`.
    #[serde(default = "default_scaling")]
    pub scaling_factor: f64,
    /// Whether `quant_conv` / `post_quant_conv` exist.
    #[serde(default = "default_true")]
    pub use_quant_conv: bool,
    /// Whether `post_quant_conv` exists.
    #[serde(default = "default_true")]
    pub use_post_quant_conv: bool,
    /// Must be true (absent) — the mid block attention.
    #[serde(default = "default_true")]
    pub mid_block_add_attention: bool,
    /// Unsupported when set.
    #[serde(default)]
    pub shift_factor: Option<f64>,
}

impl VaeConfig {
    /// Parses `vae/config.json`.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self, Error> {
        let path = path.as_ref();
        let config: Self = read_json(path)?;
        config.validate().map_err(|e| e.in_file(path))?;
        Ok(config)
    }

    /// Checks that every field holds a supported value.
    pub fn validate(&self) -> Result<(), Error> {
        let n = self.block_out_channels.len();
        in_range("block_out_channels (levels)", n, MAX_LEVELS)?;
        all_in_range("block_out_channels", &self.block_out_channels, MAX_WIDTH)?;
        in_range("in_channels", self.in_channels, MAX_WIDTH)?;
        in_range("out_channels", self.out_channels, MAX_WIDTH)?;
        in_range("latent_channels", self.latent_channels, MAX_WIDTH)?;
        in_range("layers_per_block", self.layers_per_block, MAX_LAYERS)?;
        if let Some(side) = self.sample_size {
            in_range("sample_size", side, MAX_WIDTH)?;
        }
        in_range("norm_num_groups", self.norm_num_groups, MAX_WIDTH)?;
        if self.down_block_types.len() != n || self.up_block_types.len() != n {
            return Err(Error::invalid("down_block_types/up_block_types", format!("{n} entries each")));
        }
        if let Some((i, t)) = self.down_block_types.iter().enumerate().find(|(_, t)| *t != "DownEncoderBlock2D") {
            return Err(unsupported(&format!("down_block_types[{i}]"), t, "DownEncoderBlock2D"));
        }
        if let Some((i, t)) = self.up_block_types.iter().enumerate().find(|(_, t)| *t != "UpDecoderBlock2D") {
            return Err(unsupported(&format!("up_block_types[{i}]"), t, "UpDecoderBlock2D"));
        }
        if self.act_fn != "silu" {
            return Err(unsupported("act_fn", &self.act_fn, "silu"));
        }
        if self.block_out_channels.iter().any(|c| !c.is_multiple_of(self.norm_num_groups)) {
            return Err(Error::invalid("block_out_channels", "multiples of norm_num_groups"));
        }
        if !self.use_quant_conv || !self.use_post_quant_conv || !self.mid_block_add_attention {
            return Err(Error::invalid("use_quant_conv/use_post_quant_conv/mid_block_add_attention", "true"));
        }
        if let Some(s) = self.shift_factor {
            return Err(unsupported("shift_factor", s, "absent"));
        }
        Ok(())
    }

    /// Ratio of image side to latent side.
    pub fn downscale(&self) -> usize {
        1 << (self.block_out_channels.len() - 1)
    }
}

fn default_clip_hidden() -> usize {
    768
}
fn default_clip_inter() -> usize {
    3072
}
fn default_clip_proj() -> usize {
    512
}
fn default_clip_layers() -> usize {
    12
}
fn default_clip_image() -> usize {
    224
}
fn default_clip_patch() -> usize {
    32
}
fn default_quick_gelu() -> String {
    "quick_gelu".into()
}

/// `CLIPVisionConfig` (transformers `image_encoder/config.json` of a
/// `CLIPVisionModelWithProjection`). Images are `image_size²` pixels, cut into `patch_size²`
/// patches.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
pub struct ClipVisionConfig {
    /// Token width.
    #[serde(default = "default_clip_hidden")]
    pub hidden_size: usize,
    /// MLP hidden width.
    #[serde(default = "default_clip_inter")]
    pub intermediate_size: usize,
    /// Width of the projected image embedding.
    #[serde(default = "default_clip_proj")]
    pub projection_dim: usize,
    /// Encoder layers.
    #[serde(default = "default_clip_layers")]
    pub num_hidden_layers: usize,
    /// Attention heads.
    #[serde(default = "default_clip_layers")]
    pub num_attention_heads: usize,
    /// Image channels (3).
    #[serde(default = "default_three")]
    pub num_channels: usize,
    /// Input side in pixels.
    #[serde(default = "default_clip_image")]
    pub image_size: usize,
    /// Patch side in pixels.
    #[serde(default = "default_clip_patch")]
    pub patch_size: usize,
    /// `quick_gelu` or `gelu`.
    #[serde(default = "default_quick_gelu")]
    pub hidden_act: String,
    /// LayerNorm epsilon.
    #[serde(default = "default_eps5")]
    pub layer_norm_eps: f64,
}

impl ClipVisionConfig {
    /// Parses `image_encoder/config.json`: either a vision config or a full `CLIPConfig`
    /// whose `vision_config` (and top-level `projection_dim`) is used.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self, Error> {
        let path = path.as_ref();
        let value: serde_json::Value = read_json(path)?;
        let config = Self::from_value(value).map_err(|e| e.in_file(path))?;
        Ok(config)
    }

    /// Parses a JSON value (see [`ClipVisionConfig::from_file`]).
    pub fn from_value(value: serde_json::Value) -> Result<Self, Error> {
        let parse = |v: serde_json::Value| parse_config::<Self>(v, "CLIP vision config");
        let config = match value.get("vision_config") {
            Some(vision) => {
                let mut vision = vision.clone();
                if let (Some(p), Some(obj)) = (value.get("projection_dim"), vision.as_object_mut()) {
                    obj.entry("projection_dim").or_insert(p.clone());
                }
                parse(vision)?
            }
            None => parse(value)?,
        };
        config.validate()?;
        Ok(config)
    }

    /// Checks that every field holds a supported value.
    pub fn validate(&self) -> Result<(), Error> {
        in_range("hidden_size", self.hidden_size, MAX_WIDTH)?;
        in_range("intermediate_size", self.intermediate_size, 4 * MAX_WIDTH)?;
        in_range("projection_dim", self.projection_dim, MAX_WIDTH)?;
        in_range("num_hidden_layers", self.num_hidden_layers, MAX_LAYERS)?;
        in_range("num_channels", self.num_channels, 4)?;
        in_range("image_size", self.image_size, MAX_IMAGE_SIDE)?;
        in_range("patch_size", self.patch_size, self.image_size)?;
        if self.image_size / self.patch_size > 256 {
            return Err(Error::invalid("patch_size", "at most 256 patches per side"));
        }
        if self.hidden_act != "quick_gelu" && self.hidden_act != "gelu" {
            return Err(unsupported("hidden_act", &self.hidden_act, "quick_gelu or gelu"));
        }
        if self.num_attention_heads == 0 || !self.hidden_size.is_multiple_of(self.num_attention_heads) {
            return Err(Error::invalid("num_attention_heads", "a divisor of hidden_size"));
        }
        if self.patch_size == 0 || !self.image_size.is_multiple_of(self.patch_size) {
            return Err(Error::invalid("patch_size", "a divisor of image_size"));
        }
        Ok(())
    }

    /// Patches per side.
    pub fn patches_per_side(&self) -> usize {
        self.image_size / self.patch_size
    }
}

/// The largest vocabulary a CLIP text config may declare (SD1.5's has 49 408 tokens): a bound
/// like [`MAX_WIDTH`], so a damaged `config.json` cannot ask for an enormous embedding table.
pub const MAX_VOCAB: usize = 1 << 18;
/// The most token positions a CLIP text config may declare (SD1.5's has 77).
pub const MAX_POSITIONS: usize = 4096;

fn default_text_vocab() -> usize {
    49408
}
fn default_text_hidden() -> usize {
    512
}
fn default_text_inter() -> usize {
    2048
}
fn default_text_heads() -> usize {
    8
}
fn default_text_positions() -> usize {
    77
}
fn default_bos() -> Option<u32> {
    Some(49406)
}
fn default_eos() -> Option<u32> {
    Some(49407)
}
fn default_pad() -> Option<u32> {
    Some(1)
}

/// `CLIPTextConfig` (transformers `text_encoder/config.json` of a `CLIPTextModel`, SD1.5's
/// text tower). Fields a file omits take transformers' defaults (the 512-wide CLIP-B text
/// tower); SD1.5's file states the ViT-L/14 text tower: vocabulary 49 408, 77 positions,
/// width 768, 12 layers, 12 heads, MLP 3072, `quick_gelu`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
pub struct ClipTextConfig {
    /// Token ids are `0..vocab_size` (rows of the token embedding).
    #[serde(default = "default_text_vocab")]
    pub vocab_size: usize,
    /// Token width.
    #[serde(default = "default_text_hidden")]
    pub hidden_size: usize,
    /// MLP hidden width.
    #[serde(default = "default_text_inter")]
    pub intermediate_size: usize,
    /// Encoder layers.
    #[serde(default = "default_clip_layers")]
    pub num_hidden_layers: usize,
    /// Attention heads (a divisor of `hidden_size`).
    #[serde(default = "default_text_heads")]
    pub num_attention_heads: usize,
    /// Longest token sequence (rows of the position embedding).
    #[serde(default = "default_text_positions")]
    pub max_position_embeddings: usize,
    /// `quick_gelu` or `gelu`.
    #[serde(default = "default_quick_gelu")]
    pub hidden_act: String,
    /// LayerNorm epsilon.
    #[serde(default = "default_eps5")]
    pub layer_norm_eps: f64,
    /// Begin-of-text id as the file states it. Informational: the encoder reads no special id,
    /// and the tokenizer's own ids are authoritative (SD1.5's file says 0, a legacy value; its
    /// tokenizer's `<|startoftext|>` is 49406).
    #[serde(default = "default_bos")]
    pub bos_token_id: Option<u32>,
    /// End-of-text id as the file states it (informational, see `bos_token_id`; SD1.5's file
    /// says 2, its tokenizer's `<|endoftext|>` is 49407).
    #[serde(default = "default_eos")]
    pub eos_token_id: Option<u32>,
    /// Padding id as the file states it (informational, see `bos_token_id`).
    #[serde(default = "default_pad")]
    pub pad_token_id: Option<u32>,
}

impl ClipTextConfig {
    /// Parses `text_encoder/config.json`: either a text config or a full `CLIPConfig` whose
    /// `text_config` is used.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self, Error> {
        let path = path.as_ref();
        let value: serde_json::Value = read_json(path)?;
        Self::from_value(value).map_err(|e| e.in_file(path))
    }

    /// Parses a JSON value (see [`ClipTextConfig::from_file`]).
    pub fn from_value(value: serde_json::Value) -> Result<Self, Error> {
        let value = match value.get("text_config") {
            Some(text) => text.clone(),
            None => value,
        };
        let config = parse_config::<Self>(value, "CLIP text config")?;
        config.validate()?;
        Ok(config)
    }

    /// Checks that every field holds a supported value.
    pub fn validate(&self) -> Result<(), Error> {
        in_range("vocab_size", self.vocab_size, MAX_VOCAB)?;
        in_range("hidden_size", self.hidden_size, MAX_WIDTH)?;
        in_range("intermediate_size", self.intermediate_size, 4 * MAX_WIDTH)?;
        in_range("num_hidden_layers", self.num_hidden_layers, MAX_LAYERS)?;
        in_range("max_position_embeddings", self.max_position_embeddings, MAX_POSITIONS)?;
        if self.hidden_act != "quick_gelu" && self.hidden_act != "gelu" {
            return Err(unsupported("hidden_act", &self.hidden_act, "quick_gelu or gelu"));
        }
        if self.num_attention_heads == 0 || !self.hidden_size.is_multiple_of(self.num_attention_heads) {
            return Err(Error::invalid("num_attention_heads", "a divisor of hidden_size"));
        }
        if !(self.layer_norm_eps.is_finite() && self.layer_norm_eps > 0.0) {
            return Err(Error::invalid("layer_norm_eps", format!("a positive number, found {}", self.layer_norm_eps)));
        }
        Ok(())
    }
}

fn default_train_steps() -> usize {
    1000
}
fn default_beta_start() -> f64 {
    0.0001
}
fn default_beta_end() -> f64 {
    0.02
}
fn default_linear() -> String {
    "linear".into()
}
fn default_epsilon() -> String {
    "epsilon".into()
}
fn default_leading() -> String {
    "leading".into()
}

/// `DDIMScheduler` / `DDIMInverseScheduler` config (diffusers `scheduler/scheduler_config.json`).
/// Timesteps are integer training steps in `[0, num_train_timesteps)`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
pub struct SchedulerConfig {
    /// Training timesteps T.
    #[serde(default = "default_train_steps")]
    pub num_train_timesteps: usize,
    /// First beta.
    #[serde(default = "default_beta_start")]
    pub beta_start: f64,
    /// Last beta.
    #[serde(default = "default_beta_end")]
    pub beta_end: f64,
    /// `linear`, `scaled_linear` or `squaredcos_cap_v2`.
    #[serde(default = "default_linear")]
    pub beta_schedule: String,
    /// Explicit betas (overrides the schedule).
    #[serde(default)]
    pub trained_betas: Option<Vec<f64>>,
    /// Clamp the predicted clean sample to `±clip_sample_range`.
    #[serde(default = "default_true")]
    pub clip_sample: bool,
    /// Clamp range of `clip_sample`.
    #[serde(default = "default_one")]
    pub clip_sample_range: f64,
    /// DDIM: ᾱ of the step before t = 0 is 1 (else ᾱ₀). Inverse: ᾱ before the first step.
    #[serde(default = "default_true")]
    pub set_alpha_to_one: bool,
    /// Added to every inference timestep (`leading` spacing).
    #[serde(default)]
    pub steps_offset: usize,
    /// `epsilon`, `sample` or `v_prediction`.
    #[serde(default = "default_epsilon")]
    pub prediction_type: String,
    /// Dynamic thresholding (unsupported when true).
    #[serde(default)]
    pub thresholding: bool,
    /// `leading`, `trailing` or `linspace`.
    #[serde(default = "default_leading")]
    pub timestep_spacing: String,
    /// Rescale betas to zero terminal SNR.
    #[serde(default)]
    pub rescale_betas_zero_snr: bool,
}

impl Default for SchedulerConfig {
    /// The diffusers `DDIMScheduler()` constructor defaults.
    fn default() -> Self {
        serde_json::from_str("{}").expect("all fields have defaults")
    }
}

impl SchedulerConfig {
    /// Parses `scheduler/scheduler_config.json`.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self, Error> {
        let path = path.as_ref();
        let config: Self = read_json(path)?;
        config.validate().map_err(|e| e.in_file(path))?;
        Ok(config)
    }

    /// The Stable Diffusion / Wonder3D scheduler: scaled-linear betas 0.00085 → 0.012,
    /// `set_alpha_to_one = false`, `steps_offset = 1`, leading spacing, no clipping.
    pub fn stable_diffusion() -> Self {
        Self {
            beta_start: 0.00085,
            beta_end: 0.012,
            beta_schedule: "scaled_linear".into(),
            clip_sample: false,
            set_alpha_to_one: false,
            steps_offset: 1,
            ..Self::default()
        }
    }

    /// Checks that every field holds a supported value.
    pub fn validate(&self) -> Result<(), Error> {
        if !(1..=100_000).contains(&self.num_train_timesteps) {
            return Err(Error::invalid(
                "num_train_timesteps",
                format!("a value in 1..=100000, found {}", self.num_train_timesteps),
            ));
        }
        if self.trained_betas.is_none()
            && !matches!(self.beta_schedule.as_str(), "linear" | "scaled_linear" | "squaredcos_cap_v2")
        {
            return Err(unsupported(
                "beta_schedule",
                &self.beta_schedule,
                "linear, scaled_linear or squaredcos_cap_v2",
            ));
        }
        if let Some(b) = &self.trained_betas
            && b.len() != self.num_train_timesteps
        {
            return Err(Error::invalid("trained_betas", format!("{} values", self.num_train_timesteps)));
        }
        if !matches!(self.prediction_type.as_str(), "epsilon" | "sample" | "v_prediction") {
            return Err(unsupported("prediction_type", &self.prediction_type, "epsilon, sample or v_prediction"));
        }
        if !matches!(self.timestep_spacing.as_str(), "leading" | "trailing" | "linspace") {
            return Err(unsupported("timestep_spacing", &self.timestep_spacing, "leading, trailing or linspace"));
        }
        if self.thresholding {
            return Err(unsupported("thresholding", true, "false"));
        }
        Ok(())
    }
}
