//! `rasterize`: per-pixel front-most triangle, perspective-correct barycentrics and depth,
//! and its backward pass (barycentrics and depth → vertex positions).

use rayon::prelude::*;
use w3d_core::{Camera, Error, Result};

use crate::project::{ClipVertex, NEAR_DEPTH, Projector, check_size, to_dvec};

/// Marks a pixel that no triangle covers in [`Raster::triangle`].
pub const NO_TRIANGLE: u32 = u32::MAX;

/// Rows per parallel work item.
const BAND_ROWS: u32 = 16;

/// The rasterised image of one mesh seen by one camera.
///
/// All per-pixel vectors are row-major, origin top-left (`index = row · width + column`),
/// `width · height` long.
#[derive(Debug, Clone, PartialEq)]
pub struct Raster {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// The camera the mesh was seen through.
    pub camera: Camera,
    /// Number of vertices of the rasterised mesh.
    pub vertex_count: usize,
    /// Number of triangles of the rasterised mesh.
    pub triangle_count: usize,
    /// Front-most triangle index per pixel, or [`NO_TRIANGLE`].
    pub triangle: Vec<u32>,
    /// Perspective-correct barycentrics `(u, v)` per pixel: weight `u` on the triangle's first
    /// vertex, `v` on its second, `1 − u − v` on its third; clamped to `u, v ≥ 0`,
    /// `u + v ≤ 1`; `(0, 0)` on empty pixels.
    pub uv: Vec<[f32; 2]>,
    /// Depth along the camera's viewing axis in world units; 0 on empty pixels.
    pub depth: Vec<f32>,
}

impl Raster {
    /// The triangle covering pixel `(column, row)`, if any (`None` outside the image too).
    pub fn triangle_at(&self, column: u32, row: u32) -> Option<u32> {
        if column >= self.width || row >= self.height {
            return None;
        }
        let t = self.triangle[(row * self.width + column) as usize];
        (t != NO_TRIANGLE).then_some(t)
    }

    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// The 1-channel coverage mask: 1 where a triangle covers the pixel centre, else 0.
    pub fn coverage(&self) -> Vec<f32> {
        self.triangle.iter().map(|&t| if t == NO_TRIANGLE { 0.0 } else { 1.0 }).collect()
    }

    /// Fails unless the raster is self-consistent and belongs to a mesh with
    /// `vertex_count` vertices and `triangle_count` triangles.
    pub(crate) fn check(&self, vertex_count: usize, triangles: &[[u32; 3]]) -> Result<()> {
        let n = self.pixel_count();
        if self.triangle.len() != n || self.uv.len() != n || self.depth.len() != n {
            return Err(Error::invalid(
                "raster",
                format!("{n} values per per-pixel array for {}×{}", self.width, self.height),
            ));
        }
        if self.vertex_count != vertex_count || self.triangle_count != triangles.len() {
            return Err(Error::invalid(
                "raster",
                format!(
                    "a raster of a mesh with {vertex_count} vertices and {} triangles, got {} and {}",
                    triangles.len(),
                    self.vertex_count,
                    self.triangle_count
                ),
            ));
        }
        // Branch-free count (`NO_TRIANGLE + 1` wraps to 0); locate the culprit only on failure.
        let bound = u32::try_from(triangles.len()).unwrap_or(u32::MAX);
        let bad = self.triangle.iter().fold(0u32, |n, &t| n + (t.wrapping_add(1) > bound) as u32);
        if bad > 0
            && let Some(t) = self.triangle.iter().find(|&&t| t != NO_TRIANGLE && t as usize >= triangles.len())
        {
            return Err(Error::invalid("raster.triangle", format!("ids below {}, got {t}", triangles.len())));
        }
        Ok(())
    }
}

/// The number of non-finite values (exponent bits all ones), counted without branches.
pub(crate) fn count_non_finite(values: &[f32]) -> u32 {
    values.iter().fold(0u32, |n, v| n + (v.to_bits() & 0x7f80_0000 == 0x7f80_0000) as u32)
}

/// Rasterises a mesh through one camera into a `width × height` image.
///
/// * Positions are world coordinates; triangles index them (any winding: there is no
///   back-face culling).
/// * Coverage is decided at pixel centres `(column + 0.5, row + 0.5)` in the pixel
///   coordinates of [`Camera::project`], with exact-consistent edge functions: an edge's
///   function is always evaluated from its lexicographically smaller screen endpoint, so
///   two triangles sharing an edge get exactly opposite values. **Tie rule** (a pixel
///   centre exactly on an edge): take each edge's direction `d` in the triangle's vertex
///   order, negated if the triangle's signed area in pixel coordinates is negative; the
///   pixel belongs to the triangle iff `d.y > 0`, or `d.y = 0` and `d.x > 0` (pixel axes:
///   x right, y down). Two triangles sharing an edge see it in opposite directions, so
///   exactly one takes the pixel: shared edges are never double-covered nor cracked.
/// * Nearest depth wins; equal depths go to the lower triangle index.
/// * Triangles with zero screen area, or with a vertex closer than [`NEAR_DEPTH`] to the
///   camera plane (or behind it), are not drawn.
///
/// Work is split into bands of rows on the rayon pool; the result does not depend on
/// the thread count.
pub fn rasterize(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    camera: &Camera,
    width: u32,
    height: u32,
) -> Result<Raster> {
    let mut rasters = rasterize_views(positions, triangles, std::slice::from_ref(camera), width, height)?;
    Ok(rasters.remove(0))
}

/// Rasterises a mesh through several cameras (e.g. the cameras of a
/// [`w3d_core::ViewRig`]), in parallel over views (one pass over the triangles per view
/// when there are at least twice as many views as threads) or else over row bands; see
/// [`rasterize`]. Both schedules give bit-identical rasters.
pub fn rasterize_views(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    cameras: &[Camera],
    width: u32,
    height: u32,
) -> Result<Vec<Raster>> {
    check_size(width, height)?;
    w3d_core::mesh::validate_geometry(positions, triangles)?;
    for (i, camera) in cameras.iter().enumerate() {
        camera.validate().map_err(|e| match e {
            Error::Invalid { field, expected } => Error::invalid(format!("cameras[{i}].{field}"), expected),
            other => other,
        })?;
    }
    let n = width as usize * height as usize;
    let mut rasters: Vec<Raster> = cameras
        .iter()
        .map(|camera| Raster {
            width,
            height,
            camera: *camera,
            vertex_count: positions.len(),
            triangle_count: triangles.len(),
            triangle: vec![NO_TRIANGLE; n],
            uv: vec![[0.0; 2]; n],
            depth: vec![0.0; n],
        })
        .collect();
    if cameras.len() >= 2 * rayon::current_num_threads() {
        // Enough views to keep every thread busy: one pass over the triangles per view,
        // no binning. Same pixels, same order per pixel: the same result as the bands.
        rasters.par_iter_mut().for_each(|r| {
            let setup = ViewSetup::new(positions, &r.camera, width, height);
            let items = triangles.iter().enumerate().filter_map(|(t, tri)| {
                let range = setup.centre_box(tri)?;
                Some((t as u32, setup.corners(tri), range))
            });
            setup.raster_rows(items, 0, Band { triangle: &mut r.triangle, uv: &mut r.uv, depth: &mut r.depth });
        });
        return Ok(rasters);
    }
    let setups: Vec<ViewSetup> =
        cameras.par_iter().map(|camera| ViewSetup::new(positions, camera, width, height)).collect();
    let bins: Vec<Bins> = setups.par_iter().map(|setup| setup.bins(triangles)).collect();
    // Each band writes its own rows of its view's raster: no copies, no shared writes.
    let band_len = (BAND_ROWS * width) as usize;
    let mut bands: Vec<(usize, u32, Band<'_>)> = Vec::new();
    for (v, r) in rasters.iter_mut().enumerate() {
        let chunks = r.triangle.chunks_mut(band_len).zip(r.uv.chunks_mut(band_len)).zip(r.depth.chunks_mut(band_len));
        for (b, ((triangle, uv), depth)) in chunks.enumerate() {
            bands.push((v, b as u32, Band { triangle, uv, depth }));
        }
    }
    bands.into_par_iter().for_each(|(v, b, band)| {
        let items = bins[v].items[bins[v].start[b as usize]..bins[v].start[b as usize + 1]]
            .iter()
            .map(|&(t, range)| (t, setups[v].corners(&triangles[t as usize]), range));
        setups[v].raster_rows(items, b * BAND_ROWS, band)
    });
    Ok(rasters)
}

/// One edge function `sign · (a · (py − py0) − b · (px − px0))`, evaluated from the
/// canonical (lexicographically smaller) endpoint so that shared edges agree exactly.
#[derive(Debug, Clone, Copy)]
struct Edge {
    px0: f64,
    py0: f64,
    a: f64,
    b: f64,
    sign: f64,
    include_ties: bool,
}

impl Edge {
    /// The edge from `p` to `q` of a triangle with screen orientation `orient` (±1).
    fn new(p: (f64, f64), q: (f64, f64), orient: f64) -> Self {
        let (c0, c1, sign) = if p <= q { (p, q, orient) } else { (q, p, -orient) };
        // The edge direction with the interior on its left (for the y-down pixel frame
        // "left" is a convention: only its antisymmetry matters).
        let (dx, dy) = ((q.0 - p.0) * orient, (q.1 - p.1) * orient);
        Edge {
            px0: c0.0,
            py0: c0.1,
            a: c1.0 - c0.0,
            b: c1.1 - c0.1,
            sign,
            include_ties: dy > 0.0 || (dy == 0.0 && dx > 0.0),
        }
    }

    #[inline]
    fn eval(&self, x: f64, y: f64) -> f64 {
        self.sign * (self.a * (y - self.py0) - self.b * (x - self.px0))
    }

    #[inline]
    fn inside(&self, value: f64) -> bool {
        (value > 0.0) | ((value == 0.0) & self.include_ties)
    }
}

/// Per-view data shared by the bands of that view.
struct ViewSetup {
    width: u32,
    height: u32,
    vertices: Vec<ScreenVertex>,
    /// Per vertex, its pixel-centre bounds (see [`Cells`]).
    cells: Vec<Cells>,
}

/// The pixel-centre bounds of one projected vertex: with `a = clamp(s − 0.5, −1, n)` for
/// its pixel coordinate `s` along an image side of `n` pixels, `⌈a⌉` and `⌊a⌋` per axis.
/// Rounding, clamping, `⌈⌉` and `⌊⌋` are monotone, so a triangle's centre range
/// `max(⌈min a⌉, 0) ..= min(⌊max a⌋, n − 1)` (see [`centre_bounds`]) is the min / max of its
/// corners' cells: per-triangle binning without floating-point work.
#[derive(Debug, Clone, Copy)]
struct Cells {
    /// `[⌈a⌉, ⌊a⌋]` for x (columns) then y (rows).
    x: [i32; 2],
    y: [i32; 2],
    /// In front of the near plane with finite pixel coordinates.
    drawable: bool,
}

/// The triangles touching each row band of one view, with the inclusive pixel ranges
/// `[first column, last column, first row, last row]` of the centres in their bbox.
struct Bins {
    /// Band `b` owns `items[start[b]..start[b + 1]]`, ascending by triangle.
    start: Vec<usize>,
    items: Vec<(u32, [u32; 4])>,
}

/// What the band loop needs of one projected vertex.
#[derive(Debug, Clone, Copy)]
struct ScreenVertex {
    /// Pixel coordinates (see [`ClipVertex`]).
    sx: f64,
    sy: f64,
    /// Depth along the viewing axis, world units.
    depth: f64,
    /// `1 / w` of the clip coordinates.
    inv_w: f64,
}

/// Whole consecutive rows (a band, or the whole image) of one output raster.
struct Band<'a> {
    triangle: &'a mut [u32],
    uv: &'a mut [[f32; 2]],
    depth: &'a mut [f32],
}

impl ViewSetup {
    fn new(positions: &[[f32; 3]], camera: &Camera, width: u32, height: u32) -> Self {
        let projector = Projector::new(camera, width, height);
        let vertices: Vec<ScreenVertex> = positions
            .iter()
            .map(|&p| {
                let c = projector.project(to_dvec(p));
                ScreenVertex { sx: c.sx, sy: c.sy, depth: c.depth, inv_w: 1.0 / c.w }
            })
            .collect();
        let cells = vertices
            .iter()
            .map(|c| Cells {
                x: centre_bounds(c.sx, width),
                y: centre_bounds(c.sy, height),
                drawable: (c.depth > NEAR_DEPTH) & c.sx.is_finite() & c.sy.is_finite(),
            })
            .collect();
        ViewSetup { width, height, vertices, cells }
    }

    /// The projected corners of a triangle.
    #[inline]
    fn corners(&self, tri: &[u32; 3]) -> [ScreenVertex; 3] {
        tri.map(|i| self.vertices[i as usize])
    }

    /// The inclusive ranges `[first column, last column, first row, last row]` of the
    /// pixel centres in the bbox of a drawable triangle; `None` if it is not drawn or
    /// its bbox holds no centre (most triangles of a dense mesh).
    #[inline]
    fn centre_box(&self, tri: &[u32; 3]) -> Option<[u32; 4]> {
        let c = tri.map(|i| self.cells[i as usize]);
        // Non-short-circuit `&`: one branch.
        if !(c[0].drawable & c[1].drawable & c[2].drawable) {
            return None;
        }
        let range = |a: [i32; 2], b: [i32; 2], d: [i32; 2], n: u32| {
            let first = a[0].min(b[0]).min(d[0]).max(0);
            let last = a[1].max(b[1]).max(d[1]).min(n as i32 - 1);
            (first <= last).then_some((first as u32, last as u32))
        };
        let (c0, c1) = range(c[0].x, c[1].x, c[2].x, self.width)?;
        let (r0, r1) = range(c[0].y, c[1].y, c[2].y, self.height)?;
        Some([c0, c1, r0, r1])
    }

    /// Sorts the drawable triangles into bands of [`BAND_ROWS`] rows.
    fn bins(&self, triangles: &[[u32; 3]]) -> Bins {
        let band_count = self.height.div_ceil(BAND_ROWS) as usize;
        // Pass 1: the triangles to draw, and how many go to each band.
        let mut kept = Vec::with_capacity(triangles.len());
        let mut start = vec![0usize; band_count + 1];
        for (t, tri) in triangles.iter().enumerate() {
            let Some(range) = self.centre_box(tri) else { continue };
            for band in range[2] / BAND_ROWS..=range[3] / BAND_ROWS {
                start[band as usize + 1] += 1;
            }
            kept.push((t as u32, range));
        }
        for b in 0..band_count {
            start[b + 1] += start[b];
        }
        // Pass 2: scatter in triangle order, so each band stays ascending.
        let mut next = start.clone();
        let mut items = vec![(0u32, [0u32; 4]); start[band_count]];
        for &(t, range) in &kept {
            for band in range[2] / BAND_ROWS..=range[3] / BAND_ROWS {
                items[next[band as usize]] = (t, range);
                next[band as usize] += 1;
            }
        }
        Bins { start, items }
    }

    /// Draws `items` (ascending triangle ids with their [`Self::corners`] and
    /// [`Self::centre_box`]) into the rows `row0..` of `out`, which holds whole image rows.
    fn raster_rows(&self, items: impl Iterator<Item = (u32, [ScreenVertex; 3], [u32; 4])>, row0: u32, out: Band<'_>) {
        let w = self.width as usize;
        let row1 = row0 + (out.depth.len() / w) as u32;
        // The depth test runs in f64; the raster stores f32.
        let mut best = vec![f64::INFINITY; out.depth.len()];
        for (t, v, [c0, c1, r0, r1]) in items {
            let s = v.map(|c| (c.sx, c.sy));
            let area = (s[1].0 - s[0].0) * (s[2].1 - s[0].1) - (s[1].1 - s[0].1) * (s[2].0 - s[0].0);
            if area == 0.0 || !area.is_finite() {
                continue;
            }
            let orient = area.signum();
            let edges = [Edge::new(s[1], s[2], orient), Edge::new(s[2], s[0], orient), Edge::new(s[0], s[1], orient)];
            let (r0, r1) = (r0.max(row0), r1.min(row1 - 1));
            let inv_w = v.map(|c| c.inv_w);
            let d = v.map(|c| c.depth);
            // No pixel of this triangle can pass a depth test against `best` below `reject`:
            // its depths are convex combinations of the vertex depths, whose rounding error
            // is far below 1e-9 of the largest one. Skipping those pixels changes nothing.
            let reject = d[0].min(d[1]).min(d[2]) - 1e-9 * d[0].max(d[1]).max(d[2]);
            for row in r0..=r1 {
                let y = row as f64 + 0.5;
                let line = (row - row0) as usize * w;
                for col in c0..=c1 {
                    let x = col as f64 + 0.5;
                    let e = [edges[0].eval(x, y), edges[1].eval(x, y), edges[2].eval(x, y)];
                    // Non-short-circuit `&`: one branch per pixel.
                    if !(edges[0].inside(e[0]) & edges[1].inside(e[1]) & edges[2].inside(e[2])) {
                        continue;
                    }
                    let i = line + col as usize;
                    if best[i] < reject {
                        continue;
                    }
                    // Screen-space barycentrics e_k / area made perspective-correct by 1/w_k.
                    let q = [e[0] * orient * inv_w[0], e[1] * orient * inv_w[1], e[2] * orient * inv_w[2]];
                    let inv_sum = 1.0 / (q[0] + q[1] + q[2]);
                    let (u, vv) = clamp_uv(q[0] * inv_sum, q[1] * inv_sum);
                    let depth = u * d[0] + vv * d[1] + (1.0 - u - vv) * d[2];
                    if depth < best[i] {
                        best[i] = depth;
                        out.triangle[i] = t;
                        out.uv[i] = [u as f32, vv as f32];
                        out.depth[i] = depth as f32;
                    }
                }
            }
        }
    }
}

/// Clamps barycentrics to `u, v ≥ 0`, `u + v ≤ 1` (rounding can push them out slightly).
fn clamp_uv(u: f64, v: f64) -> (f64, f64) {
    let (u, v) = (u.clamp(0.0, 1.0), v.clamp(0.0, 1.0));
    let s = u + v;
    if s > 1.0 { (u / s, v / s) } else { (u, v) }
}

/// `[⌈a⌉, ⌊a⌋]` for `a = clamp(s − 0.5, −1, n)`: the pixel indices `i` whose centre
/// `i + 0.5` lies in `[lo, hi]`, clipped to `0..n`, are
/// `max(⌈a(lo)⌉, 0) ..= min(⌊a(hi)⌋, n − 1)` (see [`Cells`]). Meaningless for non-finite `s`.
fn centre_bounds(s: f64, n: u32) -> [i32; 2] {
    // Clamp first so the integer conversions below are exact; `floor` without a libm call.
    let floor = |x: f64| {
        let i = x as i64 as f64;
        if i > x { i - 1.0 } else { i }
    };
    let a = (s - 0.5).clamp(-1.0, n as f64);
    [-floor(-a) as i32, floor(a) as i32]
}

/// Backward pass of [`rasterize`]: pulls per-pixel gradients of the barycentrics `(u, v)`
/// and (optionally) of the depth back to world-space vertex positions.
///
/// Coverage is held fixed (the triangle ids of `raster`); visibility gradients come only
/// from [`crate::antialias`]. The barycentrics are differentiated unclamped, as the
/// perspective-correct 2D-homogeneous formula `u = A₀ / ΣA`, `v = A₁ / ΣA` of the clip
/// coordinates. `grad_uv` and `grad_depth` have one entry per pixel. Returns one gradient
/// per vertex (world units⁻¹ times the loss unit), accumulated in f64.
pub fn rasterize_backward(
    raster: &Raster,
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    grad_uv: &[[f32; 2]],
    grad_depth: Option<&[f32]>,
) -> Result<Vec<[f32; 3]>> {
    w3d_core::mesh::validate_geometry(positions, triangles)?;
    raster.check(positions.len(), triangles)?;
    let n = raster.pixel_count();
    if grad_uv.len() != n {
        return Err(Error::invalid("grad_uv", format!("{n} per-pixel values, got {}", grad_uv.len())));
    }
    if let Some(g) = grad_depth
        && g.len() != n
    {
        return Err(Error::invalid("grad_depth", format!("{n} per-pixel values, got {}", g.len())));
    }
    let projector = Projector::new(&raster.camera, raster.width, raster.height);
    let clip = projector.project_all(positions);
    let mut acc = vec![[0.0f64; 4]; positions.len()];
    // Pixel-centre NDC per column and per row, as `Projector::pixel_ndc` gives them.
    let ndc_x: Vec<f64> = (0..raster.width).map(|col| projector.pixel_ndc(col, 0).0).collect();
    let ndc_y: Vec<f64> = (0..raster.height).map(|row| projector.pixel_ndc(0, row).1).collect();
    let w = raster.width as usize;
    for (row, line) in raster.triangle.chunks_exact(w).enumerate() {
        for (col, &t) in line.iter().enumerate() {
            if t == NO_TRIANGLE {
                continue;
            }
            let i = row * w + col;
            let gd = grad_depth.map_or(0.0, |g| g[i] as f64);
            let g = [grad_uv[i][0] as f64, grad_uv[i][1] as f64];
            accumulate_pixel(&clip, triangles[t as usize], (ndc_x[col], ndc_y[row]), g, gd, &mut acc);
        }
    }
    Ok(acc.iter().map(|g| projector.clip_grad_to_world(*g).as_vec3().to_array()).collect())
}

/// The 2D-homogeneous barycentric terms of pixel `(col, row)` in a triangle: returns
/// `(r, A, S)` with `r_i = (x_i − X·w_i, y_i − Y·w_i)` for the pixel centre's NDC `(X, Y)`,
/// `A_i = r_{i+1} × r_{i+2}` and `S = ΣA_i`; the perspective-correct (unclamped)
/// barycentrics are `A_i / S`.
#[cfg(test)]
pub(crate) fn pixel_barycentrics(
    projector: &Projector,
    v: [ClipVertex; 3],
    col: u32,
    row: u32,
) -> ([DVecPair; 3], [f64; 3], f64) {
    barycentrics_at(v, projector.pixel_ndc(col, row))
}

/// [`pixel_barycentrics`] at the pixel centre's NDC `(X, Y)`.
fn barycentrics_at(v: [ClipVertex; 3], (nx, ny): (f64, f64)) -> ([DVecPair; 3], [f64; 3], f64) {
    let r = v.map(|c| DVecPair(c.x - nx * c.w, c.y - ny * c.w));
    let a = [r[1].cross(r[2]), r[2].cross(r[0]), r[0].cross(r[1])];
    (r, a, a[0] + a[1] + a[2])
}

/// A 2D vector in f64 (clip-space offsets).
#[derive(Debug, Clone, Copy)]
pub(crate) struct DVecPair(pub f64, pub f64);

impl DVecPair {
    fn cross(self, o: DVecPair) -> f64 {
        self.0 * o.1 - self.1 * o.0
    }
}

/// Adds the contribution of the pixel with centre NDC `ndc` and upstream gradients
/// `g = (dL/du, dL/dv)` and `gd = dL/ddepth` to the per-vertex clip gradients
/// `acc[v] = (x, y, w, depth)`.
fn accumulate_pixel(clip: &[ClipVertex], tri: [u32; 3], ndc: (f64, f64), g: [f64; 2], gd: f64, acc: &mut [[f64; 4]]) {
    let v = tri.map(|i| clip[i as usize]);
    let (r, a, s) = barycentrics_at(v, ndc);
    if s == 0.0 || !s.is_finite() {
        return;
    }
    let (u, vv) = (a[0] / s, a[1] / s);
    let b = [u, vv, 1.0 - u - vv];
    let gu = g[0] + gd * (v[0].depth - v[2].depth);
    let gv = g[1] + gd * (v[1].depth - v[2].depth);
    let (g0, g1) = (gu / s, gv / s);
    let gb = g0 * u + g1 * vv;
    let da = [g0 - gb, g1 - gb, -gb];
    let mut dr = [(0.0f64, 0.0f64); 3];
    for (k, &dak) in da.iter().enumerate() {
        let (k1, k2) = ((k + 1) % 3, (k + 2) % 3);
        dr[k1].0 += dak * r[k2].1;
        dr[k1].1 -= dak * r[k2].0;
        dr[k2].0 -= dak * r[k1].1;
        dr[k2].1 += dak * r[k1].0;
    }
    let (nx, ny) = ndc;
    for k in 0..3 {
        let e = &mut acc[tri[k] as usize];
        e[0] += dr[k].0;
        e[1] += dr[k].1;
        e[2] -= nx * dr[k].0 + ny * dr[k].1;
        e[3] += gd * b[k];
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use glam::{DVec3, Vec3};
    use w3d_core::Projection;

    fn front(projection: Projection) -> Camera {
        Camera::look_at(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, Vec3::Y, projection).unwrap()
    }

    /// `Σ_pixels gu·u + gv·v + gd·depth` with the coverage of `raster` held fixed, in f64.
    fn fixed_coverage_loss(raster: &Raster, positions: &[DVec3], triangles: &[[u32; 3]], g: &[[f64; 3]]) -> f64 {
        let projector = Projector::new(&raster.camera, raster.width, raster.height);
        let clip: Vec<ClipVertex> = positions.iter().map(|&p| projector.project(p)).collect();
        let mut loss = 0.0;
        for (i, &t) in raster.triangle.iter().enumerate() {
            if t == NO_TRIANGLE {
                continue;
            }
            let (col, row) = ((i % raster.width as usize) as u32, (i / raster.width as usize) as u32);
            let v = triangles[t as usize].map(|k| clip[k as usize]);
            let (_, a, s) = pixel_barycentrics(&projector, v, col, row);
            let (u, vv) = (a[0] / s, a[1] / s);
            let depth = u * v[0].depth + vv * v[1].depth + (1.0 - u - vv) * v[2].depth;
            loss += g[i][0] * u + g[i][1] * vv + g[i][2] * depth;
        }
        loss
    }

    /// Relative error of the analytic gradient against central differences in f64.
    pub(crate) fn check_backward(
        positions: &[[f32; 3]],
        triangles: &[[u32; 3]],
        camera: &Camera,
        size: u32,
        seed: u64,
        vertices: &[usize],
    ) -> f64 {
        let raster = rasterize(positions, triangles, camera, size, size).unwrap();
        let mut rng = crate::tests_util::Lcg(seed);
        let g: Vec<[f64; 3]> = (0..raster.pixel_count()).map(|_| [rng.next(), rng.next(), rng.next()]).collect();
        let guv: Vec<[f32; 2]> = g.iter().map(|x| [x[0] as f32, x[1] as f32]).collect();
        let gd: Vec<f32> = g.iter().map(|x| x[2] as f32).collect();
        let g64: Vec<[f64; 3]> = guv.iter().zip(&gd).map(|(a, &d)| [a[0] as f64, a[1] as f64, d as f64]).collect();
        let analytic = rasterize_backward(&raster, positions, triangles, &guv, Some(&gd)).unwrap();
        let base: Vec<DVec3> = positions.iter().map(|&p| to_dvec(p)).collect();
        let h = 1e-6;
        let mut num = Vec::new();
        for &vtx in vertices {
            let mut row = [0.0; 3];
            for axis in 0..3 {
                let mut p = base.clone();
                p[vtx][axis] += h;
                let lp = fixed_coverage_loss(&raster, &p, triangles, &g64);
                p[vtx][axis] -= 2.0 * h;
                let lm = fixed_coverage_loss(&raster, &p, triangles, &g64);
                row[axis] = (lp - lm) / (2.0 * h);
            }
            num.push(row);
        }
        let analytic: Vec<[f32; 3]> = vertices.iter().map(|&v| analytic[v]).collect();
        crate::tests_util::relative_error(&analytic, &num)
    }

    #[test]
    fn vertices_project_to_unit_barycentrics_and_depth() {
        let positions = [[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.3]];
        for projection in [Projection::Orthographic { half_height: 1.0 }, Projection::Perspective { fov_y: 1.0 }] {
            let cam = front(projection);
            let r = rasterize(&positions, &[[0, 1, 2]], &cam, 64, 64).unwrap();
            let covered = r.triangle.iter().filter(|&&t| t == 0).count();
            assert!(covered > 100, "{covered}");
            for (i, &t) in r.triangle.iter().enumerate() {
                if t == NO_TRIANGLE {
                    continue;
                }
                let [u, v] = r.uv[i];
                assert!(u >= 0.0 && v >= 0.0 && u + v <= 1.0 + 1e-6);
                // The interpolated world point lies at the pixel centre and at the depth.
                let p = u * Vec3::from(positions[0])
                    + v * Vec3::from(positions[1])
                    + (1.0 - u - v) * Vec3::from(positions[2]);
                let px = cam.project(p, 64, 64);
                let (col, row) = ((i % 64) as f32 + 0.5, (i / 64) as f32 + 0.5);
                assert!((px.x - col).abs() < 1e-3 && (px.y - row).abs() < 1e-3, "{px} vs {col},{row}");
                assert!((px.z - r.depth[i]).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn shared_edges_cover_each_pixel_once() {
        // A fan of triangles around a centre whose edges pass exactly through pixel
        // centres: every pixel inside the polygon is covered by exactly one triangle.
        let cam = front(Projection::Orthographic { half_height: 1.0 });
        let n = 12;
        let mut positions = vec![[0.0, 0.0, 0.0]];
        for k in 0..n {
            let a = k as f32 / n as f32 * std::f32::consts::TAU;
            positions.push([0.8 * a.cos(), 0.8 * a.sin(), 0.0]);
        }
        let triangles: Vec<[u32; 3]> = (0..n).map(|k| [0, 1 + k, 1 + (k + 1) % n]).collect();
        // Odd size: the fan centre and the axis-aligned and diagonal edges pass exactly
        // through pixel centres, exercising the tie rule.
        let size = 33;
        let mut counts = vec![0u32; (size * size) as usize];
        for t in 0..n as usize {
            let r = rasterize(&positions, &triangles[t..t + 1], &cam, size, size).unwrap();
            for (c, &id) in counts.iter_mut().zip(&r.triangle) {
                *c += (id != NO_TRIANGLE) as u32;
            }
        }
        let whole = rasterize(&positions, &triangles, &cam, size, size).unwrap();
        for (i, (&c, &id)) in counts.iter().zip(&whole.triangle).enumerate() {
            assert!(c <= 1, "pixel {i} covered {c} times");
            assert_eq!(c == 1, id != NO_TRIANGLE, "pixel {i}");
        }
        // The pixel centre on the shared fan vertex and those on shared edges are covered.
        for (col, row) in [(16, 16), (20, 16), (16, 10), (12, 12)] {
            assert_eq!(counts[(row * size + col) as usize], 1, "({col}, {row})");
        }
    }

    #[test]
    fn per_view_and_banded_rasterisation_agree() {
        // Views ≥ 2 × threads: one pass per view; fewer: row bands. Same bits either way.
        let mut rng = crate::tests_util::Lcg(11);
        let mut coord = || 0.6 * rng.next() as f32;
        let positions: Vec<[f32; 3]> = (0..300).map(|_| [coord(), coord(), coord()]).collect();
        let triangles: Vec<[u32; 3]> = (0..100).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]).collect();
        let cams = [
            front(Projection::Perspective { fov_y: 1.0 }),
            Camera::look_at(
                Vec3::new(1.5, 0.5, 1.0),
                Vec3::ZERO,
                Vec3::Y,
                Projection::Orthographic { half_height: 0.8 },
            )
            .unwrap(),
        ];
        let run = |threads| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| rasterize_views(&positions, &triangles, &cams, 40, 37).unwrap())
        };
        let (per_view, banded) = (run(1), run(4));
        assert!(per_view[1].triangle.iter().filter(|&&t| t != NO_TRIANGLE).count() > 200);
        assert_eq!(per_view, banded);
    }

    #[test]
    fn front_surface_wins() {
        let cam = front(Projection::Perspective { fov_y: 1.0 });
        let quad = |z: f32| vec![[-0.5, -0.5, z], [0.5, -0.5, z], [0.5, 0.5, z], [-0.5, 0.5, z]];
        let mut positions = quad(-0.2);
        positions.extend(quad(0.2));
        let triangles = vec![[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]];
        let r = rasterize(&positions, &triangles, &cam, 32, 32).unwrap();
        let centre = r.triangle_at(16, 16).unwrap();
        assert!(centre >= 2);
        assert!((r.depth[16 * 32 + 16] - 1.8).abs() < 1e-5);
    }

    #[test]
    fn backward_matches_finite_differences_on_a_small_mesh() {
        let positions = vec![[-0.5, -0.4, 0.1], [0.6, -0.5, -0.2], [0.1, 0.6, 0.3], [0.7, 0.5, 0.0]];
        let triangles = vec![[0, 1, 2], [1, 3, 2]];
        for projection in [Projection::Orthographic { half_height: 1.0 }, Projection::Perspective { fov_y: 1.0 }] {
            let err = check_backward(&positions, &triangles, &front(projection), 24, 7, &[0, 1, 2, 3]);
            assert!(err < 1e-4, "{projection:?}: {err}");
        }
    }

    #[test]
    fn bad_input_is_an_error() {
        let cam = front(Projection::Orthographic { half_height: 1.0 });
        let p = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        assert!(rasterize(&p, &[[0, 1, 2]], &cam, 0, 8).is_err());
        assert!(rasterize(&p, &[[0, 1, 3]], &cam, 8, 8).is_err());
        assert!(rasterize(&[[f32::NAN, 0.0, 0.0], p[1], p[2]], &[[0, 1, 2]], &cam, 8, 8).is_err());
        let r = rasterize(&p, &[[0, 1, 2]], &cam, 8, 8).unwrap();
        assert!(rasterize_backward(&r, &p, &[[0, 1, 2]], &[[0.0; 2]; 3], None).is_err());
        assert!(rasterize_backward(&r, &p, &[[0, 1, 2], [0, 2, 1]], &[[0.0; 2]; 64], None).is_err());
    }
}
