//! **wonder3d**: one photo of an object in, a textured, watertight 3D mesh out — a Rust
//! reimplementation of Wonder3D++ (cross-domain multi-view diffusion + cascaded mesh
//! extraction).
//!
//! [`Pipeline`] is the whole job as one object: views (normal maps, masks and colours of a
//! 6-view rig) → closed mesh → UV atlas and baked texture, or, with a loaded model (feature
//! `diffusion`, on by default), an image → generated views → the same. The image is an RGBA
//! image whose alpha masks the object, or a photo of an object on a plain, graded or softly
//! shadowed background: [`photo`] removes the background (with a confidence score that
//! refuses what it cannot trust) and frames the object ([`prepare_image`]). One staged
//! [`Progress`] callback and one serialisable [`Report`] cover every stage. Each stage is
//! also its own crate, re-exported here ([`recon`], [`texture`], [`raster`], …): depend on
//! `w3d-recon` alone to embed only the mesh extraction in an engine (no file formats, no
//! Burn; `examples/engine_embedding.rs`).
//!
//! ```
//! use wonder3d::{Pipeline, Preset, ViewRig};
//!
//! # let dir = tempfile::tempdir().unwrap();
//! # let path = dir.path().join("views");
//! # let spot = wonder3d::demo::bundled_spot()?;
//! # wonder3d::raster::render_oracle_views(&spot, &ViewRig::wonder3d_ortho(), 96)?.save(&path)?;
//! let views = wonder3d::ViewSet::load(&path)?;     // cameras.json + normal/mask/colour PNGs
//! let pipeline = Pipeline::new().with_preset(Preset::Fast).with_texture_size(256);
//! let output = pipeline.from_views(&views, &mut |p| eprintln!("{} {}/{}", p.stage.name(), p.done, p.total))?;
//! output.save(dir.path().join("object.glb"))?;     // textured, self-contained GLB
//! assert!(output.report.triangles > 500 && output.mesh.texture().is_some());
//! # Ok::<(), wonder3d::Error>(())
//! ```
//!
//! Generating views needs the published Wonder3D++ weights (`docs/weights.md`):
//!
//! ```no_run
//! # #[cfg(feature = "diffusion")] {
//! use wonder3d::{Generator, Image, Pipeline};
//!
//! let model = Generator::load("ckpts/wonder3d_plus")?; // or, by Hub id (downloaded once, cached):
//! // let model = Generator::from_pretrained("flamehaze1115/Wonder3D_plus", &mut |_| {})?;
//! let pipeline = Pipeline::new().with_model(model);
//! let output = pipeline.from_image(&Image::read("cup.jpg")?, &mut |_| {})?; // a photo or RGBA
//! output.save("cup.glb")?;
//! # }
//! # Ok::<(), wonder3d::Error>(())
//! ```

// Layers, bottom-up: each group imports only from itself and the groups above it.
// Building blocks: input images, output-path checks, progress events, contact sheets,
// weights by Hugging Face Hub id.
mod input;
pub mod outputs;
mod progress;
pub mod sheet;
#[cfg(feature = "diffusion")]
pub mod weights;

// The multi-view diffusion model.
#[cfg(feature = "diffusion")]
mod generate;

// The pipeline: views or an image → textured mesh.
mod pipeline;

// Jobs built on the pipeline: batches, training sets, the demo, refinement.
pub mod batch;
pub mod dataset;
pub mod demo;
pub mod refine;

#[cfg(feature = "diffusion")]
pub use generate::{Generated, Generator};
pub use input::{check_surface, load_mesh_with_surface, prepare_image};
pub use pipeline::{GENERATED_VIEW_STARTS, GenerationReport, Output, Pipeline, Report, Seconds};
pub use progress::{Progress, Stage, TextureStage};
/// Meshes, cameras, view rigs, images, view sets and file IO (the `w3d-core` crate).
pub use w3d_core as core;
pub use w3d_core::{
    Camera, Error, Image, Mesh, Projection, Result, RigView, ViewImages, ViewRig, ViewSet, load_mesh, save_mesh,
};
/// The Wonder3D++ multi-view diffusion model on Burn: the multi-view cross-domain UNet, VAE,
/// CLIP image encoder, DDIM sampling and inversion, and `MultiViewPipeline` (image → 6 views
/// × {normal, colour} → `ViewSet`) (the `w3d-diffusion` crate; feature `diffusion`, default).
#[cfg(feature = "diffusion")]
pub use w3d_diffusion as diffusion;
#[cfg(feature = "diffusion")]
pub use w3d_diffusion::{Acceleration, CameraType, ComputeDevice, OpenedDevice, SampleOptions, SamplerKind};
/// Evaluation metrics: Chamfer, F-score, volume IoU, normal consistency, PSNR / SSIM
/// (the `w3d-eval` crate).
pub use w3d_eval as eval;
/// Photos in: background removal with a confidence score, and the authors' framing (the
/// `w3d-photo` crate).
pub use w3d_photo as photo;
pub use w3d_photo::{PrepareOptions, Prepared};
/// The differentiable CPU rasteriser and render helpers (the `w3d-raster` crate).
pub use w3d_raster as raster;
/// Mesh extraction from normal maps: initialisation, coarse reconstruction, untangling and
/// polishing (the `w3d-recon` crate).
pub use w3d_recon as recon;
pub use w3d_recon::{Preset, ReconOptions};
/// Continuous remeshing: the mesh optimiser and remesh operations (the `w3d-remesh` crate).
pub use w3d_remesh as remesh;
/// Texturing: vertex-colour fusion, UV atlas, baking and dilation (the `w3d-texture`
/// crate).
pub use w3d_texture as texture;
pub use w3d_texture::TextureOptions;
