//! `step_remesh/{10k,50k}`: one optimizer step plus one remesh on geodesic spheres of
//! 10 242 and 50 412 vertices, driven by a smooth synthetic gradient (pull towards a wavy
//! sphere). The target edge length is pinned to the start mesh's mean edge length so the
//! vertex count stays put and every iteration does comparable work.
#![allow(missing_docs)] // criterion_group! generates an undocumented function

use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
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

fn optimizer(frequency: u32) -> MeshOptimizer {
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
    let options = RemeshOptions { edge_len_lims: (mean, mean), ..RemeshOptions::default() };
    let mut opt = MeshOptimizer::from_mesh(&sphere, options).expect("optimizer");
    // Warm up into the steady state.
    for _ in 0..5 {
        let grad = wavy_sphere_gradient(opt.positions());
        opt.step(&grad).expect("step");
        opt.remesh();
    }
    opt
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("step_remesh");
    for (name, frequency) in [("10k", 32), ("50k", 71)] {
        let mut opt = optimizer(frequency);
        group.bench_function(name, |b| {
            b.iter_custom(|iterations| {
                let mut total = Duration::ZERO;
                for _ in 0..iterations {
                    let grad = wavy_sphere_gradient(opt.positions());
                    let start = Instant::now();
                    opt.step(&grad).expect("step");
                    std::hint::black_box(opt.remesh());
                    total += start.elapsed();
                }
                total
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
