//! UV atlas on spot (5.9k triangles) and the Stanford bunny (69k triangles, the mesh
//! xatlas takes 118 s on), and a full bake of spot at 1024² from its 256² oracle views.

use std::hint::black_box;

use criterion::Criterion;
use w3d_core::{Mesh, ViewRig, load_mesh};
use w3d_texture::{AtlasOptions, TextureOptions, bake, build_atlas};

fn mesh(path: &str) -> Mesh {
    let mut mesh = load_mesh(format!("{}/../../{path}", env!("CARGO_MANIFEST_DIR"))).expect("bench mesh");
    mesh.normalize_unit_cube();
    mesh
}

fn main() {
    let mut c = Criterion::default().configure_from_args().sample_size(10);
    let spot = mesh("assets/spot.obj");
    let bunny = mesh("../shared/data/meshes/stanford-bunny.obj");
    let options = AtlasOptions::default();
    for (name, m) in [("spot", &spot), ("bunny", &bunny)] {
        let atlas = build_atlas(m, &options).expect("atlas");
        eprintln!(
            "{name}: {} triangles, {} charts, utilisation {:.3}, angle distortion {:.2}°",
            m.triangle_count(),
            atlas.report.charts,
            atlas.report.utilisation,
            atlas.report.angle_distortion_deg
        );
        c.bench_function(&format!("atlas_{name}_{}f", m.triangle_count()), |b| {
            b.iter(|| build_atlas(black_box(m), &options).expect("atlas"))
        });
    }
    let rig = ViewRig::wonder3d_ortho();
    let views = w3d_raster::render_oracle_views(&spot, &rig, 256).expect("views");
    let geometry = spot.clone().without_attributes();
    let texture = TextureOptions::default();
    c.bench_function("bake_spot_1024", |b| b.iter(|| bake(black_box(&geometry), &views, &texture).expect("bake")));
    c.final_summary();
}
