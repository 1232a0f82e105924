//! `RemeshOptions::curvature_tolerance`: on spheres, whose normal curvature is `1 / r`
//! everywhere, remeshing settles the edges near the chord-error length `√(8 · tol · r)` —
//! shorter on the small sphere, longer on the large one — where the speed controller alone
//! leaves them at its own length whatever the radius.

use glam::Vec3;
use w3d_remesh::{MeshOptimizer, RemeshOptions, icosphere};

/// Mean edge length after `rounds` steps (zero gradient) and remeshes of a sphere of
/// radius `r`.
fn mean_edge_after(r: f32, tolerance: Option<f32>, rounds: usize) -> f32 {
    // Gain 0: the speed controller keeps every target length at the upper limit.
    let options =
        RemeshOptions::default().with_edge_len_lims((0.004, 0.12)).with_gain(0.0).with_curvature_tolerance(tolerance);
    let mut opt = MeshOptimizer::from_mesh(&icosphere(3, r).unwrap(), options).unwrap();
    for _ in 0..rounds {
        opt.step(&vec![[0.0; 3]; opt.vertex_count()]).unwrap();
        opt.remesh();
    }
    let p = opt.positions();
    let lengths: Vec<f32> =
        opt.edges().iter().map(|&[a, b]| Vec3::from(p[a as usize]).distance(Vec3::from(p[b as usize]))).collect();
    lengths.iter().sum::<f32>() / lengths.len() as f32
}

#[test]
fn edges_follow_the_curvature_bound() {
    let tolerance = 0.0005;
    // The icosphere's edges start at 0.033 (r 0.25) and 0.131 (r 1): the bound has to keep
    // the first and split the second, where the controller alone coarsens the first.
    for r in [0.25f32, 1.0] {
        let bound = (8.0 * tolerance * r).sqrt(); // 0.032 and 0.063
        let capped = mean_edge_after(r, Some(tolerance), 20);
        assert!((0.7 * bound..=1.25 * bound).contains(&capped), "r {r}: mean edge {capped}, bound {bound}");
        let free = mean_edge_after(r, None, 20);
        assert!(free > 1.4 * capped, "r {r}: without the bound {free}, with it {capped}");
    }
}

#[test]
fn a_non_positive_tolerance_is_refused() {
    for bad in [0.0, -1.0, f32::NAN] {
        let options = RemeshOptions::default().with_curvature_tolerance(Some(bad));
        let err = MeshOptimizer::from_mesh(&icosphere(1, 0.5).unwrap(), options).unwrap_err().to_string();
        assert!(err.contains("curvature_tolerance"), "{err}");
    }
}
