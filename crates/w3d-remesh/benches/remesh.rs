//! `step_remesh/{10k,50k}`: one optimizer step plus one remesh on geodesic spheres of
//! 10 242 and 50 412 vertices, driven by a smooth synthetic gradient (pull towards a wavy
//! sphere). The target edge length is pinned to the start mesh's mean edge length so the
//! vertex count stays put and every iteration does comparable work.
//!
//! `simplify/50k`: quadric simplification of the 50 412-vertex geodesic sphere pulled
//! towards the wavy sphere (about 100 k triangles of a bumpy closed surface) at tolerance
//! 0.0005, the refinement's default.
#![allow(missing_docs)] // criterion_group! generates an undocumented function

use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
mod workload;

use workload::{steady_state_optimizer, wavy_sphere_gradient};

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("step_remesh");
    for (name, frequency) in [("10k", 32), ("50k", 71)] {
        let mut opt = steady_state_optimizer(frequency);
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

    let mut group = c.benchmark_group("simplify");
    group.sample_size(10);
    // The gradient is `(r − target) · p / r`, so `p − gradient` lies on the wavy sphere.
    let sphere = w3d_remesh::geodesic_sphere(71, 0.4).expect("sphere");
    let pull = wavy_sphere_gradient(sphere.positions());
    let positions: Vec<[f32; 3]> =
        sphere.positions().iter().zip(&pull).map(|(p, g)| std::array::from_fn(|k| p[k] - g[k])).collect();
    let wavy = w3d_core::Mesh::new(positions, sphere.triangles().to_vec()).expect("mesh");
    let options = w3d_remesh::SimplifyOptions::default();
    group.bench_function("50k", |b| {
        b.iter(|| std::hint::black_box(w3d_remesh::simplify(&wavy, &options).expect("simplify")))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
