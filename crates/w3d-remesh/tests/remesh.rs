//! w3d-remesh's integration tests, in one test binary (one link instead of 4). Run one group with
//! `cargo test --release -p w3d-remesh --test remesh <group>::`.

#[path = "common/mod.rs"]
mod common;

#[path = "remesh/curvature.rs"]
mod curvature;
#[path = "remesh/golden.rs"]
mod golden;
#[path = "remesh/invariants.rs"]
mod invariants;
#[path = "remesh/repair_ops.rs"]
mod repair_ops;
#[path = "remesh/shape_fit.rs"]
mod shape_fit;
#[path = "remesh/simplify.rs"]
mod simplify;
