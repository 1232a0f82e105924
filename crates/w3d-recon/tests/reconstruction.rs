//! w3d-recon's integration tests, in one test binary (one link instead of 5). Run one group with
//! `cargo test --release -p w3d-recon --test reconstruction <group>::`.

#[path = "reconstruction/common.rs"]
mod common;

#[path = "reconstruction/coarse.rs"]
mod coarse;
#[path = "reconstruction/init.rs"]
mod init;
#[path = "reconstruction/integrate.rs"]
mod integrate;
#[path = "reconstruction/untangle.rs"]
mod untangle;
#[path = "reconstruction/views.rs"]
mod views;
