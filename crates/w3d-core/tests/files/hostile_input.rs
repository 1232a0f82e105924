//! The hostile-input findings of issue #23 that concern `w3d-core`: each case gets a clear
//! error naming the file and field (or, for output, leaves every existing file as it was),
//! quickly and without a huge allocation.

use std::path::Path;
use std::time::{Duration, Instant};

use crate::common::{message_for, write};
use w3d_core::io::{write_glb, write_obj};
use w3d_core::{Error, Image, Mesh, ViewImages, ViewRig, ViewSet, load_mesh};

/// Loads `path`, expecting an error within a second (the hangs took minutes).
fn load_error(path: &Path) -> String {
    let start = Instant::now();
    let err = load_mesh(path).expect_err("a damaged file must not load");
    assert!(start.elapsed() < Duration::from_secs(1), "took {:?}", start.elapsed());
    message_for(err, path)
}

fn tetrahedron() -> Mesh {
    let p = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    Mesh::new(p, vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]).unwrap()
}

// ---- PLY: claimed counts are checked against the file's size --------------------------

#[test]
fn ply_element_of_10e18_rows_without_properties_fails_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let header = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n\
                  element face 1\nproperty list uchar int vertex_indices\nelement junk 1000000000000000000\nend_header\n\
                  0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    let p = write(dir.path(), "junk.ply", header.as_bytes());
    let msg = load_error(&p);
    assert!(msg.contains("element junk") && msg.contains("properties"), "{msg}");
}

#[test]
fn ply_claiming_a_billion_vertices_is_refused_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    for format in ["ascii", "binary_little_endian", "binary_big_endian"] {
        let header = format!(
            "ply\nformat {format} 1.0\nelement vertex 1000000000\nproperty float x\nproperty float y\nproperty float z\n\
             element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        );
        let mut bytes = header.into_bytes();
        bytes.extend([b'0'; 64]);
        let p = write(dir.path(), &format!("{format}.ply"), &bytes);
        let msg = load_error(&p);
        assert!(msg.contains("element vertex") && msg.contains("1000000000 rows"), "{format}: {msg}");
    }
}

// ---- GLB: the container and every accessor are checked --------------------------------

/// A GLB of `mesh` whose JSON chunk was changed by `edit`.
fn edited_glb(mesh: &Mesh, edit: impl FnOnce(&mut serde_json::Value)) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("m.glb");
    write_glb(&p, mesh).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let mut json: serde_json::Value = serde_json::from_slice(&bytes[20..20 + json_len]).unwrap();
    edit(&mut json);
    let mut text = serde_json::to_vec(&json).unwrap();
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let bin = &bytes[20 + json_len..];
    let mut out = b"glTF".to_vec();
    out.extend(2u32.to_le_bytes());
    out.extend(((12 + 8 + text.len() + bin.len()) as u32).to_le_bytes());
    out.extend((text.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(text);
    out.extend(bin);
    out
}

#[test]
fn glb_index_accessor_longer_than_its_view_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    // 4 triangles in a 48-byte view; the accessor claims 12 triangles.
    let bytes = edited_glb(&tetrahedron(), |j| j["accessors"][0]["count"] = 36.into());
    let p = write(dir.path(), "long_indices.glb", &bytes);
    let msg = load_error(&p);
    assert!(msg.contains("indices") && msg.contains("accessors[0]") && msg.contains("36 elements"), "{msg}");
    // The same for a position accessor claiming a billion vertices.
    let bytes = edited_glb(&tetrahedron(), |j| j["accessors"][1]["count"] = 1_000_000_000u64.into());
    let p = write(dir.path(), "huge_positions.glb", &bytes);
    let msg = load_error(&p);
    assert!(msg.contains("POSITION") && msg.contains("1000000000 elements"), "{msg}");
    // A float index accessor (the reader would panic on it).
    let bytes = edited_glb(&tetrahedron(), |j| j["accessors"][0]["componentType"] = 5126.into());
    let p = write(dir.path(), "float_indices.glb", &bytes);
    let msg = load_error(&p);
    assert!(msg.contains("indices"), "{msg}");
    // The unedited file still loads.
    let p = write(dir.path(), "ok.glb", &edited_glb(&tetrahedron(), |_| {}));
    assert_eq!(load_mesh(&p).unwrap().triangle_count(), 4);
}

#[test]
fn empty_and_foreign_glb_files_name_the_header() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "empty.glb", b"");
    let msg = load_error(&p);
    assert!(msg.contains("empty file"), "{msg}");
    assert!(!msg.contains("fill whole buffer"), "{msg}");
    let p = write(dir.path(), "png.glb", b"\x89PNG\r\n\x1a\n0000000000000000");
    let msg = load_error(&p);
    assert!(msg.contains("GLB magic") && msg.contains("glTF"), "{msg}");
    assert!(!msg.contains("line 1 column 1"), "{msg}");
    let mut truncated = edited_glb(&tetrahedron(), |_| {});
    truncated.truncate(truncated.len() - 10);
    let p = write(dir.path(), "cut.glb", &truncated);
    let msg = load_error(&p);
    assert!(msg.contains("GLB length") && msg.contains("truncated"), "{msg}");
    let p = write(dir.path(), "empty.gltf", b"");
    assert!(load_error(&p).contains("empty file"));
}

// ---- OBJ: truncation and references are checked line by line ----------------------------

const OBJ: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvn 0 0 1\nf 1//1 3//1 2//1\nf 1//1 2//1 4//1\nf 1//1 4//1 3//1\nf 2//1 3//1 4//1\n";

#[test]
fn truncated_obj_files_are_refused_or_whole() {
    let dir = tempfile::tempdir().unwrap();
    let full = write(dir.path(), "full.obj", OBJ.as_bytes());
    assert_eq!(load_mesh(&full).unwrap().triangle_count(), 4);
    // Every cut: an error, or (a cut between lines or inside the last number) a valid
    // mesh of what is left; never a panic, and a partial mesh only where no record was cut.
    for cut in 1..OBJ.len() {
        let text = &OBJ[..cut];
        let p = write(dir.path(), "cut.obj", text.as_bytes());
        match load_mesh(&p) {
            Err(e) => {
                message_for(e, &p);
            }
            Ok(mesh) => {
                let last = text.lines().last().unwrap();
                let ends_cleanly = text.ends_with('\n')
                    || last.split_whitespace().count() == 4 && last.starts_with("f ") && last.ends_with("//1");
                assert!(ends_cleanly, "cut at {cut} ({last:?}) loaded {} triangles", mesh.triangle_count());
            }
        }
    }
    // The cases of the campaign: a cut inside a face, and one at half the file.
    let p = write(dir.path(), "mid_face.obj", &OBJ.as_bytes()[..OBJ.len() - 6]);
    let msg = load_error(&p);
    assert!(msg.contains("line 9") && msg.contains("truncated"), "{msg}");
    let p = write(dir.path(), "half.obj", &OBJ.as_bytes()[..OBJ.len() / 2]);
    load_error(&p);
}

#[test]
fn obj_faces_must_name_existing_vertices() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "far.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 40\n");
    let msg = load_error(&p);
    assert!(msg.contains("line 5") && msg.contains("1..=3") && msg.contains("\"40\""), "{msg}");
    let p = write(dir.path(), "rel.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n");
    let msg = load_error(&p);
    assert!(msg.contains("line 4") && msg.contains("-4"), "{msg}");
    let p = write(dir.path(), "zero.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n");
    assert!(load_error(&p).contains("line 4"));
    // Relative indices within range load.
    let p = write(dir.path(), "ok.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n");
    assert_eq!(load_mesh(&p).unwrap().triangle_count(), 1);
}

#[test]
fn obj_without_faces_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "points.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n");
    let msg = load_error(&p);
    assert!(msg.contains("4 vertices") && msg.contains("no faces"), "{msg}");
    assert!(!msg.contains("got none"), "{msg}");
}

#[test]
fn missing_mtl_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "m.obj", b"mtllib absent.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let msg = load_error(&p);
    assert!(msg.contains("absent.mtl") && msg.contains("missing"), "{msg}");
}

// ---- Output: nothing is overwritten before every destination is checked ----------------

#[test]
fn obj_output_onto_a_folder_touches_no_side_file() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("tex.obj")).unwrap();
    let png = write(dir.path(), "tex.png", b"old png");
    let mtl = write(dir.path(), "tex.mtl", b"old mtl");
    let mesh = tetrahedron()
        .with_uvs(vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
        .unwrap()
        .with_texture(Image::filled(4, 4, 3, 0.5).unwrap())
        .unwrap();
    let err = write_obj(dir.path().join("tex.obj"), &mesh).unwrap_err().to_string();
    assert!(err.contains("tex.obj") && err.contains("folder"), "{err}");
    assert_eq!(std::fs::read(&png).unwrap(), b"old png");
    assert_eq!(std::fs::read(&mtl).unwrap(), b"old mtl");
    // A side file that is a folder is refused as well, before the OBJ is written.
    std::fs::create_dir(dir.path().join("b.mtl")).unwrap();
    assert!(write_obj(dir.path().join("b.obj"), &mesh).is_err());
    assert!(!dir.path().join("b.obj").exists() && !dir.path().join("b.png").exists());
    let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names.len(), 4, "no temporary file is left: {names:?}");
}

// ---- Rigs: cameras frame the unit cube -------------------------------------------------

#[test]
fn cameras_json_with_absurd_framing_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let good = serde_json::to_value(ViewRig::wonder3d_ortho()).unwrap();
    let cases: [(&str, serde_json::Value, &str); 5] = [
        ("/views/2/camera/projection/half_height", 100.0.into(), "views[2].camera.projection.half_height"),
        ("/views/0/camera/projection/half_height", 1e30.into(), "views[0].camera.projection.half_height"),
        ("/views/1/camera/projection/half_height", 0.001.into(), "views[1].camera.projection.half_height"),
        ("/views/3/camera/eye", serde_json::json!([0.0, 0.0, -1e6]), "views[3].camera.eye"),
        ("/views/4/camera/target", serde_json::json!([0.0, 30.0, 0.0]), "views[4].camera.target"),
    ];
    for (pointer, value, field) in cases {
        let mut rig = good.clone();
        *rig.pointer_mut(pointer).unwrap() = value;
        let p = write(dir.path(), "cameras.json", rig.to_string().as_bytes());
        let msg = message_for(ViewRig::load_json(&p).unwrap_err(), &p);
        assert!(msg.contains(field), "{pointer}: {msg}");
    }
    let mut persp = serde_json::to_value(ViewRig::wonder3d_persp()).unwrap();
    *persp.pointer_mut("/views/0/camera/projection/fov_y").unwrap() = 3.1.into();
    let p = write(dir.path(), "cameras.json", persp.to_string().as_bytes());
    let msg = message_for(ViewRig::load_json(&p).unwrap_err(), &p);
    assert!(msg.contains("views[0].camera.projection.fov_y"), "{msg}");
    // The built-in rigs pass.
    for rig in [ViewRig::wonder3d_ortho(), ViewRig::wonder3d_persp(), ViewRig::syncdreamer16()] {
        rig.validate().unwrap();
    }
}

// ---- View sets: one render per folder, odd images blamed correctly ----------------------

fn views(rig: &ViewRig, size: u32, value: f32) -> Vec<ViewImages> {
    rig.views
        .iter()
        .map(|v| ViewImages {
            name: v.name.clone(),
            normal: Image::filled(size, size, 3, value).unwrap(),
            colour: Some(Image::filled(size, size, 3, value).unwrap()),
            mask: Image::filled(size, size, 1, 1.0).unwrap(),
            depth: None,
        })
        .collect()
}

#[test]
fn a_wrong_size_mask_is_blamed_on_the_mask() {
    let rig = ViewRig::wonder3d_ortho();
    let mut v = views(&rig, 8, 0.0);
    v[0].mask = Image::filled(6, 6, 1, 1.0).unwrap();
    let msg = ViewSet::new(rig.clone(), v).unwrap_err().to_string();
    assert!(msg.contains("views[0].mask") && msg.contains("8×8"), "{msg}");
    let mut v = views(&rig, 8, 0.0);
    v[0].normal = Image::filled(6, 6, 3, 0.0).unwrap();
    let msg = ViewSet::new(rig, v).unwrap_err().to_string();
    assert!(msg.contains("views[0].normal"), "{msg}");
}

#[test]
fn a_folder_mixing_two_renders_is_refused() {
    let rig = ViewRig::wonder3d_ortho();
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("a");
    let b = dir.path().join("b");
    ViewSet::new(rig.clone(), views(&rig, 8, 0.25)).unwrap().save(&a).unwrap();
    ViewSet::new(rig.clone(), views(&rig, 8, 0.75)).unwrap().save(&b).unwrap();
    ViewSet::load(&a).unwrap();
    // One file of the other render copied in: refused, naming it.
    std::fs::copy(b.join("colour_left.png"), a.join("colour_left.png")).unwrap();
    let msg = ViewSet::load(&a).unwrap_err().to_string();
    assert!(msg.contains("colour_left.png") && msg.contains("different renders"), "{msg}");
    // A view file cameras.json does not list (left from another render): refused.
    ViewSet::new(rig.clone(), views(&rig, 8, 0.25)).unwrap().save(&a).unwrap();
    let mut set = views(&rig, 8, 0.25);
    set.iter_mut().for_each(|v| v.depth = Some(Image::filled(8, 8, 1, 1.0).unwrap()));
    ViewSet::new(rig.clone(), set).unwrap().save(&b).unwrap();
    std::fs::copy(b.join("depth_back.exr"), a.join("depth_back.exr")).unwrap();
    let msg = ViewSet::load(&a).unwrap_err().to_string();
    assert!(msg.contains("depth_back.exr") && msg.contains("does not list"), "{msg}");
    // Without the list (an older folder, or files edited on purpose), the folder loads.
    let cameras = a.join("cameras.json");
    let mut json: serde_json::Value = serde_json::from_slice(&std::fs::read(&cameras).unwrap()).unwrap();
    json.as_object_mut().unwrap().remove("files");
    std::fs::write(&cameras, json.to_string()).unwrap();
    assert!(ViewSet::load(&a).unwrap().views()[3].depth.is_some());
}

#[test]
fn a_failed_save_leaves_the_old_folder_whole() {
    let rig = ViewRig::wonder3d_ortho();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("views");
    ViewSet::new(rig.clone(), views(&rig, 8, 0.25)).unwrap().save(&out).unwrap();
    let before = ViewSet::load(&out).unwrap();
    let new = ViewSet::new(rig.clone(), views(&rig, 8, 0.75)).unwrap();
    let err = new.save_with(&out, |_| Err(Error::invalid("disk", "space"))).unwrap_err();
    assert!(err.to_string().contains("disk"));
    assert_eq!(ViewSet::load(&out).unwrap(), before);
    // Nothing is left beside it, and a complete save replaces it.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    new.save(&out).unwrap();
    assert_ne!(ViewSet::load(&out).unwrap(), before);
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
fn saving_views_never_deletes_other_files() {
    let rig = ViewRig::wonder3d_ortho();
    let dir = tempfile::tempdir().unwrap();
    let notes = write(dir.path(), "notes.txt", b"mine");
    let set = ViewSet::new(rig.clone(), views(&rig, 8, 0.5)).unwrap();
    let msg = set.save(dir.path()).unwrap_err().to_string();
    assert!(msg.contains("notes.txt") && msg.contains("view-set files"), "{msg}");
    assert_eq!(std::fs::read(&notes).unwrap(), b"mine");
    let file = write(dir.path(), "file", b"x");
    assert!(set.save(&file).unwrap_err().to_string().contains("it is a file"));
    // Missing parents are created (as `mkdir -p`); a file in their way is named.
    let nested = dir.path().join("new/parents/views");
    set.save(&nested).unwrap();
    assert_eq!(ViewSet::load(&nested).unwrap().rig(), set.rig());
    let msg = set.save(file.join("views")).unwrap_err().to_string();
    assert!(msg.contains("is a file") && msg.contains(&*file.to_string_lossy()), "{msg}");
}

#[test]
fn glb_node_cycles_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = edited_glb(&tetrahedron(), |j| j["nodes"][0]["children"] = serde_json::json!([0]));
    let p = write(dir.path(), "cycle.glb", &bytes);
    let msg = load_error(&p);
    assert!(msg.contains("nodes[0]") && msg.contains("strict trees"), "{msg}");
}

#[test]
fn exr_headers_claiming_billions_of_pixels_are_refused_before_decoding() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("small.exr");
    Image::filled(3, 2, 4, 0.5).unwrap().write_exr(&p).unwrap();
    w3d_core::io::check_exr_size(&p).unwrap();
    // Patch the data window to 60000 × 60000 (the fuzzer's case asked for 57 GB).
    let mut bytes = std::fs::read(&p).unwrap();
    let key = b"dataWindow\0box2i\0";
    let at = bytes.windows(key.len()).position(|w| w == key).unwrap() + key.len() + 4;
    bytes[at + 8..at + 12].copy_from_slice(&59_999i32.to_le_bytes());
    bytes[at + 12..at + 16].copy_from_slice(&59_999i32.to_le_bytes());
    let huge = write(dir.path(), "huge.exr", &bytes);
    let msg = message_for(w3d_core::io::check_exr_size(&huge).unwrap_err(), &huge);
    assert!(msg.contains("data window") && msg.contains("60000×60000"), "{msg}");
    // `Image::read_exr` checks it before decoding, and so the view-set loader.
    let msg = message_for(Image::read_exr(&huge).unwrap_err(), &huge);
    assert!(msg.contains("data window"), "{msg}");
    let rig = ViewRig::wonder3d_ortho();
    let out = dir.path().join("views");
    ViewSet::new(rig.clone(), views(&rig, 4, 0.5)).unwrap().save(&out).unwrap();
    let cameras = out.join("cameras.json");
    let mut json: serde_json::Value = serde_json::from_slice(&std::fs::read(&cameras).unwrap()).unwrap();
    json.as_object_mut().unwrap().remove("files");
    std::fs::write(&cameras, json.to_string()).unwrap();
    std::fs::write(out.join("normal_front.exr"), &bytes).unwrap();
    let msg = ViewSet::load(&out).unwrap_err().to_string();
    assert!(msg.contains("normal_front.exr") && msg.contains("data window"), "{msg}");
}

/// Crashes cargo-fuzz found in the glTF crate (`fuzz/`, docs/robustness.md): a damaged key
/// (`"ac*essors"`, `"scenesors"`) makes the glTF crate skip the accessors without reading
/// them, and its validation then indexes an accessor that does not exist. The documents are
/// refused by our own checks, with a message about the document, before the crate sees them
/// (not by the catch-all for a panic inside it).
#[test]
fn gltf_documents_hiding_their_accessors_are_refused_before_the_reader() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fuzz");
    for (name, as_name) in [
        ("glb_ignored_key_hides_invalid_utf8.glb", "a.glb"),
        ("gltf_crash_2.gltf", "b.gltf"),
        ("glb_ignored_key_hides_invalid_utf8.glb", "c.gltf"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let path = write(dir.path(), as_name, &std::fs::read(data.join(name)).unwrap());
        let message = load_error(&path);
        assert!(!message.contains("failed on this one"), "{name}: {message}");
        assert!(message.contains("accessor") || message.contains("JSON"), "{name}: {message}");
    }
}

/// Coordinates near the f32 range (±3·10³⁸): the bounding box's side overflows in f32, and
/// normalising once scaled every vertex to 0 (empty views, then an empty-mask error). The
/// transform is computed in f64 and the mesh lands in the unit cube like any other.
#[test]
fn meshes_at_the_edge_of_the_f32_range_normalise_into_the_unit_cube() {
    let big = 3.0e38f32;
    let p = vec![[-big, -big, -big], [big, -big, -big], [-big, big, -big], [-big, -big, big]];
    let mut mesh = Mesh::new(p, vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]).unwrap();
    let t = mesh.normalize_unit_cube();
    let (lo, hi) = mesh.bbox();
    assert!((lo - glam::Vec3::splat(-0.5)).abs().max_element() < 1e-5, "{lo}");
    assert!((hi - glam::Vec3::splat(0.5)).abs().max_element() < 1e-5, "{hi}");
    let back = t.invert(glam::Vec3::from(mesh.positions()[1]));
    assert!((back.x / big - 1.0).abs() < 1e-5, "{back}");
}
