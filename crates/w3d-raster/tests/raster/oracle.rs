//! Independent oracle: triangle ids and depths from the rasteriser agree with ray casting
//! through an `obvhs` BVH, and closed meshes show no cracks.

use std::time::Duration;

use obvhs::{
    BvhBuildParams,
    bvh2::builder::build_bvh2_from_tris,
    ray::{Ray, RayHit},
    triangle::Triangle,
};
use rayon::prelude::*;
use w3d_core::glam::Vec3A;
use w3d_core::{Mesh, ViewRig, load_mesh};
use w3d_raster::{NO_TRIANGLE, rasterize_rig};

fn mesh(name: &str) -> Mesh {
    let path = format!("{}/../../../shared/data/meshes/{name}", env!("CARGO_MANIFEST_DIR"));
    let mut mesh = load_mesh(path).unwrap();
    mesh.normalize_unit_cube();
    mesh
}

/// Per pixel `(triangle id or NO_TRIANGLE, depth)` by ray casting.
fn ray_cast(mesh: &Mesh, camera: &w3d_core::Camera, size: u32) -> Vec<(u32, f32)> {
    let tris: Vec<Triangle> = (0..mesh.triangle_count())
        .map(|t| {
            let [a, b, c] = mesh.triangle_corners(t).map(Vec3A::from);
            Triangle { v0: a, v1: b, v2: c }
        })
        .collect();
    let bvh = build_bvh2_from_tris(&tris, BvhBuildParams::medium_build(), &mut Duration::default());
    let forward = camera.forward();
    (0..size * size)
        .into_par_iter()
        .map(|i| {
            let r = camera.ray((i % size) as f32 + 0.5, (i / size) as f32 + 0.5, size, size);
            let ray = Ray::new(r.origin.into(), r.direction.into(), 0.0, f32::INFINITY);
            let mut hit = RayHit::none();
            if bvh.ray_traverse(ray, &mut hit, |ray, id| tris[bvh.primitive_indices[id] as usize].intersect(ray)) {
                (bvh.primitive_indices[hit.primitive_id as usize], hit.t * r.direction.dot(forward))
            } else {
                (NO_TRIANGLE, 0.0)
            }
        })
        .collect()
}

#[test]
fn rasteriser_agrees_with_ray_casting() {
    let size = 256;
    for name in ["spot.obj", "armadillo.obj", "plane.obj"] {
        let mesh = mesh(name);
        for rig in [ViewRig::wonder3d_ortho(), ViewRig::wonder3d_persp(), ViewRig::syncdreamer16()] {
            let rasters = rasterize_rig(&mesh, &rig, size).unwrap();
            let (mut agree, mut total, mut cracks, mut covered) = (0usize, 0usize, 0usize, 0usize);
            let (mut fg_agree, mut fg_union) = (0usize, 0usize);
            for (raster, view) in rasters.iter().zip(&rig.views) {
                let oracle = ray_cast(&mesh, &view.camera, size);
                for (i, &(id, depth)) in oracle.iter().enumerate() {
                    let t = raster.triangle[i];
                    total += 1;
                    covered += (t != NO_TRIANGLE) as usize;
                    let same = t == id && (t == NO_TRIANGLE || (raster.depth[i] - depth).abs() < 1e-4);
                    agree += same as usize;
                    if t != NO_TRIANGLE || id != NO_TRIANGLE {
                        fg_union += 1;
                        fg_agree += same as usize;
                    }
                    // A crack: the ray hits, the raster is empty, but all four neighbours are covered.
                    let (col, row) = (i as u32 % size, i as u32 / size);
                    let neighbours_covered = [(0, -1), (0, 1), (-1, 0), (1, 0)].iter().all(|&(dc, dr)| {
                        raster.triangle_at((col as i32 + dc) as u32, (row as i32 + dr) as u32).is_some()
                    });
                    if t == NO_TRIANGLE && id != NO_TRIANGLE && neighbours_covered {
                        cracks += 1;
                    }
                }
            }
            let fraction = agree as f64 / total as f64;
            let fg_fraction = fg_agree as f64 / fg_union as f64;
            println!(
                "{name} {}: {:.4} % of {total} pixels agree ({:.4} % of the {fg_union} foreground ones), {covered} covered, {cracks} cracks",
                rig.name,
                100.0 * fraction,
                100.0 * fg_fraction
            );
            assert!(fraction >= 0.999 && fg_fraction >= 0.999, "{name} {}: {fraction} / {fg_fraction}", rig.name);
            assert_eq!(cracks, 0, "{name} {}", rig.name);
            assert!(covered > total / 20, "{name} {}: the mesh is barely visible", rig.name);
        }
    }
}
