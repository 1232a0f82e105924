//! Bad input gives the documented error, naming the file and field, and never panics.

use crate::common::{message_for, write};
use w3d_core::{Error, Image, ViewRig, ViewSet, load_mesh};

#[test]
fn missing_file_is_an_io_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("nope.obj");
    let err = load_mesh(&p).unwrap_err();
    assert!(matches!(err, Error::Io { .. }), "{err}");
    message_for(err, &p);
}

#[test]
fn empty_obj_has_no_triangles() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "empty.obj", b"");
    let msg = message_for(load_mesh(&p).unwrap_err(), &p);
    assert!(msg.contains("faces") && msg.contains("no vertices"), "{msg}");
}

#[test]
fn truncated_obj_vertex_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "trunc.obj", b"v 0 0 0\nv 1 0 0\nv 0 1");
    let msg = message_for(load_mesh(&p).unwrap_err(), &p);
    assert!(msg.contains("OBJ"), "{msg}");
}

#[test]
fn obj_with_nan_vertex_names_the_coordinate() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "nan.obj", b"v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n");
    let msg = message_for(load_mesh(&p).unwrap_err(), &p);
    assert!(msg.contains("positions[1].y") && msg.contains("finite"), "{msg}");
}

#[test]
fn obj_index_out_of_range_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "range.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n");
    message_for(load_mesh(&p).unwrap_err(), &p);
}

#[test]
fn missing_mtl_texture_names_the_texture() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "m.mtl", b"newmtl a\nmap_Kd gone.png\n");
    let p = write(
        dir.path(),
        "m.obj",
        b"mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl a\nf 1/1 2/2 3/3\n",
    );
    let msg = message_for(load_mesh(&p).unwrap_err(), &p);
    assert!(msg.contains("map_Kd") && msg.contains("gone.png"), "{msg}");
}

#[test]
fn missing_mtl_file_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "m.obj", b"mtllib absent.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let msg = message_for(load_mesh(&p).unwrap_err(), &p);
    assert!(msg.contains("mtllib"), "{msg}");
}

#[test]
fn truncated_binary_ply_names_the_row() {
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n".to_vec();
    bytes.extend(std::iter::repeat_n(0u8, 4 * 7)); // 7 of the 9 floats
    let p = write(dir.path(), "t.ply", &bytes);
    let msg = message_for(load_mesh(&p).unwrap_err(), &p);
    assert!(msg.contains("element vertex row 2"), "{msg}");
}

#[test]
fn ply_without_header_end_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "h.ply", b"ply\nformat ascii 1.0\nelement vertex 3\n");
    let msg = message_for(load_mesh(&p).unwrap_err(), &p);
    assert!(msg.contains("end_header"), "{msg}");
}

#[test]
fn ascii_ply_with_bad_index_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(
        dir.path(),
        "i.ply",
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n",
    );
    let msg = message_for(load_mesh(&p).unwrap_err(), &p);
    assert!(msg.contains("triangles[0]"), "{msg}");
}

#[test]
fn garbage_glb_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "g.glb", b"glTF\x02\0\0\0garbage");
    message_for(load_mesh(&p).unwrap_err(), &p);
}

#[test]
fn unknown_extension_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "mesh.stl", b"solid x\n");
    let msg = message_for(load_mesh(&p).unwrap_err(), &p);
    assert!(msg.contains("extension"), "{msg}");
}

#[test]
fn png_with_wrong_channel_count_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("rgb.png");
    Image::filled(4, 4, 3, 0.5).unwrap().write_png(&p).unwrap();
    let msg = message_for(Image::read_png_channels(&p, 4).unwrap_err(), &p);
    assert!(msg.contains("4 channels, got 3"), "{msg}");
}

#[test]
fn not_a_png_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "x.png", b"\x89PNG\r\n\x1a\nshort");
    message_for(Image::read_png(&p).unwrap_err(), &p);
}

#[test]
fn view_set_with_mismatched_sizes_is_rejected() {
    let rig = ViewRig::wonder3d_ortho();
    let mut views = oracle_like_views(&rig, 8);
    views[3].mask = Image::filled(8, 7, 1, 1.0).unwrap();
    let msg = ViewSet::new(rig.clone(), views).unwrap_err().to_string();
    assert!(msg.contains("views[3].mask") && msg.contains("8×8"), "{msg}");
    // Channel counts: a 4-channel colour, a 3-channel depth.
    let mut views = oracle_like_views(&rig, 8);
    views[1].colour = Some(Image::filled(8, 8, 4, 0.5).unwrap());
    let msg = ViewSet::new(rig.clone(), views).unwrap_err().to_string();
    assert!(msg.contains("views[1].colour") && msg.contains("3 channels"), "{msg}");
    let mut views = oracle_like_views(&rig, 8);
    views[5].depth = Some(Image::filled(8, 8, 3, 1.0).unwrap());
    let msg = ViewSet::new(rig.clone(), views).unwrap_err().to_string();
    assert!(msg.contains("views[5].depth") && msg.contains("1 channels"), "{msg}");
    let mut views = oracle_like_views(&rig, 8);
    views[0].normal = Image::filled(8, 8, 1, 0.0).unwrap();
    let msg = ViewSet::new(rig.clone(), views).unwrap_err().to_string();
    assert!(msg.contains("views[0].normal"), "{msg}");
    // The valid set passes and keeps its rig and size.
    let set = ViewSet::new(rig.clone(), oracle_like_views(&rig, 8)).unwrap();
    assert_eq!((set.len(), set.width(), set.height(), set.rig()), (6, 8, 8, &rig));
    assert!(set.iter().all(|(camera, images)| camera.name == images.name));
}

#[test]
fn view_set_must_match_its_rig() {
    let rig = ViewRig::wonder3d_ortho();
    // One view short.
    let mut views = oracle_like_views(&rig, 4);
    views.pop();
    let msg = ViewSet::new(rig.clone(), views).unwrap_err().to_string();
    assert!(msg.contains("6 views") && msg.contains("got 5"), "{msg}");
    // Two views swapped: names must follow rig order.
    let mut views = oracle_like_views(&rig, 4);
    views.swap(1, 2);
    let msg = ViewSet::new(rig.clone(), views).unwrap_err().to_string();
    assert!(msg.contains("views[1].name") && msg.contains("\"front_right\""), "{msg}");
    // An invalid rig is reported under `rig.`, and an empty one is refused.
    let mut bad = rig.clone();
    bad.views[4].name = "front".into();
    let msg = ViewSet::new(bad.clone(), oracle_like_views(&bad, 4)).unwrap_err().to_string();
    assert!(msg.contains("rig.views[4].name") && msg.contains("repeated"), "{msg}");
    let empty = ViewRig { name: "empty".into(), views: vec![] };
    let msg = ViewSet::new(empty, vec![]).unwrap_err().to_string();
    assert!(msg.contains("at least one view"), "{msg}");
    // Taken apart and rebuilt unchanged, the set is the same.
    let set = ViewSet::new(rig.clone(), oracle_like_views(&rig, 4)).unwrap();
    let (r, v) = set.clone().into_parts();
    assert_eq!(ViewSet::new(r, v).unwrap(), set);
}

#[test]
fn loading_a_mismatched_view_folder_names_the_folder_and_field() {
    let rig = ViewRig::wonder3d_ortho();
    let dir = tempfile::tempdir().unwrap();
    ViewSet::new(rig.clone(), oracle_like_views(&rig, 8)).unwrap().save(dir.path()).unwrap();
    // A mask of another size replaces one view's mask: cameras.json lists the files of
    // its render, so the edited file is refused by name first.
    let mask = dir.path().join("mask_left.png");
    Image::filled(8, 6, 1, 1.0).unwrap().write_png(&mask).unwrap();
    let msg = message_for(ViewSet::load(dir.path()).unwrap_err(), &mask);
    assert!(msg.contains("different renders"), "{msg}");
    // Without the list (files edited on purpose), the size is checked.
    let cameras = dir.path().join("cameras.json");
    let mut json: serde_json::Value = serde_json::from_slice(&std::fs::read(&cameras).unwrap()).unwrap();
    json.as_object_mut().unwrap().remove("files");
    std::fs::write(&cameras, json.to_string()).unwrap();
    let msg = message_for(ViewSet::load(dir.path()).unwrap_err(), dir.path());
    assert!(msg.contains("views[4].mask") && msg.contains("8×8"), "{msg}");
}

#[test]
fn malformed_cameras_json_names_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "cameras.json", b"{\"name\": \"x\",\n \"views\": [ {\"name\": 3} ] }");
    let msg = message_for(ViewRig::load_json(&p).unwrap_err(), &p);
    assert!(msg.contains("line 2"), "{msg}");
    let p = write(dir.path(), "cameras.json", b"{\"name\": \"x\", \"views\": []}");
    let msg = message_for(ViewRig::load_json(&p).unwrap_err(), &p);
    assert!(msg.contains("at least one view"), "{msg}");
}

#[test]
fn failed_write_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("nan.png");
    let err = Image::new(1, 1, 1, vec![f32::NAN]).unwrap().write_png(&p).unwrap_err();
    assert!(err.to_string().contains("NaN"));
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

fn oracle_like_views(rig: &ViewRig, size: u32) -> Vec<w3d_core::ViewImages> {
    rig.views
        .iter()
        .map(|v| w3d_core::ViewImages {
            name: v.name.clone(),
            normal: Image::filled(size, size, 3, 0.0).unwrap(),
            colour: None,
            mask: Image::filled(size, size, 1, 0.0).unwrap(),
            depth: None,
        })
        .collect()
}

#[test]
fn write_dir_atomic_replaces_a_folder_whole_and_refuses_a_file() {
    use w3d_core::io::write_dir_atomic;
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("out");
    std::fs::create_dir(&dir).unwrap();
    std::fs::write(dir.join("stale.txt"), b"earlier run").unwrap();
    // A failing fill leaves the earlier folder as it was and no staging folder beside it.
    let failed = write_dir_atomic(&dir, "new.txt", |staging| {
        std::fs::write(staging.join("half.txt"), b"half").unwrap();
        Err(w3d_core::Error::invalid("fill", "a failure for the test"))
    });
    assert!(failed.is_err());
    assert_eq!(std::fs::read(dir.join("stale.txt")).unwrap(), b"earlier run");
    assert_eq!(std::fs::read_dir(root.path()).unwrap().count(), 1, "only `out` is left");
    // A successful one replaces it as a whole.
    write_dir_atomic(&dir, "new.txt", |staging| {
        std::fs::write(staging.join("new.txt"), b"new").map_err(|e| w3d_core::Error::io(staging, e))
    })
    .unwrap();
    assert!(!dir.join("stale.txt").exists());
    assert_eq!(std::fs::read(dir.join("new.txt")).unwrap(), b"new");
    assert_eq!(std::fs::read_dir(root.path()).unwrap().count(), 1, "no backup folder is left");
    // A file at the path is refused before the fill runs, and left untouched.
    let file = root.path().join("a_file");
    std::fs::write(&file, b"keep me").unwrap();
    let mut ran = false;
    let err = write_dir_atomic(&file, "new.txt", |_| {
        ran = true;
        Ok(())
    })
    .unwrap_err()
    .to_string();
    assert!(!ran, "the fill must not run");
    assert!(err.contains("a_file") && err.contains("file"), "{err}");
    assert_eq!(std::fs::read(&file).unwrap(), b"keep me");
    assert_eq!(std::fs::read_dir(root.path()).unwrap().count(), 2);
}

/// A tmpfs mounted on `dir` for the life of the guard (unmounted on drop), or `None` where
/// this process may not mount (not root, or a sandbox without the capability).
struct Mounted(std::path::PathBuf);

impl Mounted {
    fn tmpfs(dir: &std::path::Path) -> Option<Mounted> {
        let status = std::process::Command::new("mount")
            .args(["-t", "tmpfs", "-o", "size=16m", "w3d-test", dir.to_str()?])
            .stderr(std::process::Stdio::null())
            .status()
            .ok()?;
        status.success().then(|| Mounted(dir.to_path_buf()))
    }
}

impl Drop for Mounted {
    fn drop(&mut self) {
        let _ = std::process::Command::new("umount").arg("-l").arg(&self.0).status();
    }
}

/// A folder that is a mount point (a container or Kubernetes volume) cannot be renamed, so
/// `write_dir_atomic` switches its contents in place: a failed fill leaves the old run and
/// no staging folder, a finished one leaves exactly the new run's entries, and the folder
/// stays the mount point. Runs where the machine lets the test mount a tmpfs (root, as CI
/// runs); elsewhere it says so and checks only the detection of `/`.
#[test]
fn write_dir_atomic_switches_a_mount_point_in_place() {
    use w3d_core::io::{is_mount_point, write_dir_atomic};
    assert!(is_mount_point(std::path::Path::new("/")));
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("volume");
    std::fs::create_dir(&dir).unwrap();
    assert!(!is_mount_point(&dir));
    let Some(_mounted) = Mounted::tmpfs(&dir) else {
        eprintln!("skipped: this process may not mount a tmpfs");
        return;
    };
    assert!(is_mount_point(&dir));
    std::fs::write(dir.join("manifest.json"), b"old").unwrap();
    std::fs::write(dir.join("old.txt"), b"old").unwrap();
    std::fs::create_dir(dir.join("old_sub")).unwrap();
    std::fs::write(dir.join("old_sub/x.txt"), b"old").unwrap();
    let names = |dir: &std::path::Path| {
        let mut names: Vec<String> =
            std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        names.sort();
        names
    };

    let failed = write_dir_atomic(&dir, "manifest.json", |staging| {
        assert!(staging.starts_with(&dir), "the staging folder is inside the mount: {}", staging.display());
        std::fs::write(staging.join("half.txt"), b"half").unwrap();
        Err(w3d_core::Error::invalid("fill", "a failure for the test"))
    });
    assert!(failed.is_err());
    assert_eq!(names(&dir), ["manifest.json", "old.txt", "old_sub"]);

    write_dir_atomic(&dir, "manifest.json", |staging| {
        std::fs::create_dir(staging.join("new_sub")).unwrap();
        std::fs::write(staging.join("new_sub/y.txt"), b"new").unwrap();
        std::fs::write(staging.join("new.txt"), b"new").unwrap();
        std::fs::write(staging.join("manifest.json"), b"new").map_err(|e| w3d_core::Error::io(staging, e))
    })
    .unwrap();
    assert_eq!(names(&dir), ["manifest.json", "new.txt", "new_sub"]);
    assert_eq!(std::fs::read(dir.join("manifest.json")).unwrap(), b"new");
    assert_eq!(std::fs::read(dir.join("new_sub/y.txt")).unwrap(), b"new");
    assert!(is_mount_point(&dir), "still the mount point");
    assert_eq!(names(root.path()), ["volume"], "nothing beside the mount");
}

/// A value of the wrong shape or type in `cameras.json` is named by its key path (and the
/// line and column), not only by where the parser stopped.
#[test]
fn rig_json_errors_name_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cameras.json");
    w3d_core::ViewRig::wonder3d_ortho().save_json(&path).unwrap();
    let mut json: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    json["views"][1]["camera"]["eye"] = serde_json::json!([0.0, 1.0]);
    std::fs::write(&path, serde_json::to_vec_pretty(&json).unwrap()).unwrap();
    let err = w3d_core::ViewRig::load_json(&path).unwrap_err().to_string();
    assert!(err.contains("views[1].camera.eye") && err.contains("line"), "{err}");
}
