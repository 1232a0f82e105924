//! Camera projection properties, the reference rig tables, unit-cube normalisation.

use approx::assert_abs_diff_eq;
use glam::Vec3;
use proptest::prelude::*;
use w3d_core::{Camera, Image, Mesh, Projection, ViewImages, ViewRig, ViewSet};

/// The Wonder3D rig, in order, with azimuths in degrees (`docs/architecture.md`, "Conventions").
const WONDER3D_TABLE: [(&str, f32); 6] =
    [("front", 0.0), ("front_right", 45.0), ("right", 90.0), ("back", 180.0), ("left", -90.0), ("front_left", -45.0)];

#[test]
fn wonder3d_rigs_match_the_reference_table() {
    for rig in [ViewRig::wonder3d_ortho(), ViewRig::wonder3d_persp()] {
        rig.validate().unwrap();
        assert_eq!(rig.len(), 6);
        for (view, (name, az)) in rig.views.iter().zip(WONDER3D_TABLE) {
            assert_eq!(view.name, name);
            let a = az.to_radians();
            let expected = Vec3::new(a.sin(), 0.0, a.cos());
            assert_abs_diff_eq!(view.camera.eye.normalize().to_array()[..], expected.to_array()[..], epsilon = 1e-6);
            assert_abs_diff_eq!(view.camera.eye.length(), 0.75 / 24.565f32.to_radians().tan(), epsilon = 1e-3);
            assert_abs_diff_eq!(view.camera.forward().to_array()[..], (-expected).to_array()[..], epsilon = 1e-6);
            assert_eq!(view.camera.up, Vec3::Y);
        }
        // "right" sees the +x side: +x points back towards that camera.
        let right = &rig.views[2].camera;
        assert_abs_diff_eq!(right.basis().z_axis.x, 1.0, epsilon = 1e-6);
        // In every view the image spans [-0.75, 0.75] at the origin.
        for v in &rig.views {
            let image_right = v.camera.basis().x_axis;
            let p = v.camera.project(image_right * 0.75, 256, 256);
            assert_abs_diff_eq!(p.x, 256.0, epsilon = 1e-3);
            assert_abs_diff_eq!(p.y, 128.0, epsilon = 1e-3);
        }
    }
    let Projection::Perspective { fov_y } = ViewRig::wonder3d_persp().views[0].camera.projection else { panic!() };
    assert_abs_diff_eq!(fov_y.to_degrees(), 49.13, epsilon = 0.01);
}

#[test]
fn syncdreamer_rig_matches_the_reference() {
    let rig = ViewRig::syncdreamer16();
    assert_eq!(rig.len(), 16);
    for (i, v) in rig.views.iter().enumerate() {
        let (a, e) = ((i as f32 * 22.5).to_radians(), 30f32.to_radians());
        let expected = 1.5 * Vec3::new(e.cos() * a.sin(), e.sin(), e.cos() * a.cos());
        assert_abs_diff_eq!(v.camera.eye.to_array()[..], expected.to_array()[..], epsilon = 1e-5);
        // fx = fy = 280 px at 256².
        assert_abs_diff_eq!(v.camera.focal_pixels(256).unwrap(), 280.0, epsilon = 1e-3);
    }
}

#[test]
fn rig_json_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    for rig in [ViewRig::wonder3d_ortho(), ViewRig::wonder3d_persp(), ViewRig::syncdreamer16()] {
        let p = dir.path().join("cameras.json");
        rig.save_json(&p).unwrap();
        assert_eq!(ViewRig::load_json(&p).unwrap(), rig);
    }
    assert!(ViewRig::by_name("wonder3d-persp").is_ok() && ViewRig::by_name("nope").is_err());
}

#[test]
fn view_set_round_trips_through_png_and_exr() {
    let rig = ViewRig::wonder3d_ortho();
    let (w, h) = (5u32, 3u32);
    let views = rig
        .views
        .iter()
        .enumerate()
        .map(|(k, v)| {
            let n = (w * h) as usize;
            let normal: Vec<f32> =
                (0..n).flat_map(|i| Vec3::new(i as f32 - 3.0, k as f32 + 0.5, 1.0).normalize().to_array()).collect();
            let mask: Vec<f32> = (0..n).map(|i| (i % 2) as f32).collect();
            let colour: Vec<f32> = (0..3 * n).map(|i| (i % 256) as f32 / 255.0).collect();
            let depth: Vec<f32> = (0..n).map(|i| 1.0 + i as f32 * 0.01).collect();
            ViewImages {
                name: v.name.clone(),
                normal: Image::new(w, h, 3, normal).unwrap(),
                colour: Some(Image::new(w, h, 3, colour).unwrap()),
                mask: Image::new(w, h, 1, mask).unwrap(),
                depth: Some(Image::new(w, h, 1, depth).unwrap()),
            }
        })
        .collect();
    let set = ViewSet::new(rig.clone(), views).unwrap();
    let dir = tempfile::tempdir().unwrap();
    set.save(dir.path()).unwrap();
    let back = ViewSet::load(dir.path()).unwrap();
    assert_eq!(back.rig(), &rig);
    // EXR normals and depth are exact; masks and colours are 8-bit exact for these values.
    assert_eq!(back, set);
    // Without the EXR, the 8-bit PNG normals are within half a quantisation step.
    for v in &rig.views {
        std::fs::remove_file(dir.path().join(format!("normal_{}.exr", v.name))).unwrap();
    }
    let png = ViewSet::load(dir.path()).unwrap();
    for (a, b) in png.views().iter().zip(set.views()) {
        for (x, y) in a.normal.data().iter().zip(b.normal.data()) {
            assert!((x - y).abs() <= 1.0 / 255.0 + 1e-6);
        }
    }
}

fn camera_strategy() -> impl Strategy<Value = Camera> {
    (0.0f32..360.0, -80.0f32..80.0, 0.8f32..5.0, prop::bool::ANY, 0.2f32..2.0, 0.3f32..2.5).prop_map(
        |(az, el, d, ortho, half, fov)| {
            let eye = w3d_core::rig::orbit_position(az.to_radians(), el.to_radians(), d);
            let projection = if ortho {
                Projection::Orthographic { half_height: half }
            } else {
                Projection::Perspective { fov_y: fov }
            };
            Camera::look_at(eye, Vec3::new(0.1, -0.05, 0.02), Vec3::Y, projection).unwrap()
        },
    )
}

proptest! {
    #[test]
    fn project_unproject_round_trip(cam in camera_strategy(), px in 0.0f32..320.0, py in 0.0f32..200.0, depth in 0.1f32..6.0) {
        let (w, h) = (320, 200);
        let world = cam.unproject(px, py, depth, w, h);
        let back = cam.project(world, w, h);
        prop_assert!((back.x - px).abs() < 2e-3 && (back.y - py).abs() < 2e-3, "{back:?} vs ({px}, {py})");
        prop_assert!((back.z - depth).abs() < 1e-4 * depth.max(1.0));
        prop_assert!((cam.depth(world) - depth).abs() < 1e-4 * depth.max(1.0));
        // The ray through the pixel passes through the unprojected point.
        let ray = cam.ray(px, py, w, h);
        let t = (world - ray.origin).dot(ray.direction);
        prop_assert!((ray.origin + t * ray.direction - world).length() < 1e-4 * depth.max(1.0));
        // Camera and world transforms are inverse rigid motions.
        let round = cam.camera_to_world().transform_point3(cam.world_to_camera().transform_point3(world));
        prop_assert!((round - world).length() < 1e-4 * world.length().max(1.0));
        prop_assert!((cam.to_camera(world) - cam.world_to_camera().transform_point3(world)).length() < 1e-4 * depth.max(1.0));
    }

    #[test]
    fn normalize_unit_cube_properties(points in prop::collection::vec(prop::array::uniform3(-50.0f32..50.0), 3..40), scale in 0.01f32..100.0) {
        let positions: Vec<[f32; 3]> = points.iter().map(|p| p.map(|v| v * scale)).collect();
        let triangles: Vec<[u32; 3]> = (0..positions.len() as u32 - 2).map(|i| [i, i + 1, i + 2]).collect();
        let mut mesh = Mesh::new(positions.clone(), triangles).unwrap();
        let (lo0, hi0) = mesh.bbox();
        prop_assume!((hi0 - lo0).max_element() > 1e-3);
        let t = mesh.normalize_unit_cube();
        let (lo, hi) = mesh.bbox();
        prop_assert!(((hi - lo).max_element() - 1.0).abs() < 1e-5);
        prop_assert!(((lo + hi) * 0.5).abs().max_element() < 1e-5);
        prop_assert!(lo.min_element() >= -0.5 - 1e-5 && hi.max_element() <= 0.5 + 1e-5);
        // The transform is the one applied, and it inverts.
        for (p, q) in positions.iter().zip(mesh.positions()) {
            let (p, q) = (Vec3::from(*p), Vec3::from(*q));
            prop_assert!((t.apply(p) - q).length() < 1e-5);
            prop_assert!((t.invert(q) - p).length() < 1e-4 * p.length().max(1.0));
        }
        // Idempotent.
        let again = mesh.normalize_unit_cube();
        prop_assert!((again.scale - 1.0).abs() < 1e-4 && again.centre.length() < 1e-5);
    }
}
