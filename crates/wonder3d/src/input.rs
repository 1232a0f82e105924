//! Input images: reading a photo or an RGBA image from a file and preparing it for the
//! model (background removal when there is no alpha, the authors' framing) with the
//! `w3d-photo` crate.

use std::path::Path;

use w3d_core::{Image, Result};
use w3d_photo::{PrepareOptions, Prepared};

/// Reads an image file (PNG, JPEG or WebP, recognised from its bytes; EXIF orientation
/// applied) and prepares it for the model with [`w3d_photo::prepare`]: its own alpha when it
/// has a meaningful one, else automatic background removal (refused, with the reasons,
/// below `options.min_confidence`), then cropped, scaled and centred unless
/// `options.crop` is off. Errors name the file.
pub fn prepare_image(path: impl AsRef<Path>, options: &PrepareOptions) -> Result<Prepared> {
    let path = path.as_ref();
    let image = Image::read(path)?;
    w3d_photo::prepare(&image, options).map_err(|e| e.in_file(path))
}
