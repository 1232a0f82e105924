//! Iterative refinement (Wonder3D++'s third stage): *enhance four views → refine the mesh →
//! refine the texture*, `iterations` times, after the coarse mesh.
//!
//! Each iteration renders the current textured mesh through four cameras of the views' rig
//! (front, right, back, left) at [`RefineOptions::size`], asks an [`Enhancer`] for sharper
//! views of the same cameras, fits the mesh to their normals
//! ([`w3d_recon::refine_mesh`]), bakes the refined mesh's texture from the original views and
//! projects the enhanced colours into it ([`w3d_texture::refine_texture`]).
//!
//! The enhancer is a trait so that the loop does not depend on a diffusion model:
//! [`IdentityEnhancer`] returns the renders it is given (the loop then only re-fits the mesh
//! to itself at a finer resolution), and [`OracleEnhancer`] returns renders of a known mesh
//! (the best any enhancer could do, for tests and measurements).
//!
//! ```
//! use wonder3d::refine::{OracleEnhancer, RefineOptions, refine};
//! use wonder3d::{Pipeline, Preset, ViewRig};
//!
//! let spot = wonder3d::demo::bundled_spot()?;
//! let views = wonder3d::raster::render_oracle_views(&spot, &ViewRig::wonder3d_ortho(), 64)?;
//! let coarse = Pipeline::new().with_preset(Preset::Fast).without_texture().from_views(&views, &mut |_| {})?;
//! // One iteration against sharper views of spot itself, small and short for the example.
//! let options = RefineOptions::default()
//!     .with_iterations(1)
//!     .with_size(128)
//!     .with_mesh(wonder3d::recon::RefineOptions::default().with_steps(20).with_edge_len_lims((0.02, 0.04)))
//!     .with_texture(wonder3d::TextureOptions::default().with_size(256));
//! let refined = refine(&coarse.geometry, &views, &OracleEnhancer::new(spot), &options, &mut |_| {})?;
//! assert!(refined.mesh.texture().is_some() && refined.geometry.topology().is_watertight());
//! assert_eq!(refined.report.iterations.len(), 1);
//! # Ok::<(), wonder3d::Error>(())
//! ```

use std::time::Instant;

use serde::Serialize;

use w3d_core::{Error, Mesh, Result, ViewRig, ViewSet};
use w3d_recon::RefineReport as MeshRefineReport;
use w3d_texture::{BakeReport, RefineTextureOptions, RefineTextureReport, TextureOptions};

/// The four cameras of a refinement iteration, by their rig names: the reference's
/// front, right, back and left.
pub const REFINE_VIEWS: [&str; 4] = ["front", "right", "back", "left"];

/// What an [`Enhancer`] is given in one refinement iteration.
#[derive(Debug, Clone, Copy)]
#[non_exhaustive]
pub struct EnhanceRequest<'a> {
    /// The iteration, from 0.
    pub iteration: usize,
    /// Renders of the current textured mesh (smooth world-space normals, colours, masks)
    /// through the refinement cameras at the refinement size: the images to enhance.
    pub renders: &'a ViewSet,
    /// The views the mesh was reconstructed from (for a diffusion enhancer: its generated
    /// low-resolution views, which the reference uses as init and control images).
    pub views: &'a ViewSet,
}

/// Sharper views of the refinement cameras: views in, enhanced views out.
///
/// The result must have the request's rig (the same view names, in order) and image size,
/// with normals (world space, unit length), masks and colours.
pub trait Enhancer {
    /// A short name for reports (`identity`, `oracle`, …).
    fn name(&self) -> String;

    /// The enhanced views for `request`.
    fn enhance(&self, request: &EnhanceRequest<'_>) -> Result<ViewSet>;
}

/// The enhancer that changes nothing: it returns the renders it is given.
#[derive(Debug, Clone, Copy, Default)]
pub struct IdentityEnhancer;

impl Enhancer for IdentityEnhancer {
    fn name(&self) -> String {
        "identity".into()
    }

    fn enhance(&self, request: &EnhanceRequest<'_>) -> Result<ViewSet> {
        Ok(request.renders.clone())
    }
}

/// The enhancer that knows the answer: renders of a given mesh (in the rig's world frame,
/// with its colours or texture) through the requested cameras — what a perfect enhancer
/// would return.
#[derive(Debug, Clone)]
pub struct OracleEnhancer {
    mesh: Mesh,
}

impl OracleEnhancer {
    /// An oracle showing `mesh` (already framed like the views, e.g. normalised to the unit
    /// cube for the canonical rigs).
    pub fn new(mesh: Mesh) -> Self {
        OracleEnhancer { mesh }
    }
}

impl Enhancer for OracleEnhancer {
    fn name(&self) -> String {
        "oracle".into()
    }

    fn enhance(&self, request: &EnhanceRequest<'_>) -> Result<ViewSet> {
        w3d_raster::render_oracle_views(&self.mesh, request.renders.rig(), request.renders.width())
    }
}

/// The diffusion enhancer: Wonder3D++'s ControlNet + IP-Adapter img2img call on Stable
/// Diffusion 1.5 ([`w3d_diffusion::pipelines::enhancer`]), colour and normal grids of the four views in
/// one joint call, with the authors' settings per iteration
/// ([`EnhancerOptions::for_iteration`](w3d_diffusion::pipelines::enhancer::EnhancerOptions::for_iteration)).
///
/// As in the authors' code, the init and control images are the views the mesh was
/// reconstructed from ([`EnhanceRequest::views`], brought to the refinement size with PIL's
/// bicubic filter), in every iteration; [`DiffusionEnhancer::with_init_from_renders`] uses the
/// renders of the current mesh instead (the paper's description). The IP-Adapter sees the
/// front colour view unless [`DiffusionEnhancer::with_input_image`] gives the input photo.
/// The enhanced normals are decoded as world normals, and the masks keep every pixel that is
/// not white in both the colour and the normal tile.
#[cfg(feature = "diffusion")]
#[derive(Debug)]
pub struct DiffusionEnhancer {
    pipeline: w3d_diffusion::pipelines::enhancer::EnhancerPipeline,
    device: w3d_diffusion::Device,
    input_image: Option<w3d_core::Image>,
    init_from_renders: bool,
    upstream_cfg_bugs: bool,
    acceleration: w3d_diffusion::Acceleration,
}

#[cfg(feature = "diffusion")]
impl DiffusionEnhancer {
    /// Loads an enhancer directory (`docs/weights.md`, "The enhancer") on the default CPU
    /// device.
    pub fn load(dir: impl AsRef<std::path::Path>) -> Result<Self> {
        Self::load_on(dir, w3d_diffusion::default_device())
    }

    /// Loads the enhancer `spec` names: a local enhancer directory, or a Hugging Face Hub id
    /// `owner/name[@revision][:sub/folder]` of a repository laid out the same way, downloaded
    /// into (or found in) the Hugging Face cache first
    /// ([`weights::resolve_layout`](crate::weights::resolve_layout) with
    /// [`Layout::Enhancer`](crate::weights::Layout::Enhancer); `Stage::Download` events in bytes).
    pub fn from_pretrained(spec: &str, progress: &mut dyn FnMut(crate::progress::Progress)) -> Result<Self> {
        Self::load(crate::weights::resolve_layout(spec, crate::weights::Layout::Enhancer, progress)?)
    }

    /// Loads an enhancer directory onto `device`, weights in their stored precision.
    pub fn load_on(dir: impl AsRef<std::path::Path>, device: w3d_diffusion::Device) -> Result<Self> {
        let pipeline = w3d_diffusion::pipelines::enhancer::EnhancerPipeline::from_dir_with(
            dir,
            &device,
            w3d_diffusion::WeightStorage::AsStored,
        )?;
        Ok(Self::new(pipeline, device))
    }

    /// An enhancer over loaded models.
    pub fn new(pipeline: w3d_diffusion::pipelines::enhancer::EnhancerPipeline, device: w3d_diffusion::Device) -> Self {
        DiffusionEnhancer {
            pipeline,
            device,
            input_image: None,
            init_from_renders: false,
            upstream_cfg_bugs: false,
            acceleration: w3d_diffusion::Acceleration::default(),
        }
    }

    /// This enhancer with the IP-Adapter image set to `image` (the input photo, RGB or RGBA).
    #[must_use]
    pub fn with_input_image(mut self, image: w3d_core::Image) -> Self {
        self.input_image = Some(image);
        self
    }

    w3d_core::setters! {
        /// This enhancer with the init and control images taken from the renders of the current
        /// mesh (`true`) or from the original views (`false`, the authors' code and the default).
        with_init_from_renders(init_from_renders: bool);
        /// This enhancer reproducing the batch-order bugs of the authors' pipeline (for
        /// comparisons with their outputs; off by default).
        with_upstream_cfg_bugs(upstream_cfg_bugs: bool);
        /// This enhancer with training-free accelerations in every iteration's call
        /// ([`EnhancerOptions::acceleration`](w3d_diffusion::pipelines::enhancer::EnhancerOptions::acceleration);
        /// none by default). Checked when the enhancer runs.
        with_acceleration(acceleration: w3d_diffusion::Acceleration);
    }

    /// The accelerations of every iteration's call.
    pub fn acceleration(&self) -> &w3d_diffusion::Acceleration {
        &self.acceleration
    }
}

#[cfg(feature = "diffusion")]
/// The tiles of the refinement views of `views` at `size²`: colours and normal maps
/// ((n + 1) / 2) over white.
fn enhancer_tiles(views: &ViewSet, rig: &ViewRig, size: u32) -> Result<(Vec<w3d_core::Image>, Vec<w3d_core::Image>)> {
    let mut colours = Vec::with_capacity(rig.len());
    let mut normals = Vec::with_capacity(rig.len());
    for view in &rig.views {
        let (_, images) = views
            .iter()
            .find(|(v, _)| v.name == view.name)
            .ok_or_else(|| Error::invalid("views", format!("a view named {}", view.name)))?;
        let colour = images
            .colour
            .as_ref()
            .ok_or_else(|| Error::invalid("views", format!("a colour image for view {}", view.name)))?;
        let mask = images.mask.data();
        let over_white = |rgb: &[f32], encode: fn(f32) -> f32| -> Vec<f32> {
            rgb.chunks_exact(3)
                .zip(mask)
                .flat_map(|(p, &a)| {
                    let a = a.clamp(0.0, 1.0);
                    [encode(p[0]) * a + 1.0 - a, encode(p[1]) * a + 1.0 - a, encode(p[2]) * a + 1.0 - a]
                })
                .collect()
        };
        let (w, h) = (images.normal.width(), images.normal.height());
        let colour = w3d_core::Image::new(w, h, 3, over_white(colour.data(), |v| v))?;
        let normal = w3d_core::Image::new(w, h, 3, over_white(images.normal.data(), |v| 0.5 * v + 0.5))?;
        colours.push(w3d_diffusion::pipelines::enhancer::resize_bicubic(&colour, size, size)?);
        normals.push(w3d_diffusion::pipelines::enhancer::resize_bicubic(&normal, size, size)?);
    }
    Ok((colours, normals))
}

#[cfg(feature = "diffusion")]
impl Enhancer for DiffusionEnhancer {
    fn name(&self) -> String {
        "diffusion".into()
    }

    fn enhance(&self, request: &EnhanceRequest<'_>) -> Result<ViewSet> {
        use w3d_diffusion::pipelines::enhancer::{
            EnhancerOptions, images_to_tensor, make_grid, split_grid, tensor_to_images,
        };
        let rig = request.renders.rig().clone();
        let size = request.renders.width();
        let source = if self.init_from_renders { request.renders } else { request.views };
        let (colours, normals) = enhancer_tiles(source, &rig, size)?;
        let (colour_grid, normal_grid) = (make_grid(&colours)?, make_grid(&normals)?);
        let grids = images_to_tensor(&[&colour_grid, &normal_grid], &self.device)?;
        let options = EnhancerOptions::for_iteration(request.iteration)
            .with_upstream_cfg_bugs(self.upstream_cfg_bugs)
            .with_acceleration(self.acceleration);
        let ip_image = match &self.input_image {
            Some(image) => image.clone(),
            None => colours[0].clone(),
        };
        let tokens = self.pipeline.image_tokens(&ip_image, &options, &self.device)?;
        let enhanced = self.pipeline.enhance_grids(grids, &tokens, &options, &mut |_, _| {})?;
        let mut grids = tensor_to_images(enhanced)?.into_iter();
        let (colour_grid, normal_grid) = match (grids.next(), grids.next()) {
            (Some(c), Some(n)) => (c, n),
            _ => return Err(Error::invalid("enhanced grids", "a colour and a normal grid")),
        };
        w3d_diffusion::pipelines::multiview::views_from_images(
            rig,
            &split_grid(&normal_grid)?,
            &split_grid(&colour_grid)?,
        )
    }
}

/// Options of [`refine`].
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct RefineOptions {
    /// Refinement iterations (the reference runs 2); 0 returns the input mesh textured as
    /// the pipeline would.
    pub iterations: usize,
    /// Side of the square renders and enhanced views in pixels (the reference: 512).
    pub size: u32,
    /// The mesh refinement of each iteration.
    pub mesh: w3d_recon::RefineOptions,
    /// The texture bake of each refined mesh (from the original views).
    pub texture: TextureOptions,
    /// The projection of the enhanced colours into the baked texture.
    pub texture_refinement: RefineTextureOptions,
}

impl Default for RefineOptions {
    fn default() -> Self {
        RefineOptions {
            iterations: 2,
            size: 512,
            mesh: w3d_recon::RefineOptions::default(),
            texture: TextureOptions::default(),
            texture_refinement: RefineTextureOptions::default(),
        }
    }
}

/// Chainable setters, one per field (the struct is `#[non_exhaustive]`).
impl RefineOptions {
    w3d_core::setters! {
        with_iterations(iterations: usize);
        with_size(size: u32);
        with_mesh(mesh: w3d_recon::RefineOptions);
        with_texture(texture: TextureOptions);
        with_texture_refinement(texture_refinement: RefineTextureOptions);
    }
}

/// One iteration of [`refine`].
#[derive(Debug, Clone, PartialEq, Serialize)]
#[non_exhaustive]
pub struct IterationReport {
    /// The mesh refinement.
    pub mesh: MeshRefineReport,
    /// The bake of the refined mesh from the original views.
    pub bake: BakeReport,
    /// The projection of the enhanced colours.
    pub texture: RefineTextureReport,
    /// Seconds the enhancer took.
    pub enhance_seconds: f64,
    /// Seconds of the whole iteration.
    pub seconds: f64,
}

/// What [`refine`] did.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[non_exhaustive]
pub struct RefineReport {
    /// The enhancer's [`Enhancer::name`].
    pub enhancer: String,
    /// One report per iteration.
    pub iterations: Vec<IterationReport>,
    /// Triangles of the refined mesh.
    pub triangles: usize,
    /// Wall-clock seconds of the whole refinement.
    pub seconds: f64,
}

/// A refinement event: iteration `iteration` (from 0) of `iterations` reached `step`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct RefineProgress {
    /// The iteration, from 0.
    pub iteration: usize,
    /// Iterations in all.
    pub iterations: usize,
    /// What the iteration is doing.
    pub step: RefineStep,
}

/// The parts of one refinement iteration, in order.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum RefineStep {
    /// Rendering the current mesh and running the enhancer.
    Enhancing,
    /// Fitting the mesh: `done` of `total` steps, with the loss before the step.
    Fitting {
        /// Steps done.
        done: usize,
        /// Steps in all.
        total: usize,
        /// Loss before the step.
        loss: f32,
    },
    /// Baking and refining the texture.
    Texturing,
}

/// The result of [`refine`].
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct Refined {
    /// The refined closed mesh (no attributes), in the views' world frame.
    pub geometry: Mesh,
    /// The refined mesh textured: uvs, baked and refined sRGB texture.
    pub mesh: Mesh,
    /// Measurements.
    pub report: RefineReport,
}

/// The rig of the refinement cameras ([`REFINE_VIEWS`]) taken from `rig`.
pub fn refinement_rig(rig: &ViewRig) -> Result<ViewRig> {
    let views = REFINE_VIEWS
        .iter()
        .map(|name| {
            rig.views.iter().find(|v| v.name == *name).cloned().ok_or_else(|| {
                let known: Vec<&str> = rig.views.iter().map(|v| v.name.as_str()).collect();
                Error::invalid(
                    "views",
                    format!("a rig with the refinement views {REFINE_VIEWS:?}, got {} with {known:?}", rig.name),
                )
            })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(ViewRig { name: rig.name.clone(), views })
}

/// Refines `geometry` (the closed mesh reconstructed from `views`, e.g.
/// [`crate::Output::geometry`]) with `enhancer`, [`RefineOptions::iterations`] times, and
/// textures the result (see the module documentation). `views` must carry colours and a rig
/// with the [`REFINE_VIEWS`]. `progress` receives [`RefineProgress`] events.
pub fn refine(
    geometry: &Mesh,
    views: &ViewSet,
    enhancer: &dyn Enhancer,
    options: &RefineOptions,
    progress: &mut dyn FnMut(RefineProgress),
) -> Result<Refined> {
    let start = Instant::now();
    options.texture.validate()?;
    if options.size < 16 {
        return Err(Error::invalid("size", format!("at least 16 pixels, got {}", options.size)));
    }
    let rig = refinement_rig(views.rig())?;
    let mut geometry = geometry.clone().without_attributes();
    let mut textured = w3d_texture::bake(&geometry, views, &options.texture)?.mesh;
    let mut iterations = Vec::new();
    let total = options.iterations;
    for iteration in 0..total {
        let t = Instant::now();
        let event = |step| RefineProgress { iteration, iterations: total, step };
        progress(event(RefineStep::Enhancing));
        let renders = w3d_raster::render_oracle_views(&textured, &rig, options.size)?;
        let enhanced = enhancer.enhance(&EnhanceRequest { iteration, renders: &renders, views })?;
        check_enhanced(&enhanced, &rig, options.size, &enhancer.name())?;
        let enhance_seconds = t.elapsed().as_secs_f64();
        let (refined, mesh_report) =
            w3d_recon::refine_mesh(&enhanced, &geometry, &options.mesh, &mut |done, n, loss| {
                progress(event(RefineStep::Fitting { done, total: n, loss }))
            })?;
        progress(event(RefineStep::Texturing));
        let baked = w3d_texture::bake(&refined, views, &options.texture)?;
        let (mesh, texture_report) = w3d_texture::refine_texture(&baked.mesh, &enhanced, &options.texture_refinement)?;
        iterations.push(IterationReport {
            mesh: mesh_report,
            bake: baked.report,
            texture: texture_report,
            enhance_seconds,
            seconds: t.elapsed().as_secs_f64(),
        });
        (geometry, textured) = (refined, mesh);
    }
    let report = RefineReport {
        enhancer: enhancer.name(),
        iterations,
        triangles: geometry.triangle_count(),
        seconds: start.elapsed().as_secs_f64(),
    };
    Ok(Refined { geometry, mesh: textured, report })
}

/// Fails unless `enhanced` shows `rig`'s views, in order, at `size × size`, with colours.
fn check_enhanced(enhanced: &ViewSet, rig: &ViewRig, size: u32, enhancer: &str) -> Result<()> {
    let names: Vec<&str> = enhanced.rig().views.iter().map(|v| v.name.as_str()).collect();
    let expected: Vec<&str> = rig.views.iter().map(|v| v.name.as_str()).collect();
    let what = format!("the views of enhancer {enhancer}");
    if names != expected {
        return Err(Error::invalid(what, format!("the views {expected:?}, got {names:?}")));
    }
    if (enhanced.width(), enhanced.height()) != (size, size) {
        return Err(Error::invalid(
            what,
            format!("{size}×{size} images, got {}×{}", enhanced.width(), enhanced.height()),
        ));
    }
    if let Some((rv, _)) = enhanced.iter().find(|(_, v)| v.colour.is_none()) {
        return Err(Error::invalid(what, format!("a colour image for every view, {} has none", rv.name)));
    }
    Ok(())
}
