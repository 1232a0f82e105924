//! The `step_remesh` workload, shared by the criterion benchmark (`benches/remesh.rs`) and
//! the callgrind driver (`examples/step_remesh_profile.rs`) so both measure the same thing:
//! a geodesic sphere pulled towards a wavy sphere, its target edge length pinned to the
//! start mesh's mean edge length so the vertex count stays put.

use w3d_remesh::{MeshOptimizer, RemeshOptions, geodesic_sphere};

/// Gradient of a pull towards the wavy sphere `r = 0.4 + 0.05·sin 6x·sin 6y·cos 6z`.
pub fn wavy_sphere_gradient(positions: &[[f32; 3]]) -> Vec<[f32; 3]> {
    positions
        .iter()
        .map(|p| {
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt().max(1e-6);
            let target = 0.4 + 0.05 * (6.0 * p[0]).sin() * (6.0 * p[1]).sin() * (6.0 * p[2]).cos();
            p.map(|c| (r - target) * c / r)
        })
        .collect()
}

/// An optimizer on a geodesic sphere of `frequency` (32 → 10 242 vertices, 71 → 50 412),
/// warmed up by 5 rounds into the steady state.
pub fn steady_state_optimizer(frequency: u32) -> MeshOptimizer {
    let sphere = geodesic_sphere(frequency, 0.4).expect("sphere");
    let edges = sphere.edges();
    let p = sphere.positions();
    let mean = edges
        .iter()
        .map(|&[a, b]| {
            let (a, b) = (p[a as usize], p[b as usize]);
            ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
        })
        .sum::<f32>()
        / edges.len() as f32;
    let options = RemeshOptions::default().with_edge_len_lims((mean, mean));
    let mut opt = MeshOptimizer::from_mesh(&sphere, options).expect("optimizer");
    for _ in 0..5 {
        let grad = wavy_sphere_gradient(opt.positions());
        opt.step(&grad).expect("step");
        opt.remesh();
    }
    opt
}
