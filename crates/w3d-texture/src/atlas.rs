//! The UV atlas: charts → LSCM → packing, and the seamed output mesh.

use std::sync::atomic::{AtomicUsize, Ordering};

use glam::DVec2;
use rayon::prelude::*;
use w3d_core::{Error, Mesh, Result};

use crate::charts::{Surface, grow_charts, merge_small_charts, split_in_two};
use crate::lscm::{ChartLayout, angle_distortion, is_valid, lscm};
use crate::pack::{orient_min_area, pack};

/// Charts with less than this fraction of the surface area are merged into neighbours.
const SMALL_CHART_FRACTION: f64 = 0.005;

/// Normal cone (degrees) a merged chart must stay within.
const MERGE_MAX_ANGLE_DEG: f64 = 85.0;

/// Options of [`build_atlas`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct AtlasOptions {
    /// Side of the square atlas in texels (the texture size the layout is packed for).
    pub size: u32,
    /// Empty texels kept around every chart (so neighbouring charts are at least
    /// `2 · padding` texels apart), room for dilation and bilinear / mip sampling.
    pub padding: u32,
    /// Largest angle in degrees between a face normal and its chart's mean normal
    /// (`0 < angle < 90`); larger angles give fewer, more distorted charts.
    pub max_chart_angle_deg: f32,
}

impl Default for AtlasOptions {
    fn default() -> Self {
        AtlasOptions { size: 1024, padding: 2, max_chart_angle_deg: 66.0 }
    }
}

/// Chainable setters, one per field: `AtlasOptions::default().with_…(…)` (the struct is
/// `#[non_exhaustive]`, so code outside this crate cannot use struct-literal syntax).
impl AtlasOptions {
    w3d_core::setters! {
        with_size(size: u32);
        with_padding(padding: u32);
        with_max_chart_angle_deg(max_chart_angle_deg: f32);
    }
}

/// Measurements of an atlas.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct AtlasReport {
    /// Number of charts.
    pub charts: usize,
    /// Fraction of the unit uv square covered by triangles (Σ uv areas).
    pub utilisation: f64,
    /// Mean absolute difference between corner angles in uv and on the surface, in
    /// degrees, weighted by face area.
    pub angle_distortion_deg: f64,
    /// Texels per world unit (the same for every chart: area-preserving on average).
    pub texels_per_unit: f64,
    /// Charts whose conformal map failed the validity check and were laid out by
    /// projection or split further.
    pub fallback_charts: usize,
}

/// A seamed copy of a mesh with texture coordinates: vertices are duplicated where
/// charts meet (positions bit-identical), triangles keep their order.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub struct Atlas {
    /// Vertex positions (those of the input mesh, duplicated along seams).
    pub positions: Vec<[f32; 3]>,
    /// Triangles, same order and orientation as the input mesh's.
    pub triangles: Vec<[u32; 3]>,
    /// Texture coordinates in `[0, 1]²`, OBJ convention (v up).
    pub uvs: Vec<[f32; 2]>,
    /// For each vertex, an input vertex at the same position.
    pub source_vertex: Vec<u32>,
    /// Chart of each triangle.
    pub triangle_chart: Vec<u32>,
    /// Measurements.
    pub report: AtlasReport,
}

/// Lays out one group of faces: LSCM, else the projection, else split in two and
/// recurse (down to single faces, which are always valid).
fn parameterise(surface: &Surface, faces: Vec<u32>, fallbacks: &AtomicUsize) -> Vec<ChartLayout> {
    let mut layout = ChartLayout::projected(surface, faces);
    let projected = layout.uv.clone();
    layout.uv = lscm(surface, &layout);
    if is_valid(surface, &layout) {
        return vec![layout];
    }
    fallbacks.fetch_add(1, Ordering::Relaxed);
    layout.uv = projected;
    if layout.faces.len() == 1 || is_valid(surface, &layout) {
        return vec![layout];
    }
    // Split in two halves of the group (each half again connected where possible) and
    // lay those out; single faces always succeed.
    let (first, second) = split_in_two(surface, &layout.faces);
    let parts = if first.is_empty() || second.is_empty() {
        let mut all = layout.faces;
        let rest = all.split_off(all.len() / 2);
        vec![all, rest]
    } else {
        vec![first, second]
    };
    parts.into_par_iter().flat_map(|p| parameterise(surface, p, fallbacks)).collect()
}

/// Builds a UV atlas: charts by normal-cone region growing over the position-welded
/// adjacency, least-squares conformal maps (with validity fallbacks), all charts at one
/// texel density, packed into a `size²` square with `padding` texels around each chart.
/// The layout has no overlapping triangles: each chart is checked for flipped faces and
/// boundary self-intersections, and charts occupy disjoint padded texel footprints.
///
/// Errors on invalid options, or when the charts cannot be packed at any scale (an atlas
/// too small for the padding).
pub fn build_atlas(mesh: &Mesh, options: &AtlasOptions) -> Result<Atlas> {
    if !(8..=16384).contains(&options.size) {
        return Err(Error::invalid("atlas size", format!("8 to 16384 texels, got {}", options.size)));
    }
    if options.padding > options.size / 8 {
        return Err(Error::invalid("padding", format!("at most size / 8 texels, got {}", options.padding)));
    }
    let angle = options.max_chart_angle_deg;
    if !(angle > 0.0 && angle < 90.0) {
        return Err(Error::invalid("max_chart_angle_deg", format!("an angle in (0, 90) degrees, got {angle}")));
    }
    let surface = Surface::new(mesh.positions(), mesh.triangles());
    let all: Vec<u32> = (0..mesh.triangle_count() as u32).collect();
    let groups = grow_charts(&surface, &all, f64::from(angle).to_radians().cos());
    let total_area: f64 = surface.areas.iter().sum();
    let groups =
        merge_small_charts(&surface, groups, total_area * SMALL_CHART_FRACTION, MERGE_MAX_ANGLE_DEG.to_radians().cos());
    let fallbacks = AtomicUsize::new(0);
    let mut layouts: Vec<ChartLayout> =
        groups.into_par_iter().flat_map(|g| parameterise(&surface, g, &fallbacks)).collect();
    let (distortion, weight) =
        layouts.par_iter().map(|l| angle_distortion(&surface, l)).reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    layouts.par_iter_mut().for_each(|l| {
        l.normalise_scale(&surface);
        orient_min_area(&mut l.uv);
    });
    let areas: Vec<f64> =
        layouts.iter().map(|l| l.faces.iter().map(|&f| surface.areas[f as usize]).sum::<f64>()).collect();
    // Charts of only degenerate faces still need a footprint.
    let areas: Vec<f64> = areas.iter().map(|&a| a.max(1e-12)).collect();
    let charts: Vec<(&[DVec2], &[[u32; 3]])> =
        layouts.iter().map(|l| (l.uv.as_slice(), l.triangles.as_slice())).collect();
    let packing = pack(&charts, &areas, options.size, options.padding).ok_or_else(|| {
        Error::invalid(
            "atlas size",
            format!(
                "room for {} charts with {} texels of padding, {}² is too small",
                layouts.len(),
                options.padding,
                options.size
            ),
        )
    })?;

    // One representative input vertex per welded vertex.
    let mut representative = vec![u32::MAX; surface.positions.len()];
    for (v, &w) in surface.weld.iter().enumerate().rev() {
        representative[w as usize] = v as u32;
    }
    let size = f64::from(options.size);
    let mut positions = Vec::new();
    let mut uvs = Vec::new();
    let mut source_vertex = Vec::new();
    let mut triangles = vec![[0u32; 3]; mesh.triangle_count()];
    let mut triangle_chart = vec![0u32; mesh.triangle_count()];
    let mut uv_area = 0.0;
    for (c, layout) in layouts.iter().enumerate() {
        let base = positions.len() as u32;
        for (&w, &p) in layout.vertices.iter().zip(&layout.uv) {
            let src = representative[w as usize];
            positions.push(mesh.positions()[src as usize]);
            source_vertex.push(src);
            let t = packing.texel(c, p) / size;
            uvs.push([t.x as f32, t.y as f32]);
        }
        for (t, &f) in layout.triangles.iter().zip(&layout.faces) {
            let mut triangle = t.map(|v| v + base);
            // Charts index welded vertices, so a face whose corners share one position (a
            // piece of the mesh shrunk to a point, as a coarse reconstruction can leave)
            // would repeat an index; such a corner gets its own copy (same position and uv).
            let input = mesh.triangles()[f as usize];
            for k in 1..3 {
                if triangle[..k].contains(&triangle[k]) {
                    let copy = triangle[k] as usize;
                    triangle[k] = positions.len() as u32;
                    positions.push(mesh.positions()[input[k] as usize]);
                    source_vertex.push(input[k]);
                    uvs.push(uvs[copy]);
                }
            }
            triangles[f as usize] = triangle;
            triangle_chart[f as usize] = c as u32;
            let [a, b, d] = t.map(|v| packing.texel(c, layout.uv[v as usize]));
            uv_area += 0.5 * (b - a).perp_dot(d - a);
        }
    }
    let report = AtlasReport {
        charts: layouts.len(),
        utilisation: uv_area / (size * size),
        angle_distortion_deg: if weight > 0.0 { (distortion / weight).to_degrees() } else { 0.0 },
        texels_per_unit: packing.scale,
        fallback_charts: fallbacks.into_inner(),
    };
    Ok(Atlas { positions, triangles, uvs, source_vertex, triangle_chart, report })
}
