//! w3d-raster's integration tests, in one test binary (one link instead of 2). Run one group with
//! `cargo test --release -p w3d-raster --test raster <group>::`.

#[path = "raster/fitting.rs"]
mod fitting;
#[path = "raster/oracle.rs"]
mod oracle;
