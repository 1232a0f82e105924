//! Byte-mutation tests of every loader: small valid seed files (OBJ, PLY ascii and binary,
//! GLB, glTF with a data-URI buffer, PNG, EXR, `cameras.json`) are damaged by flipping,
//! overwriting, truncating, inserting and duplicating bytes, and each loader must return
//! within a time bound without panicking; an `Ok` result must be valid (indices in range,
//! finite values, consistent sizes). `Image::read_exr` checks the EXR header's size first.
//!
//! Each property runs 128 cases by default (the whole file takes a few seconds in
//! release); `W3D_FUZZ_CASES=20000 cargo test --release -p w3d-core --test files fuzz_loaders::`
//! runs a longer campaign (`docs/robustness.md`).

use crate::mutate;

use std::path::Path;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use mutate::{Mutation, apply, mutations};
use proptest::prelude::*;
use w3d_core::io::{write_glb, write_ply};
use w3d_core::{Image, Mesh, ViewRig, load_mesh};

/// Cases per property: `W3D_FUZZ_CASES` or 128.
fn cases() -> u32 {
    std::env::var("W3D_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(128)
}

fn config() -> ProptestConfig {
    ProptestConfig { cases: cases(), failure_persistence: None, ..ProptestConfig::default() }
}

/// How long one load of a damaged seed (a few hundred bytes to a few kB) may take.
const TIME_BOUND: Duration = Duration::from_secs(2);

/// A mesh that loaded must satisfy every invariant `Mesh` promises.
fn check_mesh(mesh: &Mesh) {
    let n = mesh.vertex_count();
    assert!(mesh.triangle_count() > 0);
    w3d_core::mesh::validate_geometry(mesh.positions(), mesh.triangles()).expect("a loaded mesh is valid");
    assert!(mesh.triangles().iter().flatten().all(|&i| (i as usize) < n));
    if let Some(v) = mesh.normals() {
        assert!(v.len() == n && v.iter().flatten().all(|x| x.is_finite()));
    }
    if let Some(v) = mesh.uvs() {
        assert!(v.len() == n && v.iter().flatten().all(|x| x.is_finite()));
    }
    if let Some(v) = mesh.colours() {
        assert!(v.len() == n && v.iter().flatten().all(|x| x.is_finite()));
    }
    if let Some(t) = mesh.texture() {
        check_image(t, true);
    }
}

/// A decoded image has consistent dimensions; PNG values (from integers) are finite too.
/// EXR files may store NaN and infinities: `ViewSet::new` refuses those in view images.
fn check_image(image: &Image, finite: bool) {
    let expected = image.width() as usize * image.height() as usize * image.channels() as usize;
    assert!(expected > 0 && image.data().len() == expected);
    assert!(!finite || image.data().iter().all(|v| v.is_finite()));
}

/// Writes `bytes` as `name` in a fresh folder and runs `load` on it within [`TIME_BOUND`].
fn timed<T>(name: &str, bytes: &[u8], load: impl FnOnce(&Path) -> T) -> T {
    mutate::timed(name, bytes, TIME_BOUND, load)
}

fn fuzz_mesh(name: &str, seed: &[u8], mutations: &[Mutation]) {
    let bytes = apply(seed, mutations);
    if let Ok(mesh) = timed(name, &bytes, |p| load_mesh(p)) {
        check_mesh(&mesh);
    }
    if name.ends_with(".glb") {
        let start = Instant::now();
        if let Ok(mesh) = w3d_core::io::read_glb_bytes(name, &bytes) {
            check_mesh(&mesh);
        }
        assert!(start.elapsed() < TIME_BOUND);
    }
}

// ---- Seeds ---------------------------------------------------------------------------

/// A tetrahedron with uvs and colours.
fn tetrahedron() -> Mesh {
    let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    Mesh::new(p, vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
        .unwrap()
        .with_uvs(vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
        .unwrap()
        .with_colours(vec![[0.1, 0.2, 0.3]; 4])
        .unwrap()
}

/// Generated seeds, made once.
fn cached(cell: &'static OnceLock<Vec<u8>>, make: fn() -> Vec<u8>) -> &'static [u8] {
    cell.get_or_init(make)
}

fn written(name: &str, write: impl FnOnce(&Path)) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    write(&path);
    std::fs::read(path).unwrap()
}

const OBJ_SEED: &[u8] =
    b"# seed\no tetra\nv 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nv 0 0 1 0.5 0.5 0.5\nvt 0 0\nvt 1 0\nvt 0 1\n\
vn 0 0 -1\nvn 0 -1 0\nvn -1 0 0\nvn 1 1 1\ng g1\nf 1/1/1 3/3/1 2/2/1\nf 1/1/2 2/2/2 4/1/2\nf -4/1/3 -1/3/3 -2/2/3\n\
f 2/2/4 3/3/4 4/1/4\n";

const PLY_ASCII_SEED: &[u8] =
    b"ply\nformat ascii 1.0\ncomment seed\nelement vertex 4\nproperty float x\nproperty float y\n\
property float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\n\
property uchar blue\nelement face 4\nproperty list uchar int vertex_indices\nend_header\n0 0 0 0 0 -1 255 0 0\n\
1 0 0 0 -1 0 0 255 0\n0 1 0 -1 0 0 0 0 255\n0 0 1 1 1 1 10 20 30\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n";

fn ply_binary_seed() -> &'static [u8] {
    static SEED: OnceLock<Vec<u8>> = OnceLock::new();
    cached(&SEED, || written("t.ply", |p| write_ply(p, &tetrahedron()).unwrap()))
}

fn glb_seed() -> &'static [u8] {
    static SEED: OnceLock<Vec<u8>> = OnceLock::new();
    cached(&SEED, || {
        let textured = tetrahedron().with_texture(Image::filled(2, 2, 3, 0.5).unwrap()).unwrap();
        written("t.glb", |p| write_glb(p, &textured).unwrap())
    })
}

/// The GLB seed as a `.gltf` whose buffer is a base64 data URI.
fn gltf_seed() -> &'static [u8] {
    static SEED: OnceLock<Vec<u8>> = OnceLock::new();
    cached(&SEED, make_gltf_seed)
}

fn make_gltf_seed() -> Vec<u8> {
    let glb = glb_seed();
    let json_len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
    let mut json: serde_json::Value = serde_json::from_slice(&glb[20..20 + json_len]).unwrap();
    let bin = &glb[20 + json_len + 8..];
    json["buffers"][0]["uri"] = format!("data:application/octet-stream;base64,{}", base64(bin)).into();
    serde_json::to_vec_pretty(&json).unwrap()
}

fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let b = [chunk[0], *chunk.get(1).unwrap_or(&0), *chunk.get(2).unwrap_or(&0)];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(ALPHABET[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

fn png_seed() -> Vec<u8> {
    let mut image = Image::filled(5, 4, 4, 0.25).unwrap();
    image.pixel_mut(2, 1).copy_from_slice(&[1.0, 0.0, 0.5, 1.0]);
    image.encode_png().unwrap()
}

fn exr_seed() -> &'static [u8] {
    static SEED: OnceLock<Vec<u8>> = OnceLock::new();
    cached(&SEED, make_exr_seed)
}

fn make_exr_seed() -> Vec<u8> {
    let mut image = Image::filled(5, 4, 4, 0.25).unwrap();
    image.pixel_mut(2, 1).copy_from_slice(&[1.0, -1.0, 0.5, 1.0]);
    written("t.exr", |p| image.write_exr(p).unwrap())
}

fn cameras_seed() -> Vec<u8> {
    serde_json::to_vec_pretty(&ViewRig::wonder3d_persp()).unwrap()
}

#[test]
fn seeds_load() {
    let check = |name: &str, bytes: &[u8]| check_mesh(&timed(name, bytes, |p| load_mesh(p)).unwrap());
    check("s.obj", OBJ_SEED);
    check("s.ply", PLY_ASCII_SEED);
    check("b.ply", ply_binary_seed());
    check("s.glb", glb_seed());
    check("s.gltf", gltf_seed());
    check_image(&timed("s.png", &png_seed(), |p| Image::read_png(p)).unwrap(), true);
    check_image(&timed("s.exr", exr_seed(), |p| Image::read_exr(p)).unwrap(), true);
    timed("cameras.json", &cameras_seed(), |p| ViewRig::load_json(p)).unwrap();
    assert!(timed("s.gltf", gltf_seed(), |p| load_mesh(p)).unwrap().texture().is_some());
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn damaged_obj(m in mutations()) {
        fuzz_mesh("m.obj", OBJ_SEED, &m);
    }

    #[test]
    fn damaged_ply_ascii(m in mutations()) {
        fuzz_mesh("m.ply", PLY_ASCII_SEED, &m);
    }

    #[test]
    fn damaged_ply_binary(m in mutations()) {
        fuzz_mesh("m.ply", ply_binary_seed(), &m);
    }

    #[test]
    fn damaged_glb(m in mutations()) {
        fuzz_mesh("m.glb", glb_seed(), &m);
    }

    #[test]
    fn damaged_gltf(m in mutations()) {
        fuzz_mesh("m.gltf", gltf_seed(), &m);
    }

    #[test]
    fn damaged_png(m in mutations()) {
        let bytes = apply(&png_seed(), &m);
        if let Ok(image) = timed("m.png", &bytes, |p| Image::read_png(p)) {
            check_image(&image, true);
        }
    }

    #[test]
    fn damaged_exr(m in mutations()) {
        let bytes = apply(exr_seed(), &m);
        if let Ok(image) = timed("m.exr", &bytes, |p| Image::read_exr(p)) {
            check_image(&image, false);
        }
    }

    #[test]
    fn damaged_cameras_json(m in mutations()) {
        let bytes = apply(&cameras_seed(), &m);
        if let Ok(rig) = timed("cameras.json", &bytes, |p| ViewRig::load_json(p)) {
            rig.validate().expect("a loaded rig is valid");
        }
    }
}
