//! w3d-eval's integration tests, in one test binary (one link instead of 4). Run one group with
//! `cargo test --release -p w3d-eval --test metrics <group>::`.

#[path = "metrics/peer_parity.rs"]
mod peer_parity;
#[path = "metrics/surface_distance.rs"]
mod surface_distance;
#[path = "metrics/view_agreement.rs"]
mod view_agreement;
#[path = "metrics/visible_icp.rs"]
mod visible_icp;
