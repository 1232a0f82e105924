//! What the case generators share: the seeds, the folder of damaged shared inputs, the
//! bind mounts when the machine allows them, and each subcommand's valid, cheap command line.

use std::cell::RefCell;
use std::path::{Path, PathBuf};

use super::case::copy_recursive;
use super::inputs::Seeds;

/// Bind mounts made for the campaign (as root, where the machine allows them).
#[derive(Clone, Debug)]
pub(crate) struct Mounts {
    /// A read-only bind mount of an empty folder (named `readonly`): outputs there fail.
    pub readonly: PathBuf,
    /// A folder of writable bind mounts, one per name in [`MOUNT_POINTS`]: outputs onto a
    /// mount point (a container or Kubernetes volume) must work.
    pub points: PathBuf,
}

/// The writable mount points: one per case that writes onto one.
pub(crate) const MOUNT_POINTS: [&str; 4] = ["render", "dataset", "generate", "batch"];

/// The generators' shared state.
pub(crate) struct Ctx {
    /// The valid seeds.
    pub seeds: Seeds,
    /// `inputs/bad`: damaged copies shared by the cases (only read by them).
    pub bad: PathBuf,
    /// The bind mounts, when made (or, when only listing, where they would be).
    pub mounts: Option<Mounts>,
    /// Whether the damaged inputs are written (false: only the table is built).
    write: bool,
    /// Failures to write damaged inputs (the campaign stops on any).
    errors: RefCell<Vec<String>>,
}

/// A path as an argument.
pub(crate) fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

/// Owned arguments.
pub(crate) fn args(a: &[&str]) -> Vec<String> {
    a.iter().map(|s| s.to_string()).collect()
}

impl Ctx {
    /// A context over `seeds`; with `write`, damaged inputs are written into `seeds.dir/bad`.
    pub(crate) fn new(seeds: Seeds, mounts: Option<Mounts>, write: bool) -> Ctx {
        let bad = seeds.dir.join("bad");
        if write {
            let _ = std::fs::create_dir_all(&bad);
        }
        Ctx { seeds, bad, mounts, write, errors: RefCell::new(Vec::new()) }
    }

    /// Records a failure to make an input.
    fn fail(&self, e: String) {
        self.errors.borrow_mut().push(e);
    }

    /// The failures to make inputs.
    pub(crate) fn errors(&self) -> Vec<String> {
        self.errors.borrow().clone()
    }

    /// Reads a seed file.
    pub(crate) fn read(&self, p: &Path) -> Result<Vec<u8>, String> {
        std::fs::read(p).map_err(|e| format!("{}: {e}", p.display()))
    }

    /// A damaged shared file `bad/NAME` with the bytes `make` returns (called only when
    /// writing); its path as an argument.
    pub(crate) fn bad_file(&self, name: &str, make: impl FnOnce() -> Result<Vec<u8>, String>) -> String {
        let p = self.bad.join(name);
        if self.write {
            match make().and_then(|b| std::fs::write(&p, b).map_err(|e| format!("{}: {e}", p.display()))) {
                Ok(()) => {}
                Err(e) => self.fail(format!("input {name}: {e}")),
            }
        }
        s(&p)
    }

    /// A damaged shared folder `bad/NAME`: a copy of `from` changed by `edit` (called only
    /// when writing); its path as an argument.
    pub(crate) fn bad_dir(&self, name: &str, from: &Path, edit: impl FnOnce(&Path) -> Result<(), String>) -> String {
        let p = self.bad.join(name);
        if self.write
            && let Err(e) = copy_recursive(from, &p).and_then(|()| edit(&p))
        {
            self.fail(format!("input {name}: {e}"));
        }
        s(&p)
    }

    /// The valid command line of `command` that the generators vary: cheap (32² views, the
    /// tiny model, one sampling step, the fast preset), writing into the case's folder.
    pub(crate) fn base(&self, command: &str) -> Vec<String> {
        let sd = &self.seeds;
        let (cube, views, disc, tiny) = (s(&sd.cube_obj), s(&sd.views), s(&sd.disc_png), s(&sd.tiny));
        let a: Vec<&str> = match command {
            "info" => vec!["info", &cube],
            "render" => vec!["render", &cube, "--size", "32", "--out", "{case}/v"],
            "eval" => vec!["eval", &cube, &cube, "--samples", "2000"],
            "reconstruct" => vec!["reconstruct", &views, "--out", "{case}/r.glb", "--preset", "fast", "--quiet"],
            "texture" => vec!["texture", &cube, &views, "--out", "{case}/t.glb", "--size", "256", "--quiet"],
            "refine" => vec![
                "refine",
                &cube,
                &views,
                "--enhancer",
                "identity",
                "--out",
                "{case}/f.glb",
                "--iterations",
                "1",
                "--size",
                "32",
                "--texture-size",
                "512",
                "--quiet",
            ],
            "demo" => {
                vec![
                    "demo",
                    "--out",
                    "{case}/d",
                    "--preset",
                    "fast",
                    "--size",
                    "32",
                    "--texture-size",
                    "512",
                    "--quiet",
                ]
            }
            "prepare" => vec!["prepare", &disc, "--out", "{case}/p.png", "--size", "64"],
            "generate" => vec!["generate", &disc, "--weights", &tiny, "--steps", "1", "--out", "{case}/g", "--quiet"],
            "run" => vec![
                "run",
                &disc,
                "--weights",
                &tiny,
                "--steps",
                "1",
                "--preset",
                "fast",
                "--starts",
                "1",
                "--out",
                "{case}/r.glb",
                "--quiet",
            ],
            "batch" => {
                let m = s(&sd.manifest);
                return args(&["batch", &m, "--out", "{case}/b", "--preset", "fast", "--no-texture", "--quiet"]);
            }
            "dataset" => vec!["dataset", &cube, "--out", "{case}/ds", "--size", "32", "--samples", "1", "--quiet"],
            "train" => {
                let data = s(&sd.dataset);
                return args(&[
                    "train", "--stage", "3", "--data", &data, "--init", &tiny, "--out", "{case}/t", "--steps", "1",
                    "--warmup", "0", "--quiet",
                ]);
            }
            other => vec![other],
        };
        args(&a)
    }
}

/// `base` with `flag` set to `value` (replacing its value when `base` has the flag).
pub(crate) fn with_flag(base: &[String], flag: &str, value: &str) -> Vec<String> {
    let mut out = base.to_vec();
    match out.iter().position(|a| a == flag) {
        Some(i) if i + 1 < out.len() => out[i + 1] = value.to_string(),
        _ => out.extend([flag.to_string(), value.to_string()]),
    }
    out
}

/// `base` with the argument `old` replaced by `new` (every occurrence).
pub(crate) fn replace_arg(base: &[String], old: &str, new: &str) -> Vec<String> {
    base.iter().map(|a| if a == old { new.to_string() } else { a.clone() }).collect()
}

/// `base` without `flag` and its value.
pub(crate) fn without_flag(base: &[String], flag: &str) -> Vec<String> {
    let mut out = base.to_vec();
    if let Some(i) = out.iter().position(|a| a == flag) {
        out.drain(i..(i + 2).min(out.len()));
    }
    out
}

/// Updates the file list of the view folder `dir`'s `cameras.json` to the files as they now
/// are (a damaged file then passes the list check and reaches its decoder); entries of files
/// that are missing or not regular files are left as they were.
pub(crate) fn relist(dir: &Path) -> Result<(), String> {
    let cameras = dir.join("cameras.json");
    let text = std::fs::read(&cameras).map_err(|e| format!("{}: {e}", cameras.display()))?;
    let mut json: serde_json::Value =
        serde_json::from_slice(&text).map_err(|e| format!("{}: {e}", cameras.display()))?;
    if let Some(files) = json.get_mut("files").and_then(|f| f.as_object_mut()) {
        for (name, entry) in files.iter_mut() {
            let p = dir.join(name);
            if std::fs::symlink_metadata(&p).is_ok_and(|m| m.is_file()) {
                let bytes = std::fs::read(&p).map_err(|e| format!("{}: {e}", p.display()))?;
                *entry = serde_json::json!({"bytes": bytes.len(), "fnv1a64": wonder3d::core::io::fnv1a64(&bytes)});
            }
        }
    }
    let text = serde_json::to_string_pretty(&json).map_err(|e| e.to_string())?;
    std::fs::write(&cameras, text).map_err(|e| format!("{}: {e}", cameras.display()))
}

/// Edits a JSON file in place.
pub(crate) fn edit_json(path: &Path, edit: impl FnOnce(&mut serde_json::Value)) -> Result<(), String> {
    let text = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut json: serde_json::Value = serde_json::from_slice(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    edit(&mut json);
    let text = serde_json::to_string_pretty(&json).map_err(|e| e.to_string())?;
    std::fs::write(path, text).map_err(|e| format!("{}: {e}", path.display()))
}

/// Writes bytes to a file (an input edit).
pub(crate) fn put(path: &Path, bytes: &[u8]) -> Result<(), String> {
    std::fs::write(path, bytes).map_err(|e| format!("{}: {e}", path.display()))
}

/// Reads a file (an input edit).
pub(crate) fn get(path: &Path) -> Result<Vec<u8>, String> {
    std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))
}

/// JSON nested `depth` arrays deep (`[[[…]]]`): parsers must refuse it without
/// overflowing their stack.
pub(crate) fn deep_json(depth: usize) -> Vec<u8> {
    let mut v = vec![b'['; depth];
    v.extend(std::iter::repeat_n(b']', depth));
    v
}
