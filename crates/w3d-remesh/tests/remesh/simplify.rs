//! Quadric simplification: the surface stays within a few tolerances of the original, the
//! topology and orientation survive, flat parts lose their vertices and curved ones keep
//! them, boundaries stay put, and bad options are refused.

use crate::common;

use common::{ClosestPoints, flipped_faces, load_unit, samples};
use glam::Vec3;
use w3d_core::Mesh;
use w3d_remesh::{SimplifyOptions, check_manifold, geodesic_sphere, simplify, simplify_keeping};

/// The largest distance from the vertices and face centroids of `mesh` to the surface of
/// `reference`, and back.
fn two_sided_distance(mesh: &Mesh, reference: &Mesh) -> f32 {
    let one_way = |from: &Mesh, to: &Mesh| {
        let index = ClosestPoints::new(to.positions(), to.triangles());
        samples(from.positions(), from.triangles())
            .into_iter()
            .map(|p| (index.query(p).0 - p).length())
            .fold(0.0f32, f32::max)
    };
    one_way(mesh, reference).max(one_way(reference, mesh))
}

/// The checks every simplified closed mesh must pass: a consistently oriented closed
/// 2-manifold of the original genus, no flipped or crossing triangles.
fn assert_clean(simple: &Mesh, original: &Mesh) {
    let before = check_manifold(original.vertex_count(), original.triangles()).unwrap();
    let after = check_manifold(simple.vertex_count(), simple.triangles()).unwrap();
    assert!(after.is_closed());
    assert_eq!(after.genus(), before.genus());
    assert_eq!(after.components, before.components);
    assert_eq!(after.unreferenced, 0);
    assert!(!flipped_faces(simple.positions(), simple.triangles()).contains(&true));
    assert!(simple.self_intersections().is_empty(), "{:?}", simple.self_intersections());
}

#[test]
fn a_sphere_keeps_its_radius_within_the_tolerance() {
    let sphere = geodesic_sphere(32, 0.5).unwrap();
    let (simple, report) = simplify(&sphere, &SimplifyOptions::default().with_tolerance(0.001)).unwrap();
    assert_clean(&simple, &sphere);
    assert_eq!(report.triangles_before, sphere.triangle_count());
    assert_eq!(report.triangles_after, simple.triangle_count());
    assert_eq!(report.triangles_before - report.triangles_after, 2 * report.collapses);
    assert!(report.triangles_after < report.triangles_before / 3, "{report:?}");
    assert!(report.max_error > 0.0 && report.max_error <= 0.001, "{report:?}");
    // Every vertex stays within a few tolerances of the sphere, and so does the surface.
    let worst = simple.positions().iter().map(|p| (Vec3::from(*p).length() - 0.5).abs()).fold(0.0f32, f32::max);
    assert!(worst < 0.003, "vertex off the sphere by {worst}");
    assert!(two_sided_distance(&simple, &sphere) < 0.004);
}

#[test]
fn a_larger_tolerance_removes_more_and_zero_removes_nothing_on_a_curved_surface() {
    let sphere = geodesic_sphere(16, 0.5).unwrap();
    let counts: Vec<usize> = [0.0, 0.0005, 0.002, 0.008]
        .iter()
        .map(|&t| simplify(&sphere, &SimplifyOptions::default().with_tolerance(t)).unwrap().1.triangles_after)
        .collect();
    assert_eq!(counts[0], sphere.triangle_count(), "no vertex of a sphere is in a plane");
    assert!(counts.windows(2).all(|w| w[1] < w[0]), "{counts:?}");
}

#[test]
fn flat_parts_lose_their_vertices_and_curved_parts_keep_them() {
    // A sphere squashed into a lens: two flat caps joined by a curved band.
    let mut lens = geodesic_sphere(24, 0.5).unwrap();
    lens.map_positions(|p| Vec3::new(p.x, p.y.clamp(-0.2, 0.2), p.z)).unwrap();
    let (simple, _) = simplify(&lens, &SimplifyOptions::default().with_tolerance(0.0005)).unwrap();
    assert_clean(&simple, &lens);
    let on_caps = |m: &Mesh| m.positions().iter().filter(|p| p[1].abs() > 0.2 - 1e-6).count() as f64;
    let band = |m: &Mesh| m.positions().iter().filter(|p| p[1].abs() < 0.15).count() as f64;
    let caps_kept = on_caps(&simple) / on_caps(&lens);
    let band_kept = band(&simple) / band(&lens);
    assert!(caps_kept < 0.1, "caps keep {caps_kept}");
    assert!(band_kept > 3.0 * caps_kept, "band keeps {band_kept}, caps {caps_kept}");
    assert!(two_sided_distance(&simple, &lens) < 0.003);
}

#[test]
fn real_meshes_stay_clean_and_close() {
    for name in ["spot.obj", "torus.obj", "armadillo.obj"] {
        let mesh = load_unit(name);
        let (simple, report) = simplify(&mesh, &SimplifyOptions::default().with_tolerance(0.001)).unwrap();
        assert_clean(&simple, &mesh);
        assert!(report.triangles_after < report.triangles_before, "{name}: {report:?}");
        let d = two_sided_distance(&simple, &mesh);
        assert!(d < 0.01, "{name}: surface moved by {d}");
    }
}

#[test]
fn boundary_vertices_never_move() {
    // A flat 8 × 8 grid: every interior vertex lies in the plane and may go, the boundary
    // stays exactly where it was.
    let (positions, faces) = common::grid(&vec![vec![false; 8]; 8]);
    let grid = Mesh::new(positions.clone(), faces).unwrap();
    let (simple, report) = simplify(&grid, &SimplifyOptions::default().with_tolerance(0.0)).unwrap();
    assert!(report.collapses > 0);
    let boundary: Vec<[f32; 3]> =
        positions.iter().copied().filter(|p| p[0] == 0.0 || p[1] == 0.0 || p[0] == 8.0 || p[1] == 8.0).collect();
    for p in &boundary {
        assert!(simple.positions().contains(p), "boundary vertex {p:?} moved");
    }
    let area = |m: &Mesh| m.surface_area();
    assert!((area(&simple) - 64.0).abs() < 1e-4);
    assert!(!flipped_faces(simple.positions(), simple.triangles()).contains(&true));
}

#[test]
fn kept_vertices_stay_and_every_vertex_names_its_source() {
    let sphere = geodesic_sphere(16, 0.5).unwrap();
    // Keep the northern cap (y > 0.3) exactly as it is.
    let keep: Vec<bool> = sphere.positions().iter().map(|p| p[1] > 0.3).collect();
    let options = SimplifyOptions::default().with_tolerance(0.004);
    let free = simplify(&sphere, &options).unwrap().1;
    let kept = simplify_keeping(&sphere, &options, &keep).unwrap();
    assert_clean(&kept.mesh, &sphere);
    assert!(kept.report.triangles_after > free.triangles_after, "{:?} vs {free:?}", kept.report);
    assert_eq!(kept.source_vertex.len(), kept.mesh.vertex_count());
    for (p, &source) in kept.mesh.positions().iter().zip(&kept.source_vertex) {
        // A kept vertex is where it was; any other vertex came from one that was not kept
        // or stayed in place.
        if keep[source as usize] {
            assert_eq!(*p, sphere.positions()[source as usize]);
        }
    }
    let kept_count = keep.iter().filter(|&&k| k).count();
    let survivors = kept.source_vertex.iter().filter(|&&s| keep[s as usize]).count();
    assert_eq!(survivors, kept_count, "every kept vertex survives");
    // A short mask counts as false beyond its end.
    let short = simplify_keeping(&sphere, &options, &keep[..10]).unwrap();
    assert!(short.report.triangles_after <= kept.report.triangles_after);
}

#[test]
fn min_triangles_is_respected() {
    let sphere = geodesic_sphere(8, 0.5).unwrap();
    let (simple, _) =
        simplify(&sphere, &SimplifyOptions::default().with_tolerance(1.0).with_min_triangles(100)).unwrap();
    assert!(simple.triangle_count() >= 100, "{}", simple.triangle_count());
    assert_clean(&simple, &sphere);
}

#[test]
fn options_out_of_range_are_refused() {
    let sphere = geodesic_sphere(2, 0.5).unwrap();
    for (options, field) in [
        (SimplifyOptions::default().with_tolerance(-1.0), "tolerance"),
        (SimplifyOptions::default().with_tolerance(f32::NAN), "tolerance"),
        (SimplifyOptions::default().with_max_normal_turn_deg(0.0), "max_normal_turn_deg"),
        (SimplifyOptions::default().with_min_quality(1.0), "min_quality"),
    ] {
        let err = simplify(&sphere, &options).unwrap_err().to_string();
        assert!(err.contains(field), "{err}");
    }
}
