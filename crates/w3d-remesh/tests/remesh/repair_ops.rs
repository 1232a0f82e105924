//! The two remesh steps that are not in the reference: valence-3 vertex removal and fold
//! relaxation, on small hand-made meshes.

use crate::common;

use common::{canonical, face_normal, flipped_faces, grid};
use glam::Vec3;
use w3d_remesh::{EdgeTable, check_manifold, ops};

/// The octahedron `±x, ±y, ±z`, counter-clockwise seen from outside.
fn octahedron() -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let positions =
        vec![[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]];
    let faces = vec![[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]];
    for &t in &faces {
        let n = face_normal(&positions, t);
        let c: Vec3 = t.iter().map(|&v| Vec3::from(positions[v as usize])).sum();
        assert!(n.dot(c) > 0.0, "{t:?} faces inwards");
    }
    (positions, faces)
}

#[test]
fn valence3_vertex_is_removed_and_its_face_restored() {
    let (mut positions, octahedron_faces) = octahedron();
    // Cut face [0, 2, 4] into three around a raised centre vertex 6 (valence 3).
    positions.push([0.4, 0.4, 0.4]);
    let mut faces = octahedron_faces.clone();
    faces[0] = [6, 0, 2];
    faces.extend([[6, 2, 4], [6, 4, 0]]);
    let before = check_manifold(positions.len(), &faces).unwrap();
    let mut alive = vec![true; faces.len()];
    let table = EdgeTable::new(&faces, None, positions.len());
    let candidate = vec![true; positions.len()];
    let removed = ops::remove_valence3_vertices(&positions, &mut faces, &mut alive, &table, &candidate);
    assert_eq!(removed, 1);
    let faces = ops::pack(&mut positions, &faces, &alive);
    assert_eq!(positions.len(), 6);
    assert_eq!(canonical(&faces), canonical(&octahedron_faces));
    let after = check_manifold(positions.len(), &faces).unwrap();
    assert_eq!(after.euler, before.euler);
}

#[test]
fn valence3_removal_respects_candidates_duplicates_and_boundaries() {
    // Not a candidate: nothing happens.
    let (mut positions, mut faces) = octahedron();
    positions.push([0.4, 0.4, 0.4]);
    faces[0] = [6, 0, 2];
    faces.extend([[6, 2, 4], [6, 4, 0]]);
    let table = EdgeTable::new(&faces, None, positions.len());
    let mut alive = vec![true; faces.len()];
    let mut not_six = vec![true; positions.len()];
    not_six[6] = false;
    assert_eq!(ops::remove_valence3_vertices(&positions, &mut faces, &mut alive, &table, &not_six), 0);
    assert!(alive.iter().all(|&a| a));

    // A tetrahedron: every vertex has valence 3, but its neighbours already form a face.
    let positions = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let mut faces = vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    let table = EdgeTable::new(&faces, None, 4);
    let mut alive = vec![true; 4];
    assert_eq!(ops::remove_valence3_vertices(&positions, &mut faces, &mut alive, &table, &[true; 4]), 0);

    // Two triangles: vertices 0 and 2 have valence 3 but lie on the boundary.
    let positions = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
    let mut faces = vec![[0, 1, 2], [0, 2, 3]];
    let table = EdgeTable::new(&faces, None, 4);
    let mut alive = vec![true; 2];
    assert_eq!(ops::remove_valence3_vertices(&positions, &mut faces, &mut alive, &table, &[true; 4]), 0);
    assert_eq!(faces, vec![[0, 1, 2], [0, 2, 3]]);
}

#[test]
fn valence3_removal_skips_a_fold() {
    // Vertex 4 pulled down and inwards: the octahedron face [0, 2, 4] would be flipped
    // against its neighbours, so the fan that replaces it must stay.
    let (mut positions, octahedron_faces) = octahedron();
    positions[4] = [0.6, 0.6, -0.2];
    assert!(flipped_faces(&positions, &octahedron_faces)[0]);
    positions.push([0.9, 0.9, 0.9]);
    let mut faces = octahedron_faces.clone();
    faces[0] = [6, 0, 2];
    faces.extend([[6, 2, 4], [6, 4, 0]]);
    let table = EdgeTable::new(&faces, None, positions.len());
    let mut alive = vec![true; faces.len()];
    let candidate = vec![true; positions.len()];
    assert_eq!(ops::remove_valence3_vertices(&positions, &mut faces, &mut alive, &table, &candidate), 0);
}

#[test]
fn relax_folds_leaves_clean_meshes_alone() {
    let (mut positions, faces) = grid(&vec![vec![false; 4]; 4]);
    let before = positions.clone();
    let table = EdgeTable::new(&faces, None, positions.len());
    assert_eq!(ops::relax_folds(&mut positions, &faces, &table, 10), (0, 0));
    assert_eq!(positions, before);
}

#[test]
fn relax_folds_untangles_a_fold_and_a_zero_area_face() {
    // A flat 4 × 4 grid; interior vertex (2, 2) = 12 pushed past its right neighbour.
    let (mut positions, faces) = grid(&vec![vec![false; 4]; 4]);
    positions[12] = [3.6, 2.3, 0.0];
    let flipped = flipped_faces(&positions, &faces).iter().filter(|&&f| f).count();
    assert!(flipped > 0);
    let boundary_before: Vec<[f32; 3]> =
        positions.iter().copied().filter(|p| p[0] == 0.0 || p[0] == 4.0 || p[1] == 0.0 || p[1] == 4.0).collect();
    let table = EdgeTable::new(&faces, None, positions.len());
    let (found, left) = ops::relax_folds(&mut positions, &faces, &table, 10);
    assert_eq!((found, left), (flipped, 0));
    assert!(flipped_faces(&positions, &faces).iter().all(|&f| !f));
    assert!(faces.iter().all(|&t| face_normal(&positions, t).z > 0.0));
    let boundary_after: Vec<[f32; 3]> =
        positions.iter().copied().filter(|p| p[0] == 0.0 || p[0] == 4.0 || p[1] == 0.0 || p[1] == 4.0).collect();
    assert_eq!(boundary_before, boundary_after);

    // Interior vertex 6 = (1, 1) moved onto the segment 7–12 ((2, 1)–(2, 2)): faces around
    // it lose their area.
    let (mut positions, faces) = grid(&vec![vec![false; 4]; 4]);
    positions[6] = [2.0, 1.5, 0.0];
    let degenerate = faces.iter().filter(|&&t| face_normal(&positions, t) == Vec3::ZERO).count();
    assert!(degenerate > 0);
    let table = EdgeTable::new(&faces, None, positions.len());
    let (found, left) = ops::relax_folds(&mut positions, &faces, &table, 10);
    assert!(found >= degenerate && left == 0, "{found} {left}");
    assert!(faces.iter().all(|&t| face_normal(&positions, t).z > 0.0));
}
