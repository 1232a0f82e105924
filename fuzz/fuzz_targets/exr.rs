//! OpenEXR files through `Image::read_exr` (header size checked, then decoded).
#![no_main]

#[path = "common.rs"]
mod common;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    let path = common::file("input.exr", bytes);
    if let Ok(image) = w3d_core::Image::read_exr(&path) {
        common::check_image(&image);
    }
});
