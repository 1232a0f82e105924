//! Progress events of every long job of the facade: the [`Stage`] running and how far it is
//! ([`Progress`]).

use serde::Serialize;
use w3d_texture::BakeStage;

/// A stage of a `Pipeline` run (or of the demo, a dataset or a batch), as reported to the
/// progress callback.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum Stage {
    /// Downloading model weights from the Hugging Face Hub (`wonder3d::weights`): `done` and
    /// `total` in bytes over all the files still to fetch.
    Download,
    /// Rendering oracle views of a known mesh (the demo, benchmarks).
    Render,
    /// Preparing the input image and computing the model's conditions (CLIP, VAE).
    Condition,
    /// Denoising: one unit per sampling step.
    Denoise,
    /// Decoding the latents into the 6 normal and 6 colour views.
    Decode,
    /// Mesh extraction; the inner stage says which part (init, coarse, untangle, polish).
    Reconstruct(w3d_recon::Stage),
    /// Texturing; the inner stage says which part (fusion, atlas, baking, dilation).
    Texture(TextureStage),
    /// Scoring a result against a ground truth (the demo).
    Evaluate,
}

/// The parts of texturing, in order (the stages of `w3d_texture::bake_with_progress`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum TextureStage {
    /// Rasterising the views and fusing per-vertex colours.
    FusingVertexColours,
    /// Building the UV atlas.
    BuildingAtlas,
    /// Projecting the views into the texels.
    Baking,
    /// Dilating across chart borders.
    Dilating,
}

impl From<BakeStage> for TextureStage {
    fn from(stage: BakeStage) -> Self {
        match stage {
            BakeStage::FusingVertexColours => TextureStage::FusingVertexColours,
            BakeStage::BuildingAtlas => TextureStage::BuildingAtlas,
            BakeStage::Baking => TextureStage::Baking,
            BakeStage::Dilating => TextureStage::Dilating,
        }
    }
}

impl Stage {
    /// A short lower-case name for progress bars and logs (`denoise`, `coarse`, `atlas` …).
    pub fn name(self) -> &'static str {
        match self {
            Stage::Download => "download",
            Stage::Render => "render",
            Stage::Evaluate => "evaluate",
            Stage::Condition => "condition",
            Stage::Denoise => "denoise",
            Stage::Decode => "decode",
            Stage::Reconstruct(w3d_recon::Stage::Init) => "init",
            Stage::Reconstruct(w3d_recon::Stage::Coarse) => "coarse",
            Stage::Reconstruct(w3d_recon::Stage::Untangle) => "untangle",
            Stage::Reconstruct(w3d_recon::Stage::Polish) => "polish",
            Stage::Texture(TextureStage::FusingVertexColours) => "fusion",
            Stage::Texture(TextureStage::BuildingAtlas) => "atlas",
            Stage::Texture(TextureStage::Baking) => "bake",
            Stage::Texture(TextureStage::Dilating) => "dilate",
        }
    }
}

/// A progress event: `done` of `total` units of `stage` (steps where the stage has steps,
/// else 0/1 then 1/1), with the current loss where the stage optimises one.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct Progress {
    /// The stage running.
    pub stage: Stage,
    /// Units done.
    pub done: usize,
    /// Units in the stage.
    pub total: usize,
    /// The current loss, when the stage has one.
    pub loss: Option<f32>,
}

impl Progress {
    /// An event of `stage`.
    pub fn new(stage: Stage, done: usize, total: usize, loss: Option<f32>) -> Self {
        Progress { stage, done, total, loss }
    }
}
