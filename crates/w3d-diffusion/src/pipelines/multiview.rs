//! Wonder3D++ multi-view generation: one RGBA image in, 6 views × {normal, colour} out.
//!
//! The steps follow the authors' Wonder3D++ inference (`run.py`, `run_mv_prediction.py` and
//! their pipeline; `docs/weights.md` describes the model directory):
//! 1. [`prepare_input`]: crop to the alpha bounding box, scale the object's longest side to
//!    75 % of the model's image side, centre it, composite it over white and truncate it to
//!    8 bits as the authors' pipeline does ([`quantize_u8`]).
//! 2. [`MultiViewPipeline::condition`]: the CLIP image embedding (one token) and the VAE latent
//!    mode (× `scaling_factor`) of that 8-bit image.
//! 3. [`MultiViewPipeline::sample_from`]: DDIM with classifier-free guidance over the batch
//!    `[normal × 6 views, colour × 6 views]`, the domain / camera switchers as class labels
//!    ([`switcher_labels`]), one initial noise per view shared by both domains; the guided
//!    batch is `[normal uncond, normal cond, colour uncond, colour cond]` so the cross-domain
//!    attention pairs unconditional with unconditional (the authors' 2024-08-29 fix); the
//!    unconditional branch has a zero embedding and a zero latent.
//! 4. [`MultiViewPipeline::decode`]: VAE decode, `x / 2 + 0.5` clamped to `[0, 1]`;
//!    [`GeneratedViews::to_view_set`] turns the images into a [`ViewSet`] in the rig's frame.
//!
//! [`MultiViewPipeline::invert`] is the DDIM inversion the refinement stage uses.
//!
//! ```
//! use w3d_diffusion::{CameraType, Domain, switcher_labels};
//!
//! // Class labels of the six colour views, perspective camera: 14 values per view.
//! let labels = switcher_labels(Domain::Colour, CameraType::Perspective, 14)?;
//! assert_eq!(labels.len(), 6 * 14);
//! // The back view (index 3): d_azim = π, so its sine is ~0 and its cosine ~-1.
//! let back = &labels[3 * 14..4 * 14];
//! assert!(back[2].abs() < 1e-5 && (back[7 + 2] + 1.0).abs() < 1e-5);
//! // sin of the switches: camera [1, 0] (persp), task [0, 1] (colour).
//! assert_eq!(back[3..7], [1f32.sin(), 0.0, 0.0, 1f32.sin()]);
//! # Ok::<(), w3d_core::Error>(())
//! ```

use std::path::Path;
use std::str::FromStr;

use burn::tensor::{Device, Tensor, TensorData};
use image::imageops::FilterType;
use w3d_core::{Error, Image, ViewImages, ViewRig, ViewSet};

use crate::compute;
use crate::loading::config::SchedulerConfig;
use crate::loading::weights::{Precision, WeightStorage};
use crate::models::clip::vision::{ClipVision, preprocess as clip_preprocess};
use crate::models::unet::{FeatureCache, UNet, UNetExtra};
use crate::models::vae::Vae;
use crate::pipelines::acceleration::Acceleration;
use crate::pipelines::guidance::{classifier_free_guidance, gaussian_noise};
use crate::schedulers::{
    DdimInverseScheduler, DdimScheduler, DpmSolverMultistepScheduler, MultistepScheduler, SamplerKind,
    UniPcMultistepScheduler, ddim_invert,
};

/// A model directory's index, written last by [`MultiViewPipeline::save`].
const MODEL_INDEX: &str = "model_index.json";

/// Views generated per domain, in rig order: front, front_right, right, back, left,
/// front_left (`w3d_core::rig::WONDER3D_VIEW_NAMES`).
pub const NUM_VIEWS: usize = 6;

/// The model's view labels `(d_elev, d_azim)` in radians, in rig order. These are fixed
/// labels the model was trained with, not the true camera angles: the authors derive them
/// from tilted pose files, and the model only knows these values.
// The values the authors' dataset code computes from its pose files, to 6 decimals (3.141593 is π rounded).
#[allow(clippy::approx_constant, clippy::excessive_precision)]
pub const VIEW_LABELS: [(f32, f32); NUM_VIEWS] = [
    (0.000000, 0.000000),
    (-0.236240, 0.812378),
    (-0.168619, 1.693490),
    (0.522037, 3.141593),
    (0.690655, 4.835082),
    (0.373314, 5.586011),
];

/// Fraction of the model's image side the object's longest side fills (Wonder3D's
/// `crop_size` 192 of 256).
pub const OBJECT_FRACTION: f32 = 0.75;

/// A pixel of a generated view is background when every channel of both its normal image
/// and its colour image exceeds this (white background; a unit normal cannot encode to more
/// than 0.8 in all three channels, since that needs |n| > 1.03).
pub const BACKGROUND_THRESHOLD: f32 = 0.8;

/// Draws of [`MultiViewPipeline::sample_views`] sampled together, as one batch of the UNet.
/// A batch shares the fixed costs of every pass (operations too small to use all cores
/// alone): on 2 CPU cores a small-model draw took 0.17 s a UNet pass in a batch of 4 against
/// 0.21–0.23 s alone (docs/benchmarks.md, "Several draws as one batch"; a UNet of half its
/// width measured 10 % slower batched). More draws at once would hold more activations for
/// little more gain.
pub const DRAWS_PER_PASS: usize = 4;

/// The output domain chosen by the domain switcher.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Domain {
    /// Normal maps (switch `[1, 0]`).
    Normal,
    /// Colour images (switch `[0, 1]`).
    Colour,
}

/// The camera type chosen by the camera switcher (Wonder3D++ only).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum CameraType {
    /// Orthographic views (switch `[0, 1]`); `ViewRig::wonder3d_ortho`.
    #[default]
    Orthographic,
    /// 35 mm perspective views (switch `[1, 0]`); `ViewRig::wonder3d_persp`.
    Perspective,
}

impl CameraType {
    /// The 6-view rig of this camera type (`w3d_core::ViewRig`'s Wonder3D rigs).
    pub fn rig(self) -> ViewRig {
        match self {
            CameraType::Orthographic => ViewRig::wonder3d_ortho(),
            CameraType::Perspective => ViewRig::wonder3d_persp(),
        }
    }
}

impl FromStr for CameraType {
    type Err = Error;

    /// `ortho` / `orthographic` or `persp` / `perspective`.
    fn from_str(s: &str) -> Result<Self, Error> {
        match s {
            "ortho" | "orthographic" => Ok(CameraType::Orthographic),
            "persp" | "perspective" => Ok(CameraType::Perspective),
            other => Err(Error::invalid("camera", format!("ortho or persp (found {other:?})"))),
        }
    }
}

/// Class labels of the six views of one domain, `NUM_VIEWS × input_dim` row-major: the
/// single-frequency encoding `concat(sin v, cos v)` of
/// `v = [elev_cond = 0, d_elev, d_azim, camera(2), task(2)]` (`input_dim` 14, Wonder3D++), or
/// without the camera type (`input_dim` 10, Wonder3D v1, orthographic only). The class
/// embedding projects them and adds them to the time embedding.
pub fn switcher_labels(domain: Domain, camera: CameraType, input_dim: usize) -> Result<Vec<f32>, Error> {
    let task = match domain {
        Domain::Normal => [1.0, 0.0],
        Domain::Colour => [0.0, 1.0],
    };
    task_labels(task, camera, input_dim)
}

/// As [`switcher_labels`] with the task switch given as its two values: `[1, 0]` normal,
/// `[0, 1]` colour, `[0, 0]` for training without the domain switcher (stage 1), `[1, 1]`
/// mask in the authors' code.
pub fn task_labels(task: [f32; 2], camera: CameraType, input_dim: usize) -> Result<Vec<f32>, Error> {
    let camera_switch = match (input_dim, camera) {
        (14, CameraType::Orthographic) => vec![0.0, 1.0],
        (14, CameraType::Perspective) => vec![1.0, 0.0],
        (10, CameraType::Orthographic) => Vec::new(),
        (10, CameraType::Perspective) => {
            return Err(Error::invalid("camera", "ortho (a 10-d class embedding has no camera switcher)"));
        }
        (d, _) => {
            return Err(Error::invalid("projection_class_embeddings_input_dim", format!("10 or 14 (found {d})")));
        }
    };
    let mut labels = Vec::with_capacity(NUM_VIEWS * input_dim);
    for (d_elev, d_azim) in VIEW_LABELS {
        let v: Vec<f32> = [0.0, d_elev, d_azim].into_iter().chain(camera_switch.iter().copied()).chain(task).collect();
        labels.extend(v.iter().map(|x| x.sin()));
        labels.extend(v.iter().map(|x| x.cos()));
    }
    Ok(labels)
}

/// The 8-bit level the authors' pipeline turns a composited input value `v` (nominally in
/// `[0, 1]`) into. Their inference casts the composited image to half precision and hands it
/// to the pipeline as a tensor, which converts it to a PIL image with torchvision's
/// `to_pil_image` (`mul(255).byte()`): `trunc(f16(f16(v) · 255))`. That is truncation (floor,
/// the values being non-negative), not rounding, computed in f16 — about 4 % of uniformly
/// spread values land one level higher than `floor(255 v)` in f32 would give. CLIP's
/// preprocessing and the VAE both start from this 8-bit image. Values outside `[0, 1]` are
/// clamped first (the authors clip the composite); NaN gives 0.
///
/// ```
/// use w3d_diffusion::pipelines::multiview::quantize_u8;
///
/// assert_eq!(quantize_u8(100.6 / 255.0), 100); // truncated, not rounded to 101
/// assert_eq!(quantize_u8(0.909_746_2), 232); // f16 arithmetic: floor(255 v) in f32 is 231
/// assert_eq!(quantize_u8(1.0), 255);
/// assert!((0..=255).all(|k| quantize_u8(k as f32 / 255.0) == k as u8)); // levels are fixed points
/// ```
pub fn quantize_u8(v: f32) -> u8 {
    let v = half::f16::from_f32(v.clamp(0.0, 1.0));
    // The product of an f16 and 255 is exact in f32; rounding it to f16 is the f16 multiply.
    half::f16::from_f32(v.to_f32() * 255.0).to_f32() as u8
}

/// Wonder3D's input preprocessing: crops `rgba` (4 channels, values in `[0, 1]`, straight
/// alpha) to the bounding box of its non-zero alpha, scales it (premultiplied, bilinear with
/// antialiasing) so its longest side is [`OBJECT_FRACTION`] of `size`, centres it on a
/// `size × size` canvas, composites it over white and truncates it to 8 bits as the authors'
/// pipeline does ([`quantize_u8`]). Returns the RGB image (3 channels, every value a multiple
/// of 1/255).
pub fn prepare_input(rgba: &Image, size: u32) -> Result<Image, Error> {
    prepare_input_on(rgba, size, 1.0)
}

/// [`prepare_input`] composited over a grey level `background` in `[0, 1]` instead of white:
/// how training frames its condition images (on the sample's background), so that training
/// and inference see the object framed alike.
pub fn prepare_input_on(rgba: &Image, size: u32, background: f32) -> Result<Image, Error> {
    if rgba.channels() != 4 {
        return Err(Error::invalid(
            "image",
            format!(
                "an RGBA image whose alpha masks the object (found {} channels; remove the background first, e.g. with rembg)",
                rgba.channels()
            ),
        ));
    }
    if size == 0 {
        return Err(Error::invalid("size", "at least 1 pixel"));
    }
    let (w, h) = (rgba.width(), rgba.height());
    let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
    for y in 0..h {
        for x in 0..w {
            if rgba.pixel(x, y)[3] > 0.0 {
                (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x + 1), y1.max(y + 1));
            }
        }
    }
    if x0 == u32::MAX {
        return Err(Error::invalid("image alpha", "a non-empty object mask (every pixel is transparent)"));
    }
    let (cw, ch) = (x1 - x0, y1 - y0);
    let mut crop = image::Rgba32FImage::new(cw, ch);
    for y in 0..ch {
        for x in 0..cw {
            let p = rgba.pixel(x0 + x, y0 + y);
            let a = p[3].clamp(0.0, 1.0);
            crop.put_pixel(x, y, image::Rgba([p[0] * a, p[1] * a, p[2] * a, a]));
        }
    }
    let target = (OBJECT_FRACTION * size as f32).round().max(1.0);
    let scale = target / cw.max(ch) as f32;
    let (nw, nh) = (((cw as f32 * scale).round() as u32).max(1), ((ch as f32 * scale).round() as u32).max(1));
    let resized = image::imageops::resize(&crop, nw, nh, FilterType::Triangle);
    let (ox, oy) = ((size - nw) / 2, (size - nh) / 2);
    let background = background.clamp(0.0, 1.0);
    let level = f32::from(quantize_u8(background)) / 255.0;
    let mut out = Image::filled(size, size, 3, level)?;
    for y in 0..nh {
        for x in 0..nw {
            let p = resized.get_pixel(x, y).0;
            let a = p[3].clamp(0.0, 1.0);
            let dst = out.pixel_mut(ox + x, oy + y);
            for c in 0..3 {
                dst[c] = f32::from(quantize_u8(p[c] + background * (1.0 - a))) / 255.0;
            }
        }
    }
    Ok(out)
}

/// The conditions of one input image.
#[derive(Clone, Debug)]
pub struct Conditioning {
    /// The CLIP image embedding, `[1, cross_attention_dim]`.
    pub embeds: Tensor<2>,
    /// The VAE latent mode × `scaling_factor`, `[1, latent_channels, h, w]`.
    pub latent: Tensor<4>,
}

/// Sampling options.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleOptions {
    /// Sampling algorithm: DDIM (the authors') or DPM-Solver++(2M).
    pub sampler: SamplerKind,
    /// Sampling steps (the authors' default 50 with DDIM; about 20 suffice with
    /// DPM-Solver++(2M)).
    pub steps: usize,
    /// Classifier-free guidance scale (Wonder3D++ default 2; 1 runs no unconditional branch).
    pub guidance: f64,
    /// DDIM eta: 0 deterministic, 1 the authors' fully stochastic sampling (DPM-Solver++(2M)
    /// is deterministic and ignores it).
    pub eta: f64,
    /// Camera type of the generated views.
    pub camera: CameraType,
    /// Seed of the initial noise and of the per-step noise when `eta > 0`.
    pub seed: u64,
    /// Draws generated for the input (seeds `seed`, `seed + 1`, …) and merged into their
    /// [`GeneratedViews::consensus`]: 1 is the authors' single draw; each draw costs most of a
    /// generation (up to [`DRAWS_PER_PASS`] share the UNet's passes), and with a small model a
    /// few draws lower the normal error (docs/training.md).
    pub draws: usize,
    /// Training-free accelerations (guidance interval, DeepCache, bf16 products, token
    /// merging); the default is none of them, the reference arithmetic.
    pub acceleration: Acceleration,
}

impl Default for SampleOptions {
    /// The Wonder3D++ defaults: DDIM, 50 steps, guidance 2 at every step, eta 1, orthographic,
    /// seed 42, one draw, every pass full in f32 products.
    fn default() -> Self {
        Self {
            sampler: SamplerKind::Ddim,
            steps: 50,
            guidance: 2.0,
            eta: 1.0,
            camera: CameraType::Orthographic,
            seed: 42,
            draws: 1,
            acceleration: Acceleration::default(),
        }
    }
}

impl SampleOptions {
    /// Checks the settings that need no model: at least 1 step and 1 draw, a finite
    /// guidance scale and a valid [`Acceleration`] (its cache depth is checked against the
    /// UNet's skips when sampling starts).
    pub fn validate(&self) -> Result<(), Error> {
        if self.steps == 0 {
            return Err(Error::invalid("steps", "at least 1 sampling step (found 0)"));
        }
        if self.draws == 0 {
            return Err(Error::invalid("draws", "at least 1 draw (found 0)"));
        }
        if !self.guidance.is_finite() {
            return Err(Error::invalid("guidance", format!("a finite scale (found {})", self.guidance)));
        }
        self.acceleration.validate()
    }
}

/// The generated images, in rig order.
#[derive(Clone, Debug, PartialEq)]
pub struct GeneratedViews {
    /// Camera type the views were generated for.
    pub camera: CameraType,
    /// Normal maps as the model draws them: RGB = (n + 1) / 2 in the input camera's frame
    /// (OpenGL axes: +x right, +y up, +z towards the viewer), white background, 3 channels.
    pub normals: Vec<Image>,
    /// Colour images (sRGB in `[0, 1]`), white background, 3 channels.
    pub colours: Vec<Image>,
}

impl GeneratedViews {
    /// The views as a [`ViewSet`] carrying the rig of their camera type: normals decoded to
    /// unit vectors (`2·rgb − 1`, normalised; the input camera's frame is the canonical frame
    /// of `docs/architecture.md`, "Conventions", so no rotation), colours as generated, and
    /// masks that are 0 where both images are background (every channel above
    /// [`BACKGROUND_THRESHOLD`]); normals are zero on the background.
    pub fn to_view_set(&self) -> Result<ViewSet, Error> {
        views_from_images(self.camera.rig(), &self.normals, &self.colours)
    }

    /// The per-pixel consensus of several draws for the same input (other seeds): a pixel is
    /// object where at least half the draws have it there (not background by the rule of
    /// [`GeneratedViews::to_view_set`]); its normal is the normalised sum of those draws' unit
    /// normals and its colour their mean; elsewhere both images are white. Each draw of a
    /// small model is its estimate plus noise that differs from draw to draw, so the consensus
    /// lies nearer the truth than a typical draw, at the cost of one generation per draw.
    ///
    /// Errors: no draws, or draws of different camera types, view counts or image sizes.
    pub fn consensus(draws: &[GeneratedViews]) -> Result<GeneratedViews, Error> {
        let first = draws.first().ok_or_else(|| Error::invalid("draws", "at least one set of views"))?;
        for (k, d) in draws.iter().enumerate() {
            if d.camera != first.camera
                || d.normals.len() != first.normals.len()
                || d.colours.len() != first.normals.len()
            {
                return Err(Error::invalid(
                    "draws",
                    format!(
                        "views of one camera type and count ({:?}, {} of each; draw {k} has {:?}, {} normal and {} colour images)",
                        first.camera,
                        first.normals.len(),
                        d.camera,
                        d.normals.len(),
                        d.colours.len()
                    ),
                ));
            }
        }
        let mut normals = Vec::with_capacity(first.normals.len());
        let mut colours = Vec::with_capacity(first.normals.len());
        for view in 0..first.normals.len() {
            let (w, h) = (first.normals[view].width(), first.normals[view].height());
            for d in draws {
                d.normals[view].expect_shape("normal", w, h, 3)?;
                d.colours[view].expect_shape("colour", w, h, 3)?;
            }
            let mut normal = vec![1.0f32; (w * h * 3) as usize];
            let mut colour = vec![1.0f32; (w * h * 3) as usize];
            for px in 0..(w * h) as usize {
                let range = 3 * px..3 * px + 3;
                let (mut sum, mut rgb, mut count) = ([0.0f32; 3], [0.0f32; 3], 0usize);
                for d in draws {
                    let c = &d.colours[view].data()[range.clone()];
                    let Some(n) = object_normal(&d.normals[view].data()[range.clone()], c) else { continue };
                    count += 1;
                    for i in 0..3 {
                        sum[i] += n[i];
                        rgb[i] += c[i];
                    }
                }
                let len = (sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]).sqrt();
                // Opposite normals that cancel leave no direction: background is the honest call.
                if 2 * count < draws.len() || len < 1e-6 {
                    continue;
                }
                for i in 0..3 {
                    normal[3 * px + i] = (sum[i] / len + 1.0) * 0.5;
                    colour[3 * px + i] = rgb[i] / count as f32;
                }
            }
            normals.push(Image::new(w, h, 3, normal)?);
            colours.push(Image::new(w, h, 3, colour)?);
        }
        Ok(GeneratedViews { camera: first.camera, normals, colours })
    }
}

/// The unit normal of one generated pixel (`normal_rgb` = (n + 1) / 2, `colour` its colour),
/// or `None` where the pixel is background: both images white (every channel above
/// [`BACKGROUND_THRESHOLD`]) or no direction drawn.
fn object_normal(normal_rgb: &[f32], colour: &[f32]) -> Option<[f32; 3]> {
    let white = |p: &[f32]| p.iter().all(|&v| v > BACKGROUND_THRESHOLD);
    let v = [2.0 * normal_rgb[0] - 1.0, 2.0 * normal_rgb[1] - 1.0, 2.0 * normal_rgb[2] - 1.0];
    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    (!(white(normal_rgb) && white(colour)) && len >= 1e-6).then(|| v.map(|x| x / len))
}

/// A [`ViewSet`] of `rig` from normal maps as the diffusion models draw them (RGB =
/// (n + 1) / 2, white background) and colour images (white background), one of each per
/// view in rig order: normals decoded to unit vectors (`2·rgb − 1`, normalised), colours as
/// given, and masks that are 0 where both images are background (every channel above
/// [`BACKGROUND_THRESHOLD`]); normals are zero on the background.
pub fn views_from_images(rig: ViewRig, normals: &[Image], colours: &[Image]) -> Result<ViewSet, Error> {
    if normals.len() != rig.len() || colours.len() != rig.len() {
        return Err(Error::invalid(
            "views",
            format!("{} normal and colour images (found {}, {})", rig.len(), normals.len(), colours.len()),
        ));
    }
    let mut views = Vec::with_capacity(rig.len());
    for ((normal_rgb, colour), view) in normals.iter().zip(colours).zip(&rig.views) {
        let (w, h) = (normal_rgb.width(), normal_rgb.height());
        colour.expect_shape("colour", w, h, 3)?;
        normal_rgb.expect_shape("normal", w, h, 3)?;
        let mut normal = Vec::with_capacity((w * h * 3) as usize);
        let mut mask = Vec::with_capacity((w * h) as usize);
        for (n, c) in normal_rgb.data().chunks_exact(3).zip(colour.data().chunks_exact(3)) {
            match object_normal(n, c) {
                Some(unit) => {
                    normal.extend(unit);
                    mask.push(1.0);
                }
                None => {
                    normal.extend([0.0; 3]);
                    mask.push(0.0);
                }
            }
        }
        views.push(ViewImages {
            name: view.name.clone(),
            normal: Image::new(w, h, 3, normal)?,
            colour: Some(colour.clone()),
            mask: Image::new(w, h, 1, mask)?,
            depth: None,
        });
    }
    ViewSet::new(rig, views)
}

/// The Wonder3D++ multi-view diffusion pipeline: the multi-view cross-domain UNet, the VAE,
/// the CLIP image encoder and the DDIM scheduler config.
#[derive(Debug)]
pub struct MultiViewPipeline {
    unet: UNet,
    vae: Vae,
    clip: ClipVision,
    scheduler: SchedulerConfig,
    image_size: usize,
}

impl MultiViewPipeline {
    /// Assembles a pipeline, checking that the models fit together: the UNet has
    /// `num_views` = 6, a projection class embedding of 10 or 14 inputs, a `sample_size`,
    /// `2 × latent_channels` inputs and `latent_channels` outputs, and conditions on the CLIP
    /// projection width.
    pub fn new(unet: UNet, vae: Vae, clip: ClipVision, scheduler: SchedulerConfig) -> Result<Self, Error> {
        scheduler.validate()?;
        let u = unet.config();
        let latent = vae.config().latent_channels;
        if u.views() != NUM_VIEWS {
            return Err(Error::invalid(
                "unet num_views",
                format!("{NUM_VIEWS} (found {}; Wonder3D passes num_views: 6 to the UNet)", u.views()),
            ));
        }
        if !matches!(u.projection_class_embeddings_input_dim, Some(10 | 14)) || u.class_embed_type.is_none() {
            return Err(Error::invalid(
                "unet class_embed_type",
                "projection with projection_class_embeddings_input_dim 10 or 14 (the switchers)",
            ));
        }
        if u.in_channels != 2 * latent || u.out_channels != latent {
            return Err(Error::invalid(
                "unet in_channels/out_channels",
                format!(
                    "{} and {latent} for a {latent}-channel VAE (found {}, {})",
                    2 * latent,
                    u.in_channels,
                    u.out_channels
                ),
            ));
        }
        if u.cross_attention_dim != clip.config().projection_dim {
            return Err(Error::invalid(
                "unet cross_attention_dim",
                format!("the CLIP projection_dim {} (found {})", clip.config().projection_dim, u.cross_attention_dim),
            ));
        }
        let sample_size = u.sample_size.ok_or_else(|| Error::invalid("unet sample_size", "the latent side (32)"))?;
        let image_size = sample_size * vae.config().downscale();
        Ok(Self { unet, vae, clip, scheduler, image_size })
    }

    /// Loads a model directory as published for Wonder3D / Wonder3D++ (`docs/weights.md`):
    /// `unet/`, `vae/`, `image_encoder/` (config + safetensors each) and
    /// `scheduler/scheduler_config.json`; `feature_extractor/` and `model_index.json` may be
    /// present and are not needed (the CLIP preprocessing is fixed).
    pub fn from_dir(dir: impl AsRef<Path>, device: &Device) -> Result<Self, Error> {
        Self::from_dir_with(dir, device, WeightStorage::F32)
    }

    /// [`MultiViewPipeline::from_dir`] with the linear and convolution weights of every model
    /// held as `storage` says. [`WeightStorage::AsStored`] on an f16 checkpoint (the published
    /// weights, the shipped small model) halves the memory the models take — the real-size
    /// UNet from 3.4 to 1.7 GiB — and changes no output; the arithmetic stays f32
    /// (`docs/benchmarks.md` measures both).
    pub fn from_dir_with(dir: impl AsRef<Path>, device: &Device, storage: WeightStorage) -> Result<Self, Error> {
        let dir = dir.as_ref();
        if !dir.is_dir() {
            return Err(Error::invalid(
                "weights",
                format!(
                    "a model directory with unet/, vae/, image_encoder/, scheduler/ ({} is not a directory)",
                    dir.display()
                ),
            ));
        }
        let unet = UNet::from_dir_with(dir.join("unet"), device, storage)?;
        let vae = Vae::from_dir_with(dir.join("vae"), device, storage)?;
        let clip = ClipVision::from_dir_with(dir.join("image_encoder"), device, storage)?;
        let scheduler = SchedulerConfig::from_file(dir.join("scheduler").join("scheduler_config.json"))?;
        Self::new(unet, vae, clip, scheduler)
    }

    /// The UNet.
    pub fn unet(&self) -> &UNet {
        &self.unet
    }

    /// The VAE.
    pub fn vae(&self) -> &Vae {
        &self.vae
    }

    /// The CLIP image encoder.
    pub fn clip(&self) -> &ClipVision {
        &self.clip
    }

    /// The noise-schedule config.
    pub fn scheduler(&self) -> &SchedulerConfig {
        &self.scheduler
    }

    /// The models and the schedule, taken apart (e.g. to train the UNet and reassemble).
    pub fn into_parts(self) -> (UNet, Vae, ClipVision, SchedulerConfig) {
        (self.unet, self.vae, self.clip, self.scheduler)
    }

    /// Writes the pipeline as a model directory [`MultiViewPipeline::from_dir`] (and the
    /// authors' diffusers-based code) reads: `unet/`, `vae/`, `image_encoder/` (config + f32
    /// safetensors each), `scheduler/scheduler_config.json` and `model_index.json`. The folder
    /// is written whole into a staging folder and then put in place
    /// (`w3d_core::io::write_dir_atomic`), replacing an existing `dir`, so an interrupted save
    /// never leaves a partial model.
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<(), Error> {
        self.save_with(dir, Precision::F32)
    }

    /// [`MultiViewPipeline::save`] with the weights in `precision` (f16 halves the size).
    pub fn save_with(&self, dir: impl AsRef<Path>, precision: Precision) -> Result<(), Error> {
        w3d_core::io::write_dir_atomic(dir, MODEL_INDEX, |staging| self.write_into(staging, precision))
    }

    /// The files of [`MultiViewPipeline::save`], written into the existing folder `staging`.
    pub(crate) fn write_into(&self, staging: &Path, precision: Precision) -> Result<(), Error> {
        {
            self.unet.save_with(staging.join("unet"), precision)?;
            self.vae.save_with(staging.join("vae"), precision)?;
            self.clip.save_with(staging.join("image_encoder"), precision)?;
            let scheduler = crate::loading::weights::config_json(&self.scheduler, &[("_class_name", "DDIMScheduler")])?;
            let scheduler_dir = staging.join("scheduler");
            std::fs::create_dir_all(&scheduler_dir).map_err(|e| Error::io(&scheduler_dir, e))?;
            let json = |v: &serde_json::Value| serde_json::to_vec_pretty(v).unwrap_or_default();
            let scheduler_path = scheduler_dir.join("scheduler_config.json");
            std::fs::write(&scheduler_path, json(&scheduler)).map_err(|e| Error::io(&scheduler_path, e))?;
            let index = serde_json::json!({
                "_class_name": "MVDiffusionImagePipeline",
                "unet": ["mvdiffusion.models.unet_mv2d_condition", "UNetMV2DConditionModel"],
                "vae": ["diffusers", "AutoencoderKL"],
                "image_encoder": ["transformers", "CLIPVisionModelWithProjection"],
                "scheduler": ["diffusers", "DDIMScheduler"],
            });
            let index_path = staging.join(MODEL_INDEX);
            std::fs::write(&index_path, json(&index)).map_err(|e| Error::io(&index_path, e))
        }
    }

    /// Side of the model's square images in pixels (`sample_size` × the VAE downscale: 256).
    pub fn image_size(&self) -> usize {
        self.image_size
    }

    /// Shape of the initial noise, one latent per view: `[6, latent_channels, side, side]`.
    pub fn noise_shape(&self) -> [usize; 4] {
        let side = self.image_size / self.vae.config().downscale();
        [NUM_VIEWS, self.vae.config().latent_channels, side, side]
    }

    /// The seeded initial noise ([`MultiViewPipeline::noise_shape`]).
    pub fn initial_noise(&self, seed: u64, device: &Device) -> Tensor<4> {
        gaussian_noise(self.noise_shape(), seed, device)
    }

    /// The conditions of `rgb` (3 channels, `image_size²`, values in `[0, 1]`, white
    /// background: the output of [`prepare_input`]). As in the authors' pipeline, the image is
    /// first truncated to 8 bits ([`quantize_u8`]; values already on 8-bit levels stay): CLIP
    /// preprocesses the 8-bit image, the VAE encodes `level / 255`.
    pub fn condition(&self, rgb: &Image, device: &Device) -> Result<Conditioning, Error> {
        let s = self.image_size as u32;
        rgb.expect_shape("input image", s, s, 3)?;
        let n = self.image_size;
        let levels: Vec<f32> = rgb.data().iter().map(|&v| f32::from(quantize_u8(v))).collect();
        let size = self.clip.config().image_size;
        let pixels = clip_preprocess(&levels, n, n, size)?;
        let pixels = Tensor::<4>::from_data(TensorData::new(pixels, [1, 3, size, size]), device);
        let embeds = self.clip.image_embeds(pixels)?;
        let latent = self.image_latent(rgb, device)?;
        Ok(Conditioning { embeds, latent })
    }

    /// The VAE latent (mean × `scaling_factor`, `[1, c, h, w]`) of `rgb` as
    /// [`MultiViewPipeline::condition`] computes it (8-bit levels), without the CLIP
    /// embedding: the encoding of training targets.
    pub fn image_latent(&self, rgb: &Image, device: &Device) -> Result<Tensor<4>, Error> {
        let s = self.image_size as u32;
        rgb.expect_shape("image", s, s, 3)?;
        let n = self.image_size;
        let unit: Vec<f32> = rgb.data().iter().map(|&v| f32::from(quantize_u8(v)) / 255.0).collect();
        let chw: Tensor<3> = Tensor::from_data(TensorData::new(unit, [n, n, 3]), device);
        let image = chw.permute([2, 0, 1]).reshape([1, 3, n, n]) * 2.0 - 1.0;
        Ok(self.vae.encode_mean(image)? * self.vae.config().scaling_factor)
    }

    /// The switcher labels `[12·draws, input_dim]` of `draws` draws batched as [`join_draws`]
    /// lays them out: the normal labels of every draw's 6 views, then the colour labels.
    fn class_labels(&self, camera: CameraType, draws: usize, device: &Device) -> Result<Tensor<2>, Error> {
        let dim = self.unet.config().projection_class_embeddings_input_dim.unwrap_or(0);
        let mut labels = switcher_labels(Domain::Normal, camera, dim)?.repeat(draws);
        labels.extend(switcher_labels(Domain::Colour, camera, dim)?.repeat(draws));
        Ok(Tensor::from_data(TensorData::new(labels, [2 * NUM_VIEWS * draws, dim]), device))
    }

    /// The model of a sampling loop over `draws` draws: the guided noise prediction step by
    /// step, with the options' accelerations.
    fn denoiser<'a>(
        &'a self,
        cond: &'a Conditioning,
        draws: usize,
        options: &'a SampleOptions,
        device: &Device,
    ) -> Result<Denoiser<'a>, Error> {
        let labels = self.class_labels(options.camera, draws, device)?;
        let caches = (options.acceleration.cache_interval > 1).then(|| {
            let cache = FeatureCache::new(options.acceleration.cache_depth);
            [cache.clone(), cache]
        });
        Ok(Denoiser {
            pipeline: self,
            cond,
            labels,
            options,
            caches,
            filled_at: [None; 2],
            context: compute::current().with_settings(options.acceleration.pass),
        })
    }

    fn check_conditioning(&self, cond: &Conditioning) -> Result<(), Error> {
        let [_, c, h, w] = self.noise_shape();
        let d = self.unet.config().cross_attention_dim;
        if cond.embeds.dims() != [1, d] {
            return Err(Error::invalid("conditioning embeds", format!("[1, {d}] (found {:?})", cond.embeds.dims())));
        }
        if cond.latent.dims() != [1, c, h, w] {
            return Err(Error::invalid(
                "conditioning latent",
                format!("[1, {c}, {h}, {w}] (found {:?})", cond.latent.dims()),
            ));
        }
        Ok(())
    }

    /// Checks that the UNet has the skip a DeepCache run starts its shallow branch at.
    fn check_cache_depth(&self, options: &SampleOptions) -> Result<(), Error> {
        let skips = self.unet.skip_count();
        let a = &options.acceleration;
        if a.cache_interval > 1 && a.cache_depth >= skips {
            return Err(Error::invalid(
                "cache_depth",
                format!("a skip of the UNet, 0..{skips} (found {})", a.cache_depth),
            ));
        }
        Ok(())
    }

    fn check_latents(&self, x: &Tensor<4>, field: &str, allow_shared: bool) -> Result<(), Error> {
        let [_, c, h, w] = self.noise_shape();
        let dims = x.dims();
        let ok = (dims[0] == 2 * NUM_VIEWS || (allow_shared && dims[0] == NUM_VIEWS)) && dims[1..] == [c, h, w];
        if !ok {
            let shared = if allow_shared { format!("[{NUM_VIEWS}, {c}, {h}, {w}] or ") } else { String::new() };
            return Err(Error::invalid(field, format!("{shared}[{}, {c}, {h}, {w}] (found {dims:?})", 2 * NUM_VIEWS)));
        }
        Ok(())
    }

    /// Sampling (DDIM, DPM-Solver++(2M) or UniPC, per `options.sampler`) from `noise` down
    /// to clean latents `[12, c, h, w]` (`[normal × 6, colour × 6]`). `noise` is `[6, c, h,
    /// w]` (one latent per view, shared by both domains, as the authors sample) or `[12, c, h,
    /// w]` (per domain, e.g. from [`MultiViewPipeline::invert`]). `progress(done, total)` is
    /// called after every step.
    pub fn sample_from(
        &self,
        noise: Tensor<4>,
        cond: &Conditioning,
        options: &SampleOptions,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Tensor<4>, Error> {
        options.validate()?;
        self.check_latents(&noise, "noise", true)?;
        self.check_conditioning(cond)?;
        self.check_cache_depth(options)?;
        let mut latents = self.sample_draws(vec![noise], &[options.seed], cond, options, progress)?;
        Ok(latents.remove(0))
    }

    /// [`MultiViewPipeline::sample_from`] for several draws at once, each from its own noise
    /// (of a shape the callers checked) with its own seed for the per-step noise: the draws go through the UNet as
    /// one batch, every attention staying inside its draw, so each comes out as it would alone
    /// (up to the last bits of f32 where an operation over the larger batch is split across
    /// the cores differently) while the batch shares the passes' fixed costs.
    /// `progress(step, steps)` after every step of the batch.
    fn sample_draws(
        &self,
        noises: Vec<Tensor<4>>,
        seeds: &[u64],
        cond: &Conditioning,
        options: &SampleOptions,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Vec<Tensor<4>>, Error> {
        debug_assert_eq!(noises.len(), seeds.len(), "one seed per draw");
        let draws = noises.len();
        let Some(first) = noises.first() else {
            return Err(Error::invalid("draws", "at least 1 draw (found 0)"));
        };
        let device = first.device();
        let mut model = self.denoiser(cond, draws, options, &device)?;
        let per_domain: Vec<Tensor<4>> =
            noises.into_iter().map(|n| if n.dims()[0] == NUM_VIEWS { n.repeat_dim(0, 2) } else { n }).collect();
        let mut x = join_draws(&per_domain);
        match options.sampler {
            SamplerKind::Ddim => {
                let scheduler = DdimScheduler::new(self.scheduler.clone(), options.steps)?;
                let total = scheduler.timesteps().len();
                for (i, &t) in scheduler.timesteps().iter().enumerate() {
                    let eps = model.predict(x.clone(), t, i)?;
                    let variance_noise = (options.eta > 0.0).then(|| {
                        let shape = per_domain[0].dims();
                        let per_draw: Vec<Tensor<4>> = seeds
                            .iter()
                            .map(|&seed| {
                                let step_seed = seed ^ (i as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
                                gaussian_noise(shape, step_seed, &device)
                            })
                            .collect();
                        join_draws(&per_draw)
                    });
                    x = scheduler.step(eps, t, x, options.eta, variance_noise)?;
                    progress(i + 1, total);
                }
            }
            SamplerKind::DpmSolverPlusPlus2M => {
                let scheduler = DpmSolverMultistepScheduler::new(self.scheduler.clone(), options.steps)?;
                x = sample_multistep(scheduler, x, &mut model, progress)?;
            }
            SamplerKind::UniPc => {
                let scheduler = UniPcMultistepScheduler::new(self.scheduler.clone(), options.steps)?;
                x = sample_multistep(scheduler, x, &mut model, progress)?;
            }
        }
        Ok(split_draws(x, draws))
    }

    /// DDIM inversion of clean latents `[12, c, h, w]` (`[normal × 6, colour × 6]`) to the
    /// noise `[12, c, h, w]` that deterministic sampling (`eta = 0`, guidance 1, the same
    /// `steps`) maps back to them. The model is evaluated conditionally (guidance 1);
    /// `refinements` fixed-point iterations per step make it the exact inverse as they
    /// converge (see [`ddim_invert`]).
    pub fn invert(
        &self,
        latents: Tensor<4>,
        cond: &Conditioning,
        camera: CameraType,
        steps: usize,
        refinements: usize,
    ) -> Result<Tensor<4>, Error> {
        self.check_latents(&latents, "latents", false)?;
        self.check_conditioning(cond)?;
        let inverse = DdimInverseScheduler::new(self.scheduler.clone(), steps)?;
        let options = SampleOptions { camera, guidance: 1.0, ..SampleOptions::default() };
        let mut model = self.denoiser(cond, 1, &options, &latents.device())?;
        ddim_invert(&inverse, latents, refinements, |x, t| model.predict(x, t, 0))
    }

    /// Decodes latents `[12, c, h, w]` into the 6 normal and 6 colour images (one image at a
    /// time, to bound memory).
    pub fn decode(&self, latents: Tensor<4>, camera: CameraType) -> Result<GeneratedViews, Error> {
        self.check_latents(&latents, "latents", false)?;
        let [n, c, h, w] = latents.dims();
        let scaled = latents / self.vae.config().scaling_factor;
        let mut images = Vec::with_capacity(n);
        for i in 0..n {
            let decoded = self.vae.decode(scaled.clone().slice([i..i + 1, 0..c, 0..h, 0..w]))?;
            let [_, _, ih, iw] = decoded.dims();
            let hwc = (decoded * 0.5 + 0.5).clamp(0.0, 1.0).reshape([3, ih, iw]).permute([1, 2, 0]);
            let values = hwc
                .into_data()
                .try_to_vec::<f32>()
                .map_err(|e| Error::invalid("decoded image", format!("f32 values ({e:?})")))?;
            images.push(Image::new(iw as u32, ih as u32, 3, values)?);
        }
        let colours = images.split_off(NUM_VIEWS);
        Ok(GeneratedViews { camera, normals: images, colours })
    }

    /// The whole generation: [`prepare_input`], [`MultiViewPipeline::condition`], seeded
    /// noise, [`MultiViewPipeline::sample_from`] and [`MultiViewPipeline::decode`].
    pub fn generate(
        &self,
        rgba: &Image,
        options: &SampleOptions,
        device: &Device,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<GeneratedViews, Error> {
        let input = prepare_input(rgba, self.image_size as u32)?;
        let cond = self.condition(&input, device)?;
        self.sample_views(&cond, options, device, progress)
    }

    /// The views of one conditioning: `options.draws` draws (seeded noise,
    /// [`MultiViewPipeline::sample_from`], [`MultiViewPipeline::decode`]; seeds `seed`,
    /// `seed + 1`, …) merged into their [`GeneratedViews::consensus`], one draw as it is.
    /// Up to [`DRAWS_PER_PASS`] draws are sampled together, as one batch of the UNet; each
    /// draw's views are those it samples alone, up to the last bits of f32. `progress` counts
    /// the denoising steps of all draws together.
    pub fn sample_views(
        &self,
        cond: &Conditioning,
        options: &SampleOptions,
        device: &Device,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<GeneratedViews, Error> {
        options.validate()?;
        self.check_conditioning(cond)?;
        self.check_cache_depth(options)?;
        // Grown pass by pass: `draws` is the caller's number, not memory to claim up front.
        let mut draws = Vec::new();
        let mut first = 0;
        while first < options.draws {
            let count = (options.draws - first).min(DRAWS_PER_PASS);
            let seeds: Vec<u64> = (first..first + count).map(|k| options.seed.wrapping_add(k as u64)).collect();
            let noises = seeds.iter().map(|&seed| self.initial_noise(seed, device)).collect();
            let latents = self.sample_draws(noises, &seeds, cond, options, &mut |i, n| {
                let done = first.saturating_mul(n).saturating_add(i.saturating_mul(count));
                progress(done, options.draws.saturating_mul(n));
            })?;
            // The VAE's products as the sampling's (bf16 where asked).
            for latents in latents {
                draws.push(compute::with_settings(options.acceleration.pass, || self.decode(latents, options.camera))?);
            }
            first += count;
        }
        if draws.len() == 1 {
            return Ok(draws.remove(0));
        }
        GeneratedViews::consensus(&draws)
    }
}

/// The model of one sampling loop: the guided noise prediction of [`MultiViewPipeline`] for a
/// batch of draws, with the accelerations of its [`SampleOptions`] — guidance only inside
/// the guidance interval, DeepCache's feature caches (one per guidance branch), and the pass
/// settings carried to the thread the passes run on.
struct Denoiser<'a> {
    pipeline: &'a MultiViewPipeline,
    cond: &'a Conditioning,
    labels: Tensor<2>,
    options: &'a SampleOptions,
    /// DeepCache's features of the conditional and the unconditional branch.
    caches: Option<[FeatureCache; 2]>,
    /// The step at which each branch's cache was last filled by a full pass.
    filled_at: [Option<usize>; 2],
    context: compute::Context,
}

impl Denoiser<'_> {
    /// The guided noise prediction for latents `[12·k, c, h, w]` (`k` draws as
    /// [`join_draws`] lays them out: `[normal × 6 × k, colour × 6 × k]`) at timestep `t`, step
    /// `step` of the loop.
    ///
    /// The unconditional branch (zero image embedding, zero condition latent) and the
    /// conditional one are two UNet evaluations of the whole batch, one after the other. The
    /// reference batches them as 24 images `[normal uncond, normal cond, colour uncond, colour
    /// cond]`; every attention of the UNet stays inside one branch (multi-view attention
    /// within a domain's 6 views, cross-domain attention between view `i` of the normal and
    /// the colour half), so the numbers are the same, and the activations of one branch at a
    /// time need half the memory. Outside the guidance interval only the conditional branch
    /// runs. With DeepCache, a step that is not a multiple of the cache interval reuses each
    /// branch's deep features if that branch ran a full pass since the last multiple.
    fn predict(&mut self, x: Tensor<4>, t: usize, step: usize) -> Result<Tensor<4>, Error> {
        let options = self.options;
        let a = &options.acceleration;
        let guided = options.guidance != 1.0 && a.guided_at(t, self.pipeline.scheduler.num_train_timesteps);
        let reuse = [a.reuses_cache(step, self.filled_at[0]), a.reuses_cache(step, self.filled_at[1])];
        for (branch, filled) in self.filled_at.iter_mut().enumerate() {
            if self.caches.is_some() && !reuse[branch] && (branch == 0 || guided) {
                *filled = Some(step);
            }
        }
        let (unet, cond, labels) = (&self.pipeline.unet, self.cond, &self.labels);
        let caches = &mut self.caches;
        let context = self.context.clone();
        // On a worker of rayon's pool, which the CPU kernels share (see `cpu_pool`), with this
        // loop's pass settings.
        crate::kernels::pool::on_pool(move || {
            compute::within(context, || {
                let n = x.dims()[0];
                let cond_latent = cond.latent.clone().repeat_dim(0, n);
                let [_, d] = cond.embeds.dims();
                let context: Tensor<3> = cond.embeds.clone().reshape([1, 1, d]).repeat_dim(0, n);
                let timestep = [t as f32];
                debug_assert_eq!(labels.dims()[0], n, "labels of the [normal, colour] batch");
                let mut pass = |sample: Tensor<4>, context: Tensor<3>, branch: usize| match caches {
                    Some(caches) => unet.forward_cached(
                        sample,
                        &timestep,
                        context,
                        Some(labels.clone()),
                        &UNetExtra::default(),
                        &mut caches[branch],
                        reuse[branch],
                    ),
                    None => unet.forward(sample, &timestep, context, Some(labels.clone())),
                };
                let conditional = pass(Tensor::cat(vec![x.clone(), cond_latent.clone()], 1), context.clone(), 0)?;
                if !guided {
                    return Ok(conditional);
                }
                let unconditional = pass(Tensor::cat(vec![x, cond_latent.zeros_like()], 1), context.zeros_like(), 1)?;
                Ok(classifier_free_guidance(unconditional, conditional, options.guidance))
            })
        })
    }
}

/// The sampling loop of a multistep solver from `x` at its first timestep:
/// `progress(step, steps)` after every step.
fn sample_multistep(
    mut scheduler: impl MultistepScheduler,
    mut x: Tensor<4>,
    model: &mut Denoiser<'_>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Tensor<4>, Error> {
    let timesteps = scheduler.run_timesteps().to_vec();
    for (i, &t) in timesteps.iter().enumerate() {
        let eps = model.predict(x.clone(), t, i)?;
        x = scheduler.step(eps, t, x)?;
        progress(i + 1, timesteps.len());
    }
    Ok(x)
}

/// Draws `[12, c, h, w]` each (`[normal × 6, colour × 6]`) laid out as one UNet batch of
/// `[12·k, c, h, w]`: every draw's normal half, then every draw's colour half — the layout
/// whose cross-domain attention pairs view `i` of a draw's two halves.
fn join_draws(draws: &[Tensor<4>]) -> Tensor<4> {
    if let [one] = draws {
        return one.clone();
    }
    let half = |d: &Tensor<4>, k: usize| d.clone().narrow(0, k * NUM_VIEWS, NUM_VIEWS);
    let mut halves: Vec<Tensor<4>> = draws.iter().map(|d| half(d, 0)).collect();
    halves.extend(draws.iter().map(|d| half(d, 1)));
    Tensor::cat(halves, 0)
}

/// The inverse of [`join_draws`]: `[12·k, c, h, w]` back to `k` draws of `[12, c, h, w]`.
fn split_draws(x: Tensor<4>, draws: usize) -> Vec<Tensor<4>> {
    if draws == 1 {
        return vec![x];
    }
    let offset = draws * NUM_VIEWS;
    (0..draws)
        .map(|k| {
            let normal = x.clone().narrow(0, k * NUM_VIEWS, NUM_VIEWS);
            let colour = x.clone().narrow(0, offset + k * NUM_VIEWS, NUM_VIEWS);
            Tensor::cat(vec![normal, colour], 0)
        })
        .collect()
}
