//! OpenEXR files as view folders read them: the header's size checked first, then decoded.
#![no_main]

#[path = "common.rs"]
mod common;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    let path = common::file("input.exr", bytes);
    if let Ok(image) = w3d_core::io::check_exr_size(&path).and_then(|()| w3d_core::Image::read_exr(&path)) {
        common::check_image(&image);
    }
});
