//! Shape test: from an icosphere, minimise a two-sided squared distance to spot's surface
//! (mesh vertices → closest point on spot, spot samples → nearest mesh vertex) for 300
//! step + remesh rounds; the result must lie within a mean two-sided distance of 0.01
//! (unit-cube units), have no flipped faces, and keep every edge within the limits
//! `[lo·(1 − tol), hi·(1 + tol)]` after the last remesh.

use crate::common;

use common::{ClosestPoints, flipped_faces, load_unit, samples};
use glam::Vec3;
use w3d_remesh::{MeshOptimizer, RemeshOptions, check_manifold, icosphere};

#[test]
fn icosphere_fits_spot() {
    let spot = load_unit("spot.obj");
    let target = ClosestPoints::new(spot.positions(), spot.triangles());
    let target_samples = samples(spot.positions(), spot.triangles());
    // The lower limit stands in for a pixel footprint (0.02 ≈ 3.4 px of a 1.5-unit view at
    // 256²) and keeps the test small; everything else is the default.
    let options = RemeshOptions::default().with_edge_len_lims((0.02, 0.15));
    let mut opt = MeshOptimizer::from_mesh(&icosphere(3, 0.4).unwrap(), options).unwrap();
    let started = std::time::Instant::now();
    let (mut floor_passes, mut left_short) = (0, Vec::new());
    let floor = options.edge_len_lims.0 * (1.0 - options.edge_len_tol);
    for _ in 0..300 {
        let positions: Vec<Vec3> = opt.positions().iter().map(|&p| Vec3::from(p)).collect();
        let mut grad: Vec<Vec3> = positions.iter().map(|&x| x - target.query(x).0).collect();
        let nearest = ClosestPoints::points(&positions);
        for &p in &target_samples {
            let (q, v) = nearest.query(p);
            grad[v] += q - p;
        }
        let grad: Vec<[f32; 3]> = grad.iter().map(|g| (2.0 * *g).to_array()).collect();
        opt.step(&grad).unwrap();
        floor_passes += opt.remesh().floor_passes;
        let p = opt.positions();
        let short = opt
            .edges()
            .iter()
            .filter(|&&[a, b]| (Vec3::from(p[a as usize]) - Vec3::from(p[b as usize])).length() < floor)
            .count();
        left_short.push(short);
    }
    let (lo, hi) = options.edge_len_lims;
    let tol = options.edge_len_tol;
    let edge_range = |opt: &MeshOptimizer| {
        let p = opt.positions();
        opt.edges()
            .iter()
            .map(|&[a, b]| (Vec3::from(p[a as usize]) - Vec3::from(p[b as usize])).length())
            .fold((f32::INFINITY, 0.0f32), |(s, l), x| (s.min(x), l.max(x)))
    };
    let summary = check_manifold(opt.vertex_count(), opt.triangles()).unwrap();
    assert_eq!((summary.is_closed(), summary.genus()), (true, Some(0)));

    let fitted = ClosestPoints::new(opt.positions(), opt.triangles());
    let ours = samples(opt.positions(), opt.triangles());
    let to_spot = ours.iter().map(|&p| (target.query(p).0 - p).length()).sum::<f32>() / ours.len() as f32;
    let to_ours =
        target_samples.iter().map(|&p| (fitted.query(p).0 - p).length()).sum::<f32>() / target_samples.len() as f32;
    let (shortest, longest) = edge_range(&opt);
    let ref_range = opt.target_edge_lengths().iter().fold((f32::INFINITY, 0.0f32), |(s, l), &x| (s.min(x), l.max(x)));
    println!(
        "spot fit: {} vertices, mean distance mesh→spot {to_spot:.5}, spot→mesh {to_ours:.5}, \
         edges [{shortest:.4}, {longest:.4}], ref_len [{:.4}, {:.4}], {:.1} s",
        opt.vertex_count(),
        ref_range.0,
        ref_range.1,
        started.elapsed().as_secs_f32()
    );
    assert!(0.5 * (to_spot + to_ours) <= 0.01, "two-sided mean distance {}", 0.5 * (to_spot + to_ours));
    assert!(to_spot <= 0.01 && to_ours <= 0.01, "{to_spot} {to_ours}");
    assert!(ref_range.0 >= lo && ref_range.1 <= hi);
    let flipped = flipped_faces(opt.positions(), opt.triangles()).iter().filter(|&&f| f).count();
    println!(
        "{} triangles, {flipped} flipped; {floor_passes} floor passes in 300 remeshes; remeshes leaving edges \
         below the floor: {} (at most {} edges)",
        opt.triangle_count(),
        left_short.iter().filter(|&&n| n > 0).count(),
        left_short.iter().max().unwrap()
    );
    assert_eq!(flipped, 0);
    // The floor passes leave no edge below the limit in (almost) every remesh, not only the last.
    assert!(left_short.iter().filter(|&&n| n > 0).count() <= 3, "{left_short:?}");
    assert!(shortest >= lo * (1.0 - tol), "shortest edge {shortest} below {}", lo * (1.0 - tol));
    assert!(longest <= hi * (1.0 + tol), "longest edge {longest}");
}
