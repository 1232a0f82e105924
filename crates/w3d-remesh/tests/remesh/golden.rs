//! Golden cases ported from the reference implementation's unit tests (reference part A
//! and F), on the same small inputs, plus the optimizer arithmetic of F.

use crate::common;

use approx::assert_abs_diff_eq;
use common::{canonical, grid, signed_areas_z};
use w3d_remesh::ops::{self, RemeshParams};
use w3d_remesh::{EdgeTable, MeshOptimizer, NONE, RemeshOptions, icosphere};

/// The reference's two-triangle square (1-based `[1,2,3], [0,0,0], [2,4,3]` with a deleted
/// middle face), 0-based.
fn square() -> (Vec<[f32; 3]>, Vec<[u32; 3]>, Vec<bool>) {
    let positions = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]];
    let faces = vec![[0, 1, 2], [0, 0, 0], [1, 3, 2]];
    (positions, faces, vec![true, false, true])
}

#[test]
fn edge_table() {
    let (positions, faces, alive) = square();
    let table = EdgeTable::new(&faces, Some(&alive), 4);
    assert_eq!(table.edges, vec![[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]]);
    assert_eq!(table.face_to_edge, vec![[0, 2, 1], [NONE; 3], [3, 4, 2]]);
    // (face, side) pairs as half-edge ids 3·face + side; left traverses lo → hi.
    assert_eq!(table.edge_to_face, vec![[0, NONE], [NONE, 2], [1, 3 * 2 + 2], [3 * 2, NONE], [NONE, 3 * 2 + 1]]);
    let lengths = table.lengths(&positions);
    for (l, e) in lengths.iter().zip([1.0, 1.0, 2f32.sqrt(), 1.0, 1.0]) {
        assert_abs_diff_eq!(*l, e, epsilon = 1e-6);
    }
    assert_eq!(table.find(2, 1), Some(2));
    assert_eq!(table.find(0, 3), None);
    assert_eq!(table.boundary_count(), 4);
}

#[test]
fn collapse_single() {
    let (mut positions, mut faces, mut alive) = square();
    let table = EdgeTable::new(&faces, Some(&alive), 4);
    assert_eq!(table.edges[4], [2, 3]);
    let mut priority = vec![0.0; table.edges.len()];
    priority[4] = 1.0;
    let n = ops::collapse_edges(&mut positions, &mut faces, &mut alive, &table, &priority, 3);
    assert_eq!(n, 1);
    assert_eq!(&positions[..3], &[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 1.0, 0.0]]);
    assert_eq!(alive, vec![true, false, false]);
    assert_eq!(faces[0], [0, 1, 2]);
}

#[test]
fn collapse_respects_link_condition() {
    // A 3 × 2 grid wrapped into a cylinder of circumference 3 (column 3 glued to column 0):
    // the ring edges at y = 1 share a third neighbour, so they may not collapse.
    let (mut positions, faces) = grid(&[vec![false; 3], vec![false; 3]]);
    let mut faces: Vec<[u32; 3]> = faces.iter().map(|t| t.map(|v| if v % 4 == 3 { v - 3 } else { v })).collect();
    let mut alive = vec![true; faces.len()];
    let table = EdgeTable::new(&faces, Some(&alive), positions.len());
    let [a, b] = table.edges[9];
    assert!(positions[a as usize][1] == 1.0 && positions[b as usize][1] == 1.0);
    let mut priority = vec![0.0; table.edges.len()];
    priority[9] = 1.0;
    let (before_p, before_f) = (positions.clone(), faces.clone());
    let n = ops::collapse_edges(&mut positions, &mut faces, &mut alive, &table, &priority, 3);
    assert_eq!(n, 0);
    assert_eq!(positions, before_p);
    assert_eq!(faces, before_f);
    assert!(alive.iter().all(|&a| a));
}

#[test]
fn split_edges_golden() {
    let mut positions = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0]];
    let mut faces = vec![[0, 1, 2], [0, 3, 1]];
    let mut alive = vec![true; 2];
    let table = EdgeTable::new(&faces, None, 4);
    assert_eq!(table.edges, vec![[0, 1], [0, 2], [0, 3], [1, 2], [1, 3]]);
    let split = [false, false, true, true, true];
    assert_eq!(ops::split_edges(&mut positions, &mut faces, &mut alive, &table, &split), 3);
    let faces = ops::pack(&mut positions, &faces, &alive);
    assert_eq!(&positions[4..], &[[0.0, -0.5, 0.0], [0.5, 0.5, 0.0], [0.5, -0.5, 0.0]]);
    assert_eq!(faces, vec![[0, 5, 2], [4, 6, 1], [1, 5, 0], [0, 4, 1], [3, 6, 4]]);
}

#[test]
fn pack_golden() {
    let mut positions = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [f32::NAN; 3], [0.0, 1.0, 0.0]];
    let faces = ops::pack(&mut positions, &[[0, 1, 3], [0, 0, 0]], &[true, false]);
    assert_eq!(positions, vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    assert_eq!(faces, vec![[0, 1, 2]]);
}

fn flip_pattern() -> Vec<Vec<bool>> {
    vec![vec![false, false, false], vec![false, true, true], vec![false, false, true]]
}

#[test]
fn flip_edges_simple() {
    let (positions, mut faces) = grid(&flip_pattern());
    let table = EdgeTable::new(&faces, None, positions.len());
    ops::flip_edges(&positions, &mut faces, &table, true, true);
    let (_, expected) = grid(&[vec![false, false, false], vec![false, false, true], vec![false, false, true]]);
    assert_eq!(canonical(&faces), canonical(&expected));
}

#[test]
fn flip_edges_normal_check() {
    let (mut positions, mut faces) = grid(&flip_pattern());
    positions[6] = [1.2, 1.8, 0.0];
    let before = faces.clone();
    let table = EdgeTable::new(&faces, None, positions.len());
    let flipped = ops::flip_edges(&positions, &mut faces, &table, true, true);
    assert!(flipped.is_empty());
    assert_eq!(faces, before);
}

#[test]
fn face_collapse_flags_flipped_and_small() {
    // A fan of 4 triangles around vertex 0 in the z = 0 plane; moving 0 far out flips one.
    let mut positions = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]];
    let faces = vec![[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]];
    let alive = vec![true; 4];
    let table = EdgeTable::new(&faces, None, 5);
    let exact = RemeshParams::default().with_shortest_probability(1.0);
    let tiny = vec![1e-3; 5];
    let flags = |positions: &[[f32; 3]], min_len: &[f32]| {
        let len = table.lengths(positions);
        ops::face_collapse_flags(positions, &faces, &alive, &table, &len, min_len, &exact, 7)
    };
    assert!(flags(&positions, &tiny).iter().all(|&f| !f));
    positions[0] = [0.8, 0.8, 0.0]; // face [0, 1, 2] is now clockwise
    assert!(signed_areas_z(&positions, &faces)[0] < 0.0);
    let flagged: Vec<[u32; 2]> =
        flags(&positions, &tiny).iter().zip(&table.edges).filter(|(f, _)| **f).map(|(_, e)| *e).collect();
    // Its shortest edge (0, 1) or (0, 2) — |(0.2, −0.8)| = |(−0.8, 0.2)|, the first wins.
    assert_eq!(flagged, vec![[0, 1]]);
    // Small faces: min length 1 → faces of area 0.5 are not small (0.5 · 1²), with 1.1 they are.
    positions[0] = [0.0, 0.0, 0.0];
    assert!(flags(&positions, &[1.0; 5]).iter().all(|&f| !f));
    let flagged = flags(&positions, &[1.1; 5]);
    // Each face picks its first shortest edge: the spokes (0, 1), (0, 2), (0, 3), (0, 4).
    let expected: Vec<bool> = table.edges.iter().map(|e| e[0] == 0).collect();
    assert_eq!(flagged, expected);
}

#[test]
fn face_collapse_flags_random_choice() {
    // One small triangle with three different edge lengths; p = 0.7 → randlim 7: shortest
    // with probability 5/7, middle and longest 1/7 each; exactly one edge per draw.
    let positions = vec![[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.0, 0.2, 0.0]];
    let faces = vec![[0, 1, 2]];
    let table = EdgeTable::new(&faces, None, 3);
    let len = table.lengths(&positions);
    let params = RemeshParams::default().with_shortest_probability(0.7);
    let mut counts = [0usize; 3];
    for seed in 0..3500u64 {
        let flags = ops::face_collapse_flags(&positions, &faces, &[true], &table, &len, &[1.0; 3], &params, seed);
        assert_eq!(flags.iter().filter(|&&f| f).count(), 1);
        counts[flags.iter().position(|&f| f).unwrap()] += 1;
    }
    // Edges (0,1) = 0.3 middle, (0,2) = 0.2 shortest, (1,2) = 0.36 longest.
    let expected = [500.0, 2500.0, 500.0];
    for (c, e) in counts.iter().zip(expected) {
        assert!((*c as f64 - e).abs() < 4.0 * (e * (1.0 - e / 3500.0)).sqrt(), "{counts:?}");
    }
    // Same seed, same choice.
    let a = ops::face_collapse_flags(&positions, &faces, &[true], &table, &len, &[1.0; 3], &params, 11);
    let b = ops::face_collapse_flags(&positions, &faces, &[true], &table, &len, &[1.0; 3], &params, 11);
    assert_eq!(a, b);
}

#[test]
fn optimizer_first_step_arithmetic() {
    let sphere = icosphere(1, 0.5).unwrap();
    let mut opt = MeshOptimizer::from_mesh(&sphere, RemeshOptions::default()).unwrap();
    let n = opt.vertex_count();
    let mut grad = vec![[0.0f32; 3]; n];
    grad[0] = [3.0, -4.0, 0.0]; // |g| = 5
    let before = opt.positions().to_vec();
    opt.step(&grad).unwrap();
    let moved = opt.positions()[0];
    // 0.3 (lr) · 0.2 (ramp at t = 1) · 0.15 (ref_len) = 0.009 along −g/|g|.
    assert_abs_diff_eq!(moved[0] - before[0][0], -0.009 * 0.6, epsilon = 1e-6);
    assert_abs_diff_eq!(moved[1] - before[0][1], 0.009 * 0.8, epsilon = 1e-6);
    assert_eq!(moved[2], before[0][2]);
    assert_eq!(opt.first_moments()[0], [3.0, -4.0, 0.0]);
    assert_abs_diff_eq!(opt.second_moments()[0], 25.0, epsilon = 1e-4);
    assert_abs_diff_eq!(opt.relative_speeds()[0], 1.0, epsilon = 1e-6);
    // nu = 1: 0.15 · 1.14 clamped to 0.15; nu = 0: 0.15 · 0.94 = 0.141.
    assert_eq!(opt.target_edge_lengths()[0], 0.15);
    assert_abs_diff_eq!(opt.target_edge_lengths()[1], 0.141, epsilon = 1e-6);
    assert_eq!(opt.positions()[1], before[1]);
}

#[test]
fn optimizer_learning_rate_ramp() {
    // Constant gradient, no Laplacian: |velocity| = 1, the step is lr · min(1, 0.2 t) · 0.15.
    let sphere = icosphere(1, 0.5).unwrap();
    let options = RemeshOptions::default().with_laplacian_weight(0.0);
    let mut opt = MeshOptimizer::from_mesh(&sphere, options).unwrap();
    let grad = vec![[0.0, 0.0, 1.0]; opt.vertex_count()];
    for t in 1..=7 {
        let z = opt.positions()[0][2];
        opt.step(&grad).unwrap();
        let expected = 0.3 * (0.2 * t as f32).min(1.0) * 0.15;
        assert_abs_diff_eq!(z - opt.positions()[0][2], expected, epsilon = 1e-6);
    }
}

#[test]
fn step_rejects_bad_gradients() {
    let sphere = icosphere(0, 0.5).unwrap();
    let mut opt = MeshOptimizer::from_mesh(&sphere, RemeshOptions::default()).unwrap();
    let err = opt.step(&[[0.0; 3]; 3]).unwrap_err().to_string();
    assert!(err.contains("grad") && err.contains("12"), "{err}");
    let mut grad = vec![[0.0; 3]; 12];
    grad[4][1] = f32::NAN;
    let err = opt.step(&grad).unwrap_err().to_string();
    assert!(err.contains("grad[4].y"), "{err}");
    assert_eq!(opt.step_count(), 0);
}

#[test]
fn new_rejects_bad_meshes() {
    let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let o = RemeshOptions::default();
    // Inconsistent orientation.
    let err = MeshOptimizer::new(p.clone(), vec![[0, 1, 2], [0, 1, 3]], o).unwrap_err().to_string();
    assert!(err.contains("opposite directions"), "{err}");
    // Unused vertex.
    let err = MeshOptimizer::new(p.clone(), vec![[0, 1, 2]], o).unwrap_err().to_string();
    assert!(err.contains("unused"), "{err}");
    // Two fans at one vertex (bow tie).
    let p6 = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [-1.0, -1.0, 0.0]];
    let err = MeshOptimizer::new(p6, vec![[0, 1, 2], [0, 3, 4]], o).unwrap_err().to_string();
    assert!(err.contains("vertex 0"), "{err}");
    // Bad options.
    let bad = o.with_edge_len_lims((0.2, 0.1));
    let err = MeshOptimizer::new(p, vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], bad).unwrap_err().to_string();
    assert!(err.contains("edge_len_lims"), "{err}");
}
