//! Geometric initialisation: a closed start mesh for the coarse reconstruction.
//!
//! 1. The front and back normal maps (or, without one of them, the first two views that face
//!    each other, e.g. left and right) are integrated to depth maps ([`integrate_normals`];
//!    grazing normals, which is where depth jumps inside a silhouette, carry no weight, and
//!    silhouette pixels are anchored to the plane through the origin).
//! 2. **Concave check** (the paper's rule, made robust to steps): in each of the two depth
//!    maps, the mean depth of the centre region (the middle half of the silhouette's
//!    bounding box) is compared with the mean over the whole silhouette. A centre *farther*
//!    from the camera than the silhouette's mean by more than `concave_margin` suggests a
//!    bowl or cup opening towards that camera; the paper's rule alone also fires on stepped
//!    objects (a hammer seen along its handle, the armadillo's forward arms: measured +0.036
//!    and +0.015), so it must be confirmed by the normals leaning *towards* the silhouette's
//!    centre on average by more than 0.1 (the inner wall of a bowl), where convex and stepped objects lean
//!    outwards. A concave view falls back to a sphere sized to the silhouettes.
//! 3. Both depth maps are back-projected to oriented points (normal = the view's target
//!    normal, area = pixel area / |cos|), and a **screened Poisson** problem is solved on a
//!    dense grid over `[-extent, extent]³`: find χ whose gradient matches the splatted
//!    normal field in the least-squares sense (Neumann boundary), with a screening term that
//!    pulls χ to the iso-value at the samples; Jacobi-preconditioned conjugate gradients.
//!    A hand-written dense-grid solver replaced the `poisson_reconstruction` crate, which
//!    took about a minute at depth 5 and was systematically off the samples (measured on
//!    50 000 points of a sphere: 59 s and a mean radial error of 17 % of the radius at depth
//!    5, 219 s and 6 % at depth 6); this one takes ≈ 0.2 s at 64³.
//! 4. The indicator is **carved by the visual hull** of all the rig's masks (a grid node
//!    outside any silhouette is outside), which bounds the sides that front and back cannot
//!    see and opens holes that a side view shows.
//! 5. The zero set is extracted by marching tetrahedra (six Kuhn tetrahedra per cell, so the
//!    result is a closed 2-manifold), specks are dropped, and the mesh is simplified to the
//!    start edge length by the remesher's collapse / split / flip passes.
//!
//! Perspective rigs are integrated with the weak-perspective approximation: an orthographic
//! camera at the same pose whose image spans what the perspective one spans at the origin.

use std::collections::HashMap;
use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use w3d_core::{Camera, Error, Image, Mesh, Projection, Result, ViewSet};
use w3d_raster::rasterize_rig;
use w3d_remesh::{MeshOptimizer, RemeshOptions};

use crate::coarse::silhouette_sphere;
use crate::integrate::{IntegrateOptions, conjugate_gradients, integrate_normals_anchored};

/// How strongly the normals must lean towards the silhouette's centre (mean radial
/// component, see `radial_normal_lean`) to confirm a concave view: the armadillo's front
/// reads −0.03 through the perspective rig, a bowl facing the camera about −0.4.
const CONCAVE_LEAN: f32 = 0.1;

/// Options of [`initial_mesh`]. Lengths are in world (unit-cube) units.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct InitOptions {
    /// Cells per axis of the Poisson grid over `[-extent, extent]³`.
    pub grid: usize,
    /// Half side of the cube the Poisson grid covers (the views span ±0.75 at the origin).
    pub extent: f32,
    /// Weight of the screening term relative to the gradient term.
    pub screening: f64,
    /// Target edge length of the simplified start mesh.
    pub edge_length: f32,
    /// The front or back view counts as concave when its centre is farther than the
    /// silhouette's mean depth by more than this (world units).
    pub concave_margin: f32,
    /// Taubin smoothing iterations applied to the start mesh (removes the grid staircase).
    pub smoothing_iterations: usize,
    /// Skip the Poisson initialisation and always start from the silhouette sphere.
    pub force_sphere: bool,
    /// When the Poisson start's silhouette IoU is below this in some view,
    /// [`crate::reconstruct`] also optimises from the [`visual_hull_mesh`] and keeps the
    /// result with the lower settled loss (see [`InitReport::silhouette_iou`] and
    /// [`hull_alternative_margin`](Self::hull_alternative_margin)).
    pub hull_alternative_iou: f32,
    /// How much lower (as a fraction) the settled loss of the visual-hull result must be
    /// than the Poisson result's for [`crate::reconstruct`] to keep it: the Poisson start
    /// carries the integrated depth of the front and back views, the hull only the
    /// silhouettes, so the hull wins only when it explains the views clearly better than
    /// the run-to-run spread of the loss. Measured (default preset, remesher seeds 0–3, the
    /// loss as the mean of the last 10 % of steps): the hull result's advantage over the
    /// Poisson result ranged over −18 … +22 % on the plane and the perspective hammer (views
    /// that both results match about equally well; CD of the plane 0.003–0.005 from
    /// Poisson, 0.006–0.009 from the hull) and +31 … +57 % on the orthographic hammer and
    /// the teacup (where the hull result is the better one: CD 0.031 against 0.05–0.08,
    /// 0.012 against 0.025). With the bare last loss and no margin the choice followed
    /// the last bits of the views (plane, perspective: Poisson CD 0.0031 before the shared
    /// normals, hull 0.0063 after).
    pub hull_alternative_margin: f32,
}

impl Default for InitOptions {
    fn default() -> Self {
        InitOptions {
            grid: 64,
            extent: 0.8,
            screening: 1.0,
            edge_length: 0.04,
            concave_margin: 0.005,
            smoothing_iterations: 10,
            force_sphere: false,
            hull_alternative_iou: 0.5,
            hull_alternative_margin: 0.25,
        }
    }
}

/// Chainable setters, one per field: `InitOptions::default().with_…(…)` (the struct is
/// `#[non_exhaustive]`, so code outside this crate cannot use struct-literal syntax).
impl InitOptions {
    w3d_core::setters! {
        with_grid(grid: usize);
        with_extent(extent: f32);
        with_screening(screening: f64);
        with_edge_length(edge_length: f32);
        with_concave_margin(concave_margin: f32);
        with_smoothing_iterations(smoothing_iterations: usize);
        with_force_sphere(force_sphere: bool);
        with_hull_alternative_iou(hull_alternative_iou: f32);
        with_hull_alternative_margin(hull_alternative_margin: f32);
    }
}

/// Which start mesh [`initial_mesh`] chose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum InitChoice {
    /// Normal integration + screened Poisson + visual-hull carving.
    Poisson,
    /// An icosphere sized to the silhouettes.
    Sphere,
    /// The visual hull of all views' masks ([`visual_hull_mesh`]), kept by
    /// [`crate::reconstruct`] when the Poisson start missed a silhouette and the hull
    /// start reached a clearly lower loss ([`InitOptions::hull_alternative_margin`]).
    VisualHull,
}

/// What [`initial_mesh`] did and why.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct InitReport {
    /// The start mesh that was used.
    pub choice: InitChoice,
    /// Why (the concave-check numbers, or the reason for a fallback).
    pub reason: String,
    /// Centre-minus-silhouette mean depth of the front view (world units; > 0: concave),
    /// or of the first of the two facing views integrated instead (named in `reason`).
    pub front_concavity: Option<f32>,
    /// Centre-minus-silhouette mean depth of the back view (world units; > 0: concave),
    /// or of the second of the two facing views integrated instead.
    pub back_concavity: Option<f32>,
    /// The smallest silhouette IoU of the Poisson start over the views (`None` for a
    /// sphere start).
    pub silhouette_iou: Option<f32>,
    /// Triangles of the start mesh.
    pub triangles: usize,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// The start mesh for [`crate::reconstruct_coarse`]: normal integration + screened Poisson
/// carved by the visual hull, or a silhouette-sized sphere when the concave check fires
/// (see the module docs). Integrates the views named `front` and `back`, or without them the
/// first two views that face each other; a rig with no such pair (a subset of the Wonder3D
/// rig missing one of `front` and `back` and one of `left` and `right`, say) falls back to
/// the sphere, and the report says so.
pub fn initial_mesh(views: &ViewSet, options: &InitOptions) -> Result<(Mesh, InitReport)> {
    let (mesh, report, _) = start_meshes(views, options, false)?;
    Ok((mesh, report))
}

/// [`initial_mesh`], and with `want_alternative` also the [`visual_hull_mesh`] (from the
/// hull field already computed for carving) when the Poisson start's worst silhouette IoU
/// is below [`InitOptions::hull_alternative_iou`].
pub(crate) fn start_meshes(
    views: &ViewSet,
    options: &InitOptions,
    want_alternative: bool,
) -> Result<(Mesh, InitReport, Option<Mesh>)> {
    let rig = views.rig();
    if options.grid < 8 || options.grid > 512 {
        return Err(Error::invalid("InitOptions::grid", format!("8 to 512 cells, got {}", options.grid)));
    }
    if !(options.extent > 0.0 && options.edge_length > 0.0 && options.screening >= 0.0) {
        return Err(Error::invalid("InitOptions", "extent > 0, edge_length > 0 and screening ≥ 0"));
    }
    if !(0.0..1.0).contains(&options.hull_alternative_margin) {
        return Err(Error::invalid(
            "InitOptions::hull_alternative_margin",
            format!("a fraction in [0, 1), got {}", options.hull_alternative_margin),
        ));
    }
    let start = Instant::now();
    let sphere = |reason: String, front: Option<f32>, back: Option<f32>| -> Result<(Mesh, InitReport, Option<Mesh>)> {
        let mesh = silhouette_sphere(views, 3)?;
        let report = InitReport {
            choice: InitChoice::Sphere,
            reason,
            front_concavity: front,
            back_concavity: back,
            silhouette_iou: None,
            triangles: mesh.triangle_count(),
            seconds: start.elapsed().as_secs_f64(),
        };
        Ok((mesh, report, None))
    };
    if options.force_sphere {
        return sphere("sphere requested (InitOptions::force_sphere)".into(), None, None);
    }
    let Some((front, back)) = integration_pair(rig) else {
        return sphere(
            "the rig has no two views facing each other (`front` and `back`) to integrate".into(),
            None,
            None,
        );
    };
    let (front_name, back_name) = (rig.views[front].name.as_str(), rig.views[back].name.as_str());
    let (w, h) = (views.width(), views.height());
    let grid = Grid::new(options.grid, options.extent);
    let hull = visual_hull(&grid, views);
    let mut points = Vec::new();
    let mut concavity = [0.0f32; 2];
    let mut lean = [0.0f32; 2];
    for v in [front, back] {
        let true_camera = rig.views[v].camera;
        let camera = weak_perspective(&true_camera);
        let view = &views.views()[v];
        let anchor = hull_entry_depth(&grid, &hull, &true_camera, &view.mask)?;
        let depth =
            integrate_normals_anchored(&view.normal, &view.mask, &camera, Some(&anchor), &IntegrateOptions::default())?;
        if let Some(slot) = [front, back].iter().position(|&f| f == v) {
            concavity[slot] = centre_minus_mean_depth(&depth, &view.mask);
            lean[slot] = radial_normal_lean(&view.normal, &view.mask, &camera);
        }
        back_project(&depth, view, &true_camera, &camera, &mut points, w, h);
    }
    let [fc, bc] = concavity;
    let [fl, bl] = lean;
    let numbers = format!(
        "centre − silhouette mean depth: {front_name} {fc:+.4}, {back_name} {bc:+.4} (margin {}); radial normal lean: \
         {front_name} {fl:+.3}, {back_name} {bl:+.3}",
        options.concave_margin
    );
    let concave = |depth: f32, lean: f32| depth > options.concave_margin && lean < -CONCAVE_LEAN;
    if concave(fc, fl) || concave(bc, bl) {
        let which = if concave(fc, fl) { front_name } else { back_name };
        return sphere(format!("concave {which} view ({numbers}): sphere start"), Some(fc), Some(bc));
    }
    let chi = screened_poisson(&grid, &points, options.screening);
    let iso = {
        let (mut s, mut wsum) = (0.0f64, 0.0f64);
        for p in &points {
            s += p.area as f64 * grid.sample(&chi, p.position);
            wsum += p.area as f64;
        }
        s / wsum.max(1e-300)
    };
    let field: Vec<f32> = chi.iter().zip(&hull).map(|(&c, &m)| ((c - iso) as f32).max(0.5 - m)).collect();
    let Some(mesh) = marching_tetrahedra(&grid, &field)? else {
        return sphere(format!("Poisson + hull gave an empty surface ({numbers}): sphere start"), Some(fc), Some(bc));
    };
    let mesh = taubin_smooth(&simplify(&mesh, options.edge_length)?, options.smoothing_iterations)?;
    let (worst_iou, worst_view) = silhouette_agreement(&mesh, views)?;
    let alternative = if want_alternative && worst_iou < options.hull_alternative_iou {
        Some(hull_mesh(&grid, &hull, options)?)
    } else {
        None
    };
    let report = InitReport {
        choice: InitChoice::Poisson,
        reason: format!(
            "convex {front_name} and {back_name} ({numbers}); silhouette IoU of the start ≥ {worst_iou:.2} ({worst_view}): Poisson start"
        ),
        front_concavity: Some(fc),
        back_concavity: Some(bc),
        silhouette_iou: Some(worst_iou),
        triangles: mesh.triangle_count(),
        seconds: start.elapsed().as_secs_f64(),
    };
    Ok((mesh, report, alternative))
}

/// The visual hull of all the rig's masks as a closed start mesh (marching tetrahedra on
/// the [`InitOptions::grid`], simplified to [`InitOptions::edge_length`] and smoothed).
/// It matches every silhouette by construction but not the concavities between them; it
/// is the alternative start where front and back do not show how far the object extends
/// along their axis (a handle pointing at the camera hides behind its head, with a depth
/// step that integration cannot see).
pub fn visual_hull_mesh(views: &ViewSet, options: &InitOptions) -> Result<Mesh> {
    let grid = Grid::new(options.grid, options.extent);
    hull_mesh(&grid, &visual_hull(&grid, views), options)
}

/// The surface of a [`visual_hull`] field, simplified and smoothed as the start meshes are.
fn hull_mesh(grid: &Grid, hull: &[f32], options: &InitOptions) -> Result<Mesh> {
    let field: Vec<f32> = hull.iter().map(|&m| 0.5 - m).collect();
    let Some(mesh) = marching_tetrahedra(grid, &field)? else {
        return Err(Error::invalid("views masks", "silhouettes whose visual hull is not empty"));
    };
    taubin_smooth(&simplify(&mesh, options.edge_length)?, options.smoothing_iterations)
}

/// The smallest silhouette IoU of `mesh` over the rig's views (the mesh's pixel-centre
/// coverage against the views' masks thresholded at 0.5) and the name of that view.
fn silhouette_agreement(mesh: &Mesh, views: &ViewSet) -> Result<(f32, String)> {
    let (w, h) = (views.width(), views.height());
    if w != h {
        return Err(Error::invalid("views", format!("square images for the silhouette check, got {w}×{h}")));
    }
    let rasters = rasterize_rig(mesh, views.rig(), w)?;
    let mut worst = (f32::INFINITY, String::new());
    for (raster, (rv, view)) in rasters.iter().zip(views.iter()) {
        let (mut both, mut either) = (0usize, 0usize);
        for (&a, &b) in raster.coverage().iter().zip(view.mask.data()) {
            both += usize::from(a >= 0.5 && b >= 0.5);
            either += usize::from(a >= 0.5 || b >= 0.5);
        }
        let iou = if either == 0 { 1.0 } else { both as f32 / either as f32 };
        if iou < worst.0 {
            worst = (iou, rv.name.clone());
        }
    }
    Ok(worst)
}

/// The two views whose normal maps are integrated: `front` and `back` when the rig has
/// both, else the first pair (in rig order) that face each other (viewing directions within
/// about 2.6° of opposite), e.g. `left` and `right` of a Wonder3D rig without its front
/// view; `None` when no two views face each other.
fn integration_pair(rig: &w3d_core::ViewRig) -> Option<(usize, usize)> {
    let find = |name: &str| rig.views.iter().position(|v| v.name == name);
    if let (Some(front), Some(back)) = (find("front"), find("back")) {
        return Some((front, back));
    }
    let n = rig.views.len();
    (0..n)
        .flat_map(|i| (i + 1..n).map(move |j| (i, j)))
        .find(|&(i, j)| rig.views[i].camera.forward().dot(rig.views[j].camera.forward()) < -0.999)
}

/// An orthographic camera with the pose of `camera` whose image spans what `camera` sees
/// at the depth of the origin (identity for orthographic cameras).
fn weak_perspective(camera: &Camera) -> Camera {
    match camera.projection {
        Projection::Orthographic { .. } => *camera,
        Projection::Perspective { fov_y } => {
            let half_height = camera.depth(Vec3::ZERO) * (0.5 * fov_y).tan();
            Camera { projection: Projection::Orthographic { half_height }, ..*camera }
        }
    }
}

/// Mean depth over the middle half of the silhouette's bounding box minus the mean depth
/// over the whole silhouette (world units; 0 for an empty mask).
fn centre_minus_mean_depth(depth: &Image, mask: &Image) -> f32 {
    let (w, h) = (depth.width() as usize, depth.height() as usize);
    let inside = |p: usize| mask.data()[p] >= 0.5;
    let (mut lo, mut hi) = ((usize::MAX, usize::MAX), (0, 0));
    let (mut sum, mut count) = (0.0f64, 0usize);
    for y in 0..h {
        for x in 0..w {
            if inside(y * w + x) {
                lo = (lo.0.min(x), lo.1.min(y));
                hi = (hi.0.max(x), hi.1.max(y));
                sum += depth.data()[y * w + x] as f64;
                count += 1;
            }
        }
    }
    if count == 0 {
        return 0.0;
    }
    let quarter = ((hi.0 - lo.0) / 4, (hi.1 - lo.1) / 4);
    let (mut csum, mut ccount) = (0.0f64, 0usize);
    for y in lo.1 + quarter.1..=hi.1 - quarter.1 {
        for x in lo.0 + quarter.0..=hi.0 - quarter.0 {
            if inside(y * w + x) {
                csum += depth.data()[y * w + x] as f64;
                ccount += 1;
            }
        }
    }
    if ccount == 0 {
        return 0.0;
    }
    (csum / ccount as f64 - sum / count as f64) as f32
}

/// Mean over the silhouette of the in-image component of the (camera-frame) normal along
/// the direction from the silhouette's centroid: positive when normals lean outwards (a
/// convex or stepped surface), negative when they lean towards the centre (the inner wall
/// of a bowl facing the camera).
fn radial_normal_lean(normal: &Image, mask: &Image, camera: &Camera) -> f32 {
    let (w, h) = (mask.width() as usize, mask.height() as usize);
    let to_camera = camera.basis().transpose();
    let (mut cx, mut cy, mut count) = (0.0f64, 0.0f64, 0usize);
    for y in 0..h {
        for x in 0..w {
            if mask.data()[y * w + x] >= 0.5 {
                cx += x as f64;
                cy += y as f64;
                count += 1;
            }
        }
    }
    if count == 0 {
        return 0.0;
    }
    let (cx, cy) = ((cx / count as f64) as f32, (cy / count as f64) as f32);
    let mut sum = 0.0f64;
    for y in 0..h {
        for x in 0..w {
            let p = y * w + x;
            if mask.data()[p] < 0.5 {
                continue;
            }
            let d = glam::Vec2::new(x as f32 - cx, cy - y as f32); // image y grows downwards
            let Some(d) = d.try_normalize() else { continue };
            let n = &normal.data()[3 * p..3 * p + 3];
            let n = to_camera * Vec3::new(n[0], n[1], n[2]);
            sum += (n.x * d.x + n.y * d.y) as f64;
        }
    }
    (sum / count as f64) as f32
}

/// An oriented surface sample for the Poisson solve.
struct OrientedPoint {
    position: Vec3,
    normal: Vec3,
    /// Surface area the sample stands for (world units²).
    area: f32,
}

/// Back-projects every foreground pixel of `depth` through `camera` with the view's target
/// normal; `proxy` (its weak-perspective stand-in) gives the pixel area.
fn back_project(
    depth: &Image,
    view: &w3d_core::ViewImages,
    camera: &Camera,
    proxy: &Camera,
    out: &mut Vec<OrientedPoint>,
    w: u32,
    h: u32,
) {
    let Projection::Orthographic { half_height } = proxy.projection else { return };
    let pixel_area = (2.0 * half_height / h as f32).powi(2);
    for y in 0..h {
        for x in 0..w {
            let p = (y * w + x) as usize;
            if view.mask.data()[p] < 0.5 {
                continue;
            }
            let n = &view.normal.data()[3 * p..3 * p + 3];
            let normal = Vec3::new(n[0], n[1], n[2]).normalize_or_zero();
            let position = camera.unproject(x as f32 + 0.5, y as f32 + 0.5, depth.data()[p], w, h);
            let cos = normal.dot(-camera.view_direction(position));
            if cos <= 0.05 {
                continue; // grazing or back-facing: no reliable position
            }
            out.push(OrientedPoint { position, normal, area: pixel_area / cos.max(0.2) });
        }
    }
}

/// A cubic grid of `(cells + 1)³` nodes over `[-extent, extent]³`, x fastest.
struct Grid {
    cells: usize,
    extent: f32,
    spacing: f32,
}

impl Grid {
    fn new(cells: usize, extent: f32) -> Self {
        Grid { cells, extent, spacing: 2.0 * extent / cells as f32 }
    }

    fn nodes_per_axis(&self) -> usize {
        self.cells + 1
    }

    fn index(&self, i: usize, j: usize, k: usize) -> usize {
        let n = self.nodes_per_axis();
        i + n * (j + n * k)
    }

    fn position(&self, i: usize, j: usize, k: usize) -> Vec3 {
        Vec3::new(i as f32, j as f32, k as f32) * self.spacing - Vec3::splat(self.extent)
    }

    /// The 8 nodes around `p` with their trilinear weights (`None` outside the grid).
    fn corners(&self, p: Vec3) -> Option<[(usize, f32); 8]> {
        let g = (p + Vec3::splat(self.extent)) / self.spacing;
        let c = self.cells as f32;
        if !(g.x >= 0.0 && g.y >= 0.0 && g.z >= 0.0 && g.x < c && g.y < c && g.z < c) {
            return None;
        }
        let (i, j, k) = (g.x as usize, g.y as usize, g.z as usize);
        let f = g - Vec3::new(i as f32, j as f32, k as f32);
        let mut out = [(0usize, 0.0f32); 8];
        for (c, slot) in out.iter_mut().enumerate() {
            let (dx, dy, dz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
            let wx = if dx == 1 { f.x } else { 1.0 - f.x };
            let wy = if dy == 1 { f.y } else { 1.0 - f.y };
            let wz = if dz == 1 { f.z } else { 1.0 - f.z };
            *slot = (self.index(i + dx, j + dy, k + dz), wx * wy * wz);
        }
        Some(out)
    }

    fn sample_f32(&self, values: &[f32], p: Vec3) -> f32 {
        self.corners(p).map_or(0.0, |c| c.iter().map(|&(n, w)| w * values[n]).sum())
    }

    fn sample(&self, values: &[f64], p: Vec3) -> f64 {
        self.corners(p).map_or(0.0, |c| c.iter().map(|&(n, w)| w as f64 * values[n]).sum())
    }
}

/// Solves the screened Poisson problem on `grid` (see the module docs) and returns χ at the
/// nodes; χ grows along the normals (inside is below the iso-value).
fn screened_poisson(grid: &Grid, points: &[OrientedPoint], screening: f64) -> Vec<f64> {
    let n = grid.nodes_per_axis();
    let nodes = n * n * n;
    let h = grid.spacing as f64;
    // Splat normal × area / h³ (a surface-delta density) onto the nodes.
    let mut field = vec![[0.0f64; 3]; nodes];
    let mut screen: Vec<([(usize, f32); 8], f64)> = Vec::with_capacity(points.len());
    for p in points {
        let Some(corners) = grid.corners(p.position) else { continue };
        let density = p.area as f64 / (h * h * h);
        for &(node, w) in &corners {
            for (f, n) in field[node].iter_mut().zip(p.normal.to_array()) {
                *f += w as f64 * density * n as f64;
            }
        }
        screen.push((corners, screening * p.area as f64 / (h * h)));
    }
    // Normal equations of Σ_edges (χ_b − χ_a − h·V_edge)² + Σ_samples α (χ(p) − c)²: the
    // graph Laplacian (Neumann boundary for free), the screening rows, and Gᵀ(h V) on the
    // right. The screening target c is 0; the iso-value is read off χ afterwards.
    let mut rhs = vec![0.0f64; nodes];
    let mut diag = vec![0.0f64; nodes];
    let strides = [1usize, n, n * n];
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let a = grid.index(i, j, k);
                let ijk = [i, j, k];
                for axis in 0..3 {
                    if ijk[axis] + 1 >= n {
                        continue;
                    }
                    let b = a + strides[axis];
                    let v = 0.5 * (field[a][axis] + field[b][axis]) * h;
                    rhs[b] += v;
                    rhs[a] -= v;
                    diag[a] += 1.0;
                    diag[b] += 1.0;
                }
            }
        }
    }
    for (corners, alpha) in &screen {
        for &(node, w) in corners {
            diag[node] += alpha * (w as f64) * (w as f64);
        }
    }
    for d in &mut diag {
        *d = d.max(1e-12);
    }
    let apply = |x: &[f64], out: &mut [f64]| {
        out.par_chunks_mut(n * n).enumerate().for_each(|(k, plane)| {
            for j in 0..n {
                for i in 0..n {
                    let a = grid.index(i, j, k);
                    let mut s = 0.0;
                    let mut deg = 0.0;
                    if i > 0 {
                        s += x[a - 1];
                        deg += 1.0;
                    }
                    if i + 1 < n {
                        s += x[a + 1];
                        deg += 1.0;
                    }
                    if j > 0 {
                        s += x[a - n];
                        deg += 1.0;
                    }
                    if j + 1 < n {
                        s += x[a + n];
                        deg += 1.0;
                    }
                    if k > 0 {
                        s += x[a - n * n];
                        deg += 1.0;
                    }
                    if k + 1 < n {
                        s += x[a + n * n];
                        deg += 1.0;
                    }
                    plane[i + n * j] = deg * x[a] - s;
                }
            }
        });
        for (corners, alpha) in &screen {
            let t: f64 = corners.iter().map(|&(node, w)| w as f64 * x[node]).sum();
            for &(node, w) in corners {
                out[node] += alpha * w as f64 * t;
            }
        }
    };
    conjugate_gradients(&apply, &diag, &rhs, 400, 1e-5)
}

/// Per grid node, the smallest mask value over the views (bilinear; 0 outside an image):
/// above 0.5 inside the visual hull.
fn visual_hull(grid: &Grid, views: &ViewSet) -> Vec<f32> {
    let n = grid.nodes_per_axis();
    let (w, h) = (views.width(), views.height());
    let mut hull = vec![0.0f32; n * n * n];
    hull.par_chunks_mut(n * n).enumerate().for_each(|(k, plane)| {
        for j in 0..n {
            for i in 0..n {
                let p = grid.position(i, j, k);
                let mut m = 1.0f32;
                for (rv, view) in views.iter() {
                    let q = rv.camera.project(p, w, h);
                    m = m.min(bilinear(&view.mask, q.x - 0.5, q.y - 0.5));
                    if m < 0.5 {
                        break;
                    }
                }
                plane[i + n * j] = m;
            }
        }
    });
    hull
}

/// Per foreground pixel of `mask`, the depth along `camera`'s ray where it first enters the
/// visual hull (`hull` ≥ 0.5, marched at half a grid cell and refined linearly); NaN where
/// the ray misses the hull or on the background.
fn hull_entry_depth(grid: &Grid, hull: &[f32], camera: &Camera, mask: &Image) -> Result<Image> {
    let (w, h) = (mask.width(), mask.height());
    let reach = grid.extent * 3f32.sqrt();
    let centre = camera.depth(Vec3::ZERO);
    let step = 0.5 * grid.spacing;
    let steps = (2.0 * reach / step).ceil() as usize;
    let mut depth = vec![f32::NAN; (w * h) as usize];
    depth.par_chunks_mut(w as usize).enumerate().for_each(|(y, row)| {
        for (x, d) in row.iter_mut().enumerate() {
            if mask.data()[y * w as usize + x] < 0.5 {
                continue;
            }
            let at = |t: f32| camera.unproject(x as f32 + 0.5, y as f32 + 0.5, t, w, h);
            let mut previous = (centre - reach, 0.0f32);
            for s in 0..=steps {
                let t = centre - reach + s as f32 * step;
                let v = grid.sample_f32(hull, at(t));
                if v >= 0.5 {
                    let (t0, v0) = previous;
                    let f = if v > v0 { ((0.5 - v0) / (v - v0)).clamp(0.0, 1.0) } else { 1.0 };
                    *d = t0 + (t - t0) * f;
                    break;
                }
                previous = (t, v);
            }
        }
    });
    Image::new(w, h, 1, depth)
}

/// Bilinear sample of a 1-channel image at continuous pixel coordinates (pixel centres at
/// integers), 0 outside.
fn bilinear(image: &Image, x: f32, y: f32) -> f32 {
    let (w, h) = (image.width() as i64, image.height() as i64);
    if !(x.is_finite() && y.is_finite()) {
        return 0.0;
    }
    let (x0, y0) = (x.floor() as i64, y.floor() as i64);
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let at = |xi: i64, yi: i64| -> f32 {
        if xi < 0 || yi < 0 || xi >= w || yi >= h { 0.0 } else { image.data()[(yi * w + xi) as usize] }
    };
    let top = at(x0, y0) * (1.0 - fx) + at(x0 + 1, y0) * fx;
    let bottom = at(x0, y0 + 1) * (1.0 - fx) + at(x0 + 1, y0 + 1) * fx;
    top * (1.0 - fy) + bottom * fy
}

/// The zero set of `field` (negative inside) as a closed, consistently oriented mesh, by
/// marching tetrahedra over the six Kuhn tetrahedra of each cell. Components with fewer
/// than 1 % of the triangles are dropped. `None` when nothing is inside.
fn marching_tetrahedra(grid: &Grid, field: &[f32]) -> Result<Option<Mesh>> {
    let n = grid.nodes_per_axis();
    // Nudge exact zeros outside so no vertex lands on a node (keeps the output manifold).
    let value = |node: usize| -> f32 { if field[node] == 0.0 { 1e-7 } else { field[node] } };
    const KUHN: [[usize; 3]; 6] = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
    let mut vertex_of: HashMap<(usize, u8), u32> = HashMap::new();
    let mut positions: Vec<[f32; 3]> = Vec::new();
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    let cells = grid.cells;
    for k in 0..cells {
        for j in 0..cells {
            for i in 0..cells {
                let base = [i, j, k];
                let corner = |bits: usize| -> ([usize; 3], usize) {
                    let c = [base[0] + (bits & 1), base[1] + ((bits >> 1) & 1), base[2] + ((bits >> 2) & 1)];
                    (c, grid.index(c[0], c[1], c[2]))
                };
                let all: [f32; 8] = std::array::from_fn(|b| value(corner(b).1));
                if all.iter().all(|&v| v > 0.0) || all.iter().all(|&v| v < 0.0) {
                    continue;
                }
                for perm in KUHN {
                    let bits = [0usize, 1 << perm[0], (1 << perm[0]) | (1 << perm[1]), 7];
                    let inside: Vec<usize> = (0..4).filter(|&t| all[bits[t]] < 0.0).collect();
                    if inside.is_empty() || inside.len() == 4 {
                        continue;
                    }
                    let outside: Vec<usize> = (0..4).filter(|&t| all[bits[t]] >= 0.0).collect();
                    let mut edge_vertex = |a: usize, b: usize| -> u32 {
                        let (lo, hi) = if bits[a] < bits[b] { (bits[a], bits[b]) } else { (bits[b], bits[a]) };
                        let (lo_c, lo_node) = corner(lo);
                        let key = (lo_node, (hi & !lo) as u8);
                        *vertex_of.entry(key).or_insert_with(|| {
                            let (hi_c, _) = corner(hi);
                            let (fa, fb) = (all[lo], all[hi]);
                            let t = (fa / (fa - fb)).clamp(0.02, 0.98);
                            let pa = grid.position(lo_c[0], lo_c[1], lo_c[2]);
                            let pb = grid.position(hi_c[0], hi_c[1], hi_c[2]);
                            positions.push((pa + (pb - pa) * t).to_array());
                            (positions.len() - 1) as u32
                        })
                    };
                    let centre = |set: &[usize]| -> Vec3 {
                        set.iter().map(|&t| grid.position_of_bits(base, bits[t])).sum::<Vec3>() / set.len() as f32
                    };
                    let outward = centre(&outside) - centre(&inside);
                    let mut emit = |tri: [u32; 3], positions: &[[f32; 3]]| {
                        let normal = w3d_core::normals::face_normal(positions, tri);
                        triangles.push(if normal.dot(outward.as_dvec3()) >= 0.0 {
                            tri
                        } else {
                            [tri[0], tri[2], tri[1]]
                        });
                    };
                    match inside.len() {
                        1 => {
                            let tri = [
                                edge_vertex(inside[0], outside[0]),
                                edge_vertex(inside[0], outside[1]),
                                edge_vertex(inside[0], outside[2]),
                            ];
                            emit(tri, &positions);
                        }
                        3 => {
                            let tri = [
                                edge_vertex(inside[0], outside[0]),
                                edge_vertex(inside[1], outside[0]),
                                edge_vertex(inside[2], outside[0]),
                            ];
                            emit(tri, &positions);
                        }
                        _ => {
                            let q = [
                                edge_vertex(inside[0], outside[0]),
                                edge_vertex(inside[0], outside[1]),
                                edge_vertex(inside[1], outside[1]),
                                edge_vertex(inside[1], outside[0]),
                            ];
                            emit([q[0], q[1], q[2]], &positions);
                            emit([q[0], q[2], q[3]], &positions);
                        }
                    }
                }
            }
        }
    }
    let _ = n;
    if triangles.is_empty() {
        return Ok(None);
    }
    Ok(Some(drop_small_components(positions, triangles, 0.01)?))
}

impl Grid {
    /// World position of the corner `bits` (x | y << 1 | z << 2) of cell `base`.
    fn position_of_bits(&self, base: [usize; 3], bits: usize) -> Vec3 {
        self.position(base[0] + (bits & 1), base[1] + ((bits >> 1) & 1), base[2] + ((bits >> 2) & 1))
    }
}

/// Keeps the edge-connected components holding at least `fraction` of the triangles and
/// renumbers the vertices.
fn drop_small_components(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>, fraction: f32) -> Result<Mesh> {
    // Union-find over vertices; triangles join their corners.
    let mut parent: Vec<u32> = (0..positions.len() as u32).collect();
    fn root(parent: &mut [u32], mut v: u32) -> u32 {
        while parent[v as usize] != v {
            parent[v as usize] = parent[parent[v as usize] as usize];
            v = parent[v as usize];
        }
        v
    }
    for t in &triangles {
        for e in 0..2 {
            let (a, b) = (root(&mut parent, t[e]), root(&mut parent, t[e + 1]));
            if a != b {
                parent[a.max(b) as usize] = a.min(b);
            }
        }
    }
    let mut size: HashMap<u32, usize> = HashMap::new();
    for t in &triangles {
        *size.entry(root(&mut parent, t[0])).or_default() += 1;
    }
    let keep_min = (fraction * triangles.len() as f32).ceil() as usize;
    let mut remap = vec![u32::MAX; positions.len()];
    let mut kept_positions = Vec::new();
    let mut kept = Vec::new();
    for t in &triangles {
        if size[&root(&mut parent, t[0])] < keep_min {
            continue;
        }
        kept.push(t.map(|v| {
            if remap[v as usize] == u32::MAX {
                remap[v as usize] = kept_positions.len() as u32;
                kept_positions.push(positions[v as usize]);
            }
            remap[v as usize]
        }));
    }
    Mesh::new(kept_positions, kept)
}

/// Taubin λ|μ smoothing (λ = 0.5, μ = −0.53, uniform weights): removes the grid's
/// staircase without shrinking the shape.
fn taubin_smooth(mesh: &Mesh, iterations: usize) -> Result<Mesh> {
    let mut positions: Vec<Vec3> = mesh.positions().iter().map(|&p| Vec3::from(p)).collect();
    let edges = mesh.edges();
    let mut degree = vec![0.0f32; positions.len()];
    for e in &edges {
        degree[e[0] as usize] += 1.0;
        degree[e[1] as usize] += 1.0;
    }
    for _ in 0..iterations {
        for factor in [0.5f32, -0.53] {
            let mut sum = vec![Vec3::ZERO; positions.len()];
            for e in &edges {
                let (a, b) = (e[0] as usize, e[1] as usize);
                sum[a] += positions[b];
                sum[b] += positions[a];
            }
            for ((p, s), d) in positions.iter_mut().zip(sum).zip(&degree) {
                if *d > 0.0 {
                    *p += factor * (s / *d - *p);
                }
            }
        }
    }
    Mesh::new(positions.iter().map(|p| p.to_array()).collect(), mesh.triangles().to_vec())
}

/// Brings a fine marching-tetrahedra mesh to about `edge_length` with the remesher's
/// collapse / split / flip passes (no optimisation steps).
fn simplify(mesh: &Mesh, edge_length: f32) -> Result<Mesh> {
    // The reference passes only (see `reconstruct_coarse` for why the repairs are off).
    let options = RemeshOptions::default()
        .with_edge_len_lims((edge_length, edge_length))
        .with_edge_floor_passes(0)
        .with_fold_relaxation_rounds(0)
        .with_remove_valence3(false);
    let mut opt = MeshOptimizer::from_mesh(mesh, options)?;
    for _ in 0..8 {
        let lengths = vec![edge_length; opt.vertex_count()];
        opt.set_target_edge_lengths(&lengths)?;
        let stats = opt.remesh_now();
        if stats.collapsed == 0 && stats.split == 0 {
            break;
        }
    }
    opt.to_mesh()
}
