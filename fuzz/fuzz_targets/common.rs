//! Shared by the fuzz targets: the loaders read paths, so each input is written to a file in
//! a per-process folder (in `/dev/shm` when it exists), and what loaded must be valid.
#![allow(dead_code)]

use std::path::PathBuf;
use std::sync::OnceLock;

use w3d_core::{Image, Mesh};

/// Writes `bytes` as `name` in this process's scratch folder and returns its path.
pub fn file(name: &str, bytes: &[u8]) -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    let dir = DIR.get_or_init(|| {
        let base =
            if std::path::Path::new("/dev/shm").is_dir() { PathBuf::from("/dev/shm") } else { std::env::temp_dir() };
        let dir = base.join(format!("wonder3d-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    });
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

/// A loaded mesh keeps every invariant `Mesh` promises.
pub fn check_mesh(mesh: &Mesh) {
    let n = mesh.vertex_count();
    assert!(mesh.triangle_count() > 0);
    w3d_core::mesh::validate_geometry(mesh.positions(), mesh.triangles()).expect("a loaded mesh is valid");
    for attribute in [mesh.normals().map(|v| v.len()), mesh.colours().map(|v| v.len())].into_iter().flatten() {
        assert_eq!(attribute, n);
    }
    if let Some(uvs) = mesh.uvs() {
        assert!(uvs.len() == n && uvs.iter().flatten().all(|x| x.is_finite()));
    }
    if let Some(t) = mesh.texture() {
        check_image(t);
    }
}

/// A decoded image has consistent dimensions.
pub fn check_image(image: &Image) {
    let expected = image.width() as usize * image.height() as usize * image.channels() as usize;
    assert!(expected > 0 && image.data().len() == expected);
}
