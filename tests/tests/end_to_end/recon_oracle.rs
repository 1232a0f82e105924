//! The whole oracle pipeline on the bundled spot: render its 6 ortho views at 256², write
//! and re-read them as a view-set folder (the `wonder3d render` → `wonder3d reconstruct`
//! hand-over), reconstruct with the default preset, and score against the original.

use wonder3d::eval::{EvalOptions, evaluate};
use wonder3d::recon::{InitChoice, ReconOptions, Stage, reconstruct};
use wonder3d::{ViewRig, ViewSet, load_mesh};

#[test]
fn spot_oracle_pipeline_reaches_the_accuracy_target() {
    let mut spot = load_mesh(concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/spot.obj")).unwrap().without_attributes();
    spot.normalize_unit_cube();
    let rig = ViewRig::wonder3d_ortho();
    let views = wonder3d::raster::render_oracle_views(&spot, &rig, 256).unwrap();
    let dir = tempfile::tempdir().unwrap();
    views.save(dir.path()).unwrap();
    let views = ViewSet::load(dir.path()).unwrap();
    assert_eq!(views.rig(), &rig);

    let mut events = Vec::new();
    let (mesh, report) =
        reconstruct(&views, &ReconOptions::default(), &mut |p| events.push((p.stage, p.done))).unwrap();
    assert_eq!(report.init.choice, InitChoice::Poisson, "{}", report.init.reason);
    let coarse_steps = events.iter().filter(|(stage, _)| *stage == Stage::Coarse).map(|e| e.1).max();
    assert_eq!(coarse_steps, Some(ReconOptions::default().coarse.steps));
    assert_eq!(events.last(), Some(&(Stage::Polish, 1)));
    assert!(report.polish.loss_after <= report.polish.loss_before, "polish raised the loss: {:?}", report.polish);
    assert!(mesh.topology().is_watertight());
    assert!(mesh.self_intersections().is_empty(), "{:?}", report.untangle);
    let m = evaluate(&mesh, &spot, &EvalOptions::default()).unwrap();
    eprintln!(
        "spot: CD {:.4}, F@0.02 {:.3}, IoU {:.3}, {} triangles, {:.1} s",
        m.chamfer, m.fscore_002, m.iou_64, report.triangles, report.seconds
    );
    assert!(m.chamfer <= 0.008, "{m:?}");
    assert!(m.iou_64 >= 0.88, "{m:?}");
}

/// The concave acceptance objects (from `../shared/data/meshes`): the teapot and the
/// upright teacup come out watertight, finite and free of self-intersections.
#[test]
fn teapot_and_teacup_come_out_without_self_intersections() {
    for (name, max_chamfer) in [("teapot", 0.006), ("teacup", 0.015)] {
        let path = format!("{}/../../shared/data/meshes/{name}.obj", env!("CARGO_MANIFEST_DIR"));
        let mut truth = load_mesh(&path).unwrap().without_attributes();
        truth.normalize_unit_cube();
        let rig = ViewRig::wonder3d_ortho();
        let views = wonder3d::raster::render_oracle_views(&truth, &rig, 256).unwrap();
        let (mesh, report) = reconstruct(&views, &ReconOptions::default(), &mut |_| {}).unwrap();
        assert!(mesh.positions().iter().flatten().all(|x| x.is_finite()), "{name}");
        assert!(mesh.topology().is_watertight(), "{name}");
        assert_eq!(report.untangle.after, 0, "{name}: {:?}", report.untangle);
        assert!(mesh.self_intersections().is_empty(), "{name}");
        let m = evaluate(&mesh, &truth, &EvalOptions::default()).unwrap();
        eprintln!("{name}: CD {:.4}, {:?}, {:.1} s", m.chamfer, report.untangle, report.seconds);
        assert!(m.chamfer <= max_chamfer, "{name}: {m:?}");
    }
}
