//! `cameras.json` (a view rig) through `ViewRig::load_json`; a loaded rig validates.
#![no_main]

#[path = "common.rs"]
mod common;

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| {
    if let Ok(rig) = w3d_core::ViewRig::load_json(common::file("cameras.json", bytes)) {
        rig.validate().expect("a loaded rig is valid");
    }
});
