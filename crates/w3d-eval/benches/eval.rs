//! Speed of the main mesh metrics on armadillo (29k triangles), normalised into the unit
//! cube: Chamfer + F-score at 100k samples per mesh, and volume IoU on the SyncDreamer
//! 64³ lattice. Target: both together in ≤ 2 s on 2 cores. Also the whole [`evaluate`]
//! (adds the 128³ IoU over the union bounding box).

use std::path::PathBuf;

use criterion::Criterion;
use w3d_core::{Mesh, load_mesh};
use w3d_eval::{EvalOptions, Grid, SurfaceComparison, evaluate, sample_surface, volume_iou};

fn armadillo_pair() -> (Mesh, Mesh) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/meshes/armadillo.obj");
    let mut gt = load_mesh(&path).expect("armadillo.obj from ../shared/data/meshes");
    gt.normalize_unit_cube();
    let mut pred = gt.clone();
    pred.map_positions(|p| p * 1.01 + glam::Vec3::new(0.005, 0.0, 0.0)).unwrap();
    (pred, gt)
}

fn bench(c: &mut Criterion) {
    let (pred, gt) = armadillo_pair();
    let mut group = c.benchmark_group("armadillo");
    group.sample_size(10);
    group.bench_function("chamfer_fscore_100k", |b| {
        b.iter(|| {
            let a = sample_surface(&pred, 100_000, 0).unwrap();
            let g = sample_surface(&gt, 100_000, 1).unwrap();
            let s = SurfaceComparison::new(&a, &g).unwrap();
            (s.chamfer(), s.fscore(0.01).unwrap())
        })
    });
    group.bench_function("iou_64", |b| b.iter(|| volume_iou(&pred, &gt, &Grid::syncdreamer64()).unwrap()));
    group.bench_function("chamfer_100k_plus_iou_64", |b| {
        b.iter(|| {
            let a = sample_surface(&pred, 100_000, 0).unwrap();
            let g = sample_surface(&gt, 100_000, 1).unwrap();
            let s = SurfaceComparison::new(&a, &g).unwrap();
            (s.chamfer(), volume_iou(&pred, &gt, &Grid::syncdreamer64()).unwrap())
        })
    });
    group.bench_function("evaluate_all_metrics", |b| b.iter(|| evaluate(&pred, &gt, &EvalOptions::default()).unwrap()));
    group.finish();
}

fn main() {
    let mut c = Criterion::default().configure_from_args();
    bench(&mut c);
    c.final_summary();
}
