//! PNG, JPEG and WebP bytes through `Image::decode` with the default size limits (what
//! `Image::read` runs after reading the file).
#![no_main]

#[path = "common.rs"]
mod common;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    if let Ok(image) = w3d_core::Image::decode(bytes, &w3d_core::image::ReadLimits::default()) {
        common::check_image(&image);
        assert!(image.data().iter().all(|v| v.is_finite()));
    }
});
