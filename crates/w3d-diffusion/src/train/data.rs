//! The training set `wonder3d dataset` writes (layout in `docs/training.md`), read back as the
//! model's images, encoded once by the frozen VAE and CLIP encoder, and assembled into
//! [`TrainBatch`]es for each stage.
//!
//! Each sample is a view-set folder (the rotated object's 6 views: normals in the front
//! camera's frame, colour, mask) plus its camera type and background in `dataset.json`. The
//! model images are made here, at load time, so input and targets share one background:
//! - colour: `rgb · mask + bg · (1 − mask)`;
//! - normal: `(n + 1) / 2 · mask + bg · (1 − mask)` (the encoding inference decodes);
//! - mask: the mask in every channel (white object on black), whatever the background.
//!
//! The condition (input) image is the front view of the input domain framed as inference
//! frames a user's image ([`crate::prepare_input`]: cropped to the object, scaled to
//! [`crate::pipelines::multiview::OBJECT_FRACTION`] of the side, centred) on the sample's background
//! (mask-domain inputs on black), so a photo at inference is framed like the inputs the model
//! was trained on; the targets keep the rig's framing, as in Wonder3D.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use burn::tensor::{Device, Tensor, TensorData};
use serde::Deserialize;
use w3d_core::{Error, Image, ViewSet};

use crate::pipelines::multiview::{CameraType, MultiViewPipeline, NUM_VIEWS, prepare_input_on, task_labels};
use crate::train::options::{Stage, TrainBatch};

pub use w3d_core::dataset::FORMAT;

/// Largest `dataset.json` read (bytes).
const MAX_INDEX_BYTES: u64 = 64 << 20;

/// The view names of the rig, in the order of the model's views.
pub const VIEW_NAMES: [&str; NUM_VIEWS] = ["front", "front_right", "right", "back", "left", "front_left"];

pub use w3d_core::dataset::Background;

/// The domain of a group of views in a training batch.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TrainDomain {
    /// Normal maps.
    Normal,
    /// Colour images.
    Colour,
    /// Masks (stage 1 only).
    Mask,
}

impl TrainDomain {
    fn index(self) -> usize {
        match self {
            TrainDomain::Normal => 0,
            TrainDomain::Colour => 1,
            TrainDomain::Mask => 2,
        }
    }

    /// The domain switcher's task label: `[1, 0]` normal, `[0, 1]` colour; stage 1 trains
    /// without switchers (`[0, 0]` for every domain).
    pub fn task(self, stage: Stage) -> [f32; 2] {
        match (stage, self) {
            (Stage::MultiDomain, _) => [0.0, 0.0],
            (_, TrainDomain::Normal) => [1.0, 0.0],
            (_, TrainDomain::Colour | TrainDomain::Mask) => [0.0, 1.0],
        }
    }
}

/// One sample of the set.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainingSample {
    /// Folder name under the set's root.
    pub id: String,
    /// Camera type of the views.
    pub camera: CameraType,
    /// Background of the model images.
    pub background: Background,
}

#[derive(Deserialize)]
struct Index {
    format: String,
    version: u32,
    size: u32,
    views: Vec<String>,
    samples: Vec<IndexSample>,
}

#[derive(Deserialize)]
struct IndexSample {
    id: String,
    camera: String,
    background: String,
}

/// A training set on disk.
#[derive(Clone, Debug)]
pub struct TrainingSet {
    dir: PathBuf,
    size: u32,
    samples: Vec<TrainingSample>,
    background: Option<Background>,
}

/// The model images of one sample: 6 views per domain, 3 channels, values in `[0, 1]`.
#[derive(Clone, Debug)]
pub struct SampleImages {
    /// Camera type.
    pub camera: CameraType,
    /// Normal, colour and mask images, 6 each, in [`TrainDomain`] order.
    pub domains: [Vec<Image>; 3],
    /// The condition image of each domain: its front view framed as inference frames an
    /// input (see the module docs).
    pub inputs: [Image; 3],
}

impl TrainingSet {
    /// Reads `dir/dataset.json` and checks it: format and version, the 6 view names in rig
    /// order, unique sample ids naming folders inside `dir`, known camera types and
    /// backgrounds. Images are read later, by [`TrainingSet::images`].
    pub fn open(dir: impl AsRef<Path>) -> Result<Self, Error> {
        let dir = dir.as_ref().to_path_buf();
        let path = dir.join("dataset.json");
        let len = std::fs::metadata(&path).map_err(|e| Error::io(&path, e))?.len();
        if len > MAX_INDEX_BYTES {
            return Err(Error::format(&path, "size", format!("at most {MAX_INDEX_BYTES} bytes (found {len})")));
        }
        let text = std::fs::read(&path).map_err(|e| Error::io(&path, e))?;
        let mut json = serde_json::Deserializer::from_slice(&text);
        let index: Index = serde_path_to_error::deserialize(&mut json).map_err(|e| {
            let key = e.path().to_string();
            let field = if key == "." { "json".to_string() } else { key };
            Error::format(&path, field, format!("the training-set index ({})", e.inner()))
        })?;
        if index.format != FORMAT || index.version != 2 {
            return Err(Error::format(
                &path,
                "format",
                format!("{FORMAT:?} version 2 (found {:?} version {})", index.format, index.version),
            ));
        }
        if index.views != VIEW_NAMES {
            return Err(Error::format(&path, "views", format!("{VIEW_NAMES:?} (found {:?})", index.views)));
        }
        if !(8..=4096).contains(&index.size) {
            return Err(Error::format(&path, "size", format!("8 to 4096 pixels (found {})", index.size)));
        }
        if index.samples.is_empty() {
            return Err(Error::format(&path, "samples", "at least one sample"));
        }
        let mut seen = BTreeSet::new();
        let mut samples = Vec::with_capacity(index.samples.len());
        for (i, s) in index.samples.into_iter().enumerate() {
            let field = |name: &str| format!("samples[{i}].{name}");
            let safe = !s.id.is_empty()
                && s.id != "."
                && s.id != ".."
                && !s.id.contains(['/', '\\'])
                && s.id.chars().all(|c| !c.is_control());
            if !safe {
                return Err(Error::format(
                    &path,
                    field("id"),
                    format!("a folder name inside the set (found {:?})", s.id),
                ));
            }
            if !seen.insert(s.id.clone()) {
                return Err(Error::format(&path, field("id"), format!("a unique id ({:?} repeats)", s.id)));
            }
            let camera = s.camera.parse::<CameraType>().map_err(|_| {
                Error::format(&path, field("camera"), format!("\"ortho\" or \"persp\" (found {:?})", s.camera))
            })?;
            let background = match Background::from_name(&s.background) {
                Some(background) => background,
                None => {
                    let other = &s.background;
                    return Err(Error::format(
                        &path,
                        field("background"),
                        format!("\"white\", \"black\" or \"grey\" (found {other:?})"),
                    ));
                }
            };
            if !dir.join(&s.id).is_dir() {
                return Err(Error::format(
                    &path,
                    field("id"),
                    format!("a sample folder {}", dir.join(&s.id).display()),
                ));
            }
            samples.push(TrainingSample { id: s.id, camera, background });
        }
        Ok(Self { dir, size: index.size, samples, background: None })
    }

    /// The set's folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Side of the images in pixels.
    pub fn size(&self) -> u32 {
        self.size
    }

    /// The samples.
    pub fn samples(&self) -> &[TrainingSample] {
        &self.samples
    }

    /// The set with every sample composited on `background` instead of the one its index
    /// records (`None`: the recorded one). Inference always uses white; a model too small to
    /// spend capacity on the other two backgrounds can train on white alone.
    #[must_use]
    pub fn with_background(mut self, background: Option<Background>) -> Self {
        self.background = background;
        self
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether the set is empty (never, once opened).
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// The model images of sample `index` (see the module docs), checked against the index:
    /// the rig of its camera type, the set's size, colour present in every view.
    pub fn images(&self, index: usize) -> Result<SampleImages, Error> {
        let sample = self.samples.get(index).ok_or_else(|| {
            Error::invalid("sample", format!("an index below {} (found {index})", self.samples.len()))
        })?;
        let folder = self.dir.join(&sample.id);
        let set = ViewSet::load(&folder)?;
        let expected = sample.camera.rig();
        if set.rig().name != expected.name {
            return Err(Error::format(
                folder.join("cameras.json"),
                "name",
                format!("the rig {:?} of the sample's camera type (found {:?})", expected.name, set.rig().name),
            ));
        }
        let bg = self.background.unwrap_or(sample.background).value();
        let mut domains: [Vec<Image>; 3] = Default::default();
        let mut inputs = Vec::with_capacity(3);
        for view in set.views() {
            let (w, h) = (view.mask.width(), view.mask.height());
            if (w, h) != (self.size, self.size) {
                return Err(Error::format(
                    folder.join(format!("mask_{}.png", view.name)),
                    "size",
                    format!("{0}×{0} as dataset.json says (found {w}×{h})", self.size),
                ));
            }
            let colour = view.colour.as_ref().ok_or_else(|| {
                Error::format(
                    folder.join(format!("colour_{}.png", view.name)),
                    "colour",
                    "a colour image for every view",
                )
            })?;
            let mask = view.mask.data();
            let composite = |values: &[f32], encode: fn(f32) -> f32| -> Result<Image, Error> {
                let data = values
                    .chunks_exact(3)
                    .zip(mask)
                    .flat_map(|(px, &m)| px.iter().map(move |&v| encode(v) * m + bg * (1.0 - m)).collect::<Vec<_>>())
                    .collect();
                Image::new(w, h, 3, data)
            };
            domains[0].push(composite(view.normal.data(), |n| (n + 1.0) * 0.5)?);
            domains[1].push(composite(colour.data(), |c| c)?);
            domains[2].push(Image::new(w, h, 3, mask.iter().flat_map(|&m| [m; 3]).collect())?);
            if inputs.is_empty() {
                let rgba = |rgb: Vec<f32>| -> Result<Image, Error> {
                    let data = rgb.chunks_exact(3).zip(mask).flat_map(|(px, &m)| [px[0], px[1], px[2], m]).collect();
                    Image::new(w, h, 4, data)
                };
                let normal: Vec<f32> = view.normal.data().iter().map(|n| (n + 1.0) * 0.5).collect();
                let field = |name: &str| folder.join(format!("{name}_{}.png", view.name));
                let frame = |image: Image, bg: f32, name: &str| {
                    prepare_input_on(&image, self.size, bg)
                        .map_err(|e| Error::format(field(name), "mask", e.to_string()))
                };
                inputs.push(frame(rgba(normal)?, bg, "normal")?);
                inputs.push(frame(rgba(colour.data().to_vec())?, bg, "colour")?);
                inputs.push(frame(rgba(vec![1.0; mask.len() * 3])?, 0.0, "mask")?);
            }
        }
        let inputs: [Image; 3] = inputs.try_into().map_err(|_| Error::format(&folder, "views", "a front view"))?;
        Ok(SampleImages { camera: sample.camera, domains, inputs })
    }
}

/// One sample encoded by the frozen VAE and CLIP encoder of a pipeline: what training needs
/// of it, on the device it was encoded on.
#[derive(Clone, Debug)]
pub struct EncodedSample {
    /// Camera type.
    pub camera: CameraType,
    /// Latents (VAE mean × scaling factor) of the 6 views, `[6, c, h, w]`, per
    /// [`TrainDomain`].
    pub latents: [Tensor<4>; 3],
    /// Latents `[1, c, h, w]` of each domain's condition image ([`SampleImages::inputs`]).
    pub input_latents: [Tensor<4>; 3],
    /// CLIP image embeddings `[1, d]` of each domain's condition image (stage 1 conditions on
    /// the domain it generates; stages 2 and 3 on colour).
    pub input_embeds: [Tensor<2>; 3],
}

impl EncodedSample {
    /// Encodes `images` with `pipeline`'s VAE and CLIP encoder on `device` (the images must
    /// be the pipeline's size).
    pub fn encode(pipeline: &MultiViewPipeline, images: &SampleImages, device: &Device) -> Result<Self, Error> {
        let mut latents = Vec::with_capacity(3);
        for views in &images.domains {
            let per_view: Vec<Tensor<4>> =
                views.iter().map(|image| pipeline.image_latent(image, device)).collect::<Result<_, _>>()?;
            latents.push(Tensor::cat(per_view, 0));
        }
        let mut input_latents = Vec::with_capacity(3);
        let mut input_embeds = Vec::with_capacity(3);
        for input in &images.inputs {
            let condition = pipeline.condition(input, device)?;
            input_latents.push(condition.latent);
            input_embeds.push(condition.embeds);
        }
        let array = |v: Vec<Tensor<4>>| -> [Tensor<4>; 3] { v.try_into().expect("three domains") };
        let embeds: [Tensor<2>; 3] = input_embeds.try_into().expect("three domains");
        Ok(Self {
            camera: images.camera,
            latents: array(latents),
            input_latents: array(input_latents),
            input_embeds: embeds,
        })
    }

    /// A copy on `device` (e.g. the trainer's autodiff device).
    pub fn to_device(&self, device: &Device) -> Self {
        Self {
            camera: self.camera,
            latents: self.latents.clone().map(|t| t.to_device(device)),
            input_latents: self.input_latents.clone().map(|t| t.to_device(device)),
            input_embeds: self.input_embeds.clone().map(|t| t.to_device(device)),
        }
    }
}

/// A whole [`TrainingSet`] encoded by a pipeline's frozen VAE encoder and CLIP image encoder
/// ([`EncodedSample`] per sample, in the set's order), on the background the set composites
/// on. Training only ever changes the UNet, so the phases of one recipe that train on the
/// same background can share one encoding ([`crate::train::run_training_encoded`]) instead of
/// encoding the set again each (half a minute a phase for 84 samples at 64² on 2 cores).
#[derive(Clone, Debug)]
pub struct EncodedSet {
    dir: PathBuf,
    size: u32,
    samples: Vec<EncodedSample>,
}

impl EncodedSet {
    /// Encodes every sample of `set` with `pipeline`'s VAE and CLIP encoder on `device`,
    /// calling `on_sample(done, total)` after each. The set's images must be the pipeline's
    /// size (an error naming the set's `dataset.json` otherwise, before any encoding).
    pub fn encode(
        pipeline: &MultiViewPipeline,
        set: &TrainingSet,
        device: &Device,
        on_sample: &mut dyn FnMut(usize, usize),
    ) -> Result<Self, Error> {
        check_set_size(set.dir(), set.size(), pipeline)?;
        let mut samples = Vec::with_capacity(set.len());
        for i in 0..set.len() {
            samples.push(EncodedSample::encode(pipeline, &set.images(i)?, device)?);
            on_sample(i + 1, set.len());
        }
        Ok(Self { dir: set.dir().to_path_buf(), size: set.size(), samples })
    }

    /// The folder of the set it was encoded from.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Side of the set's images in pixels.
    pub fn size(&self) -> u32 {
        self.size
    }

    /// The encoded samples, in the set's order.
    pub fn samples(&self) -> &[EncodedSample] {
        &self.samples
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether the set is empty (never, once encoded from an opened set).
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }
}

/// Refuses a set whose image side is not `pipeline`'s, naming the set's `dataset.json`.
pub(crate) fn check_set_size(dir: &Path, size: u32, pipeline: &MultiViewPipeline) -> Result<(), Error> {
    if size as usize != pipeline.image_size() {
        return Err(Error::format(
            dir.join("dataset.json"),
            "size",
            format!("the model's image side {} (found {size})", pipeline.image_size()),
        ));
    }
    Ok(())
}

/// Assembles the batch of `stage` from `samples` (one object each): stage 3 takes both the
/// normal and the colour views of every object (`domains` ignored); stages 1 and 2 take the
/// views of `domains[i]` for object `i`. The condition is the colour input image, or in
/// stage 1 the input image of the object's domain. `class_dim` is the UNet's
/// `projection_class_embeddings_input_dim` (14 or 10).
pub fn assemble_batch(
    stage: Stage,
    samples: &[&EncodedSample],
    domains: &[TrainDomain],
    class_dim: usize,
) -> Result<TrainBatch, Error> {
    if samples.is_empty() {
        return Err(Error::invalid("samples", "at least one object"));
    }
    let groups: Vec<(usize, TrainDomain)> = match stage {
        Stage::CrossDomain => (0..samples.len())
            .map(|i| (i, TrainDomain::Normal))
            .chain((0..samples.len()).map(|i| (i, TrainDomain::Colour)))
            .collect(),
        _ => {
            if domains.len() != samples.len() {
                return Err(Error::invalid(
                    "domains",
                    format!("one per object ({}, found {})", samples.len(), domains.len()),
                ));
            }
            if stage == Stage::MixedDomain && domains.contains(&TrainDomain::Mask) {
                return Err(Error::invalid("domains", "normal or colour in stage 2 (masks are a stage-1 domain)"));
            }
            domains.iter().copied().enumerate().collect()
        }
    };
    let mut latents = Vec::with_capacity(groups.len());
    let mut condition = Vec::with_capacity(groups.len());
    let mut embeds = Vec::with_capacity(groups.len());
    let mut labels = Vec::with_capacity(groups.len() * NUM_VIEWS * class_dim);
    for &(object, domain) in &groups {
        let s = samples[object];
        latents.push(s.latents[domain.index()].clone());
        let source = if stage == Stage::MultiDomain { domain.index() } else { TrainDomain::Colour.index() };
        condition.push(s.input_latents[source].clone().repeat_dim(0, NUM_VIEWS));
        let [_, d] = s.input_embeds[source].dims();
        embeds.push(s.input_embeds[source].clone().reshape([1, 1, d]).repeat_dim(0, NUM_VIEWS));
        labels.extend(task_labels(domain.task(stage), s.camera, class_dim)?);
    }
    let device = samples[0].latents[0].device();
    let n = groups.len() * NUM_VIEWS;
    Ok(TrainBatch {
        latents: Tensor::cat(latents, 0),
        condition_latents: Tensor::cat(condition, 0),
        image_embeddings: Tensor::cat(embeds, 0),
        class_labels: Some(Tensor::from_data(TensorData::new(labels, [n, class_dim]), &device)),
        domains: if stage == Stage::CrossDomain { 2 } else { 1 },
    })
}
