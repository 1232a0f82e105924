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

use w3d_remesh::{MeshOptimizer, RemeshOptions, geodesic_sphere};

fn wavy_sphere_gradient(positions: &[[f32; 3]]) -> Vec<[f32; 3]> {
    positions
        .iter()
        .map(|p| {
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt().max(1e-6);
            let target = 0.4 + 0.05 * (6.0 * p[0]).sin() * (6.0 * p[1]).sin() * (6.0 * p[2]).cos();
            p.map(|c| (r - target) * c / r)
        })
        .collect()
}

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
    let sphere = geodesic_sphere(frequency, 0.4).expect("sphere");
    let p = sphere.positions();
    let edges = sphere.edges();
    let mean = edges
        .iter()
        .map(|&[a, b]| {
            let (a, b) = (p[a as usize], p[b as usize]);
            ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
        })
        .sum::<f32>()
        / edges.len() as f32;
    let options = RemeshOptions { edge_len_lims: (mean, mean), ..RemeshOptions::default() };
    let mut opt = MeshOptimizer::from_mesh(&sphere, options).expect("optimizer");
    for _ in 0..5 {
        let grad = wavy_sphere_gradient(opt.positions());
        opt.step(&grad).expect("step");
        opt.remesh();
    }
    let mut operations = 0;
    for _ in 0..rounds {
        let grad = wavy_sphere_gradient(opt.positions());
        operations += measured_round(&mut opt, &grad);
    }
    println!("{} vertices, {rounds} rounds, {operations} remesh operations", opt.vertex_count());
}
