//! Texture refinement: projecting new views (sharper or enhanced ones) into the atlas a
//! mesh already has, without rebuilding it.

use glam::Vec3;
use rayon::prelude::*;
use w3d_core::image::srgb_to_linear;
use w3d_core::{Error, Image, Mesh, Result, ViewSet};

use crate::bake::{dilate_and_encode, texel_map};
use crate::charts::Surface;
use crate::fusion;

/// Options of [`refine_texture`].
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct RefineTextureOptions {
    /// Weight of each view, in the order of the views' rig; empty (the default) gives the
    /// reference's weights by view name: 1.0 for `front` and `back`, 0.5 for every other
    /// view (in its four-view refinement rig, [1.0, 0.5, 1.0, 0.5] for front, right, back,
    /// left).
    pub view_weights: Vec<f32>,
    /// Accumulated weight from which a texel takes the projected views alone (default 0.8,
    /// as the reference). Below it the texel blends with the current texture in proportion:
    /// `(current · (r − Σw) + Σ w·c) / r`.
    pub replace_weight: f32,
    /// Rings of texels grown outwards from every chart after refining (default 8, as
    /// [`TextureOptions::dilation`](crate::TextureOptions::dilation)).
    pub dilation: u32,
}

impl Default for RefineTextureOptions {
    fn default() -> Self {
        RefineTextureOptions { view_weights: Vec::new(), replace_weight: 0.8, dilation: 8 }
    }
}

/// Chainable setters, one per field (the struct is `#[non_exhaustive]`).
impl RefineTextureOptions {
    w3d_core::setters! {
        with_view_weights(view_weights: Vec<f32>);
        with_replace_weight(replace_weight: f32);
        with_dilation(dilation: u32);
    }
}

/// What [`refine_texture`] did, as fractions of the texels the triangles cover.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct RefineTextureReport {
    /// Views with a colour image that took part.
    pub views_used: usize,
    /// Texels whose accumulated weight reached [`RefineTextureOptions::replace_weight`]:
    /// they show the projected views alone.
    pub replaced_fraction: f64,
    /// Texels some view sees with a smaller weight: blended with the current texture.
    pub blended_fraction: f64,
    /// Texels no view sees usefully (hidden, grazing or on a silhouette): unchanged.
    pub unchanged_fraction: f64,
}

/// Projects the colour views of `views` into the texture `mesh` already has (its uvs and
/// atlas stay), as the reference's UV refinement does after each enhancement.
///
/// Per texel, its surface point and smooth normal (normals welded by position, so chart
/// seams do not show) are projected into every view with a colour image. A view that sees
/// the point (in front, inside its mask) contributes weight
/// `view weight × cos² × coverage × (1 − edge)`, where `cos` is the angle between the normal
/// and the view, `coverage` the visible share of the pixel footprint, and `edge` 1 on the
/// silhouettes and creases of the mesh in that view (where the view angle changes by more
/// than 10° of 90° from one pixel to the next): colours there mix the object with what lies
/// behind its outline. The view's colour is first blended with the current texel by
/// `coverage`. Where the weights sum to [`RefineTextureOptions::replace_weight`] or more the
/// texel takes their weighted mean; below, it moves towards it in proportion; texels no
/// view sees keep their colour. The charts are then dilated again from the refined texels.
/// Colours are blended in linear RGB; the texture stays sRGB at its size.
///
/// Errors when the mesh has no uvs or texture, when no view has colours, or when an option
/// is out of range (named).
///
/// ```
/// use w3d_core::{Mesh, ViewRig};
/// use w3d_texture::{RefineTextureOptions, TextureOptions, bake, refine_texture};
///
/// // An octahedron with vertex colours, baked from views at 16², refined from views at 64².
/// let p = vec![[0.4, 0.0, 0.0], [-0.4, 0.0, 0.0], [0.0, 0.4, 0.0], [0.0, -0.4, 0.0], [0.0, 0.0, 0.4], [0.0, 0.0, -0.4]];
/// let t = vec![[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]];
/// let colours = vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 0.0], [0.0, 1.0, 1.0], [1.0, 0.0, 1.0]];
/// let truth = Mesh::new(p, t)?.with_colours(colours)?;
/// let rig = ViewRig::wonder3d_ortho();
/// let coarse = w3d_raster::render_oracle_views(&truth, &rig, 16)?;
/// let textured = bake(&truth.clone().without_attributes(), &coarse, &TextureOptions::default().with_size(64))?;
/// let sharp = w3d_raster::render_oracle_views(&truth, &rig, 64)?;
/// let (refined, report) = refine_texture(&textured.mesh, &sharp, &RefineTextureOptions::default())?;
/// assert_eq!(refined.uvs(), textured.mesh.uvs());
/// assert!(report.replaced_fraction > 0.3);
/// # Ok::<(), w3d_core::Error>(())
/// ```
pub fn refine_texture(
    mesh: &Mesh,
    views: &ViewSet,
    options: &RefineTextureOptions,
) -> Result<(Mesh, RefineTextureReport)> {
    let (Some(uvs), Some(texture)) = (mesh.uvs(), mesh.texture()) else {
        return Err(Error::invalid("mesh", "a textured mesh (uvs and a texture), as `bake` returns"));
    };
    validate(options, views)?;
    let (width, height) = (texture.width(), texture.height());
    if width != height {
        return Err(Error::invalid("mesh.texture", format!("a square texture, got {width}×{height}")));
    }
    let channels = texture.channels() as usize;
    if channels < 3 {
        return Err(Error::invalid("mesh.texture", format!("an RGB or RGBA texture, got {channels} channels")));
    }
    let surface = Surface::new(mesh.positions(), mesh.triangles());
    let welded = fusion::welded_normals(&surface);
    let normals: Vec<Vec3> = surface.weld.iter().map(|&w| welded[w as usize]).collect();
    let samplers = fusion::samplers(mesh.positions(), mesh.triangles(), views, Some(&normals))?;
    let weights: Vec<f32> = samplers.iter().map(|s| view_weight(options, views, s.view)).collect();
    let positions: Vec<Vec3> = mesh.positions().iter().map(|&p| Vec3::from(p)).collect();
    let current: Vec<Vec3> = texture
        .data()
        .chunks_exact(channels)
        .map(|c| Vec3::new(srgb_to_linear(c[0]), srgb_to_linear(c[1]), srgb_to_linear(c[2])))
        .collect();
    let map = texel_map(uvs, mesh.triangles(), width);
    let replace = options.replace_weight;
    // Per covered texel: its refined colour and which of the three outcomes it had.
    let texels: Vec<Option<(Vec3, Outcome)>> = map
        .triangle
        .par_iter()
        .zip(&map.bary)
        .zip(&current)
        .map(|((&t, b), &now)| {
            let tri = mesh.triangles().get(t as usize)?.map(|v| v as usize);
            let lerp = |a: &[Vec3]| a[tri[0]] * b[0] + a[tri[1]] * b[1] + a[tri[2]] * b[2];
            let (p, n) = (lerp(&positions), lerp(&normals).normalize_or_zero());
            let (mut sum, mut total) = (Vec3::ZERO, 0.0f32);
            for (sampler, &view_weight) in samplers.iter().zip(&weights) {
                let Some(look) = sampler.look(p, n) else { continue };
                if look.on_edge {
                    continue;
                }
                let w = view_weight * look.cos * look.cos * look.coverage;
                sum += w * (look.colour * look.coverage + now * (1.0 - look.coverage));
                total += w;
            }
            Some(if total <= 0.0 {
                (now, Outcome::Unchanged)
            } else if total > replace {
                (sum / total, Outcome::Replaced)
            } else {
                ((now * (replace - total) + sum) / replace, Outcome::Blended)
            })
        })
        .collect();
    let covered = texels.iter().flatten().count().max(1) as f64;
    let share = |o: Outcome| texels.iter().flatten().filter(|t| t.1 == o).count() as f64 / covered;
    let report = RefineTextureReport {
        views_used: samplers.len(),
        replaced_fraction: share(Outcome::Replaced),
        blended_fraction: share(Outcome::Blended),
        unchanged_fraction: share(Outcome::Unchanged),
    };
    let refined = texels.into_iter().map(|t| t.map(|t| t.0)).collect();
    let data = dilate_and_encode(refined, width as usize, options.dilation);
    Ok((mesh.clone().with_texture(Image::new(width, height, 3, data)?)?, report))
}

/// How a texel fared in [`refine_texture`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Outcome {
    Replaced,
    Blended,
    Unchanged,
}

/// The weight of view `index` of `views`' rig (see [`RefineTextureOptions::view_weights`]).
fn view_weight(options: &RefineTextureOptions, views: &ViewSet, index: usize) -> f32 {
    match options.view_weights.get(index) {
        Some(&w) => w,
        None if matches!(views.rig().views[index].name.as_str(), "front" | "back") => 1.0,
        None => 0.5,
    }
}

fn validate(options: &RefineTextureOptions, views: &ViewSet) -> Result<()> {
    let weights = &options.view_weights;
    if !weights.is_empty() && weights.len() != views.len() {
        return Err(Error::invalid(
            "view_weights",
            format!("one weight per view ({}) or none, got {}", views.len(), weights.len()),
        ));
    }
    if let Some(w) = weights.iter().find(|w| !(w.is_finite() && **w >= 0.0)) {
        return Err(Error::invalid("view_weights", format!("finite weights ≥ 0, got {w}")));
    }
    let r = options.replace_weight;
    if !(r.is_finite() && r > 0.0) {
        return Err(Error::invalid("replace_weight", format!("a finite weight > 0, got {r}")));
    }
    if options.dilation > 16384 {
        return Err(Error::invalid("dilation", format!("at most 16384 rings, got {}", options.dilation)));
    }
    Ok(())
}
