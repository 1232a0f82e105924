//! How well each view agrees with a reconstructed mesh: the mesh rendered into every view of
//! the rig and compared with that view's mask and normals. Generated views are never fully
//! consistent; a view the others outvoted (another object, a face drawn on the back, a
//! silhouette grown or cut) is the one the closed surface fits worst, so the view with the
//! lowest score is the one to distrust, and a user can be told which.

use glam::Vec3;
use w3d_core::{Mesh, Result, ViewSet};
use w3d_raster::{NO_TRIANGLE, interpolate, rasterize_rig};

use crate::normals::vertex_normals;

/// The agreement of one view with a mesh.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct ViewAgreement {
    /// The view's name in the rig.
    pub view: String,
    /// Intersection over union of the mesh's silhouette and the view's mask (mask ≥ 0.5),
    /// in [0, 1].
    pub mask_iou: f32,
    /// Mean angle in degrees between the mesh's rendered normals and the view's normals over
    /// the pixels both cover (90 when they cover none).
    pub normal_error_deg: f32,
    /// `mask_iou × (1 − normal_error_deg / 90)`, in [0, 1]: 1 for a view the mesh explains
    /// exactly.
    pub score: f32,
}

/// The agreement of every view of `views` with `mesh` (in the views' world frame), in rig
/// order: one render of the mesh per view at the views' size.
pub fn view_agreement(views: &ViewSet, mesh: &Mesh) -> Result<Vec<ViewAgreement>> {
    let rasters = rasterize_rig(mesh, views.rig(), views.width())?;
    let normals = vertex_normals(mesh.positions(), mesh.triangles())?;
    let attributes: Vec<f32> = normals.iter().flatten().copied().collect();
    let mut out = Vec::with_capacity(views.len());
    for ((rv, view), raster) in views.iter().zip(&rasters) {
        let rendered = interpolate(&attributes, 3, mesh.triangles(), raster)?;
        let (mut both, mut either, mut angle_sum) = (0usize, 0usize, 0.0f64);
        for (p, &t) in raster.triangle.iter().enumerate() {
            let covered = t != NO_TRIANGLE;
            let inside = view.mask.data()[p] >= 0.5;
            either += usize::from(covered || inside);
            if !(covered && inside) {
                continue;
            }
            both += 1;
            let r = Vec3::from_slice(&rendered[3 * p..3 * p + 3]).normalize_or_zero();
            let n = Vec3::from_slice(&view.normal.data()[3 * p..3 * p + 3]).normalize_or_zero();
            angle_sum += f64::from(r.dot(n).clamp(-1.0, 1.0).acos().to_degrees());
        }
        let mask_iou = if either == 0 { 1.0 } else { both as f32 / either as f32 };
        let normal_error_deg = if both == 0 { 90.0 } else { (angle_sum / both as f64) as f32 };
        let score = mask_iou * (1.0 - normal_error_deg / 90.0).max(0.0);
        out.push(ViewAgreement { view: rv.name.clone(), mask_iou, normal_error_deg, score });
    }
    Ok(out)
}

/// The view that disagrees with the others, if one does: the lowest score when it is below
/// `ratio` times the median of the others' (0.85 in the run reports). `None` when the views
/// agree about equally.
pub fn disagreeing_view(agreement: &[ViewAgreement], ratio: f32) -> Option<&ViewAgreement> {
    let worst = agreement.iter().min_by(|a, b| a.score.total_cmp(&b.score))?;
    let mut others: Vec<f32> = agreement.iter().filter(|a| a.view != worst.view).map(|a| a.score).collect();
    if others.is_empty() {
        return None;
    }
    others.sort_by(f32::total_cmp);
    let median = others[others.len() / 2];
    (worst.score < ratio * median).then_some(worst)
}

#[cfg(test)]
mod tests {
    use w3d_core::ViewRig;
    use w3d_raster::render_oracle_views;

    use super::*;

    fn sphere() -> Mesh {
        w3d_remesh::icosphere(4, 0.35).unwrap()
    }

    #[test]
    fn the_views_of_a_mesh_agree_with_it_and_another_objects_view_does_not() {
        let mesh = sphere();
        let views = render_oracle_views(&mesh, &ViewRig::wonder3d_ortho(), 64).unwrap();
        let agreement = view_agreement(&views, &mesh).unwrap();
        assert_eq!(agreement.len(), 6);
        for a in &agreement {
            assert!(a.mask_iou > 0.97 && a.normal_error_deg < 3.0 && a.score > 0.93, "{a:?}");
        }
        assert!(disagreeing_view(&agreement, 0.85).is_none());
        // One view of a smaller sphere: its silhouette and normals disagree.
        let mut small = mesh.clone();
        small.map_positions(|p| p * 0.6).unwrap();
        let other = render_oracle_views(&small, &ViewRig::wonder3d_ortho(), 64).unwrap();
        let (rig, mut images) = views.into_parts();
        images[3] = other.views()[3].clone();
        let mixed = ViewSet::new(rig, images).unwrap();
        let agreement = view_agreement(&mixed, &mesh).unwrap();
        let worst = disagreeing_view(&agreement, 0.85).expect("one view disagrees");
        assert_eq!(worst.view, mixed.rig().views[3].name);
        assert!(worst.mask_iou < 0.5, "{worst:?}");
    }
}
