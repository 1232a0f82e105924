//! Normal integration against real renders: the front normal map of a rendered shape
//! integrates back to its rendered depth.

use w3d_core::{Mesh, ViewRig};
use w3d_recon::{IntegrateOptions, integrate_normals};

fn sphere(radius: f32) -> Mesh {
    w3d_remesh::icosphere(5, radius).unwrap()
}

/// Over foreground pixels at least `margin` pixels from the silhouette: the mean depth
/// offset (integrated − rendered; the integration constant, fixed only approximately by
/// the silhouette anchor) and the mean and max absolute error once that offset is removed.
fn depth_error(mesh: &Mesh, view: usize, size: u32, margin: usize) -> (f64, f64, f64) {
    let rig = ViewRig::wonder3d_ortho();
    let views = w3d_raster::render_oracle_views(mesh, &rig, size).unwrap();
    let v = &views.views()[view];
    let depth = integrate_normals(&v.normal, &v.mask, &rig.views[view].camera, &IntegrateOptions::default()).unwrap();
    let truth = v.depth.as_ref().unwrap();
    let s = size as usize;
    let solid = |x: usize, y: usize| v.mask.data()[y * s + x] >= 1.0;
    let mut diffs = Vec::new();
    for y in margin..s - margin {
        for x in margin..s - margin {
            let interior = (y - margin..=y + margin).all(|yy| (x - margin..=x + margin).all(|xx| solid(xx, yy)));
            if interior {
                diffs.push((depth.data()[y * s + x] - truth.data()[y * s + x]) as f64);
            }
        }
    }
    assert!(diffs.len() > 100, "too few interior pixels");
    let offset = diffs.iter().sum::<f64>() / diffs.len() as f64;
    let mean = diffs.iter().map(|d| (d - offset).abs()).sum::<f64>() / diffs.len() as f64;
    let max = diffs.iter().map(|d| (d - offset).abs()).fold(0.0, f64::max);
    (offset, mean, max)
}

#[test]
fn sphere_normals_integrate_to_its_depth() {
    // A sphere centred at the origin: its silhouette lies on the origin plane, exactly
    // where the integration anchors it.
    // Pixel size 1.5 / 128 ≈ 0.012; the rim pixels sit up to a pixel inside the silhouette,
    // where a sphere of radius 0.4 is already ≈ √(2·0.4·0.012) ≈ 0.1 above the origin plane.
    let (offset, mean, max) = depth_error(&sphere(0.4), 0, 128, 2);
    assert!(mean < 0.005 && max < 0.02, "offset {offset}, mean {mean}, max {max}");
    assert!(offset.abs() < 0.1, "offset {offset}");
}

#[test]
fn integration_works_from_the_side_views_too() {
    let (offset, mean, max) = depth_error(&sphere(0.4), 2, 128, 2);
    assert!(mean < 0.005 && max < 0.02, "right view: offset {offset}, mean {mean}, max {max}");
}

#[test]
fn perspective_cameras_and_empty_masks_are_rejected() {
    let rig = ViewRig::wonder3d_persp();
    let views = w3d_raster::render_oracle_views(&sphere(0.3), &ViewRig::wonder3d_ortho(), 32).unwrap();
    let v = &views.views()[0];
    assert!(integrate_normals(&v.normal, &v.mask, &rig.views[0].camera, &IntegrateOptions::default()).is_err());
    let empty = w3d_core::Image::filled(32, 32, 1, 0.0).unwrap();
    let ortho = ViewRig::wonder3d_ortho();
    let err = integrate_normals(&v.normal, &empty, &ortho.views[0].camera, &IntegrateOptions::default()).unwrap_err();
    assert!(err.to_string().contains("foreground"), "{err}");
}
