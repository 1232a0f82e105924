//! `RemeshOptions::curvature_tolerance`: on spheres, whose normal curvature is `1 / r`
//! everywhere, remeshing settles the edges near the chord-error length `√(8 · tol · r)` —
//! shorter on the small sphere, longer on the large one — where the speed controller alone
//! leaves them at its own length whatever the radius. A curvature hint
//! (`MeshOptimizer::set_curvature_hint`) replaces the mesh's curvature or bounds it from below.

use glam::Vec3;
use w3d_remesh::{CurvatureHint, MeshOptimizer, RemeshOptions, icosphere};

/// Mean edge length after `rounds` steps (zero gradient) and remeshes of a sphere of
/// radius `r`.
fn mean_edge_after(r: f32, tolerance: Option<f32>, rounds: usize) -> f32 {
    mean_edge_after_with_hint(r, tolerance, rounds, None)
}

/// [`mean_edge_after`] with the same curvature hint `hint` on every vertex before each step.
fn mean_edge_after_with_hint(r: f32, tolerance: Option<f32>, rounds: usize, hint: Option<CurvatureHint>) -> f32 {
    // Gain 0: the speed controller keeps every target length at the upper limit.
    let options =
        RemeshOptions::default().with_edge_len_lims((0.004, 0.12)).with_gain(0.0).with_curvature_tolerance(tolerance);
    let mut opt = MeshOptimizer::from_mesh(&icosphere(3, r).unwrap(), options).unwrap();
    for _ in 0..rounds {
        if let Some(h) = hint {
            opt.set_curvature_hint(vec![h; opt.vertex_count()]).unwrap();
        }
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

#[test]
fn a_curvature_hint_sizes_the_edges_instead_of_the_mesh() {
    let (tolerance, r) = (0.0005f32, 1.0f32);
    let own = mean_edge_after(r, Some(tolerance), 20);
    // A curvature of 4 (a sphere of radius 0.25) on the sphere of radius 1: the edges settle
    // near the small sphere's length, half the large one's; as a floor under the mesh's
    // curvature (1) it decides too.
    let bound = (8.0 * tolerance / 4.0).sqrt();
    for hint in [CurvatureHint::Replace(4.0), CurvatureHint::AtLeast(4.0)] {
        let hinted = mean_edge_after_with_hint(r, Some(tolerance), 20, Some(hint));
        assert!((0.7 * bound..=1.25 * bound).contains(&hinted), "{hint:?}: mean edge {hinted}, bound {bound}");
        assert!(own > 1.6 * hinted, "own curvature {own}, {hint:?} {hinted}");
    }
    // A floor below the mesh's curvature, or no hint, is the run without a hint; replacing
    // it by a smaller curvature lengthens the edges.
    for hint in [CurvatureHint::Mesh, CurvatureHint::AtLeast(0.25)] {
        assert_eq!(mean_edge_after_with_hint(r, Some(tolerance), 20, Some(hint)), own, "{hint:?}");
    }
    assert!(mean_edge_after_with_hint(r, Some(tolerance), 20, Some(CurvatureHint::Replace(0.25))) > 1.2 * own);
}

#[test]
fn a_bad_curvature_hint_is_refused_by_name() {
    let options = RemeshOptions::default().with_curvature_tolerance(Some(0.001));
    let mut opt = MeshOptimizer::from_mesh(&icosphere(1, 0.5).unwrap(), options).unwrap();
    let n = opt.vertex_count();
    let err = opt.set_curvature_hint(vec![CurvatureHint::Mesh; n - 1]).unwrap_err().to_string();
    assert!(err.contains("curvature") && err.contains(&n.to_string()), "{err}");
    for (i, bad) in [
        (3, CurvatureHint::Replace(-1.0)),
        (5, CurvatureHint::AtLeast(f32::INFINITY)),
        (0, CurvatureHint::Replace(f32::NAN)),
    ] {
        let mut hints = vec![CurvatureHint::Replace(1.0); n];
        hints[i] = bad;
        let err = opt.set_curvature_hint(hints).unwrap_err().to_string();
        assert!(err.contains(&format!("curvature[{i}]")), "{err}");
    }
}
