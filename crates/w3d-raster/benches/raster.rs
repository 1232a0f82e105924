//! Forward and forward+backward of the differentiable rasteriser over the 6-view
//! orthographic rig: rasterize → interpolate (vertex normals) → antialias, and back to
//! vertex positions and attributes. Meshes: spot (5.9k triangles), armadillo (29k).

use std::hint::black_box;

use criterion::Criterion;
use rayon::prelude::*;
use w3d_core::{Mesh, ViewRig, load_mesh};
use w3d_raster::{
    EdgeTopology, Raster, antialias, antialias_backward, interpolate, interpolate_backward, rasterize_backward,
    rasterize_rig,
};

struct Scene {
    mesh: Mesh,
    normals: Vec<f32>,
    topology: EdgeTopology,
}

fn scene(name: &str) -> Scene {
    let path = format!("{}/../../../shared/data/meshes/{name}.obj", env!("CARGO_MANIFEST_DIR"));
    let mut mesh = load_mesh(path).expect("bench mesh");
    mesh.normalize_unit_cube();
    let normals = mesh.vertex_normals().into_iter().flatten().collect();
    let topology = EdgeTopology::new(mesh.positions(), mesh.triangles()).expect("topology");
    Scene { mesh, normals, topology }
}

/// Forward of one view: the anti-aliased normal image.
fn forward_view(s: &Scene, r: &Raster) -> (Vec<f32>, w3d_raster::Antialiased) {
    let (p, t) = (s.mesh.positions(), s.mesh.triangles());
    let img = interpolate(&s.normals, 3, t, r).expect("interpolate");
    let aa = antialias(&img, 3, r, p, t, &s.topology).expect("antialias");
    (img, aa)
}

fn forward(s: &Scene, rig: &ViewRig, size: u32) -> Vec<Vec<f32>> {
    let rasters = rasterize_rig(&s.mesh, rig, size).expect("rasterize");
    rasters.par_iter().map(|r| forward_view(s, r).1.image).collect()
}

/// Forward, an L2 loss against zero, and the backward pass to positions (summed over views).
fn forward_backward(s: &Scene, rig: &ViewRig, size: u32) -> Vec<[f32; 3]> {
    let (p, t) = (s.mesh.positions(), s.mesh.triangles());
    let rasters = rasterize_rig(&s.mesh, rig, size).expect("rasterize");
    let per_view: Vec<Vec<[f32; 3]>> = rasters
        .par_iter()
        .map(|r| {
            let (img, aa) = forward_view(s, r);
            let g: Vec<f32> = aa.image.iter().map(|v| 2.0 * v).collect();
            let ga = antialias_backward(&aa, &img, 3, r, p, t, &g).expect("antialias backward");
            let gi = interpolate_backward(&s.normals, 3, t, r, &ga.colour).expect("interpolate backward");
            let mut gp = rasterize_backward(r, p, t, &gi.uv, None).expect("rasterize backward");
            for (a, b) in gp.iter_mut().zip(&ga.positions) {
                *a = [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
            }
            gp
        })
        .collect();
    let mut total = vec![[0.0f32; 3]; p.len()];
    for view in per_view {
        for (a, b) in total.iter_mut().zip(view) {
            *a = [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
        }
    }
    total
}

fn bench(c: &mut Criterion) {
    let rig = ViewRig::wonder3d_ortho();
    let mut group = c.benchmark_group("raster");
    group.sample_size(10);
    for name in ["spot", "armadillo"] {
        let s = scene(name);
        for size in [256u32, 512] {
            group.bench_function(format!("{name}/6x{size}/forward"), |b| b.iter(|| black_box(forward(&s, &rig, size))));
            group.bench_function(format!("{name}/6x{size}/forward_backward"), |b| {
                b.iter(|| black_box(forward_backward(&s, &rig, size)))
            });
        }
    }
    group.finish();
}

fn main() {
    let mut c = Criterion::default().configure_from_args();
    bench(&mut c);
    c.final_summary();
}
