//! Per-view images (normals, colours, masks, depth) and their folder layout on disk.
//!
//! Folder layout written by [`ViewSet::save`] and read by [`ViewSet::load`]:
//!
//! | file | content |
//! |---|---|
//! | `cameras.json` | the [`ViewRig`] |
//! | `normal_<view>.png` | RGB = (n + 1) / 2 (canonical frame), alpha = mask |
//! | `normal_<view>.exr` | full-precision normals (RGB = n), alpha = mask |
//! | `colour_<view>.png` | sRGB colour, alpha = mask (optional) |
//! | `mask_<view>.png` | the mask as 8-bit grey |
//! | `depth_<view>.exr` | depth in world units along the view axis, 0 on background (optional) |
//!
//! On load, `normal_<view>.exr` is preferred over the PNG when present, and the mask
//! comes from `mask_<view>.png`, or else from the normal map's alpha.

#[cfg(feature = "io")]
use std::path::Path;

use crate::image::Image;
use crate::rig::{RigView, ViewRig};
use crate::{Error, Result};

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
    /// - every image has the size of the first view's mask, and the documented channel count:
    ///   normal 3, mask 1, colour 3, depth 1 (`views[i].normal`, `views[i].mask`, …).
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
        // The rig has at least one view, so `views[0]` exists.
        let (w, h) = (views[0].mask.width(), views[0].mask.height());
        for (i, (v, r)) in views.iter().zip(&rig.views).enumerate() {
            if v.name != r.name {
                return Err(Error::invalid(
                    format!("views[{i}].name"),
                    format!("{:?} as in the rig, got {:?}", r.name, v.name),
                ));
            }
            v.normal.expect_shape(&format!("views[{i}].normal"), w, h, 3)?;
            v.mask.expect_shape(&format!("views[{i}].mask"), w, h, 1)?;
            if let Some(c) = &v.colour {
                c.expect_shape(&format!("views[{i}].colour"), w, h, 3)?;
            }
            if let Some(d) = &v.depth {
                d.expect_shape(&format!("views[{i}].depth"), w, h, 1)?;
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
}

/// View-set folders (feature `io`).
#[cfg(feature = "io")]
impl ViewSet {
    /// Writes the rig and every image into `dir` (created if needed), in the layout of
    /// the module documentation. Each file is written atomically.
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<()> {
        let dir = dir.as_ref();
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        self.rig.save_json(dir.join("cameras.json"))?;
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
    pub fn load(dir: impl AsRef<Path>) -> Result<ViewSet> {
        let dir = dir.as_ref();
        let rig = ViewRig::load_json(dir.join("cameras.json"))?;
        let mut views = Vec::with_capacity(rig.views.len());
        for r in &rig.views {
            let name = &r.name;
            let exr_path = dir.join(format!("normal_{name}.exr"));
            let png_path = dir.join(format!("normal_{name}.png"));
            let (normal, alpha) = if exr_path.is_file() {
                let img = Image::read_exr(&exr_path)?;
                split_rgba(&img, |x| x)
            } else {
                let img = Image::read_png_channels(&png_path, 4)?;
                split_rgba(&img, |x| x * 2.0 - 1.0)
            };
            let mask_path = dir.join(format!("mask_{name}.png"));
            let mask = if mask_path.is_file() { Image::read_png_channels(&mask_path, 1)? } else { alpha };
            let colour_path = dir.join(format!("colour_{name}.png"));
            let colour = if colour_path.is_file() {
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
            let depth = if depth_path.is_file() {
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

/// Splits an RGBA image into (RGB mapped by `f`, alpha).
#[cfg(feature = "io")]
fn split_rgba(img: &Image, f: impl Fn(f32) -> f32) -> (Image, Image) {
    let rgb: Vec<f32> = img.data().chunks_exact(4).flat_map(|p| [f(p[0]), f(p[1]), f(p[2])]).collect();
    let a: Vec<f32> = img.data().chunks_exact(4).map(|p| p[3]).collect();
    let (w, h) = (img.width(), img.height());
    (Image::new(w, h, 3, rgb).expect("same size"), Image::new(w, h, 1, a).expect("same size"))
}
