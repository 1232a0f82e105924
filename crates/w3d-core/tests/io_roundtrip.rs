//! OBJ / PLY / GLB round trips on every real test mesh.

mod common;

use w3d_core::{Mesh, load_mesh, save_mesh};

fn assert_same_geometry(a: &Mesh, b: &Mesh, what: &str) {
    assert_eq!(a.vertex_count(), b.vertex_count(), "{what}: vertex count");
    assert_eq!(a.triangles(), b.triangles(), "{what}: triangles");
    assert_eq!(a.positions(), b.positions(), "{what}: positions");
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
            assert_same_geometry(&mesh, &back, &format!("{stem}.{ext}"));
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
    assert_eq!(spot.uvs().unwrap(), back.uvs().unwrap());
    assert_eq!(spot.normals().unwrap(), back.normals().unwrap());
    // 8-bit texture: PNG is lossless, so the texels come back bit for bit.
    assert_eq!(texture, back.texture().unwrap());
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
    assert_eq!(bob.texture(), back.texture());
    assert_eq!(bob.uvs(), back.uvs());
    // No temporary files are left behind.
    let names: Vec<String> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
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
