//! Sampling the colour views with visibility, per-vertex colour fusion and propagation
//! to vertices no view sees.

use std::f32::consts::FRAC_PI_2;

use glam::{Mat3, Vec3};
use rayon::prelude::*;
use w3d_core::image::srgb_to_linear;
use w3d_core::{Camera, Error, Projection, Result, ViewSet};
use w3d_raster::{NO_TRIANGLE, Raster, rasterize_views};

use crate::charts::Surface;

/// Depth tolerance of the visibility test, in pixels (world size of one pixel at the
/// point's depth).
const DEPTH_TOLERANCE_PIXELS: f32 = 2.0;

/// Jacobi rounds of neighbour averaging on the propagated colours.
const PROPAGATION_SMOOTHING_ROUNDS: usize = 8;

/// Mask value from which a view pixel counts as foreground.
const MASK_THRESHOLD: f32 = 0.5;

/// One colour view ready for sampling: the geometry's raster (front-most depth per pixel)
/// and the view's linear colours.
pub(crate) struct ViewSampler {
    camera: Camera,
    /// World-to-camera rotation (the transposed camera basis) and the viewing axis,
    /// precomputed for [`ViewSampler::sample`].
    to_camera: Mat3,
    forward: Vec3,
    width: u32,
    height: u32,
    /// Per pixel: front-most depth of the mesh, or a negative value where the pixel is
    /// background in the raster or the mask.
    depth: Vec<f32>,
    /// Linear RGB per pixel.
    colour: Vec<[f32; 3]>,
    /// World size of a pixel: at unit depth for perspective cameras, absolute for orthographic.
    pixel_size: f32,
    perspective: bool,
    /// The view's index in its rig.
    pub view: usize,
    /// Per pixel: on a silhouette or a crease of the mesh as this view sees it (see
    /// [`edge_mask`]); empty when not asked for.
    edge: Vec<bool>,
}

/// What a view shows of one surface point ([`ViewSampler::look`]).
pub(crate) struct Look {
    /// `−n·d`, the cosine between the normal and the direction to the camera (> 0).
    pub cos: f32,
    /// The visible share of the bilinear footprint (inside the mask and in front), in (0, 1].
    pub coverage: f32,
    /// The linear colour, averaged over the visible footprint.
    pub colour: Vec3,
    /// The nearest pixel is on a silhouette or a crease (false without an edge mask).
    pub on_edge: bool,
}

/// Samplers for every view of `views` that has a colour image, with the mesh rasterised
/// through the set's rig at the views' size. With `edge_normals` (unit normals per vertex
/// of `positions`), each also gets the [`edge_mask`] of its view. Errors when no view has
/// colours.
pub(crate) fn samplers(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    views: &ViewSet,
    edge_normals: Option<&[Vec3]>,
) -> Result<Vec<ViewSampler>> {
    let with_colour: Vec<usize> = (0..views.len()).filter(|&i| views.views()[i].colour.is_some()).collect();
    if with_colour.is_empty() {
        return Err(Error::invalid("views", "at least one view with a colour image"));
    }
    let (w, h) = (views.width(), views.height());
    let cameras: Vec<Camera> = with_colour.iter().map(|&i| views.rig().views[i].camera).collect();
    let rasters = rasterize_views(positions, triangles, &cameras, w, h)?;
    Ok(rasters
        .into_par_iter()
        .zip(with_colour)
        .map(|(raster, i)| {
            let images = &views.views()[i];
            let colour_image = images.colour.as_ref().expect("filtered on colour");
            let mask = images.mask.data();
            let depth = raster
                .triangle
                .iter()
                .zip(&raster.depth)
                .zip(mask)
                .map(|((&t, &d), &m)| if t != NO_TRIANGLE && m >= MASK_THRESHOLD { d } else { -1.0 })
                .collect();
            let colour = colour_image
                .data()
                .chunks_exact(3)
                .map(|c| [0, 1, 2].map(|k| srgb_to_linear(c[k].clamp(0.0, 1.0))))
                .collect();
            let camera = raster.camera;
            let (pixel_size, perspective) = match camera.projection {
                Projection::Orthographic { half_height } => (2.0 * half_height / h as f32, false),
                Projection::Perspective { fov_y } => (2.0 * (0.5 * fov_y).tan() / h as f32, true),
            };
            let edge = edge_normals.map(|n| edge_mask(&raster, triangles, n)).unwrap_or_default();
            let mut sampler = ViewSampler::new(camera, w, h, depth, colour, pixel_size, perspective);
            (sampler.view, sampler.edge) = (i, edge);
            sampler
        })
        .collect())
}

/// The change of the normalised view angle from one pixel to the next above which a pixel
/// lies on a silhouette or a crease: 10° of 90° (the reference's texture refinement).
pub(crate) const EDGE_ANGLE_STEP: f32 = 10.0 / 90.0;

/// Pixels on the silhouettes and creases of the mesh as `raster` sees it: per pixel the
/// view angle `a = (arccos(cos) − π/2) / (π/2)` (cos of the interpolated normal against the
/// viewing ray, clamped to [−1, 0]; 0 on the background, 1 facing the camera), then
/// `|∇a|` by central differences above [`EDGE_ANGLE_STEP`], dilated by a square of side
/// `2·⌊width / 512⌋ + 1`. Colours there mix the object with what lies behind its edge.
pub(crate) fn edge_mask(raster: &Raster, triangles: &[[u32; 3]], normals: &[Vec3]) -> Vec<bool> {
    let (w, h) = (raster.width as usize, raster.height as usize);
    let camera = raster.camera;
    let angle: Vec<f32> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let t = raster.triangle[i];
            if t == NO_TRIANGLE {
                return 0.0;
            }
            let [u, v] = raster.uv[i];
            let tri = triangles[t as usize].map(|k| normals[k as usize]);
            let n = (tri[0] * u + tri[1] * v + tri[2] * (1.0 - u - v)).normalize_or_zero();
            let (x, y) = ((i % w) as f32 + 0.5, (i / w) as f32 + 0.5);
            let direction = camera.ray(x, y, raster.width, raster.height).direction;
            let cos = n.dot(direction).clamp(-1.0, 0.0);
            ((cos.acos() - FRAC_PI_2) / FRAC_PI_2).clamp(0.0, 1.0)
        })
        .collect();
    let at = |x: usize, y: usize| angle[y * w + x];
    let edge: Vec<bool> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let gx = 0.5 * (at((x + 1).min(w - 1), y) - at(x.saturating_sub(1), y));
            let gy = 0.5 * (at(x, (y + 1).min(h - 1)) - at(x, y.saturating_sub(1)));
            (gx * gx + gy * gy).sqrt() > EDGE_ANGLE_STEP
        })
        .collect();
    let reach = w / 512;
    if reach == 0 {
        return edge;
    }
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            (y.saturating_sub(reach)..=(y + reach).min(h - 1))
                .any(|yy| (x.saturating_sub(reach)..=(x + reach).min(w - 1)).any(|xx| edge[yy * w + xx]))
        })
        .collect()
}

impl ViewSampler {
    fn new(
        camera: Camera,
        width: u32,
        height: u32,
        depth: Vec<f32>,
        colour: Vec<[f32; 3]>,
        pixel_size: f32,
        perspective: bool,
    ) -> Self {
        let (to_camera, forward) = (camera.basis().transpose(), camera.forward());
        let (view, edge) = (0, Vec::new());
        ViewSampler { camera, to_camera, forward, width, height, depth, colour, pixel_size, perspective, view, edge }
    }

    /// The linear colour this view shows at surface point `p` with unit normal `n`, and
    /// its weight `max(0, −n·d)^k · (visible bilinear coverage)`; `None` where the view
    /// does not see the point (back-facing, occluded, outside the image or the mask).
    pub fn sample(&self, p: Vec3, n: Vec3, exponent: f32) -> Option<(f32, Vec3)> {
        let look = self.look(p, n)?;
        let cos = look.cos;
        let weight =
            if exponent.fract() == 0.0 && exponent <= 16.0 { cos.powi(exponent as i32) } else { cos.powf(exponent) };
        Some((weight * look.coverage, look.colour))
    }

    /// What this view shows at surface point `p` with unit normal `n`; `None` where it does
    /// not see the point (back-facing, occluded, outside the image or the mask).
    pub fn look(&self, p: Vec3, n: Vec3) -> Option<Look> {
        let direction = if self.perspective { (p - self.camera.eye).normalize_or(self.forward) } else { self.forward };
        let cos = -n.dot(direction);
        if cos <= 0.0 {
            return None;
        }
        // Camera::project with the basis precomputed.
        let (w, h) = (self.width as f32, self.height as f32);
        let ndc = self.camera.camera_to_ndc(self.to_camera * (p - self.camera.eye), w / h);
        let q = Vec3::new((ndc.x + 1.0) * 0.5 * w, (1.0 - ndc.y) * 0.5 * h, ndc.z);
        let tolerance = DEPTH_TOLERANCE_PIXELS * self.pixel_size * if self.perspective { q.z.max(0.0) } else { 1.0 };
        let (fx, fy) = (q.x - 0.5, q.y - 0.5);
        let (x0, y0) = (fx.floor(), fy.floor());
        let (tx, ty) = (fx - x0, fy - y0);
        let mut sum = Vec3::ZERO;
        let mut coverage = 0.0f32;
        for (dx, dy, w) in
            [(0, 0, (1.0 - tx) * (1.0 - ty)), (1, 0, tx * (1.0 - ty)), (0, 1, (1.0 - tx) * ty), (1, 1, tx * ty)]
        {
            let (x, y) = (x0 as i64 + dx, y0 as i64 + dy);
            if x < 0 || y < 0 || x >= self.width as i64 || y >= self.height as i64 || w <= 0.0 {
                continue;
            }
            let i = y as usize * self.width as usize + x as usize;
            let d = self.depth[i];
            if d >= 0.0 && (d - q.z).abs() <= tolerance {
                sum += Vec3::from(self.colour[i]) * w;
                coverage += w;
            }
        }
        if coverage <= 1e-4 {
            return None;
        }
        let (px, py) = (q.x.floor() as i64, q.y.floor() as i64);
        let on_edge = !self.edge.is_empty()
            && px >= 0
            && py >= 0
            && px < self.width as i64
            && py < self.height as i64
            && self.edge[py as usize * self.width as usize + px as usize];
        Some(Look { cos, coverage, colour: sum / coverage, on_edge })
    }
}

/// Per-vertex colours of the welded surface (linear RGB) and whether a view saw each.
pub(crate) struct WeldedColours {
    pub colours: Vec<Vec3>,
    pub seen: Vec<bool>,
}

/// Area-weighted unit normals of the welded vertices: the vertex normals
/// ([`w3d_core::normals::vertex_normals`]) of the welded surface.
pub(crate) fn welded_normals(surface: &Surface) -> Vec<Vec3> {
    // Exact: the welded positions are the input's f32 positions.
    let positions: Vec<[f32; 3]> = surface.positions.iter().map(|p| p.as_vec3().to_array()).collect();
    w3d_core::normals::vertex_normals(&positions, &surface.triangles).into_iter().map(Vec3::from).collect()
}

/// Fuses the views into welded-vertex colours (weighted mean of the views that see each
/// vertex), then propagates colours to unseen vertices over the edge graph: breadth-first
/// from coloured neighbours, then [`PROPAGATION_SMOOTHING_ROUNDS`] Jacobi rounds of
/// neighbour averaging on the unseen vertices only (smoothing towards a harmonic fill).
/// Parts of the mesh no seen vertex reaches get the mean seen colour. Errors when no view
/// sees any vertex.
pub(crate) fn fuse(
    surface: &Surface,
    normals: &[Vec3],
    samplers: &[ViewSampler],
    exponent: f32,
) -> Result<WeldedColours> {
    let fused: Vec<Option<Vec3>> = surface
        .positions
        .par_iter()
        .zip(normals)
        .map(|(p, &n)| {
            let p = p.as_vec3();
            let (mut sum, mut weight) = (Vec3::ZERO, 0.0f32);
            for s in samplers {
                if let Some((w, c)) = s.sample(p, n, exponent) {
                    sum += c * w;
                    weight += w;
                }
            }
            (weight > 0.0).then(|| sum / weight)
        })
        .collect();
    let seen: Vec<bool> = fused.iter().map(Option::is_some).collect();
    let seen_count = seen.iter().filter(|&&s| s).count();
    if seen_count == 0 {
        return Err(Error::invalid("views", "at least one view that sees the mesh (no vertex is visible in any view)"));
    }
    let mean = fused.iter().flatten().sum::<Vec3>() / seen_count as f32;
    let mut colours: Vec<Vec3> = fused.iter().map(|c| c.unwrap_or(Vec3::ZERO)).collect();
    if seen_count == colours.len() {
        return Ok(WeldedColours { colours, seen });
    }
    // Vertex adjacency (CSR) from the welded triangles.
    let n = colours.len();
    let mut edges: Vec<(u32, u32)> = surface
        .triangles
        .iter()
        .flat_map(|t| [0, 1, 2].map(|k| (t[k], t[(k + 1) % 3])))
        .flat_map(|(a, b)| [(a, b), (b, a)])
        .filter(|(a, b)| a != b)
        .collect();
    edges.sort_unstable();
    edges.dedup();
    let mut start = vec![0usize; n + 1];
    for &(a, _) in &edges {
        start[a as usize + 1] += 1;
    }
    for i in 0..n {
        start[i + 1] += start[i];
    }
    let neighbours = |v: usize| edges[start[v]..start[v + 1]].iter().map(|e| e.1 as usize);
    let mut known = seen.clone();
    let mut frontier: Vec<usize> = (0..n).filter(|&v| !known[v]).collect();
    loop {
        let layer: Vec<(usize, Vec3)> = frontier
            .iter()
            .filter_map(|&v| {
                let (mut sum, mut count) = (Vec3::ZERO, 0);
                for u in neighbours(v) {
                    if known[u] {
                        sum += colours[u];
                        count += 1;
                    }
                }
                (count > 0).then(|| (v, sum / count as f32))
            })
            .collect();
        if layer.is_empty() {
            break;
        }
        for &(v, c) in &layer {
            colours[v] = c;
            known[v] = true;
        }
        frontier.retain(|&v| !known[v]);
    }
    for v in frontier {
        colours[v] = mean;
    }
    let unseen: Vec<usize> = (0..n).filter(|&v| !seen[v]).collect();
    for _ in 0..PROPAGATION_SMOOTHING_ROUNDS {
        let next: Vec<Vec3> = unseen
            .par_iter()
            .map(|&v| {
                let (mut sum, mut count) = (Vec3::ZERO, 0);
                for u in neighbours(v) {
                    sum += colours[u];
                    count += 1;
                }
                if count > 0 { sum / count as f32 } else { colours[v] }
            })
            .collect();
        for (&v, c) in unseen.iter().zip(next) {
            colours[v] = c;
        }
    }
    Ok(WeldedColours { colours, seen })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A strip of quads along x, `n` quads long, in the plane z = 0.
    fn strip(n: usize) -> Surface {
        let mut p = Vec::new();
        for i in 0..=n {
            p.push([i as f32, 0.0, 0.0]);
            p.push([i as f32, 1.0, 0.0]);
        }
        let mut t = Vec::new();
        for i in 0..n as u32 {
            t.push([2 * i, 2 * i + 2, 2 * i + 3]);
            t.push([2 * i, 2 * i + 3, 2 * i + 1]);
        }
        Surface::new(&p, &t)
    }

    /// Propagation alone: a sampler-free fusion cannot run, so drive `fuse` with one
    /// orthographic view that sees only the left end of the strip.
    #[test]
    fn unseen_vertices_get_neighbour_colours() {
        let surface = strip(8);
        let normals = welded_normals(&surface);
        assert!(normals.iter().all(|n| (n.z - 1.0).abs() < 1e-6));
        let camera = Camera::look_at(
            Vec3::new(0.5, 0.5, 3.0),
            Vec3::new(0.5, 0.5, 0.0),
            Vec3::Y,
            Projection::Orthographic { half_height: 1.5 },
        )
        .unwrap();
        let (w, h) = (16u32, 16u32);
        let raster = w3d_raster::rasterize(
            &surface.positions.iter().map(|p| p.as_vec3().to_array()).collect::<Vec<_>>(),
            &surface.triangles,
            &camera,
            w,
            h,
        )
        .unwrap();
        // The image shows x in [-1, 2]: only vertices with x ≤ 1 (plus tolerance) are inside.
        let depth =
            raster.triangle.iter().zip(&raster.depth).map(|(&t, &d)| if t != NO_TRIANGLE { d } else { -1.0 }).collect();
        let colour = vec![[0.2, 0.4, 0.6]; (w * h) as usize];
        let sampler = ViewSampler::new(camera, w, h, depth, colour, 3.0 / h as f32, false);
        let fused = fuse(&surface, &normals, &[sampler], 4.0).unwrap();
        let seen = fused.seen.iter().filter(|&&s| s).count();
        assert!(seen >= 4 && seen < fused.seen.len(), "{seen}");
        for c in &fused.colours {
            assert!((*c - Vec3::new(0.2, 0.4, 0.6)).abs().max_element() < 1e-5, "{c}");
        }
    }
}
