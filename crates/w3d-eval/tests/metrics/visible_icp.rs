//! Visible-surface Chamfer (SyncDreamer's 16-view depth protocol) and the ICP + scale
//! diagnostic, on boxes and on the shared spot mesh, with 20k surface samples.

use std::path::PathBuf;

use glam::{DMat3, DQuat, DVec3, Vec3};
use w3d_core::{Mesh, load_mesh};
use w3d_eval::{
    IcpOptions, Similarity, SurfaceComparison, VisibleOptions, align_icp_scale, sample_surface, visible_surface_chamfer,
};

fn spot() -> Mesh {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/meshes/spot.obj");
    let mut mesh = load_mesh(path).unwrap();
    mesh.normalize_unit_cube();
    mesh
}

/// Triangles of an axis-aligned box from `lo` to `hi`, wound outwards, with vertex indices
/// starting at `base`.
fn box_parts(lo: Vec3, hi: Vec3, base: u32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let corner = |i: u32| Vec3::select(glam::BVec3::new(i & 1 != 0, i & 2 != 0, i & 4 != 0), hi, lo);
    let positions = (0..8).map(|i| corner(i).to_array()).collect();
    let centre = 0.5 * (lo + hi);
    // Each face: the four corners with one coordinate bit fixed, as two triangles.
    let mut triangles = Vec::new();
    for axis in 0..3 {
        for side in 0..2u32 {
            let bit = 1 << axis;
            let (u, v) = (1 << ((axis + 1) % 3), 1 << ((axis + 2) % 3));
            let f = side * bit;
            for t in [[f, f | u, f | u | v], [f, f | u | v, f | v]] {
                let [a, b, c] = t.map(corner);
                let outward = (b - a).cross(c - a).dot((a + b + c) / 3.0 - centre) > 0.0;
                let t = if outward { t } else { [t[0], t[2], t[1]] };
                triangles.push(t.map(|i| i + base));
            }
        }
    }
    (positions, triangles)
}

fn boxes(parts: &[(Vec3, Vec3)]) -> Mesh {
    let (mut positions, mut triangles) = (Vec::new(), Vec::new());
    for &(lo, hi) in parts {
        let (p, t) = box_parts(lo, hi, positions.len() as u32);
        positions.extend(p);
        triangles.extend(t);
    }
    Mesh::new(positions, triangles).unwrap()
}

fn surface_chamfer(pred: &Mesh, gt: &Mesh) -> f64 {
    let a = sample_surface(pred, 20_000, 0).unwrap();
    let b = sample_surface(gt, 20_000, 1).unwrap();
    SurfaceComparison::new(&a, &b).unwrap().chamfer()
}

#[test]
fn visible_chamfer_is_zero_for_the_same_mesh_and_small_for_a_subpixel_shift() {
    let options = VisibleOptions::default();
    let gt = spot();
    let same = visible_surface_chamfer(&gt, &gt, &options).unwrap();
    println!("spot vs spot: {same:?}");
    assert!(same.chamfer < 1e-6, "{same:?}");
    assert!(same.pred_points > 5_000 && same.pred_points == same.gt_points, "{same:?}");
    // A shift of 0.002 (below the 0.0054 pixel footprint at the rig's 1.5 distance) re-bins
    // the voxels: each mean moves by at most the shift plus a voxel diagonal (0.019); in
    // practice by about 0.003, the noise floor of this metric (SyncDreamer's too).
    let mut moved = gt.clone();
    moved.map_positions(|p| p + Vec3::new(0.002, 0.0, 0.0)).unwrap();
    let near = visible_surface_chamfer(&moved, &gt, &options).unwrap();
    println!("spot shifted 0.002: {near:?}");
    assert!(near.chamfer > 0.001 && near.chamfer < 0.005, "{near:?}");
}

#[test]
fn visible_chamfer_of_a_shifted_slab_is_close_to_the_shift() {
    // 0.9 × 0.01 × 0.9: the cameras (elevation 30°) see its top, which moves by exactly the
    // shift, and thin rims; the bottom is hidden.
    let slab = boxes(&[(Vec3::new(-0.45, -0.005, -0.45), Vec3::new(0.45, 0.005, 0.45))]);
    let mut lifted = slab.clone();
    lifted.map_positions(|p| p + Vec3::new(0.0, 0.02, 0.0)).unwrap();
    let c = visible_surface_chamfer(&lifted, &slab, &VisibleOptions::default()).unwrap();
    println!("slab lifted by 0.02: {c:?}");
    assert!(c.chamfer > 0.018 && c.chamfer < 0.0205, "{c:?}");
}

#[test]
fn hidden_interior_parts_change_the_full_chamfer_but_not_the_visible_one() {
    let outer = (Vec3::splat(-0.4), Vec3::splat(0.4));
    let gt = boxes(&[outer]);
    let pred = boxes(&[outer, (Vec3::splat(-0.2), Vec3::splat(0.2))]);
    let options = VisibleOptions::default();
    let (visible_same, visible_hidden) = (
        visible_surface_chamfer(&gt, &gt, &options).unwrap().chamfer,
        visible_surface_chamfer(&pred, &gt, &options).unwrap().chamfer,
    );
    let (full_same, full_hidden) = (surface_chamfer(&gt, &gt), surface_chamfer(&pred, &gt));
    println!("visible CD {visible_same:.6} -> {visible_hidden:.6}, full CD {full_same:.6} -> {full_hidden:.6}");
    assert!(visible_hidden - visible_same < 1e-4, "visible {visible_same} -> {visible_hidden}");
    assert!(full_hidden - full_same > 0.01, "full {full_same} -> {full_hidden}");
}

#[test]
fn visible_chamfer_rejects_bad_options_and_unseen_meshes() {
    let gt = spot();
    let e = visible_surface_chamfer(&gt, &gt, &VisibleOptions::default().with_size(0)).unwrap_err();
    assert!(e.to_string().contains("size"), "{e}");
    let e = visible_surface_chamfer(&gt, &gt, &VisibleOptions::default().with_voxel(-1.0)).unwrap_err();
    assert!(e.to_string().contains("voxel"), "{e}");
    // Behind every camera's near side: 10 units away, outside all 16 views.
    let far = boxes(&[(Vec3::splat(10.0), Vec3::splat(10.1))]);
    let e = visible_surface_chamfer(&far, &gt, &VisibleOptions::default()).unwrap_err();
    assert!(e.to_string().contains("mesh"), "{e}");
}

#[test]
fn icp_recovers_a_rotated_scaled_shifted_spot() {
    let gt = spot();
    let truth = Similarity {
        scale: 1.07,
        rotation: DMat3::from_quat(DQuat::from_axis_angle(DVec3::new(0.3, 1.0, -0.2).normalize(), 8f64.to_radians())),
        translation: DVec3::new(0.03, -0.02, 0.04),
    };
    let pred = truth.apply_to_mesh(&gt).unwrap();
    let options = IcpOptions::default().with_samples(20_000);
    let found = align_icp_scale(&pred, &gt, &options).unwrap();
    // found ∘ truth should be the identity.
    let rotation_error =
        Similarity { rotation: found.rotation * truth.rotation, ..Similarity::IDENTITY }.rotation_deg();
    let scale_error = (found.scale * truth.scale - 1.0).abs();
    let aligned = found.apply_to_mesh(&pred).unwrap();
    let (before, after, floor) =
        (surface_chamfer(&pred, &gt), surface_chamfer(&aligned, &gt), surface_chamfer(&gt, &gt));
    println!(
        "icp: scale {:.5}, rotation {:.3}°, translation {:?}; rotation error {rotation_error:.4}°, scale error \
         {scale_error:.5}; CD before {before:.5}, after {after:.5}, floor {floor:.5}",
        found.scale,
        found.rotation_deg(),
        found.translation
    );
    assert!(rotation_error < 0.5, "rotation error {rotation_error}°");
    assert!(scale_error < 0.005, "scale error {scale_error}");
    assert!(before > 0.02, "before {before}");
    assert!(after < floor * 1.1, "after {after}, floor {floor}");
    assert_eq!(align_icp_scale(&pred, &gt, &options).unwrap(), found, "not deterministic");
}

#[test]
fn icp_rejects_bad_options() {
    let gt = spot();
    let bad = |o: IcpOptions| align_icp_scale(&gt, &gt, &o).unwrap_err().to_string();
    assert!(bad(IcpOptions::default().with_max_iterations(0)).contains("max_iterations"));
    assert!(bad(IcpOptions::default().with_tolerance(f64::NAN)).contains("tolerance"));
    assert!(bad(IcpOptions::default().with_samples(0)).contains("sample count"));
}
