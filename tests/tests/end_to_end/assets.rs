//! The bundled assets load on a fresh clone, keep their genus through GLB export, and
//! survive unit-cube normalisation.

use w3d_core::{load_mesh, save_mesh};

#[test]
fn bundled_assets_keep_topology_through_glb() {
    let dir = tempfile::tempdir().unwrap();
    for (file, genus) in [("spot.obj", 0), ("bob_tri.obj", 1), ("torus.obj", 1)] {
        let mut mesh = load_mesh(wonder3d_tests::assets().join(file)).unwrap();
        mesh.normalize_unit_cube();
        let (lo, hi) = mesh.bbox();
        assert!(((hi - lo).max_element() - 1.0).abs() < 1e-6, "{file}");
        let out = dir.path().join(file.replace(".obj", ".glb"));
        save_mesh(&out, &mesh).unwrap();
        let back = load_mesh(&out).unwrap();
        let topology = back.merge_by_position().0.topology();
        assert_eq!(topology.genus(), Some(genus), "{file}");
        assert!(back.signed_volume() > 0.0, "{file}: outward winding");
    }
}
