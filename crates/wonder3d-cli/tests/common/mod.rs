//! Helpers shared by the CLI's integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

use wonder3d::Image;

/// Runs the `wonder3d` binary with `args`.
pub fn wonder3d(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_wonder3d")).args(args).output().unwrap()
}

/// The tiny random-weight model directory (real Wonder3D key names and layout, 32² images).
pub fn tiny_weights() -> String {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../w3d-diffusion/tests/fixtures/wonder3d_tiny");
    dir.to_str().unwrap().to_string()
}

/// An RGBA PNG: an opaque disc shaded left to right on a transparent background.
pub fn write_input(path: &Path) {
    let (w, h) = (48u32, 40u32);
    let mut image = Image::filled(w, h, 4, 0.0).unwrap();
    for y in 0..h {
        for x in 0..w {
            let (dx, dy) = (x as f32 - 24.0, y as f32 - 20.0);
            if dx * dx + dy * dy < 15.0 * 15.0 {
                image.pixel_mut(x, y).copy_from_slice(&[0.3 + x as f32 / 96.0, 0.5, 0.7, 1.0]);
            }
        }
    }
    image.write_png(path).unwrap();
}

/// A path as `&str` (test paths are UTF-8).
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The JSON document in the file at `path`.
pub fn read_json(path: &Path) -> serde_json::Value {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_slice(&bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A tmpfs mounted on `dir` for the life of the guard (unmounted on drop): an output folder
/// that is a mount point, as a container or Kubernetes volume is. `None` where this process
/// may not mount (not root, or a sandbox without the capability).
pub struct Mounted(PathBuf);

impl Mounted {
    pub fn tmpfs(dir: &Path) -> Option<Mounted> {
        let status = Command::new("mount")
            .args(["-t", "tmpfs", "-o", "size=64m", "w3d-test", dir.to_str()?])
            .stderr(std::process::Stdio::null())
            .status()
            .ok()?;
        status.success().then(|| Mounted(dir.to_path_buf()))
    }
}

impl Drop for Mounted {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(&self.0).status();
    }
}
