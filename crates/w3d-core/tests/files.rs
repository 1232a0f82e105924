//! w3d-core's integration tests, in one test binary (one link instead of six): reading and
//! writing mesh, image and view files, hostile and byte-mutated input, cameras and rigs.
//! Run one group with `cargo test --release -p w3d-core --test files <group>::`, e.g.
//! `fuzz_loaders::`.

#[path = "common/mod.rs"]
mod common;
#[path = "mutate/mod.rs"]
mod mutate;

#[path = "files/bad_input.rs"]
mod bad_input;
#[path = "files/cameras_and_rigs.rs"]
mod cameras_and_rigs;
#[path = "files/fuzz_loaders.rs"]
mod fuzz_loaders;
#[path = "files/hostile_input.rs"]
mod hostile_input;
#[path = "files/image_read.rs"]
mod image_read;
#[path = "files/io_roundtrip.rs"]
mod io_roundtrip;
