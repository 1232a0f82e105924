//! The end-to-end tests, in one test binary (one link instead of 2). Run one group with
//! `cargo test --release -p wonder3d-tests --test end_to_end <group>::`.

#[path = "end_to_end/assets.rs"]
mod assets;
#[path = "end_to_end/recon_oracle.rs"]
mod recon_oracle;
#[path = "end_to_end/view_agreement.rs"]
mod view_agreement;
