//! A size limit for OpenEXR files, checked on the header before any pixel is decoded.

use std::path::Path;

use crate::error::{Error, Result};

/// The most pixels an EXR image may have to be read: 8192² (1 GiB as f32 RGBA). A damaged
/// or hostile header can claim billions of pixels (a 100-byte file asked for 57 GB and
/// aborted the process on allocation); view images here are at most 4096².
pub const MAX_EXR_PIXELS: usize = 8192 * 8192;

/// Fails unless `path` is a regular file whose EXR layers each have at most
/// [`MAX_EXR_PIXELS`] pixels (checked on the header alone). A header the EXR reader
/// cannot parse passes: reading the image reports it. [`crate::ViewSet::load`] calls it
/// before `Image::read_exr`; other callers of `Image::read_exr` on untrusted files should
/// too.
pub fn check_exr_size(path: impl AsRef<Path>) -> Result<()> {
    let path = path.as_ref();
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        return Err(Error::format(path, "file", "a regular file (not a folder, device or pipe)"));
    }
    let Ok(exr) = exr::meta::MetaData::read_from_file(path, false) else { return Ok(()) };
    for (i, header) in exr.headers.iter().enumerate() {
        let (w, h) = (header.layer_size.width(), header.layer_size.height());
        if w.checked_mul(h).is_none_or(|pixels| pixels > MAX_EXR_PIXELS) {
            return Err(Error::format(
                path,
                format!("EXR layer {i} data window"),
                format!("at most {MAX_EXR_PIXELS} pixels (8192²), got {w}×{h}"),
            ));
        }
    }
    Ok(())
}
