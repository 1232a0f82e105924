//! Runs the `step_remesh` benchmark's workload (one optimizer step plus one remesh on a
//! geodesic sphere, pulled towards a wavy sphere) a fixed number of times, for instruction
//! counts under callgrind, which do not depend on machine load:
//!
//! ```text
//! cargo build --release -p w3d-remesh --example step_remesh_profile
//! valgrind --tool=callgrind --toggle-collect='*measured_round*' \
//!     target/release/examples/step_remesh_profile 71 10
//! ```
//!
//! Arguments: the sphere's frequency (32 → 10 242 vertices, 71 → 50 412) and the number of
//! measured rounds; the instructions inside `measured_round` divided by the rounds are the
//! cost of one step + remesh.

#[path = "../benches/workload/mod.rs"]
mod workload;

use w3d_remesh::MeshOptimizer;
use workload::{steady_state_optimizer, wavy_sphere_gradient};

/// The measured part: one step + remesh (the gradient is computed outside, as in the
/// benchmark); returns the number of remesh operations.
#[inline(never)]
fn measured_round(opt: &mut MeshOptimizer, grad: &[[f32; 3]]) -> usize {
    opt.step(grad).expect("step");
    let stats = opt.remesh();
    stats.collapsed + stats.split + stats.flipped
}

fn main() {
    let args: Vec<usize> = std::env::args().skip(1).map(|a| a.parse().expect("a number")).collect();
    let (frequency, rounds) = (args.first().copied().unwrap_or(71) as u32, args.get(1).copied().unwrap_or(10));
    let mut opt = steady_state_optimizer(frequency);
    let mut operations = 0;
    for _ in 0..rounds {
        let grad = wavy_sphere_gradient(opt.positions());
        operations += measured_round(&mut opt, &grad);
    }
    println!("{} vertices, {rounds} rounds, {operations} remesh operations", opt.vertex_count());
}
