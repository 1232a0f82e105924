//! `antialias`: analytic silhouette-edge anti-aliasing with gradients to vertex positions.
//!
//! For every pair of horizontally or vertically adjacent pixels whose triangle ids differ,
//! the front-most of the two triangles is examined. If the edge through which the pair's
//! axis leaves that triangle is a *silhouette* edge (no neighbouring triangle, or the
//! neighbour folds over to the same side on screen) and is steeper than 45° to the axis,
//! the two pixel colours are blended by how far along the axis the edge crosses: with the
//! crossing `dc` pixels from the covered pixel's centre towards its neighbour (clamped to
//! `[0, 1]`), the covered pixel moves `0.5 − dc` of the way to the neighbour's colour, or
//! the neighbour moves `dc − 0.5` of the way to the covered colour. The blend weight is
//! differentiable in the edge's endpoint positions, which gives silhouette gradients.
//! Only the input colours are read, so the result does not depend on processing order;
//! a pixel can receive several contributions, so outputs may leave the input range.

use std::collections::HashMap;

use rayon::prelude::*;
use w3d_core::{Error, Result};

use crate::project::{ClipVertex, Projector};
use crate::raster::{NO_TRIANGLE, Raster};

/// Marks a missing neighbour in [`EdgeTopology::opposite`].
pub const NO_VERTEX: u32 = u32::MAX;

/// Per triangle, the vertex of the neighbouring triangle opposite each edge.
///
/// Edges are matched by vertex *position* (bit-identical), so meshes split at UV or normal
/// seams still find their neighbours. An edge shared by more than two triangles keeps the
/// first two (in triangle order).
#[derive(Debug, Clone, PartialEq)]
pub struct EdgeTopology {
    /// `opposite[t][i]`: the far vertex of the triangle across edge `i` of triangle `t`
    /// (edge `i` joins corners `i + 1` and `i + 2`, mod 3), or [`NO_VERTEX`].
    pub opposite: Vec<[u32; 3]>,
}

impl EdgeTopology {
    /// Builds the table for a mesh. Fails on indices out of range or non-finite positions.
    pub fn new(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Result<Self> {
        w3d_core::mesh::validate_geometry(positions, triangles)?;
        let welded = w3d_core::mesh::weld_by_position(positions);
        let mut edges: HashMap<(u32, u32), [(u32, u32); 2]> = HashMap::with_capacity(triangles.len() * 2);
        let key = |a: u32, b: u32| if a < b { (a, b) } else { (b, a) };
        for (t, tri) in triangles.iter().enumerate() {
            for i in 0..3 {
                let (a, b) = (welded[tri[(i + 1) % 3] as usize], welded[tri[(i + 2) % 3] as usize]);
                let slot = edges.entry(key(a, b)).or_insert([(NO_VERTEX, NO_VERTEX); 2]);
                if let Some(free) = slot.iter_mut().find(|s| s.0 == NO_VERTEX) {
                    *free = (t as u32, tri[i]);
                }
            }
        }
        let opposite = triangles
            .iter()
            .enumerate()
            .map(|(t, tri)| {
                std::array::from_fn(|i| {
                    let (a, b) = (welded[tri[(i + 1) % 3] as usize], welded[tri[(i + 2) % 3] as usize]);
                    let slot = edges[&key(a, b)];
                    slot.iter().find(|s| s.0 != NO_VERTEX && s.0 != t as u32).map_or(NO_VERTEX, |s| s.1)
                })
            })
            .collect();
        Ok(EdgeTopology { opposite })
    }
}

/// One blended pixel pair, kept for the backward pass.
#[derive(Debug, Clone, Copy, PartialEq)]
struct EdgeSample {
    /// Pixel indices of the pair (`p1` is right of or below `p0`).
    p0: u32,
    p1: u32,
    /// The pixel whose triangle was analysed (its centre is the origin of the crossing).
    centre: u32,
    /// That triangle and its silhouette edge (joining corners `edge + 1`, `edge + 2`).
    triangle: u32,
    edge: u8,
    vertical: bool,
    /// Blend weight: `out[p0] += α·(c1 − c0)` if `α > 0`, else `out[p1] += α·(c1 − c0)`.
    alpha: f64,
}

/// The output of [`antialias`]: the image and what its backward pass needs.
#[derive(Debug, Clone, PartialEq)]
pub struct Antialiased {
    /// The anti-aliased image, `[H][W][C]`.
    pub image: Vec<f32>,
    samples: Vec<EdgeSample>,
}

impl Antialiased {
    /// Number of blended pixel pairs (silhouette crossings found).
    pub fn sample_count(&self) -> usize {
        self.samples.len()
    }
}

/// Gradients returned by [`antialias_backward`].
#[derive(Debug, Clone, PartialEq)]
pub struct AntialiasGrad {
    /// Gradient of the input colour image, `[H][W][C]`.
    pub colour: Vec<f32>,
    /// Gradient per vertex position (world space), from the silhouette crossings.
    pub positions: Vec<[f32; 3]>,
}

fn check(
    colour: &[f32],
    channels: usize,
    raster: &Raster,
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
) -> Result<()> {
    w3d_core::mesh::validate_geometry(positions, triangles)?;
    raster.check(positions.len(), triangles)?;
    if channels == 0 {
        return Err(Error::invalid("channels", "at least one channel"));
    }
    if colour.len() != raster.pixel_count() * channels {
        return Err(Error::invalid(
            "colour",
            format!(
                "{} values ({} pixels × {channels}), got {}",
                raster.pixel_count() * channels,
                raster.pixel_count(),
                colour.len()
            ),
        ));
    }
    Ok(())
}

/// Anti-aliases the silhouettes of a rendered image (see the module docs).
///
/// `colour` is the `[H][W][C]` image to anti-alias (the final shaded image, masked before
/// this call); `raster`, `positions` and `triangles` are what produced it and `topology`
/// comes from [`EdgeTopology::new`] on the same mesh.
pub fn antialias(
    colour: &[f32],
    channels: usize,
    raster: &Raster,
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    topology: &EdgeTopology,
) -> Result<Antialiased> {
    check(colour, channels, raster, positions, triangles)?;
    if topology.opposite.len() != triangles.len() {
        return Err(Error::invalid(
            "topology",
            format!("one entry per triangle ({}), got {}", triangles.len(), topology.opposite.len()),
        ));
    }
    if topology.opposite.iter().flatten().any(|&v| v != NO_VERTEX && v as usize >= positions.len()) {
        return Err(Error::invalid("topology.opposite", format!("vertex indices below {}", positions.len())));
    }
    let projector = Projector::new(&raster.camera, raster.width, raster.height);
    let clip = projector.project_all(positions);
    let samples = find_samples(raster, &clip, triangles, topology);
    let mut image = colour.to_vec();
    for s in &samples {
        let (c0, c1) = (s.p0 as usize * channels, s.p1 as usize * channels);
        let target = if s.alpha > 0.0 { c0 } else { c1 };
        for c in 0..channels {
            image[target + c] += (s.alpha * (colour[c1 + c] as f64 - colour[c0 + c] as f64)) as f32;
        }
    }
    Ok(Antialiased { image, samples })
}

/// All blended pairs of the raster, in pixel order.
fn find_samples(
    raster: &Raster,
    clip: &[ClipVertex],
    triangles: &[[u32; 3]],
    topology: &EdgeTopology,
) -> Vec<EdgeSample> {
    let (w, h) = (raster.width, raster.height);
    let silhouettes = silhouette_edges(clip, triangles, topology);
    (0..h)
        .into_par_iter()
        .flat_map_iter(|row| {
            let mut found = Vec::new();
            for col in 0..w {
                let p0 = row * w + col;
                for (vertical, p1) in
                    [(false, (col + 1 < w).then_some(p0 + 1)), (true, (row + 1 < h).then_some(p0 + w))]
                {
                    let Some(p1) = p1 else { continue };
                    if let Some(s) = analyse_pair(raster, clip, triangles, &silhouettes, p0, p1, vertical) {
                        found.push(s);
                    }
                }
            }
            found
        })
        .collect()
}

/// Signed area of the screen triangle `(a, b, c)`.
fn area(a: &ClipVertex, b: &ClipVertex, c: &ClipVertex) -> f64 {
    (b.sx - a.sx) * (c.sy - a.sy) - (c.sx - a.sx) * (b.sy - a.sy)
}

/// Coordinates of a vertex relative to the centre of pixel `centre`, with the pair axis
/// along +x (x and y swapped for vertical pairs).
fn relative(v: &ClipVertex, raster: &Raster, centre: u32, vertical: bool) -> (f64, f64) {
    let (cx, cy) = ((centre % raster.width) as f64 + 0.5, (centre / raster.width) as f64 + 0.5);
    let (x, y) = (v.sx - cx, v.sy - cy);
    if vertical { (y, x) } else { (x, y) }
}

/// Per triangle, which of its edges are silhouettes on screen: no neighbour, or the
/// neighbour's far vertex lies on the same side of the edge as the triangle's own.
fn silhouette_edges(clip: &[ClipVertex], triangles: &[[u32; 3]], topology: &EdgeTopology) -> Vec<[bool; 3]> {
    triangles
        .par_iter()
        .zip(&topology.opposite)
        .map(|(tri, opposite)| {
            let v = tri.map(|i| clip[i as usize]);
            let bb = area(&v[0], &v[1], &v[2]);
            std::array::from_fn(|i| {
                let o = opposite[i];
                o == NO_VERTEX || {
                    let a = area(&clip[o as usize], &v[(i + 1) % 3], &v[(i + 2) % 3]);
                    a.is_sign_negative() == bb.is_sign_negative()
                }
            })
        })
        .collect()
}

fn analyse_pair(
    raster: &Raster,
    clip: &[ClipVertex],
    triangles: &[[u32; 3]],
    silhouettes: &[[bool; 3]],
    p0: u32,
    p1: u32,
    vertical: bool,
) -> Option<EdgeSample> {
    let (t0, t1) = (raster.triangle[p0 as usize], raster.triangle[p1 as usize]);
    if t0 == t1 {
        return None;
    }
    let use_p1 = t0 == NO_TRIANGLE || (t1 != NO_TRIANGLE && raster.depth[p1 as usize] <= raster.depth[p0 as usize]);
    let (centre, t, ds) = if use_p1 { (p1, t1, -1.0) } else { (p0, t0, 1.0) };
    let silhouette = silhouettes[t as usize];
    if !silhouette.iter().any(|&s| s) {
        return None;
    }
    let v = triangles[t as usize].map(|i| clip[i as usize]);
    let rel = v.map(|c| relative(&c, raster, centre, vertical));
    // The edge through which the axis leaves the triangle towards the neighbour: the
    // crossing with the largest signed distance ds·x*.
    let mut best: Option<(usize, f64)> = None;
    for i in 0..3 {
        let (a, b) = (rel[(i + 1) % 3], rel[(i + 2) % 3]);
        if a.1.is_sign_negative() == b.1.is_sign_negative() {
            continue;
        }
        let crossing = ds * (a.0 * b.1 - b.0 * a.1) / (b.1 - a.1);
        if best.is_none_or(|(_, c)| crossing > c) {
            best = Some((i, crossing));
        }
    }
    let (edge, dc) = best?;
    let (a, b) = (rel[(edge + 1) % 3], rel[(edge + 2) % 3]);
    if !silhouette[edge] || (b.1 - a.1).abs() < (b.0 - a.0).abs() || !(dc > -1.0 / 16.0 && dc < 1.0 + 1.0 / 16.0) {
        return None;
    }
    let alpha = ds * (0.5 - dc.clamp(0.0, 1.0));
    (alpha != 0.0).then_some(EdgeSample { p0, p1, centre, triangle: t, edge: edge as u8, vertical, alpha })
}

/// Backward pass of [`antialias`]: pulls `grad_out` (`[H][W][C]`) back to the input colours
/// and, through the edge crossings, to the world positions of the silhouette edges'
/// endpoints. Saturated blends (`|α| = 0.5`, crossing clamped) give no position gradient.
pub fn antialias_backward(
    forward: &Antialiased,
    colour: &[f32],
    channels: usize,
    raster: &Raster,
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    grad_out: &[f32],
) -> Result<AntialiasGrad> {
    if grad_out.len() != colour.len() || forward.image.len() != colour.len() {
        return Err(Error::invalid(
            "grad_out",
            format!("{} values like the colour image, got {}", colour.len(), grad_out.len()),
        ));
    }
    check(colour, channels, raster, positions, triangles)?;
    if let Some(s) =
        forward.samples.iter().find(|s| s.triangle as usize >= triangles.len() || s.p1 as usize >= raster.pixel_count())
    {
        return Err(Error::invalid("forward", format!("samples of this raster and mesh, got triangle {}", s.triangle)));
    }
    let projector = Projector::new(&raster.camera, raster.width, raster.height);
    let clip = projector.project_all(positions);
    let mut grad_colour = grad_out.to_vec();
    let mut acc = vec![[0.0f64; 4]; positions.len()];
    for s in &forward.samples {
        let (c0, c1) = (s.p0 as usize * channels, s.p1 as usize * channels);
        let target = if s.alpha > 0.0 { c0 } else { c1 };
        let mut dd = 0.0f64;
        for c in 0..channels {
            let g = grad_out[target + c] as f64;
            grad_colour[c0 + c] -= (s.alpha * g) as f32;
            grad_colour[c1 + c] += (s.alpha * g) as f32;
            dd += g * (colour[c1 + c] as f64 - colour[c0 + c] as f64);
        }
        if s.alpha.abs() >= 0.5 {
            continue;
        }
        let ids = [
            triangles[s.triangle as usize][(s.edge as usize + 1) % 3],
            triangles[s.triangle as usize][(s.edge as usize + 2) % 3],
        ];
        let [(x1, y1), (x2, y2)] = ids.map(|i| relative(&clip[i as usize], raster, s.centre, s.vertical));
        let dy = y2 - y1;
        let xs = (x1 * y2 - x2 * y1) / dy;
        // α = ±0.5 − x*, so dL/dx* = −dL/dα.
        let gx = -dd;
        let grads = [(gx * y2 / dy, gx * (xs - x2) / dy), (-gx * y1 / dy, gx * (x1 - xs) / dy)];
        for (&i, &(gxr, gyr)) in ids.iter().zip(&grads) {
            let (gsx, gsy) = if s.vertical { (gyr, gxr) } else { (gxr, gyr) };
            let g = projector.screen_grad_to_clip(&clip[i as usize], gsx, gsy);
            let e = &mut acc[i as usize];
            e[0] += g[0];
            e[1] += g[1];
            e[2] += g[2];
        }
    }
    let positions = acc.iter().map(|g| projector.clip_grad_to_world(*g).as_vec3().to_array()).collect();
    Ok(AntialiasGrad { colour: grad_colour, positions })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::project::to_dvec;
    use crate::raster::rasterize;
    use crate::tests_util::{Lcg, relative_error};
    use glam::{DVec3, Vec3};
    use w3d_core::{Camera, Projection};

    /// `Σ g·antialias(colour)` minus the constant `Σ g·colour`, in f64, with the raster and
    /// the selected samples held fixed, at world positions `p`.
    fn blend_loss(
        aa: &Antialiased,
        raster: &Raster,
        p: &[DVec3],
        tris: &[[u32; 3]],
        colour: &[f32],
        c: usize,
        g: &[f32],
    ) -> f64 {
        let projector = Projector::new(&raster.camera, raster.width, raster.height);
        let clip: Vec<ClipVertex> = p.iter().map(|&x| projector.project(x)).collect();
        let mut total = 0.0;
        for s in &aa.samples {
            let tri = tris[s.triangle as usize];
            let [(x1, y1), (x2, y2)] = [tri[(s.edge as usize + 1) % 3], tri[(s.edge as usize + 2) % 3]]
                .map(|i| relative(&clip[i as usize], raster, s.centre, s.vertical));
            let xs = (x1 * y2 - x2 * y1) / (y2 - y1);
            let ds = if s.centre == s.p0 { 1.0 } else { -1.0 };
            let alpha = ds * (0.5 - (ds * xs).clamp(0.0, 1.0));
            let target = if s.alpha > 0.0 { s.p0 } else { s.p1 } as usize * c;
            for ch in 0..c {
                total += g[target + ch] as f64
                    * alpha
                    * (colour[s.p1 as usize * c + ch] - colour[s.p0 as usize * c + ch]) as f64;
            }
        }
        total
    }

    /// Relative error of the antialias position gradient against central differences.
    pub(crate) fn check_antialias(
        positions: &[[f32; 3]],
        tris: &[[u32; 3]],
        camera: &Camera,
        size: u32,
        seed: u64,
        vertices: &[usize],
    ) -> f64 {
        let raster = rasterize(positions, tris, camera, size, size).unwrap();
        let topo = EdgeTopology::new(positions, tris).unwrap();
        let mut rng = Lcg(seed);
        let c = 2;
        // Colour: a smooth function of the pixel inside, 0 outside (masked before AA).
        let colour: Vec<f32> = (0..raster.pixel_count() * c)
            .map(|i| if raster.triangle[i / c] == NO_TRIANGLE { 0.0 } else { 0.5 + 0.3 * ((i % 7) as f32 / 7.0) })
            .collect();
        let g: Vec<f32> = (0..colour.len()).map(|_| rng.next() as f32).collect();
        let aa = antialias(&colour, c, &raster, positions, tris, &topo).unwrap();
        assert!(aa.sample_count() > 0);
        let grad = antialias_backward(&aa, &colour, c, &raster, positions, tris, &g).unwrap();
        let base: Vec<DVec3> = positions.iter().map(|&p| to_dvec(p)).collect();
        let h = 1e-7;
        let num: Vec<[f64; 3]> = vertices
            .iter()
            .map(|&v| {
                std::array::from_fn(|axis| {
                    let mut p = base.clone();
                    p[v][axis] += h;
                    let lp = blend_loss(&aa, &raster, &p, tris, &colour, c, &g);
                    p[v][axis] -= 2.0 * h;
                    (lp - blend_loss(&aa, &raster, &p, tris, &colour, c, &g)) / (2.0 * h)
                })
            })
            .collect();
        let analytic: Vec<[f32; 3]> = vertices.iter().map(|&v| grad.positions[v]).collect();
        relative_error(&analytic, &num)
    }

    fn grid(n: usize, jitter: f32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let mut rng = Lcg(5);
        let mut positions = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                let (x, y) = (i as f32 / n as f32 - 0.5, j as f32 / n as f32 - 0.5);
                positions.push([
                    x + jitter * rng.next() as f32,
                    y + jitter * rng.next() as f32,
                    0.1 * rng.next() as f32,
                ]);
            }
        }
        let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        let mut tris = Vec::new();
        for j in 0..n {
            for i in 0..n {
                tris.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                tris.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        (positions, tris)
    }

    #[test]
    fn only_the_outline_of_a_flat_patch_changes() {
        let cam =
            Camera::look_at(Vec3::Z * 2.0, Vec3::ZERO, Vec3::Y, Projection::Orthographic { half_height: 0.6 }).unwrap();
        let (positions, tris) = grid(4, 0.0);
        let positions: Vec<[f32; 3]> =
            positions.iter().map(|p| [p[0] * 0.9 + 0.013, p[1] * 0.9 - 0.007, 0.0]).collect();
        let raster = rasterize(&positions, &tris, &cam, 40, 40).unwrap();
        let mask = raster.coverage();
        let aa =
            antialias(&mask, 1, &raster, &positions, &tris, &EdgeTopology::new(&positions, &tris).unwrap()).unwrap();
        let mut changed_outline = 0;
        for (i, (&a, &m)) in aa.image.iter().zip(&mask).enumerate() {
            let (col, row) = (i as u32 % 40, i as u32 / 40);
            let near_outline = (-1..=1).any(|d: i32| {
                [(col as i32 + d, row as i32), (col as i32, row as i32 + d)]
                    .iter()
                    .any(|&(c, r)| (0..40).contains(&c) && (0..40).contains(&r) && mask[(r * 40 + c) as usize] != m)
            });
            if a != m {
                assert!(near_outline, "interior or background pixel {i} changed");
                changed_outline += 1;
            }
        }
        assert!(changed_outline > 40, "{changed_outline}");
        // Duplicated vertices (no shared indices) but welded by position: same result.
        let split_pos: Vec<[f32; 3]> = tris.iter().flat_map(|t| t.map(|v| positions[v as usize])).collect();
        let split_tris: Vec<[u32; 3]> = (0..tris.len() as u32).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]).collect();
        let r2 = rasterize(&split_pos, &split_tris, &cam, 40, 40).unwrap();
        let aa2 =
            antialias(&mask, 1, &r2, &split_pos, &split_tris, &EdgeTopology::new(&split_pos, &split_tris).unwrap())
                .unwrap();
        assert_eq!(aa.image, aa2.image);
    }

    #[test]
    fn sweeping_an_edge_is_continuous_and_tracks_coverage() {
        // A wide quad whose right edge sweeps across one pixel in 1/64 px steps: the
        // anti-aliased row sum equals the covered width.
        let cam =
            Camera::look_at(Vec3::Z * 2.0, Vec3::ZERO, Vec3::Y, Projection::Orthographic { half_height: 1.0 }).unwrap();
        let size = 16;
        let px = 2.0 / size as f32;
        let mut previous = None;
        for step in 0..=64 {
            let right = 0.3 * px + step as f32 / 64.0 * px;
            let positions = vec![[-0.5, -0.5, 0.0], [right, -0.5, 0.0], [right, 0.5, 0.0], [-0.5, 0.5, 0.0]];
            let tris = vec![[0, 1, 2], [0, 2, 3]];
            let raster = rasterize(&positions, &tris, &cam, size, size).unwrap();
            let aa = antialias(
                &raster.coverage(),
                1,
                &raster,
                &positions,
                &tris,
                &EdgeTopology::new(&positions, &tris).unwrap(),
            )
            .unwrap();
            let row = 8 * size as usize;
            let sum: f32 = aa.image[row..row + size as usize].iter().sum();
            let covered = (right + 0.5) / px;
            assert!((sum - covered).abs() < 1e-3, "step {step}: {sum} vs {covered}");
            if let Some(p) = previous {
                assert!((sum - p) > 0.0 && sum - p < 2.0 / 64.0);
            }
            previous = Some(sum);
        }
    }

    #[test]
    fn position_gradients_match_finite_differences() {
        let (positions, tris) = grid(3, 0.04);
        for (i, projection) in [Projection::Orthographic { half_height: 0.7 }, Projection::Perspective { fov_y: 0.8 }]
            .into_iter()
            .enumerate()
        {
            let cam = Camera::look_at(Vec3::new(0.3, 0.2, 2.0), Vec3::ZERO, Vec3::Y, projection).unwrap();
            let all: Vec<usize> = (0..positions.len()).collect();
            let err = check_antialias(&positions, &tris, &cam, 32, i as u64, &all);
            assert!(err < 1e-4, "{projection:?}: {err}");
        }
    }
}
