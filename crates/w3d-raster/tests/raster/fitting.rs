//! End-to-end behaviour through the public API: a mask-only loss moves a silhouette,
//! results are identical with any thread count, bad input is an error.

use w3d_core::glam::Vec3;
use w3d_core::{Mesh, ViewRig};
use w3d_raster::{
    EdgeTopology, antialias, antialias_backward, interpolate, interpolate_backward, rasterize_backward, rasterize_rig,
    rasterize_views, render_oracle_views,
};

/// A unit sphere: an octahedron subdivided `levels` times, vertices pushed to radius 1.
fn sphere(levels: u32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let mut p: Vec<Vec3> = vec![Vec3::X, -Vec3::X, Vec3::Y, -Vec3::Y, Vec3::Z, -Vec3::Z];
    let mut t: Vec<[u32; 3]> =
        vec![[0, 2, 4], [4, 2, 1], [1, 2, 5], [5, 2, 0], [4, 3, 0], [1, 3, 4], [5, 3, 1], [0, 3, 5]];
    for _ in 0..levels {
        let mut mid = std::collections::HashMap::new();
        let mut next = Vec::new();
        for tri in &t {
            let m: [u32; 3] = std::array::from_fn(|k| {
                let (a, b) = (tri[k].min(tri[(k + 1) % 3]), tri[k].max(tri[(k + 1) % 3]));
                *mid.entry((a, b)).or_insert_with(|| {
                    p.push((p[a as usize] + p[b as usize]).normalize());
                    (p.len() - 1) as u32
                })
            });
            next.extend([[tri[0], m[0], m[2]], [m[0], tri[1], m[1]], [m[2], m[1], tri[2]], [m[0], m[1], m[2]]]);
        }
        t = next;
    }
    (p.iter().map(|v| v.normalize().to_array()).collect(), t)
}

/// Initial step size (world units per unit of gradient).
const LR: f32 = 1e-3;
/// Rings of neighbours the step is diffused over.
const SMOOTHING_RINGS: usize = 3;
/// Step decay per iteration.
const DECAY: f32 = 0.98;

fn transformed(p: &[[f32; 3]], scale: f32, shift: Vec3) -> Vec<[f32; 3]> {
    p.iter().map(|&v| (Vec3::from(v) * scale + shift).to_array()).collect()
}

/// Anti-aliased masks of every view of the rig.
fn masks(p: &[[f32; 3]], t: &[[u32; 3]], rig: &ViewRig, size: u32) -> Vec<Vec<f32>> {
    let cams: Vec<_> = rig.cameras().copied().collect();
    let topo = EdgeTopology::new(p, t).unwrap();
    rasterize_views(p, t, &cams, size, size)
        .unwrap()
        .iter()
        .map(|r| antialias(&r.coverage(), 1, r, p, t, &topo).unwrap().image)
        .collect()
}

#[test]
fn mask_loss_pulls_a_sphere_onto_the_target_silhouette() {
    let rig = ViewRig::wonder3d_ortho();
    let size = 64;
    let (unit, tris) = sphere(3);
    let target = masks(&transformed(&unit, 0.4, Vec3::new(0.04, -0.03, 0.02)), &tris, &rig, size);
    let mut p = transformed(&unit, 0.33, Vec3::ZERO);
    let topo = EdgeTopology::new(&p, &tris).unwrap();
    let cams: Vec<_> = rig.cameras().copied().collect();
    let mut losses = Vec::new();
    for iteration in 0..100 {
        let rasters = rasterize_views(&p, &tris, &cams, size, size).unwrap();
        let mut grad = vec![Vec3::ZERO; p.len()];
        let mut loss = 0.0f64;
        for (r, tgt) in rasters.iter().zip(&target) {
            let mask = r.coverage();
            let aa = antialias(&mask, 1, r, &p, &tris, &topo).unwrap();
            let g: Vec<f32> = aa.image.iter().zip(tgt).map(|(a, b)| 2.0 * (a - b)).collect();
            loss += aa.image.iter().zip(tgt).map(|(a, b)| ((a - b) as f64).powi(2)).sum::<f64>();
            let back = antialias_backward(&aa, &mask, 1, r, &p, &tris, &g).unwrap();
            for (acc, v) in grad.iter_mut().zip(&back.positions) {
                *acc += Vec3::from(*v);
            }
        }
        losses.push(loss);
        // Gradient descent with the step diffused over a few rings of neighbours, so that
        // vertices off the silhouettes follow their neighbours and the mesh stays smooth.
        let mut step = grad;
        for _ in 0..SMOOTHING_RINGS {
            let mut next = step.clone();
            let mut count = vec![1.0f32; p.len()];
            for tri in &tris {
                for k in 0..3 {
                    let (a, b) = (tri[k] as usize, tri[(k + 1) % 3] as usize);
                    next[a] += step[b];
                    next[b] += step[a];
                    count[a] += 1.0;
                    count[b] += 1.0;
                }
            }
            step = next.iter().zip(&count).map(|(s, c)| *s / *c).collect();
        }
        for (v, s) in p.iter_mut().zip(&step) {
            *v = (Vec3::from(*v) - LR * DECAY.powi(iteration) * *s).to_array();
        }
    }
    let (first, last) = (losses[0], *losses.last().unwrap());
    println!(
        "mask loss {first:.3} -> {last:.4} ({:.1}x): {:?}",
        first / last,
        losses.iter().step_by(15).map(|l| *l as f32).collect::<Vec<_>>()
    );
    assert!(last * 10.0 <= first, "mask loss only fell from {first} to {last}");
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let (unit, tris) = sphere(3);
    let p = transformed(&unit, 0.4, Vec3::new(0.02, 0.01, 0.0));
    let rig = ViewRig::wonder3d_persp();
    let run = || {
        let cams: Vec<_> = rig.cameras().copied().collect();
        let topo = EdgeTopology::new(&p, &tris).unwrap();
        let attr: Vec<f32> = p.iter().flatten().copied().collect();
        let mut bytes = Vec::new();
        for r in rasterize_views(&p, &tris, &cams, 96, 96).unwrap() {
            let img = interpolate(&attr, 3, &tris, &r).unwrap();
            let aa = antialias(&img, 3, &r, &p, &tris, &topo).unwrap();
            let g: Vec<f32> = aa.image.iter().map(|v| v.sin()).collect();
            let ga = antialias_backward(&aa, &img, 3, &r, &p, &tris, &g).unwrap();
            let gi = interpolate_backward(&attr, 3, &tris, &r, &ga.colour).unwrap();
            let gp = rasterize_backward(&r, &p, &tris, &gi.uv, Some(&r.depth)).unwrap();
            let floats = r.uv.iter().flatten().chain(&r.depth).chain(&aa.image).chain(ga.positions.iter().flatten());
            bytes.extend(floats.chain(gi.attributes.iter()).chain(gp.iter().flatten()).flat_map(|v| v.to_le_bytes()));
            bytes.extend(r.triangle.iter().flat_map(|t| t.to_le_bytes()));
        }
        let mesh = Mesh::new(p.clone(), tris.clone()).unwrap();
        for v in render_oracle_views(&mesh, &rig, 64).unwrap().views() {
            bytes.extend(v.normal.data().iter().chain(v.mask.data()).flat_map(|x| x.to_le_bytes()));
        }
        bytes
    };
    let pool = |n| rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
    let one = pool(1).install(run);
    let two = pool(2).install(run);
    let three = pool(3).install(run);
    assert!(one == two && two == three);
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let (p, t) = sphere(1);
    let mesh = Mesh::new(p.clone(), t.clone()).unwrap();
    let rig = ViewRig::wonder3d_ortho();
    let cams: Vec<_> = rig.cameras().copied().collect();
    assert!(rasterize_rig(&mesh, &rig, 0).is_err());
    let mut nan = p.clone();
    nan[3][1] = f32::NAN;
    let err = rasterize_views(&nan, &t, &cams, 16, 16).unwrap_err().to_string();
    assert!(err.contains("positions[3].y"), "{err}");
    let mut bad = t.clone();
    bad[2][0] = 999;
    let err = rasterize_views(&p, &bad, &cams, 16, 16).unwrap_err().to_string();
    assert!(err.contains("triangles[2]"), "{err}");
    assert!(EdgeTopology::new(&p, &bad).is_err());
    let r = &rasterize_views(&p, &t, &cams, 16, 16).unwrap()[0];
    assert!(interpolate(&[0.0; 4], 3, &t, r).is_err());
    assert!(antialias(&[0.0; 10], 1, r, &p, &t, &EdgeTopology::new(&p, &t).unwrap()).is_err());
    let empty_rig = ViewRig { name: "empty".into(), views: vec![] };
    assert!(render_oracle_views(&mesh, &empty_rig, 16).is_err());
}
