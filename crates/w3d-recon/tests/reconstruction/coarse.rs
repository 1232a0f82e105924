//! Coarse reconstruction from oracle views of real meshes.

use w3d_core::ViewRig;

use crate::common::spot;
use w3d_eval::{EvalOptions, evaluate};
use w3d_recon::{CoarseOptions, reconstruct_coarse, silhouette_sphere};

#[test]
fn spot_is_recovered_from_its_oracle_views() {
    let spot = spot();
    let rig = ViewRig::wonder3d_ortho();
    let views = w3d_raster::render_oracle_views(&spot, &rig, 128).unwrap();
    let init = silhouette_sphere(&views, 3).unwrap();
    let options = CoarseOptions::default().with_steps(150).with_edge_len_lims((0.025, 0.1));
    let (mesh, report) = reconstruct_coarse(&views, &init, &options, &mut |_, _, _| {}).unwrap();
    let metrics = evaluate(&mesh, &spot, &EvalOptions::default().with_samples(20_000)).unwrap();
    eprintln!(
        "spot 128²: chamfer {:.4}, F@0.02 {:.3}, iou64 {:.3}, {} triangles, loss {:.4} -> {:.4}, {:.1} s",
        metrics.chamfer,
        metrics.fscore_002,
        metrics.iou_64,
        mesh.triangle_count(),
        report.losses[0],
        report.losses.last().unwrap(),
        report.seconds
    );
    assert!(report.losses.last().unwrap() < &(report.losses[0] * 0.2));
    assert!(metrics.chamfer < 0.02, "{metrics:?}");
}
