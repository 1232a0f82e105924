//! Agreement of generated views with the true views of the same rig: how a multi-view
//! generator is scored before any mesh is made from its views.

use w3d_core::{Error, Result, ViewSet};

/// How far generated normal maps and masks are from the truth ([`view_agreement`]).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct ViewAgreement {
    /// Mean angle in degrees between true and generated normals, over every pixel the true
    /// mask covers (≥ 0.5) in every view; a generated normal of zero length counts as 90°.
    pub normal_angle_deg: f64,
    /// Intersection over union of the true and generated masks (each thresholded at 0.5),
    /// pooled over all views; 1 when both are empty.
    pub mask_iou: f64,
    /// Pixels the angle is averaged over.
    pub pixels: usize,
    /// The mean angle in degrees over the true mask's interior only: its pixels whose eight
    /// neighbours all lie inside the true mask and the image (0 when there are none). The
    /// rest, the silhouette's one-pixel rim, is where a decoder's blur and an outline off by a
    /// pixel weigh most; the two means tell those errors from the ones inside.
    pub interior_normal_angle_deg: f64,
    /// Pixels of the true mask's interior ([`Self::interior_normal_angle_deg`]).
    pub interior_pixels: usize,
}

/// Compares `generated` with `truth`, view by view (both must have the same views in the
/// same order and the same image size; the rigs themselves are not compared, so views
/// generated for a rig can be scored against renders of the object with it).
///
/// ```
/// use w3d_core::{Image, ViewImages, ViewRig, ViewSet};
/// use w3d_eval::view_agreement;
///
/// let rig = ViewRig::wonder3d_ortho();
/// let set = |nz: f32| {
///     let views = rig.views.iter().map(|v| ViewImages {
///         name: v.name.clone(),
///         normal: Image::new(2, 2, 3, [0.0, (1.0 - nz * nz).sqrt(), nz].repeat(4)).unwrap(),
///         colour: None,
///         mask: Image::new(2, 2, 1, vec![1.0, 1.0, 1.0, 0.0]).unwrap(),
///         depth: None,
///     });
///     ViewSet::new(rig.clone(), views.collect()).unwrap()
/// };
/// let a = view_agreement(&set(1.0), &set(0.5f32.sqrt()))?; // normals tilted by 45°
/// assert!((a.normal_angle_deg - 45.0).abs() < 1e-3);
/// assert_eq!((a.mask_iou, a.pixels), (1.0, 18));
/// # Ok::<(), w3d_core::Error>(())
/// ```
pub fn view_agreement(truth: &ViewSet, generated: &ViewSet) -> Result<ViewAgreement> {
    let (t, g) = (truth.views(), generated.views());
    if t.len() != g.len() {
        return Err(Error::invalid(
            "generated views",
            format!("as many views as the truth ({}, found {})", t.len(), g.len()),
        ));
    }
    let (mut angle, mut pixels, mut inter, mut union) = (0.0f64, 0usize, 0usize, 0usize);
    let (mut interior_angle, mut interior_pixels) = (0.0f64, 0usize);
    for (tv, gv) in t.iter().zip(g) {
        if tv.name != gv.name || (tv.mask.width(), tv.mask.height()) != (gv.mask.width(), gv.mask.height()) {
            return Err(Error::invalid(
                format!("generated view {}", gv.name),
                format!("view {} at {}×{} as in the truth", tv.name, tv.mask.width(), tv.mask.height()),
            ));
        }
        let (tn, gn) = (tv.normal.data(), gv.normal.data());
        let (w, h) = (tv.mask.width() as usize, tv.mask.height() as usize);
        let inside = |x: usize, y: usize| tv.mask.data()[y * w + x] >= 0.5;
        let interior = |i: usize| {
            let (x, y) = (i % w, i / w);
            x > 0
                && y > 0
                && x + 1 < w
                && y + 1 < h
                && (y - 1..=y + 1).all(|yy| (x - 1..=x + 1).all(|xx| inside(xx, yy)))
        };
        for (i, (&tm, &gm)) in tv.mask.data().iter().zip(gv.mask.data()).enumerate() {
            let (a, b) = (tm >= 0.5, gm >= 0.5);
            inter += usize::from(a && b);
            union += usize::from(a || b);
            if a {
                let (u, v) = (&tn[3 * i..3 * i + 3], &gn[3 * i..3 * i + 3]);
                let (lu, lv) = (
                    f64::from(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt(),
                    f64::from(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt(),
                );
                let dot = f64::from(u[0] * v[0] + u[1] * v[1] + u[2] * v[2]);
                let cos = if lu > 0.0 && lv > 0.0 { dot / (lu * lv) } else { 0.0 };
                let degrees = cos.clamp(-1.0, 1.0).acos().to_degrees();
                angle += degrees;
                pixels += 1;
                if interior(i) {
                    interior_angle += degrees;
                    interior_pixels += 1;
                }
            }
        }
    }
    Ok(ViewAgreement {
        normal_angle_deg: angle / pixels.max(1) as f64,
        mask_iou: if union == 0 { 1.0 } else { inter as f64 / union as f64 },
        pixels,
        interior_normal_angle_deg: interior_angle / interior_pixels.max(1) as f64,
        interior_pixels,
    })
}
