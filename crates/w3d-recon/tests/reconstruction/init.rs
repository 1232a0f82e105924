//! The geometric initialisation on oracle views of real meshes: a closed start mesh close
//! to the object, the concave check firing for a cup that opens towards the camera and not
//! for convex objects, and the perspective rig.

use w3d_core::{Mesh, ViewRig};

use crate::common::{shared_mesh, spot};
use w3d_eval::{EvalOptions, evaluate};
use w3d_recon::{InitChoice, InitOptions, initial_mesh};

#[test]
fn poisson_start_is_closed_and_close_to_spot() {
    let truth = spot();
    for rig in [ViewRig::wonder3d_ortho(), ViewRig::wonder3d_persp()] {
        let views = w3d_raster::render_oracle_views(&truth, &rig, 128).unwrap();
        let (mesh, report) = initial_mesh(&views, &InitOptions::default()).unwrap();
        assert_eq!(report.choice, InitChoice::Poisson, "{}: {}", rig.name, report.reason);
        let topology = mesh.topology();
        assert!(topology.is_watertight(), "{}: {topology:?}", rig.name);
        assert_eq!(topology.genus(), Some(0), "{}", rig.name);
        let m = evaluate(&mesh, &truth, &EvalOptions::default().with_samples(20_000)).unwrap();
        eprintln!(
            "{}: init {} triangles, CD {:.4}, IoU {:.3}, {:.2} s",
            rig.name, report.triangles, m.chamfer, m.iou_64, report.seconds
        );
        assert!(m.chamfer < 0.03 && m.iou_64 > 0.75, "{}: {m:?}", rig.name);
    }
}

/// A closed bowl (outer radius 0.45, inner 0.38, a flat rim) opening towards +z: the
/// profile polyline revolved about the z axis.
fn bowl() -> Mesh {
    let segments = 48;
    let mut profile: Vec<(f32, f32)> = Vec::new(); // (radius, z), pole to pole
    let arc = 12;
    for i in 0..=arc {
        let a = std::f32::consts::FRAC_PI_2 * i as f32 / arc as f32; // 0 at the bottom pole
        profile.push((0.45 * a.sin(), -0.45 * a.cos()));
    }
    for i in (0..=arc).rev() {
        let a = std::f32::consts::FRAC_PI_2 * i as f32 / arc as f32;
        profile.push((0.38 * a.sin(), -0.38 * a.cos()));
    }
    // Vertices: the two poles (profile ends) once, every other profile point per segment.
    let mut positions = vec![[0.0, 0.0, profile[0].1], [0.0, 0.0, profile[profile.len() - 1].1]];
    let ring = profile.len() - 2;
    for s in 0..segments {
        let t = std::f32::consts::TAU * s as f32 / segments as f32;
        for &(r, z) in &profile[1..profile.len() - 1] {
            positions.push([r * t.cos(), r * t.sin(), z]);
        }
    }
    let at = |s: usize, k: usize| (2 + (s % segments) * ring + k) as u32;
    let mut triangles = Vec::new();
    for s in 0..segments {
        triangles.push([0, at(s + 1, 0), at(s, 0)]);
        triangles.push([1, at(s, ring - 1), at(s + 1, ring - 1)]);
        for k in 0..ring - 1 {
            triangles.push([at(s, k), at(s + 1, k), at(s + 1, k + 1)]);
            triangles.push([at(s, k), at(s + 1, k + 1), at(s, k + 1)]);
        }
    }
    let mut mesh = Mesh::new(positions, triangles).unwrap();
    if mesh.signed_volume() < 0.0 {
        mesh.flip_winding();
    }
    mesh
}

#[test]
fn concave_check_fires_for_a_bowl_facing_the_camera_only() {
    let rig = ViewRig::wonder3d_ortho();
    let report = |mesh: &Mesh| {
        let views = w3d_raster::render_oracle_views(mesh, &rig, 128).unwrap();
        let (_, report) = initial_mesh(&views, &InitOptions::default()).unwrap();
        eprintln!("{:?}: {}", report.choice, report.reason);
        report
    };
    let bowl = bowl();
    assert!(bowl.topology().is_watertight());
    let facing = report(&bowl);
    assert_eq!(facing.choice, InitChoice::Sphere);
    assert!(facing.front_concavity.unwrap() > InitOptions::default().concave_margin);
    // Seen from the side a bowl is convex; the hammer seen along its handle and the
    // armadillo's forward arms are stepped, not concave (the paper's depth rule alone fires).
    let mut side = bowl.clone();
    side.map_positions(|p| glam::Vec3::new(p.x, p.z, -p.y)).unwrap();
    assert_eq!(report(&side).choice, InitChoice::Poisson);
    for name in ["hammer.obj", "armadillo.obj"] {
        let r = report(&shared_mesh(name));
        assert_eq!(r.choice, InitChoice::Poisson, "{name}: {}", r.reason);
    }
    let r = report(&spot());
    assert_eq!(r.choice, InitChoice::Poisson);
    assert!(r.front_concavity.unwrap() < 0.0 && r.back_concavity.unwrap() < 0.0);
}

#[test]
fn bad_options_are_rejected() {
    let truth = spot();
    let rig = ViewRig::wonder3d_ortho();
    let views = w3d_raster::render_oracle_views(&truth, &rig, 64).unwrap();
    let err = initial_mesh(&views, &InitOptions::default().with_grid(4)).unwrap_err();
    assert!(err.to_string().contains("grid"), "{err}");
    let err = initial_mesh(&views, &InitOptions::default().with_edge_length(0.0)).unwrap_err();
    assert!(err.to_string().contains("edge_length"), "{err}");
    for margin in [-0.1, 1.0, f32::NAN] {
        let err = initial_mesh(&views, &InitOptions::default().with_hull_alternative_margin(margin)).unwrap_err();
        assert!(err.to_string().contains("hull_alternative_margin"), "{err}");
    }
}
