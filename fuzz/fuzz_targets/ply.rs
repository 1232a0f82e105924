//! `.ply` files through `w3d_core::load_mesh`.
#![no_main]

#[path = "common.rs"]
mod common;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    if let Ok(mesh) = w3d_core::load_mesh(common::file("input.ply", bytes)) {
        common::check_mesh(&mesh);
    }
});
