//! Finite-difference gradient checks of every backward pass on random small meshes
//! (proptest) and on spot, in f64 with the coverage held fixed.

use glam::Vec3;
use proptest::prelude::*;
use w3d_core::{Camera, Mesh, Projection, ViewRig};

use crate::antialias::tests::check_antialias;
use crate::interpolate::tests::check_interpolate;
use crate::raster::tests::check_backward;

/// Relative error bound of the acceptance criteria.
const TOLERANCE: f64 = 1e-3;

/// A random "crumpled sheet": a 3×3 grid of quads with jittered vertices.
fn sheet(jitter: &[f32]) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let n = 3;
    let mut positions = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let k = 3 * (j * (n + 1) + i);
            let (x, y) = (i as f32 / n as f32 - 0.5, j as f32 / n as f32 - 0.5);
            positions.push([x + 0.1 * jitter[k], y + 0.1 * jitter[k + 1], 0.3 * jitter[k + 2]]);
        }
    }
    let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    let mut tris = Vec::new();
    for j in 0..n {
        for i in 0..n {
            tris.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            tris.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    (positions, tris)
}

fn camera(azimuth: f32, elevation: f32, perspective: bool) -> Camera {
    let eye = 2.0 * Vec3::new(elevation.cos() * azimuth.sin(), elevation.sin(), elevation.cos() * azimuth.cos());
    let projection = if perspective {
        Projection::Perspective { fov_y: 0.9 }
    } else {
        Projection::Orthographic { half_height: 0.8 }
    };
    Camera::look_at(eye, Vec3::ZERO, Vec3::Y, projection).unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 8, ..ProptestConfig::default() })]

    #[test]
    fn random_meshes_pass_gradient_checks(
        jitter in proptest::collection::vec(-1.0f32..1.0, 48),
        azimuth in -0.6f32..0.6,
        elevation in -0.5f32..0.5,
        perspective: bool,
        seed: u64,
    ) {
        let (positions, tris) = sheet(&jitter);
        let cam = camera(azimuth, elevation, perspective);
        let all: Vec<usize> = (0..positions.len()).collect();
        let e_raster = check_backward(&positions, &tris, &cam, 24, seed, &all);
        let e_interp = check_interpolate(&positions, &tris, &cam, 24, seed, &all);
        let e_aa = check_antialias(&positions, &tris, &cam, 24, seed, &all);
        prop_assert!(e_raster < TOLERANCE, "rasterize: {}", e_raster);
        prop_assert!(e_interp < TOLERANCE, "interpolate: {}", e_interp);
        prop_assert!(e_aa < TOLERANCE, "antialias: {}", e_aa);
    }
}

#[test]
fn spot_passes_gradient_checks() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared/data/meshes/spot.obj");
    let mut mesh: Mesh = w3d_core::load_mesh(path).unwrap();
    mesh.normalize_unit_cube();
    let (positions, tris) = (mesh.positions(), mesh.triangles());
    // Every 23rd vertex: a spread-out subset (the full check would take minutes).
    let subset: Vec<usize> = (0..positions.len()).step_by(23).collect();
    for rig in [ViewRig::wonder3d_ortho(), ViewRig::wonder3d_persp()] {
        let cam = &rig.views[1].camera;
        let e_raster = check_backward(positions, tris, cam, 64, 1, &subset);
        let e_interp = check_interpolate(positions, tris, cam, 64, 2, &subset);
        let e_aa = check_antialias(positions, tris, cam, 64, 3, &subset);
        println!("spot {}: rasterize {e_raster:.2e}, interpolate {e_interp:.2e}, antialias {e_aa:.2e}", rig.name);
        assert!(e_raster < TOLERANCE && e_interp < TOLERANCE && e_aa < TOLERANCE);
    }
}
