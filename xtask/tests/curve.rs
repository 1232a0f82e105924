//! The xtask binary's pure helpers, compiled into a test harness (the binary has none).

#[path = "../src/curve.rs"]
mod curve;
