//! Baking: which surface point each texel shows, its colour from the views (with the
//! fused vertex colours as a prior and as the fill where no view sees it), and dilation
//! across chart borders.

use glam::{DVec2, Vec3};
use rayon::prelude::*;
use w3d_core::image::linear_to_srgb;

use crate::fusion::ViewSampler;

/// Marks a texel no triangle covers.
const NONE: u32 = u32::MAX;

/// Weight of the fused vertex colour in each texel's blend, relative to the view weights
/// `cos^k` (so it only matters where views see the surface at grazing angles or not at all).
const VERTEX_PRIOR_WEIGHT: f32 = 1e-4;

/// Texels within this distance (texels) of a triangle but outside every triangle take the
/// colour of the nearest point of the nearest triangle (exact colours under bilinear
/// lookups at chart borders).
const BORDER_REACH: f64 = 1.5;

/// The surface point behind each texel of a `size²` atlas: triangle and barycentrics, or
/// [`NONE`]. Texel `(i, j)` (column, row from the top) has its centre at
/// `uv = ((i + 0.5) / size, 1 − (j + 0.5) / size)`.
pub(crate) struct TexelMap {
    pub triangle: Vec<u32>,
    pub bary: Vec<[f32; 3]>,
}

/// Barycentrics of `p` in triangle `t` (unnormalised-safe: returns `None` when degenerate).
fn barycentrics(p: DVec2, t: [DVec2; 3]) -> Option<[f64; 3]> {
    let area = (t[1] - t[0]).perp_dot(t[2] - t[0]);
    if area == 0.0 || !area.is_finite() {
        return None;
    }
    let b1 = (p - t[0]).perp_dot(t[2] - t[0]) / area;
    let b2 = (t[1] - t[0]).perp_dot(p - t[0]) / area;
    Some([1.0 - b1 - b2, b1, b2])
}

/// Closest point of triangle `t` to `p`: `(distance, barycentrics)`.
fn closest(p: DVec2, t: [DVec2; 3]) -> Option<(f64, [f64; 3])> {
    let b = barycentrics(p, t)?;
    if b.iter().all(|&x| x >= 0.0) {
        return Some((0.0, b));
    }
    let mut best = (f64::INFINITY, [0.0; 3]);
    for k in 0..3 {
        let (i, j) = (k, (k + 1) % 3);
        let d = t[j] - t[i];
        let s = ((p - t[i]).dot(d) / d.length_squared()).clamp(0.0, 1.0);
        let dist = (t[i] + d * s - p).length();
        if dist < best.0 {
            let mut bc = [0.0; 3];
            bc[i] = 1.0 - s;
            bc[j] = s;
            best = (dist, bc);
        }
    }
    Some(best)
}

/// Rasterises the uv triangles into the texel grid: texel centres inside a triangle
/// (edges inclusive, first triangle wins), then texels within [`BORDER_REACH`] of a
/// triangle take its closest point.
pub(crate) fn texel_map(uvs: &[[f32; 2]], triangles: &[[u32; 3]], size: u32) -> TexelMap {
    let n = size as usize;
    let s = f64::from(size);
    let to_texel = |uv: [f32; 2]| DVec2::new(f64::from(uv[0]) * s, (1.0 - f64::from(uv[1])) * s);
    let mut triangle = vec![NONE; n * n];
    let mut bary = vec![[0.0f32; 3]; n * n];
    let mut distance = vec![f64::INFINITY; n * n];
    for pass in 0..2 {
        let reach = if pass == 0 { 0.0 } else { BORDER_REACH };
        for (f, t) in triangles.iter().enumerate() {
            let q = t.map(|v| to_texel(uvs[v as usize]));
            let lo = q[0].min(q[1]).min(q[2]) - DVec2::splat(reach + 0.5);
            let hi = q[0].max(q[1]).max(q[2]) + DVec2::splat(reach - 0.5);
            let (x0, y0) = (lo.x.ceil().max(0.0) as usize, lo.y.ceil().max(0.0) as usize);
            let (x1, y1) = (hi.x.floor().min(s - 1.0), hi.y.floor().min(s - 1.0));
            if x1 < 0.0 || y1 < 0.0 {
                continue;
            }
            for y in y0..=y1 as usize {
                for x in x0..=x1 as usize {
                    let i = y * n + x;
                    let centre = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                    if pass == 0 {
                        if triangle[i] != NONE {
                            continue;
                        }
                        if let Some(b) = barycentrics(centre, q)
                            && b.iter().all(|&v| v >= 0.0)
                        {
                            triangle[i] = f as u32;
                            bary[i] = b.map(|v| v as f32);
                            distance[i] = 0.0;
                        }
                    } else if distance[i] > 0.0
                        && let Some((d, b)) = closest(centre, q)
                        && d <= reach
                        && d < distance[i]
                    {
                        triangle[i] = f as u32;
                        bary[i] = b.map(|v| v as f32);
                        distance[i] = d;
                    }
                }
            }
        }
    }
    TexelMap { triangle, bary }
}

/// What a texel needs from the mesh: per-vertex positions, normals and fused colours
/// (linear) of the triangles the texel map refers to.
pub(crate) struct SurfaceAttributes<'a> {
    pub triangles: &'a [[u32; 3]],
    pub positions: &'a [Vec3],
    pub normals: &'a [Vec3],
    pub colours: &'a [Vec3],
}

/// Linear colours of the covered texels (`None` elsewhere) and the number of covered
/// texels that at least one view sees.
pub(crate) fn shade(
    map: &TexelMap,
    mesh: &SurfaceAttributes,
    samplers: &[ViewSampler],
    exponent: f32,
) -> (Vec<Option<Vec3>>, usize) {
    let texels: Vec<(Option<Vec3>, bool)> = map
        .triangle
        .par_iter()
        .zip(&map.bary)
        .map(|(&t, b)| {
            if t == NONE {
                return (None, false);
            }
            let tri = mesh.triangles[t as usize].map(|v| v as usize);
            let lerp = |a: &[Vec3]| a[tri[0]] * b[0] + a[tri[1]] * b[1] + a[tri[2]] * b[2];
            let (p, n, prior) = (lerp(mesh.positions), lerp(mesh.normals).normalize_or_zero(), lerp(mesh.colours));
            let (mut sum, mut weight) = (prior * VERTEX_PRIOR_WEIGHT, VERTEX_PRIOR_WEIGHT);
            let mut seen = false;
            for s in samplers {
                if let Some((w, c)) = s.sample(p, n, exponent) {
                    sum += c * w;
                    weight += w;
                    seen = true;
                }
            }
            (Some(sum / weight), seen)
        })
        .collect();
    let seen = texels.iter().filter(|t| t.1).count();
    (texels.into_iter().map(|t| t.0).collect(), seen)
}

/// Grows the coloured texels outwards by `iterations` rings (each empty texel with
/// coloured 8-neighbours takes their mean), then fills what is still empty with the mean
/// colour, and encodes to an sRGB `[H][W][3]` buffer.
pub(crate) fn dilate_and_encode(mut texels: Vec<Option<Vec3>>, size: usize, iterations: u32) -> Vec<f32> {
    let neighbours = |i: usize| {
        let (x, y) = ((i % size) as i64, (i / size) as i64);
        (-1..=1i64)
            .flat_map(move |dy| (-1..=1i64).map(move |dx| (x + dx, y + dy)))
            .filter(move |&(nx, ny)| (nx, ny) != (x, y) && nx >= 0 && ny >= 0 && nx < size as i64 && ny < size as i64)
            .map(move |(nx, ny)| ny as usize * size + nx as usize)
    };
    // The ring to fill next: empty texels next to coloured ones.
    let mut queued = vec![false; size * size];
    let mut ring: Vec<usize> =
        (0..size * size).filter(|&i| texels[i].is_none() && neighbours(i).any(|j| texels[j].is_some())).collect();
    for &i in &ring {
        queued[i] = true;
    }
    for _ in 0..iterations {
        if ring.is_empty() {
            break;
        }
        let values: Vec<Vec3> = ring
            .par_iter()
            .map(|&i| {
                let (mut sum, mut count) = (Vec3::ZERO, 0);
                for j in neighbours(i) {
                    if let Some(c) = texels[j] {
                        sum += c;
                        count += 1;
                    }
                }
                sum / count as f32
            })
            .collect();
        for (&i, v) in ring.iter().zip(values) {
            texels[i] = Some(v);
        }
        let mut next = Vec::new();
        for &i in &ring {
            for j in neighbours(i) {
                if texels[j].is_none() && !queued[j] {
                    queued[j] = true;
                    next.push(j);
                }
            }
        }
        ring = next;
    }
    let filled: Vec<Vec3> = texels.iter().flatten().copied().collect();
    let mean = if filled.is_empty() { Vec3::splat(0.5) } else { filled.iter().sum::<Vec3>() / filled.len() as f32 };
    texels
        .par_iter()
        .flat_map_iter(|c| c.unwrap_or(mean).to_array().map(|v| linear_to_srgb(v.clamp(0.0, 1.0))))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texel_map_covers_a_triangle_and_its_border() {
        // A right triangle over the lower-left half of a 16² atlas (v up).
        let uvs = [[0.25, 0.25], [0.75, 0.25], [0.25, 0.75]];
        let map = texel_map(&uvs, &[[0, 1, 2]], 16);
        // Texel (5, 10): centre uv (0.34, 0.34) is inside.
        let i = 10 * 16 + 5;
        assert_eq!(map.triangle[i], 0);
        let b = map.bary[i];
        assert!((b.iter().sum::<f32>() - 1.0).abs() < 1e-6 && b.iter().all(|&v| v >= 0.0));
        // One texel left of the triangle's left edge: border, clamped onto the edge.
        let j = 10 * 16 + 3;
        assert_eq!(map.triangle[j], 0);
        assert!(map.bary[j][1].abs() < 1e-6);
        // Far away: uncovered.
        assert_eq!(map.triangle[15], NONE);
    }

    #[test]
    fn dilation_spreads_colours_and_fills_the_rest() {
        let mut texels = vec![None; 64];
        texels[0] = Some(Vec3::new(1.0, 0.0, 0.0));
        let out = dilate_and_encode(texels, 8, 2);
        let red = |p: &[f32]| (p[0] - 1.0).abs() < 1e-6 && p[1] == 0.0 && p[2] == 0.0;
        assert!(red(&out[3 * 2..3 * 3])); // (2, 0): two rings out
        assert!(red(&out[3 * 63..])); // the rest: the mean colour
    }
}
