//! Per-view images (normals, colours, masks, depth) and their folder layout on disk.
//!
//! Folder layout written by [`ViewSet::save`] and read by [`ViewSet::load`]:
//!
//! | file | content |
//! |---|---|
//! | `cameras.json` | the [`ViewRig`], and `files`: every view file's size and FNV-1a hash |
//! | `normal_<view>.png` | RGB = (n + 1) / 2 (canonical frame), alpha = mask |
//! | `normal_<view>.exr` | full-precision normals (RGB = n), alpha = mask |
//! | `colour_<view>.png` | sRGB colour, alpha = mask (optional) |
//! | `mask_<view>.png` | the mask as 8-bit grey |
//! | `depth_<view>.exr` | depth in world units along the view axis, 0 on background (optional) |
//!
//! On load, `normal_<view>.exr` is preferred over the PNG when present, and the mask
//! comes from `mask_<view>.png`, or else from the normal map's alpha. A folder is written
//! whole ([`ViewSet::save_with`]) and a file that does not match the `files` list is
//! refused, so a folder never mixes two renders.

#[cfg(feature = "io")]
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::image::Image;
use crate::rig::{RigView, ViewRig};

/// The view set's manifest, written last: the rig and every view file's size and hash.
const MANIFEST: &str = "cameras.json";

/// The images of one view. All images of a [`ViewSet`] share one size.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewImages {
    /// View name (matches the rig's view name).
    pub name: String,
    /// Unit normals in the canonical frame, 3 channels; zero on the background.
    pub normal: Image,
    /// Colour, 3 channels, sRGB-encoded in `[0, 1]`, if available.
    pub colour: Option<Image>,
    /// Foreground coverage in `[0, 1]`, 1 channel.
    pub mask: Image,
    /// Depth along the view axis in world units (0 on the background), 1 channel, if
    /// available.
    pub depth: Option<Image>,
}

/// A rig and one [`ViewImages`] per view of it, in rig order: the input of reconstruction
/// and texturing.
///
/// The fields are private so that a `ViewSet` is valid by construction: [`ViewSet::new`]
/// (and [`ViewSet::load`]) check the rig, the view names and every image's size and channel
/// count once, and every consumer can rely on that without checking again. To change the
/// images, take the set apart with [`ViewSet::into_parts`] and build a new one.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewSet {
    rig: ViewRig,
    views: Vec<ViewImages>,
}

impl ViewSet {
    /// Pairs `views` with `rig` after checking that:
    /// - the rig is valid ([`ViewRig::validate`]; its errors are reported under `rig.`);
    /// - there is one view per rig view, with the rig's names in rig order (`views[i].name`);
    /// - every image has the same size (an image whose size differs from the size most
    ///   images share is the one reported), the documented channel count: normal 3,
    ///   mask 1, colour 3, depth 1 (`views[i].normal`, `views[i].mask`, …), and finite
    ///   values (an EXR file may hold NaN or infinities).
    pub fn new(rig: ViewRig, views: Vec<ViewImages>) -> Result<ViewSet> {
        rig.validate().map_err(|e| match e {
            Error::Invalid { field, expected } => Error::invalid(format!("rig.{field}"), expected),
            other => other,
        })?;
        if views.len() != rig.views.len() {
            return Err(Error::invalid(
                "views",
                format!("{} views to match the rig {:?}, got {}", rig.views.len(), rig.name, views.len()),
            ));
        }
        // The size most images have, so that the one odd image is the one blamed (the rig
        // has at least one view, so there is at least one image).
        let (w, h) = common_size(&views);
        for (i, (v, r)) in views.iter().zip(&rig.views).enumerate() {
            if v.name != r.name {
                return Err(Error::invalid(
                    format!("views[{i}].name"),
                    format!("{:?} as in the rig, got {:?}", r.name, v.name),
                ));
            }
            let images = [
                ("normal", Some(&v.normal), 3u32),
                ("mask", Some(&v.mask), 1),
                ("colour", v.colour.as_ref(), 3),
                ("depth", v.depth.as_ref(), 1),
            ];
            for (kind, image, channels) in images {
                let Some(image) = image else { continue };
                let field = format!("views[{i}].{kind}");
                image.expect_shape(&field, w, h, channels)?;
                if let Some(k) = image.data().iter().position(|x| !x.is_finite()) {
                    let pixel = k / channels as usize;
                    return Err(Error::invalid(
                        field,
                        format!(
                            "finite values, got {} at pixel ({}, {})",
                            image.data()[k],
                            pixel % w as usize,
                            pixel / w as usize
                        ),
                    ));
                }
            }
        }
        Ok(ViewSet { rig, views })
    }

    /// The cameras the views were taken with.
    pub fn rig(&self) -> &ViewRig {
        &self.rig
    }

    /// The images, one per rig view, in rig order.
    pub fn views(&self) -> &[ViewImages] {
        &self.views
    }

    /// Number of views (at least one).
    pub fn len(&self) -> usize {
        self.views.len()
    }

    /// Always `false`: a valid set has at least one view (kept for the `len` convention).
    pub fn is_empty(&self) -> bool {
        self.views.is_empty()
    }

    /// Image width in pixels, common to every image of the set.
    pub fn width(&self) -> u32 {
        self.views[0].mask.width()
    }

    /// Image height in pixels, common to every image of the set.
    pub fn height(&self) -> u32 {
        self.views[0].mask.height()
    }

    /// Each view's camera (with its name) and images, in rig order.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = (&RigView, &ViewImages)> {
        self.rig.views.iter().zip(&self.views)
    }

    /// The rig and the images, e.g. to change the images and build a new set with
    /// [`ViewSet::new`] (which checks them again).
    pub fn into_parts(self) -> (ViewRig, Vec<ViewImages>) {
        (self.rig, self.views)
    }

    /// The views named in `names` (any order, each once), with their cameras, as a set of
    /// their own in rig order: a view set with a view missing, e.g. one a generator got
    /// wrong. The rig keeps its name; its views are the ones kept. Fails on an empty
    /// selection, a name the rig does not have, or a name given twice.
    ///
    /// ```
    /// use w3d_core::{Image, ViewImages, ViewRig, ViewSet};
    ///
    /// let rig = ViewRig::wonder3d_ortho();
    /// let views = rig
    ///     .views
    ///     .iter()
    ///     .map(|v| ViewImages {
    ///         name: v.name.clone(),
    ///         normal: Image::filled(4, 4, 3, 0.0).unwrap(),
    ///         colour: None,
    ///         mask: Image::filled(4, 4, 1, 0.0).unwrap(),
    ///         depth: None,
    ///     })
    ///     .collect();
    /// let set = ViewSet::new(rig, views)?;
    /// let five = set.subset(["front", "front_right", "right", "back", "front_left"])?;
    /// assert_eq!(five.len(), 5);
    /// assert!(five.iter().all(|(rv, v)| rv.name == v.name && v.name != "left"));
    /// assert!(set.subset(["top"]).is_err());
    /// # Ok::<(), w3d_core::Error>(())
    /// ```
    pub fn subset<S: AsRef<str>>(&self, names: impl IntoIterator<Item = S>) -> Result<ViewSet> {
        let mut keep = vec![false; self.views.len()];
        for name in names {
            let name = name.as_ref();
            let Some(i) = self.rig.views.iter().position(|v| v.name == name) else {
                let known: Vec<&str> = self.rig.views.iter().map(|v| v.name.as_str()).collect();
                return Err(Error::invalid("views", format!("one of the rig's views {known:?}, got {name:?}")));
            };
            if keep[i] {
                return Err(Error::invalid("views", format!("each view once, {name:?} is named twice")));
            }
            keep[i] = true;
        }
        if !keep.contains(&true) {
            return Err(Error::invalid("views", "at least one view to keep"));
        }
        let rig = ViewRig {
            name: self.rig.name.clone(),
            views: self.rig.views.iter().zip(&keep).filter(|&(_, &k)| k).map(|(v, _)| v.clone()).collect(),
        };
        let views = self.views.iter().zip(&keep).filter(|&(_, &k)| k).map(|(v, _)| v.clone()).collect();
        ViewSet::new(rig, views)
    }
}

/// View-set folders (feature `io`).
#[cfg(feature = "io")]
impl ViewSet {
    /// Writes the rig and every image into the folder `dir`, in the layout of the module
    /// documentation; see [`ViewSet::save_with`].
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<()> {
        self.save_with(dir, |_| Ok(()))
    }

    /// Writes the view set into the folder `dir` all at once: every file goes into a
    /// temporary sibling folder first, `extra` may add files of its own there (a contact
    /// sheet, the input image), `cameras.json` comes last and lists every view file with its
    /// size and FNV-1a hash (so [`ViewSet::load`] can refuse a folder whose files come from
    /// different renders), and only then the finished folder replaces `dir`. A failure at
    /// any point leaves `dir` as it was.
    ///
    /// `dir` must pass [`ViewSet::check_output_dir`]: an existing folder is replaced only
    /// when it holds nothing but view-set files, so no other file is ever deleted.
    pub fn save_with(&self, dir: impl AsRef<Path>, extra: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
        let dir = dir.as_ref();
        ViewSet::check_output_dir(dir)?;
        crate::files::write_dir_atomic(dir, MANIFEST, |staging| {
            self.write_files(staging)?;
            extra(staging)?;
            write_manifest(staging, &self.rig)
        })
    }

    /// Fails unless `dir` can receive a view set from [`ViewSet::save`] without losing
    /// anything: not a file, no file in the way of its missing parents (the save creates them),
    /// and, if `dir` exists, a folder
    /// holding only view-set files (`cameras.json`, `normal_*.png|exr`, `colour_*.png`,
    /// `mask_*.png`, `depth_*.exr`, `input.png`, `views.png`), which the new set replaces.
    /// Commands call it before any long work.
    pub fn check_output_dir(dir: impl AsRef<Path>) -> Result<()> {
        let dir = dir.as_ref();
        let field = || format!("output folder {}", dir.display());
        if !crate::files::replaceable_folder(dir)? {
            return Ok(());
        }
        for entry in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
            let entry = entry.map_err(|e| Error::io(dir, e))?;
            let name = entry.file_name();
            let is_file = entry.file_type().map_err(|e| Error::io(entry.path(), e))?.is_file();
            if !(is_file && name.to_str().is_some_and(is_view_set_file)) {
                return Err(Error::invalid(
                    field(),
                    format!(
                        "a new folder, or one holding only view-set files (it is replaced); {} is not one: \
                         choose another folder",
                        entry.path().display()
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The view-set files in the folder `dir` (`cameras.json`, `normal_*.png|exr`, …): what
    /// [`ViewSet::load`] may read there, so a command's outputs can be checked against them
    /// before work. Empty when `dir` is not a readable folder (loading then says why).
    pub fn input_files(dir: impl AsRef<Path>) -> Vec<PathBuf> {
        let Ok(entries) = std::fs::read_dir(dir.as_ref()) else { return Vec::new() };
        let mut files: Vec<PathBuf> = entries
            .filter_map(|entry| entry.ok())
            .filter(|entry| entry.file_name().to_str().is_some_and(is_view_set_file))
            .map(|entry| entry.path())
            .collect();
        files.sort();
        files
    }

    /// Writes every image file of the set into `dir` (which exists).
    fn write_files(&self, dir: &Path) -> Result<()> {
        for v in &self.views {
            let n = v.normal.data();
            let m = v.mask.data();
            let rgba = |f: &dyn Fn(f32) -> f32, src: &[f32]| -> Vec<f32> {
                src.chunks_exact(3).zip(m).flat_map(|(p, &a)| [f(p[0]), f(p[1]), f(p[2]), a]).collect()
            };
            let (w, h) = (v.mask.width(), v.mask.height());
            Image::new(w, h, 4, rgba(&|x| (x + 1.0) * 0.5, n))?
                .write_png(dir.join(format!("normal_{}.png", v.name)))?;
            Image::new(w, h, 4, rgba(&|x| x, n))?.write_exr(dir.join(format!("normal_{}.exr", v.name)))?;
            v.mask.write_png(dir.join(format!("mask_{}.png", v.name)))?;
            if let Some(c) = &v.colour {
                Image::new(w, h, 4, rgba(&|x| x, c.data()))?.write_png(dir.join(format!("colour_{}.png", v.name)))?;
            }
            if let Some(d) = &v.depth {
                d.write_exr(dir.join(format!("depth_{}.exr", v.name)))?;
            }
        }
        Ok(())
    }

    /// Reads a folder written by [`ViewSet::save`] (or by `wonder3d render` /
    /// `wonder3d generate`), checked as by [`ViewSet::new`]; errors name the folder.
    ///
    /// When `cameras.json` lists the files of its render (as [`ViewSet::save`] writes it),
    /// every listed file that is present must have the recorded size and hash, and every
    /// view file present must be listed: a folder mixing two renders (a failed write into an
    /// old folder, files copied in) is refused, naming the file.
    pub fn load(dir: impl AsRef<Path>) -> Result<ViewSet> {
        let dir = dir.as_ref();
        let rig = ViewRig::load_json(dir.join(MANIFEST))?;
        check_manifest(dir, &rig)?;
        let mut views = Vec::with_capacity(rig.views.len());
        for r in &rig.views {
            let name = &r.name;
            let exr_path = dir.join(format!("normal_{name}.exr"));
            let png_path = dir.join(format!("normal_{name}.png"));
            let (normal, alpha) = if present(&exr_path)? {
                let img = Image::read_exr(&exr_path)?;
                split_rgba(&img, |x| x)
            } else {
                let img = Image::read_png_channels(&png_path, 4)?;
                split_rgba(&img, |x| x * 2.0 - 1.0)
            };
            let mask_path = dir.join(format!("mask_{name}.png"));
            let mask = if present(&mask_path)? { Image::read_png_channels(&mask_path, 1)? } else { alpha };
            let colour_path = dir.join(format!("colour_{name}.png"));
            let colour = if present(&colour_path)? {
                let img = Image::read_png(&colour_path)?;
                match img.channels() {
                    3 => Some(img),
                    4 => Some(split_rgba(&img, |x| x).0),
                    c => {
                        return Err(Error::format(
                            &colour_path,
                            "PNG channels",
                            format!("RGB or RGBA, got {c} channels"),
                        ));
                    }
                }
            } else {
                None
            };
            let depth_path = dir.join(format!("depth_{name}.exr"));
            let depth = if present(&depth_path)? {
                let img = Image::read_exr(&depth_path)?;
                let d: Vec<f32> = img.data().chunks_exact(4).map(|p| p[0]).collect();
                Some(Image::new(img.width(), img.height(), 1, d)?)
            } else {
                None
            };
            views.push(ViewImages { name: name.clone(), normal, colour, mask, depth });
        }
        ViewSet::new(rig, views).map_err(|e| e.in_file(dir))
    }
}

/// The image size shared by most images of `views` (ties: the first view's mask's).
fn common_size(views: &[ViewImages]) -> (u32, u32) {
    let mut counts: Vec<((u32, u32), usize)> = Vec::new();
    let images = views.iter().flat_map(|v| [Some(&v.mask), Some(&v.normal), v.colour.as_ref(), v.depth.as_ref()]);
    for image in images.flatten() {
        let size = (image.width(), image.height());
        match counts.iter_mut().find(|(s, _)| *s == size) {
            Some((_, n)) => *n += 1,
            None => counts.push((size, 1)),
        }
    }
    // `max_by_key` keeps the last maximum: scan in reverse so ties go to the first size.
    counts.iter().rev().max_by_key(|(_, n)| *n).map(|(s, _)| *s).unwrap_or((0, 0))
}

/// Whether `name` is a file of the view-set layout (the files [`ViewSet::save_with`] may
/// replace).
#[cfg(feature = "io")]
fn is_view_set_file(name: &str) -> bool {
    const KINDS: [(&str, &str); 5] =
        [("normal_", ".png"), ("normal_", ".exr"), ("colour_", ".png"), ("mask_", ".png"), ("depth_", ".exr")];
    matches!(name, "cameras.json" | "input.png" | "views.png")
        || KINDS.iter().any(|(prefix, ext)| name.starts_with(prefix) && name.ends_with(ext))
}

/// Whether the view file `path` is there to be read: `false` when nothing has that name,
/// `true` for a regular file (links followed), an error naming it for anything else (a
/// folder, a FIFO, a device, a dangling link), which would otherwise be passed over for
/// the view's other files without a word.
#[cfg(feature = "io")]
fn present(path: &Path) -> Result<bool> {
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(false),
        Err(e) => Err(Error::io(path, e)),
        Ok(_) => crate::files::regular_file(path).map(|_| true),
    }
}

/// The files the loader may read for view `name`.
#[cfg(feature = "io")]
fn view_file_names(name: &str) -> [String; 5] {
    [
        format!("normal_{name}.exr"),
        format!("normal_{name}.png"),
        format!("mask_{name}.png"),
        format!("colour_{name}.png"),
        format!("depth_{name}.exr"),
    ]
}

/// Writes `cameras.json` into `dir`: the rig, plus `files`, the size and hash of every view
/// file already in `dir`.
#[cfg(feature = "io")]
fn write_manifest(dir: &Path, rig: &ViewRig) -> Result<()> {
    let mut files = serde_json::Map::new();
    for r in &rig.views {
        for name in view_file_names(&r.name) {
            let path = dir.join(&name);
            if path.is_file() {
                let bytes = std::fs::read(&path).map_err(|e| Error::io(&path, e))?;
                files.insert(
                    name,
                    serde_json::json!({ "bytes": bytes.len(), "fnv1a64": crate::files::fnv1a64(&bytes) }),
                );
            }
        }
    }
    let mut value = serde_json::to_value(rig).expect("a rig always serialises");
    value["files"] = serde_json::Value::Object(files);
    let text = serde_json::to_string_pretty(&value).expect("JSON values serialise");
    let path = dir.join(MANIFEST);
    crate::files::write_atomic(&path, |w| {
        std::io::Write::write_all(w, text.as_bytes()).map_err(|e| Error::io(&path, e))
    })
}

/// The checks of [`ViewSet::load`] against the `files` list of `cameras.json`, if it has
/// one (folders written before the list existed, or edited by hand with the list removed,
/// load without it).
#[cfg(feature = "io")]
fn check_manifest(dir: &Path, rig: &ViewRig) -> Result<()> {
    let cameras = dir.join(MANIFEST);
    let text = std::fs::read_to_string(&cameras).map_err(|e| Error::io(&cameras, e))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| Error::format(&cameras, "JSON", format!("a camera rig ({e})")))?;
    let Some(files) = value.get("files") else { return Ok(()) };
    let files = files
        .as_object()
        .ok_or_else(|| Error::format(&cameras, "files", "an object mapping file names to {\"bytes\", \"fnv1a64\"}"))?;
    let tip = "the folder mixes files of different renders; render it again (or, for files edited on \
               purpose, delete the \"files\" list from cameras.json)";
    for r in &rig.views {
        for name in view_file_names(&r.name) {
            let path = dir.join(&name);
            if !present(&path)? {
                continue;
            }
            let Some(entry) = files.get(&name) else {
                return Err(Error::format(
                    &path,
                    "file",
                    format!("a file listed in cameras.json, which does not list it: {tip}"),
                ));
            };
            let (bytes, hash) =
                (entry.get("bytes").and_then(|b| b.as_u64()), entry.get("fnv1a64").and_then(|h| h.as_str()));
            let (Some(bytes), Some(hash)) = (bytes, hash) else {
                return Err(Error::format(&cameras, format!("files.{name}"), "{\"bytes\": N, \"fnv1a64\": \"HEX\"}"));
            };
            let len = std::fs::metadata(&path).map_err(|e| Error::io(&path, e))?.len();
            let matches = len == bytes && {
                let data = std::fs::read(&path).map_err(|e| Error::io(&path, e))?;
                crate::files::fnv1a64(&data) == hash
            };
            if !matches {
                return Err(Error::format(
                    &path,
                    "content",
                    format!(
                        "the file cameras.json lists ({bytes} bytes, FNV-1a {hash}), got {len} bytes of other content: {tip}"
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Splits an RGBA image into (RGB mapped by `f`, alpha).
#[cfg(feature = "io")]
fn split_rgba(img: &Image, f: impl Fn(f32) -> f32) -> (Image, Image) {
    let rgb: Vec<f32> = img.data().chunks_exact(4).flat_map(|p| [f(p[0]), f(p[1]), f(p[2])]).collect();
    let a: Vec<f32> = img.data().chunks_exact(4).map(|p| p[3]).collect();
    let (w, h) = (img.width(), img.height());
    (Image::new(w, h, 3, rgb).expect("same size"), Image::new(w, h, 1, a).expect("same size"))
}
