//! SyncDreamer's visible-surface Chamfer distance: both meshes are rendered to depth in the
//! 16 fixed views, every foreground pixel is back-projected to a world point, each cloud is
//! voxel down-sampled, and the clouds are compared with nearest neighbours. Surfaces no
//! camera sees (interiors, hidden cavities) do not count, unlike the surface-sample
//! Chamfer of [`crate::evaluate`].

use glam::DVec3;
use w3d_core::{Error, Mesh, Result, ViewRig};

use crate::distance::nearest;

/// Options of [`visible_surface_chamfer`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct VisibleOptions {
    /// Side of the square depth renders in pixels (SyncDreamer: 256; the rig's focal length
    /// scales with it, 280 px at 256).
    pub size: u32,
    /// Edge of the down-sampling voxels in world (unit-cube) units (SyncDreamer: 0.01).
    pub voxel: f32,
}

impl Default for VisibleOptions {
    fn default() -> Self {
        VisibleOptions { size: 256, voxel: 0.01 }
    }
}

/// Chainable setters, one per field: `VisibleOptions::default().with_…(…)` (the struct is
/// `#[non_exhaustive]`, so code outside this crate cannot use struct-literal syntax).
impl VisibleOptions {
    w3d_core::setters! {
        with_size(size: u32);
        with_voxel(voxel: f32);
    }
}

/// The visible-surface Chamfer distance and its parts, in world (unit-cube) units.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct VisibleChamfer {
    /// `(pred_to_gt + gt_to_pred) / 2`, Euclidean, not squared.
    pub chamfer: f64,
    /// Mean distance from each down-sampled predicted point to the nearest ground-truth one.
    pub pred_to_gt: f64,
    /// Mean distance from each down-sampled ground-truth point to the nearest predicted one.
    pub gt_to_pred: f64,
    /// Predicted points after voxel down-sampling.
    pub pred_points: usize,
    /// Ground-truth points after voxel down-sampling.
    pub gt_points: usize,
}

/// The world points seen by the SyncDreamer 16-view rig ([`ViewRig::syncdreamer16`]):
/// `mesh` (used as given, in the canonical frame) is rendered to depth at
/// `options.size²` and the centre `(i + 0.5, j + 0.5)` of every pixel with a positive depth
/// is back-projected along its camera ray, then the merged cloud of all views is
/// down-sampled with [`voxel_down_sample`] at `options.voxel`.
///
/// Errors: a zero size, a voxel that is not positive and finite, a mesh no view sees.
pub fn visible_points(mesh: &Mesh, options: &VisibleOptions) -> Result<Vec<[f32; 3]>> {
    if options.size == 0 {
        return Err(Error::invalid("visible options.size", "a render size of at least 1 pixel, got 0"));
    }
    let rig = ViewRig::syncdreamer16();
    let depths = w3d_raster::render_depth(mesh, &rig, options.size)?;
    let n = options.size;
    let mut points = Vec::new();
    for (camera, depth) in rig.cameras().zip(&depths) {
        for (k, &d) in depth.data().iter().enumerate() {
            if d > 0.0 {
                let (i, j) = (k as u32 % n, k as u32 / n);
                let p = camera.unproject(i as f32 + 0.5, j as f32 + 0.5, d, n, n);
                points.push(p.to_array());
            }
        }
    }
    if points.is_empty() {
        return Err(Error::invalid("mesh", "a mesh visible in at least one syncdreamer16 view, got an empty render"));
    }
    voxel_down_sample(&points, options.voxel)
}

/// One point per occupied voxel: the **mean** of the points in it, as Open3D's
/// `voxel_down_sample` (which SyncDreamer's evaluation calls) does. The mean, unlike the
/// first point, does not depend on the order of the points, and it smooths the pixel-grid
/// pattern of back-projected depth. The grid follows Open3D's placement: voxel `k` along an
/// axis spans `[lo − voxel/2 + k·voxel, lo + voxel/2 + k·voxel)`, `lo` being the cloud's
/// minimum on that axis. Output is ordered by voxel index (x, then y, then z), so the
/// result is deterministic.
///
/// Errors: a voxel that is not positive and finite, a non-finite point.
pub fn voxel_down_sample(points: &[[f32; 3]], voxel: f32) -> Result<Vec<[f32; 3]>> {
    if !(voxel > 0.0 && voxel.is_finite()) {
        return Err(Error::invalid("voxel size", format!("a positive, finite edge length, got {voxel}")));
    }
    if let Some(i) = points.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(Error::invalid(format!("points[{i}]"), "finite coordinates"));
    }
    let Some(first) = points.first() else { return Ok(Vec::new()) };
    let lo = points.iter().fold(DVec3::from(first.map(f64::from)), |m, p| m.min(DVec3::from(p.map(f64::from))));
    let origin = lo - 0.5 * f64::from(voxel);
    let mut keyed: Vec<([i64; 3], usize)> = points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let c = ((DVec3::from(p.map(f64::from)) - origin) / f64::from(voxel)).floor();
            ([c.x as i64, c.y as i64, c.z as i64], i)
        })
        .collect();
    keyed.sort_unstable();
    let mut out = Vec::new();
    for run in keyed.chunk_by(|a, b| a.0 == b.0) {
        let sum: DVec3 = run.iter().map(|&(_, i)| DVec3::from(points[i].map(f64::from))).sum();
        out.push((sum / run.len() as f64).as_vec3().to_array());
    }
    Ok(out)
}

/// SyncDreamer's visible-surface Chamfer distance between `pred` and `gt`, both used as
/// given (normalise `gt`, and `pred` if wanted, into the unit cube first): the clouds of
/// [`visible_points`], compared with exact nearest neighbours both ways.
///
/// For the same surface in both meshes the result is 0 up to float noise; a pixel-scale
/// change of the sampling can move a voxel mean by at most a voxel diagonal (√3 · voxel
/// ≈ 0.017 at 0.01), and in practice moves the Chamfer by far less (see the tests).
///
/// Errors: as [`visible_points`] for either mesh.
pub fn visible_surface_chamfer(pred: &Mesh, gt: &Mesh, options: &VisibleOptions) -> Result<VisibleChamfer> {
    let p = visible_points(pred, options)?;
    let g = visible_points(gt, options)?;
    let mean = |d: Vec<(f32, usize)>| d.iter().map(|&(v, _)| f64::from(v)).sum::<f64>() / d.len() as f64;
    let (pred_to_gt, gt_to_pred) = (mean(nearest(&p, &g)), mean(nearest(&g, &p)));
    Ok(VisibleChamfer {
        chamfer: 0.5 * (pred_to_gt + gt_to_pred),
        pred_to_gt,
        gt_to_pred,
        pred_points: p.len(),
        gt_points: g.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn voxel_means_by_hand() {
        // lo = (0, 0, 0): voxels of edge 1 start at -0.5, so x in [-0.5, 0.5) is voxel 0.
        let points = [[0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 2.0, 0.0], [0.2, 0.3, 0.0]];
        let out = voxel_down_sample(&points, 1.0).unwrap();
        assert_eq!(out, vec![[0.2, 0.1, 0.0], [1.0, 0.0, 0.0], [2.0, 2.0, 0.0]]);
        assert!(voxel_down_sample(&points, 0.0).unwrap_err().to_string().contains("voxel size"));
        assert!(voxel_down_sample(&[[f32::NAN; 3]], 1.0).unwrap_err().to_string().contains("points[0]"));
        assert!(voxel_down_sample(&[], 1.0).unwrap().is_empty());
    }
}
