//! w3d-texture's integration tests, in one test binary (one link instead of 3). Run one group with
//! `cargo test --release -p w3d-texture --test texture <group>::`.

#[path = "texture/atlas.rs"]
mod atlas;
#[path = "texture/fidelity.rs"]
mod fidelity;
#[path = "texture/robustness.rs"]
mod robustness;
