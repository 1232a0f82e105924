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
use crate::rig::ViewRig;
use crate::{Error, Result};

/// The images of one view. All images of a view set share one size.
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

/// One [`ViewImages`] per view of a rig, in rig order.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewSet {
    /// The views.
    pub views: Vec<ViewImages>,
}

impl ViewSet {
    /// Image width in pixels (of the first view; [`ViewSet::validate`] checks the rest).
    pub fn width(&self) -> u32 {
        self.views.first().map_or(0, |v| v.mask.width())
    }

    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.views.first().map_or(0, |v| v.mask.height())
    }

    /// Checks that the set matches `rig` (same count and names) and that every image has
    /// the common size and the documented channel count.
    pub fn validate(&self, rig: &ViewRig) -> Result<()> {
        if self.views.len() != rig.views.len() {
            return Err(Error::invalid(
                "views",
                format!("{} views to match the rig, got {}", rig.views.len(), self.views.len()),
            ));
        }
        let (w, h) = (self.width(), self.height());
        for (i, (v, r)) in self.views.iter().zip(&rig.views).enumerate() {
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
        Ok(())
    }
}

/// View-set folders (feature `io`).
#[cfg(feature = "io")]
impl ViewSet {
    /// Writes the rig and every image into `dir` (created if needed), in the layout of
    /// the module documentation. Each file is written atomically.
    pub fn save(&self, dir: impl AsRef<Path>, rig: &ViewRig) -> Result<()> {
        let dir = dir.as_ref();
        self.validate(rig)?;
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        rig.save_json(dir.join("cameras.json"))?;
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
    /// `wonder3d generate`), returning the view set and its rig.
    pub fn load(dir: impl AsRef<Path>) -> Result<(ViewSet, ViewRig)> {
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
        let set = ViewSet { views };
        set.validate(&rig).map_err(|e| e.in_file(dir))?;
        Ok((set, rig))
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
