//! Binary glTF from memory through `w3d_core::io::read_glb_bytes` (what `load_mesh` runs
//! for a `.glb` file after reading it).
#![no_main]

#[path = "common.rs"]
mod common;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    if let Ok(mesh) = w3d_core::io::read_glb_bytes("input.glb", bytes) {
        common::check_mesh(&mesh);
    }
});
