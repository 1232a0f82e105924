//! OBJ / PLY / GLB round trips on every real test mesh.

use crate::common;

use w3d_core::{Mesh, load_mesh, save_mesh};

/// Asserts two slices are equal, reporting only the first difference (they can be long).
fn assert_slices_eq<T: PartialEq + std::fmt::Debug>(a: &[T], b: &[T], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: lengths");
    if let Some(i) = (0..a.len()).find(|&i| a[i] != b[i]) {
        panic!("{what}: first difference at {i}: {:?} vs {:?}", a[i], b[i]);
    }
}

fn assert_same_geometry(a: &Mesh, b: &Mesh, what: &str) {
    assert_slices_eq(a.triangles(), b.triangles(), &format!("{what}: triangles"));
    assert_slices_eq(a.positions(), b.positions(), &format!("{what}: positions"));
}

fn assert_same_corners(a: &Mesh, b: &Mesh, what: &str) {
    for t in 0..a.triangle_count() {
        assert_eq!(a.triangle_corners(t), b.triangle_corners(t), "{what}: triangle {t}");
    }
}

/// uvs pass through `1 - v` twice in glTF IO: equal to within f32 rounding.
fn assert_uvs_close(a: &[[f32; 2]], b: &[[f32; 2]], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: uv count");
    for (i, (p, q)) in a.iter().zip(b).enumerate() {
        assert!((p[0] - q[0]).abs() <= 1e-6 && (p[1] - q[1]).abs() <= 1e-6, "{what}: uv {i}: {p:?} vs {q:?}");
    }
}

#[test]
fn every_shared_mesh_round_trips_through_obj_ply_and_glb() {
    let files = common::shared_mesh_files();
    assert_eq!(files.len(), 18, "expected the 18 meshes of ../shared/data/meshes");
    let dir = tempfile::tempdir().unwrap();
    for file in &files {
        let mesh = load_mesh(file).unwrap_or_else(|e| panic!("{e}"));
        let stem = file.file_stem().unwrap().to_string_lossy().into_owned();
        for ext in ["obj", "ply", "glb"] {
            let out = dir.path().join(format!("{stem}.{ext}"));
            save_mesh(&out, &mesh).unwrap_or_else(|e| panic!("{e}"));
            let back = load_mesh(&out).unwrap_or_else(|e| panic!("{e}"));
            let what = format!("{stem} -> {ext}");
            assert_eq!(mesh.vertex_count(), back.vertex_count(), "{what}: vertex count");
            assert_eq!(mesh.triangle_count(), back.triangle_count(), "{what}: triangle count");
            if ext == "obj" && file.extension().unwrap() != "obj" {
                // OBJ readers number vertices in face order: same corners, maybe renumbered.
                assert_same_corners(&mesh, &back, &what);
            } else {
                assert_same_geometry(&mesh, &back, &what);
            }
            assert_eq!(mesh.uvs().is_some(), back.uvs().is_some(), "{stem}.{ext}: uvs kept");
        }
    }
}

#[test]
fn horse_ply_reads_with_its_normals() {
    let mesh = load_mesh(common::shared_meshes().join("horse.ply")).unwrap();
    assert_eq!((mesh.vertex_count(), mesh.triangle_count()), (48485, 96966));
    assert!(mesh.normals().is_some());
    // The file is wound inward (SOURCES.md): negative volume until flipped.
    let mut flipped = mesh.clone();
    assert!(mesh.signed_volume() < 0.0);
    flipped.flip_winding();
    assert!(flipped.signed_volume() > 0.0);
}

#[test]
fn textured_glb_round_trips_exactly() {
    let spot = load_mesh(common::assets().join("spot.obj")).unwrap();
    let texture = spot.texture().expect("spot.mtl names spot_texture.png");
    assert_eq!((texture.width(), texture.height(), texture.channels()), (1024, 1024, 3));
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("spot.glb");
    save_mesh(&out, &spot).unwrap();
    let back = load_mesh(&out).unwrap();
    assert_same_geometry(&spot, &back, "spot.glb");
    assert_uvs_close(spot.uvs().unwrap(), back.uvs().unwrap(), "spot.glb");
    // glTF requires unit normals, so the writer renormalises the file's 6-digit normals.
    for (a, b) in spot.normals().unwrap().iter().zip(back.normals().unwrap()) {
        assert!((0..3).all(|k| (a[k] - b[k]).abs() < 1e-5), "spot.glb normals: {a:?} vs {b:?}");
    }
    // 8-bit texture: PNG is lossless, so the texels come back bit for bit.
    assert!(texture == back.texture().unwrap(), "spot.glb: texture changed");
}

#[test]
fn textured_obj_writes_mtl_and_png() {
    let bob = load_mesh(common::assets().join("bob_tri.obj")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bob.obj");
    save_mesh(&out, &bob).unwrap();
    assert!(dir.path().join("bob.mtl").is_file() && dir.path().join("bob.png").is_file());
    let back = load_mesh(&out).unwrap();
    assert_same_geometry(&bob, &back, "bob.obj");
    assert!(bob.texture() == back.texture(), "bob.obj: texture changed");
    assert_slices_eq(bob.uvs().unwrap(), back.uvs().unwrap(), "bob.obj uvs");
    // No temporary files are left behind.
    let names: Vec<String> =
        std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert!(names.iter().all(|n| !n.ends_with(".tmp")), "{names:?}");
}

#[test]
fn vertex_colours_round_trip_through_glb() {
    let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let colours = vec![[1.0, 0.0, 0.0], [0.2, 0.5, 0.7], [0.0, 0.0, 1.0]];
    let mesh = Mesh::new(p, vec![[0, 1, 2]]).unwrap().with_colours(colours.clone()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("c.glb");
    save_mesh(&out, &mesh).unwrap();
    let back = load_mesh(&out).unwrap();
    for (a, b) in colours.iter().flatten().zip(back.colours().unwrap().iter().flatten()) {
        assert!((a - b).abs() < 1e-5, "{a} vs {b}");
    }
}
