//! Texturing for wonder3d-rs: turns a mesh and its colour views (a [`ViewSet`], which carries its rig)
//! into a textured mesh. [`bake`] fuses the views into per-vertex colours (visibility from
//! the rasteriser, weights `|cos(view, normal)|^k`), propagates colours to vertices no view
//! sees, builds a UV atlas ([`build_atlas`]: normal-cone charts, least-squares conformal
//! maps, bit-grid packing with padding), projects the views into the atlas texels with the
//! same visibility and weights, fills unseen texels from the vertex colours and dilates
//! across chart borders. [`fuse_vertex_colours`] is the per-vertex part alone (the
//! vertex-colour fallback). [`refine_texture`] projects new views (sharper, or enhanced)
//! into the atlas a textured mesh already has, leaving silhouettes and grazing views out.
//!
//! Conventions: positions in the canonical frame (`docs/architecture.md`, "Conventions"); uvs in the OBJ
//! convention of [`Mesh::with_uvs`] (v up); view colours are sRGB in `[0, 1]` and are
//! blended in linear RGB; the baked texture is sRGB, `[H][W][3]`, row 0 at the top (v = 1).
//! The textured mesh has the input's triangles in the same order and positions, with
//! vertices duplicated along chart seams, so it rasterises identically.
//!
//! ```
//! use w3d_core::{Mesh, ViewRig};
//! use w3d_texture::{TextureOptions, bake};
//!
//! // An octahedron, rendered into the 6 views with per-vertex colours, then baked.
//! let p = vec![[0.4, 0.0, 0.0], [-0.4, 0.0, 0.0], [0.0, 0.4, 0.0], [0.0, -0.4, 0.0], [0.0, 0.0, 0.4], [0.0, 0.0, -0.4]];
//! let t = vec![[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]];
//! let colours = vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 0.0], [0.0, 1.0, 1.0], [1.0, 0.0, 1.0]];
//! let mesh = Mesh::new(p, t)?.with_colours(colours)?;
//! let rig = ViewRig::wonder3d_ortho();
//! let views = w3d_raster::render_oracle_views(&mesh, &rig, 64)?;
//! let options = TextureOptions::default().with_size(128);
//! let textured = bake(&mesh.clone().without_attributes(), &views, &options)?;
//! assert_eq!(textured.mesh.triangle_count(), 8);
//! assert_eq!(textured.mesh.texture().unwrap().width(), 128);
//! assert!(textured.report.atlas.charts >= 2);
//! // The poles are edge-on in every view: their colours are propagated from the equator.
//! assert_eq!(textured.report.seen_vertex_fraction, 4.0 / 6.0);
//! # Ok::<(), w3d_core::Error>(())
//! ```

mod atlas;
mod bake;
mod charts;
mod fusion;
mod lscm;
mod pack;
mod refine;

pub use atlas::{Atlas, AtlasOptions, AtlasReport, build_atlas};
pub use refine::{RefineTextureOptions, RefineTextureReport, refine_texture};

use glam::Vec3;
use w3d_core::image::linear_to_srgb;
use w3d_core::{Error, Image, Mesh, Result, ViewSet};

use crate::charts::Surface;

/// Options of [`bake`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct TextureOptions {
    /// Side of the square texture in texels (default 1024).
    pub size: u32,
    /// Empty texels kept around each chart in the atlas (default 2, so charts are at
    /// least 4 texels apart; see [`AtlasOptions::padding`]).
    pub padding: u32,
    /// Rings of texels grown outwards from every chart after baking (default 8, at least
    /// 4 recommended so bilinear and mip lookups at seams do not read unbaked texels).
    pub dilation: u32,
    /// Exponent `k` of the view weight `|cos(view, normal)|^k` (default 4): larger values
    /// favour the most frontal view more strongly.
    pub view_weight_exponent: f32,
    /// Normal-cone angle of the atlas charts in degrees (default 66; see
    /// [`AtlasOptions::max_chart_angle_deg`]).
    pub max_chart_angle_deg: f32,
}

impl Default for TextureOptions {
    fn default() -> Self {
        TextureOptions { size: 1024, padding: 2, dilation: 8, view_weight_exponent: 4.0, max_chart_angle_deg: 66.0 }
    }
}

/// Chainable setters, one per field: `TextureOptions::default().with_…(…)` (the struct is
/// `#[non_exhaustive]`, so code outside this crate cannot use struct-literal syntax).
impl TextureOptions {
    w3d_core::setters! {
        with_size(size: u32);
        with_padding(padding: u32);
        with_dilation(dilation: u32);
        with_view_weight_exponent(view_weight_exponent: f32);
        with_max_chart_angle_deg(max_chart_angle_deg: f32);
    }
}

impl TextureOptions {
    /// The atlas part of the options.
    pub fn atlas(&self) -> AtlasOptions {
        AtlasOptions { size: self.size, padding: self.padding, max_chart_angle_deg: self.max_chart_angle_deg }
    }

    /// Checks every option against its range, the size before what is measured against it:
    /// size 8 to 16384 texels, dilation at most the size, padding at most size / 8, a finite
    /// view-weight exponent ≥ 0 and a chart angle in (0, 90) degrees. [`bake`] calls it
    /// first; callers with long work before the bake (reconstruction) call it before that.
    pub fn validate(&self) -> Result<()> {
        if !(8..=16384).contains(&self.size) {
            return Err(Error::invalid("size", format!("a texture side of 8 to 16384 texels, got {}", self.size)));
        }
        if self.dilation > self.size {
            return Err(Error::invalid("dilation", format!("at most the texture size, got {}", self.dilation)));
        }
        if self.padding > self.size / 8 {
            return Err(Error::invalid(
                "padding",
                format!("at most size / 8 = {} texels, got {}", self.size / 8, self.padding),
            ));
        }
        let k = self.view_weight_exponent;
        if !(k.is_finite() && k >= 0.0) {
            return Err(Error::invalid("view_weight_exponent", format!("a finite value ≥ 0, got {k}")));
        }
        let angle = self.max_chart_angle_deg;
        if !(angle > 0.0 && angle < 90.0) {
            return Err(Error::invalid("max_chart_angle_deg", format!("an angle in (0, 90) degrees, got {angle}")));
        }
        Ok(())
    }
}

/// Measurements of a bake.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct BakeReport {
    /// The atlas measurements.
    pub atlas: AtlasReport,
    /// Views with a colour image that took part.
    pub views_used: usize,
    /// Fraction of (position-welded) vertices at least one view sees; the others got
    /// propagated colours.
    pub seen_vertex_fraction: f64,
    /// Fraction of the texels covered by triangles that at least one view sees; the others
    /// got the fused vertex colours.
    pub seen_texel_fraction: f64,
}

/// The result of [`bake`].
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct TexturedMesh {
    /// The input geometry with vertices split along chart seams, uvs, position-welded
    /// smooth normals and the baked sRGB texture (export with `w3d_core::io::write_glb` or
    /// `write_obj`).
    pub mesh: Mesh,
    /// The vertex-colour fallback: the input positions and triangles as given, with
    /// position-welded smooth normals and the fused (and propagated) sRGB vertex colours
    /// (the mesh [`fuse_vertex_colours`] returns).
    pub vertex_coloured: Mesh,
    /// Measurements.
    pub report: BakeReport,
}

/// Stages reported by [`bake_with_progress`], in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BakeStage {
    /// Rasterising the views and fusing per-vertex colours.
    FusingVertexColours,
    /// Building the UV atlas.
    BuildingAtlas,
    /// Projecting the views into the texels.
    Baking,
    /// Dilating across chart borders and encoding the texture.
    Dilating,
}

/// The vertex-colour result of [`fuse_vertex_colours`].
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct VertexColoured {
    /// The input positions and triangles as given, with position-welded smooth normals and
    /// the fused (and propagated) sRGB vertex colours.
    pub mesh: Mesh,
    /// Views with a colour image that took part.
    pub views_used: usize,
    /// Fraction of (position-welded) vertices at least one view sees.
    pub seen_vertex_fraction: f64,
}

/// Validates the exponent, rasterises the views and fuses per-vertex colours.
fn fuse_views(
    mesh: &Mesh,
    views: &ViewSet,
    k: f32,
) -> Result<(Vec<fusion::ViewSampler>, Surface, Vec<Vec3>, fusion::WeldedColours)> {
    if !(k.is_finite() && k >= 0.0) {
        return Err(Error::invalid("view_weight_exponent", format!("a finite value ≥ 0, got {k}")));
    }
    // Colours come only from inside the masks: with every mask empty nothing can be seen,
    // and the fault is the views', not the mesh's.
    if views.iter().all(|(_, v)| v.mask.data().iter().all(|&m| m < 0.5)) {
        return Err(Error::invalid(
            "views[..].mask",
            "a silhouette (mask ≥ 0.5) in at least one view, but every view's mask is empty",
        ));
    }
    let samplers = fusion::samplers(mesh.positions(), mesh.triangles(), views, None)?;
    let surface = Surface::new(mesh.positions(), mesh.triangles());
    let normals = fusion::welded_normals(&surface);
    let fused = fusion::fuse(&surface, &normals, &samplers, k)?;
    Ok((samplers, surface, normals, fused))
}

fn unit_normal(n: Vec3) -> [f32; 3] {
    if n == Vec3::ZERO { [0.0, 1.0, 0.0] } else { n.to_array() }
}

fn vertex_coloured_mesh(
    mesh: &Mesh,
    surface: &Surface,
    normals: &[Vec3],
    fused: &fusion::WeldedColours,
) -> Result<Mesh> {
    let srgb = |c: Vec3| c.to_array().map(|v| linear_to_srgb(v.clamp(0.0, 1.0)));
    Mesh::new(mesh.positions().to_vec(), mesh.triangles().to_vec())?
        .with_normals(surface.weld.iter().map(|&w| unit_normal(normals[w as usize])).collect())?
        .with_colours(surface.weld.iter().map(|&w| srgb(fused.colours[w as usize])).collect())
}

fn seen_fraction(fused: &fusion::WeldedColours) -> f64 {
    fused.seen.iter().filter(|&&s| s).count() as f64 / fused.seen.len() as f64
}

/// Only the per-vertex part of [`bake`]: fuses the views into vertex colours (weights
/// `|cos|^k` with `k = options.view_weight_exponent`, visibility from the rasteriser) and
/// propagates them to unseen vertices; no atlas, no texture. The fallback for viewers
/// without textures, and much cheaper than a bake.
pub fn fuse_vertex_colours(mesh: &Mesh, views: &ViewSet, options: &TextureOptions) -> Result<VertexColoured> {
    let (samplers, surface, normals, fused) = fuse_views(mesh, views, options.view_weight_exponent)?;
    Ok(VertexColoured {
        mesh: vertex_coloured_mesh(mesh, &surface, &normals, &fused)?,
        views_used: samplers.len(),
        seen_vertex_fraction: seen_fraction(&fused),
    })
}

/// Textures `mesh` from the colour images of `views` (seen through the set's rig); see the
/// crate documentation. Views without a colour image are skipped.
///
/// Errors when no view has colours or sees the mesh, or the options are out of range.
pub fn bake(mesh: &Mesh, views: &ViewSet, options: &TextureOptions) -> Result<TexturedMesh> {
    bake_with_progress(mesh, views, options, &mut |_| {})
}

/// [`bake`], calling `progress` as each stage starts.
pub fn bake_with_progress(
    mesh: &Mesh,
    views: &ViewSet,
    options: &TextureOptions,
    progress: &mut dyn FnMut(BakeStage),
) -> Result<TexturedMesh> {
    let k = options.view_weight_exponent;
    // Every option first (`--size 0` used to be reported as a dilation problem).
    options.validate()?;
    progress(BakeStage::FusingVertexColours);
    let (samplers, surface, normals, fused) = fuse_views(mesh, views, k)?;

    progress(BakeStage::BuildingAtlas);
    let atlas = build_atlas(mesh, &options.atlas())?;

    progress(BakeStage::Baking);
    // Per output vertex: its welded vertex's position, normal and fused colour.
    let welded: Vec<usize> = atlas.source_vertex.iter().map(|&v| surface.weld[v as usize] as usize).collect();
    let positions: Vec<Vec3> = atlas.positions.iter().map(|p| Vec3::from(*p)).collect();
    let out_normals: Vec<Vec3> = welded.iter().map(|&w| normals[w]).collect();
    let out_colours: Vec<Vec3> = welded.iter().map(|&w| fused.colours[w]).collect();
    let map = bake::texel_map(&atlas.uvs, &atlas.triangles, options.size);
    let attributes = bake::SurfaceAttributes {
        triangles: &atlas.triangles,
        positions: &positions,
        normals: &out_normals,
        colours: &out_colours,
    };
    let (texels, seen_texels) = bake::shade(&map, &attributes, &samplers, k);
    let covered = texels.iter().filter(|t| t.is_some()).count();

    progress(BakeStage::Dilating);
    let size = options.size;
    let texture = Image::new(size, size, 3, bake::dilate_and_encode(texels, size as usize, options.dilation))?;
    let textured = Mesh::new(atlas.positions.clone(), atlas.triangles.clone())?
        .with_normals(out_normals.iter().map(|&n| unit_normal(n)).collect())?
        .with_uvs(atlas.uvs.clone())?
        .with_texture(texture)?;
    let vertex_coloured = vertex_coloured_mesh(mesh, &surface, &normals, &fused)?;
    let report = BakeReport {
        atlas: atlas.report,
        views_used: samplers.len(),
        seen_vertex_fraction: seen_fraction(&fused),
        seen_texel_fraction: if covered > 0 { seen_texels as f64 / covered as f64 } else { 0.0 },
    };
    Ok(TexturedMesh { mesh: textured, vertex_coloured, report })
}
