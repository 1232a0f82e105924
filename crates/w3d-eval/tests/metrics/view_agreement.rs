//! `view_agreement`: the mean normal angle over the whole true mask and over its interior.

use w3d_core::{Image, ViewImages, ViewRig, ViewSet};
use w3d_eval::view_agreement;

/// Six 6×6 views whose mask is the 4×4 block at (1..5, 1..5): its interior (pixels whose eight
/// neighbours are all inside) is the 2×2 centre, its rim the other 12 pixels. `normal` gives
/// each masked pixel's normal from whether it is interior.
fn views(normal: impl Fn(bool) -> [f32; 3]) -> ViewSet {
    let rig = ViewRig::wonder3d_ortho();
    let inside = |x: usize, y: usize| (1..5).contains(&x) && (1..5).contains(&y);
    let (mut normals, mut mask) = (Vec::new(), Vec::new());
    for y in 0..6 {
        for x in 0..6 {
            let interior = (2..4).contains(&x) && (2..4).contains(&y);
            normals.extend(if inside(x, y) { normal(interior) } else { [0.0, 0.0, 0.0] });
            mask.push(if inside(x, y) { 1.0 } else { 0.0 });
        }
    }
    let views = rig.views.iter().map(|v| ViewImages {
        name: v.name.clone(),
        normal: Image::new(6, 6, 3, normals.clone()).unwrap(),
        colour: None,
        mask: Image::new(6, 6, 1, mask.clone()).unwrap(),
        depth: None,
    });
    ViewSet::new(rig.clone(), views.collect()).unwrap()
}

#[test]
fn the_interior_mean_leaves_out_the_silhouettes_rim() {
    let truth = views(|_| [0.0, 0.0, 1.0]);
    // Right inside, a right angle on the rim.
    let rim_wrong = views(|interior| if interior { [0.0, 0.0, 1.0] } else { [1.0, 0.0, 0.0] });
    let a = view_agreement(&truth, &rim_wrong).unwrap();
    assert_eq!((a.pixels, a.interior_pixels), (6 * 16, 6 * 4));
    assert!((a.normal_angle_deg - 12.0 * 90.0 / 16.0).abs() < 1e-9, "{a:?}");
    assert!(a.interior_normal_angle_deg.abs() < 1e-9, "{a:?}");
    // Wrong inside, right on the rim: the interior carries all of it.
    let interior_wrong = views(|interior| if interior { [0.0, 1.0, 0.0] } else { [0.0, 0.0, 1.0] });
    let b = view_agreement(&truth, &interior_wrong).unwrap();
    assert!((b.normal_angle_deg - 4.0 * 90.0 / 16.0).abs() < 1e-9, "{b:?}");
    assert!((b.interior_normal_angle_deg - 90.0).abs() < 1e-9, "{b:?}");
    assert_eq!(b.mask_iou, 1.0);
}
