//! Reconstruction from view sets other than six clean views: a subset of the rig's views
//! (`ViewSet::subset`: a view left out), and a view of another object in place of one.

use w3d_core::{ViewRig, ViewSet};

use crate::common::{shared_mesh, spot};
use w3d_eval::{SurfaceComparison, sample_surface};
use w3d_recon::{InitChoice, Preset, ReconOptions, initial_mesh, reconstruct, reconstruct_coarse, untangle};

/// Any subset reconstructs: without a side view as before, without the front view from the
/// left and right views integrated instead, and without both a front-back and a left-right
/// view from the silhouette sphere.
#[test]
fn any_subset_of_the_rig_reconstructs() {
    let truth = spot();
    let all = w3d_raster::render_oracle_views(&truth, &ViewRig::wonder3d_ortho(), 80).unwrap();
    let fast = ReconOptions::preset(Preset::Fast);
    let options = fast.with_coarse_steps(30).with_init(fast.init.with_grid(40));
    // (views kept, start, what the report says, largest Chamfer distance)
    let cases: [(&[&str], InitChoice, &str, f64); 3] = [
        (&["front", "front_right", "right", "back", "front_left"], InitChoice::Poisson, "convex front and back", 0.012),
        (&["front_right", "right", "back", "left", "front_left"], InitChoice::Poisson, "convex right and left", 0.012),
        (&["front_right", "right", "back", "front_left"], InitChoice::Sphere, "no two views facing", 0.06),
    ];
    for (names, choice, reason, largest) in cases {
        let views = all.subset(names.iter().copied()).unwrap();
        assert_eq!(views.len(), names.len());
        let (mesh, report) = reconstruct(&views, &options, &mut |_| {}).unwrap();
        assert_eq!(report.init.choice, choice, "{names:?}: {}", report.init.reason);
        assert!(report.init.reason.contains(reason), "{names:?}: {}", report.init.reason);
        assert!(mesh.positions().iter().flatten().all(|x| x.is_finite()), "{names:?}");
        assert!(mesh.topology().is_watertight(), "{names:?}");
        assert!(mesh.self_intersections().is_empty(), "{names:?}");
        let (ours, theirs) = (sample_surface(&mesh, 20_000, 1).unwrap(), sample_surface(&truth, 20_000, 2).unwrap());
        let chamfer = SurfaceComparison::new(&ours, &theirs).unwrap().chamfer();
        eprintln!("{names:?}: CD {chamfer:.4}, {:.1} s, {}", report.seconds, report.init.reason);
        assert!(chamfer < largest, "{names:?}: CD {chamfer}");
    }
    assert!(all.subset(["front", "top"]).is_err());
    assert!(all.subset(["front", "front"]).is_err());
    assert!(all.subset(Vec::<&str>::new()).is_err());
}

/// The fandisk's views with the `front_right` view taken from spot's: views that contradict
/// each other crumple the coarse mesh (12 232 crossing pairs at remesher seed 2) into
/// patches of sub-floor triangles that untangling cannot clear (30 pairs left); the
/// remesher's repairs do not leave them (0 pairs). `reconstruct` runs the coarse stage
/// again when untangling leaves crossings (the next seed, then the repairs) and ends clean;
/// before, it returned the crossing mesh (and before that, with more crossing pairs than
/// triangles, did not even try to untangle it).
#[test]
fn a_wrong_view_ends_without_crossings() {
    let rig = ViewRig::wonder3d_ortho();
    let views = w3d_raster::render_oracle_views(&shared_mesh("fandisk.obj"), &rig, 128).unwrap();
    let spot = w3d_raster::render_oracle_views(&spot(), &rig, 128).unwrap();
    let (rig, mut images) = views.into_parts();
    images[1] = spot.views()[1].clone();
    let views = ViewSet::new(rig, images).unwrap();
    let options = ReconOptions::preset(Preset::Fast).with_seed(2);
    // With the remesher's repairs, the coarse stage leaves few crossings, all untangled.
    let (start, _) = initial_mesh(&views, &options.init).unwrap();
    let repaired = options.coarse.with_remesh_repairs(true);
    let (coarse, _) = reconstruct_coarse(&views, &start, &repaired, &mut |_, _, _| {}).unwrap();
    let (_, untangled) = untangle(&coarse, options.untangle_rounds).unwrap();
    assert!(untangled.before < 100 && untangled.after == 0, "{untangled:?}");
    // The whole pipeline ends without crossings.
    let (mesh, report) = reconstruct(&views, &options, &mut |_| {}).unwrap();
    eprintln!("{:?}, {} reruns, repairs {}", report.untangle, report.coarse_reseeds, report.remesh_repairs);
    assert!(report.coarse_reseeds > 0, "the first coarse run leaves crossings, so the stage runs again");
    assert!(report.coarse.losses.len() == options.coarse.steps);
    assert!(mesh.positions().iter().flatten().all(|x| x.is_finite()));
    assert!(mesh.topology().is_watertight());
    assert_eq!(report.untangle.after, 0, "{:?}", report.untangle);
    assert!(mesh.self_intersections().is_empty());
}

/// Several starts: each is the fit one start with its seed would give, the one that fits the
/// views best is returned, and 0 starts is refused. Views that disagree (spot with the
/// fandisk's `front_right` view) spread the fits, as generated views do.
#[test]
fn several_starts_keep_the_best_fit() {
    let rig = ViewRig::wonder3d_ortho();
    let views = w3d_raster::render_oracle_views(&spot(), &rig, 64).unwrap();
    let other = w3d_raster::render_oracle_views(&shared_mesh("fandisk.obj"), &rig, 64).unwrap();
    let (rig, mut images) = views.into_parts();
    images[1] = other.views()[1].clone();
    let views = ViewSet::new(rig, images).unwrap();
    let fast = ReconOptions::preset(Preset::Fast).with_coarse_steps(30).with_seed(5);

    let error = reconstruct(&views, &fast.with_starts(0), &mut |_| {}).unwrap_err().to_string();
    assert!(error.contains("starts"), "{error}");

    let (mesh, report) = reconstruct(&views, &fast.with_starts(3), &mut |_| {}).unwrap();
    // One view of another object: the views disagree, yet far less than noise does.
    assert_eq!((report.start_losses.len(), report.starts_skipped), (3, 0));
    eprintln!("losses {:?}, kept {}", report.start_losses, report.start_kept);
    assert!(report.start_losses.iter().any(|&l| l != report.start_losses[0]), "the seeds changed nothing");
    let best = report.start_losses.iter().cloned().fold(f32::INFINITY, f32::min);
    assert_eq!(report.untangle.after, 0);
    assert_eq!(report.start_losses[report.start_kept], best);
    assert_eq!(report.polish.loss_after, best);
    // Start k is the single fit with the remesher seed 5 + 4k (seeds spaced past the reruns).
    for k in [0, report.start_kept] {
        let single = fast.with_seed(5 + 4 * k as u64);
        let (alone, alone_report) = reconstruct(&views, &single, &mut |_| {}).unwrap();
        assert_eq!(alone_report.start_losses, vec![report.start_losses[k]], "start {k}");
        if k == report.start_kept {
            assert_eq!(alone.positions(), mesh.positions());
            assert_eq!(alone.triangles(), mesh.triangles());
        }
    }
}

/// Views no closed surface explains (noise for normals and masks, as a model with random
/// weights generates) get one fit however many starts were asked for: the others would
/// only choose among equally wrong meshes (`ReconOptions::hopeless_view_loss`). With the
/// bound lifted every start runs, and a negative or NaN bound is refused by name.
#[test]
fn views_no_surface_explains_get_one_fit() {
    let sphere = w3d_remesh::icosphere(3, 0.4).unwrap();
    let views = w3d_raster::render_oracle_views(&sphere, &ViewRig::wonder3d_ortho(), 32).unwrap();
    let (rig, mut images) = views.into_parts();
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut uniform = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    for view in &mut images {
        for m in view.mask.data_mut() {
            // Keep the sphere's silhouette, with a third of its pixels dropped and specks outside.
            *m = if (*m > 0.5) == (uniform() < 0.67) { 1.0 } else { 0.0 };
        }
        for n in view.normal.data_mut().chunks_exact_mut(3) {
            let v = glam::Vec3::new(uniform() - 0.5, uniform() - 0.5, uniform() - 0.5).normalize_or(glam::Vec3::Z);
            n.copy_from_slice(&v.to_array());
        }
    }
    let views = ViewSet::new(rig, images).unwrap();
    let fast = ReconOptions::preset(Preset::Fast).with_coarse_steps(10).with_untangle_rounds(0).with_polish_steps(0);

    let (_, report) = reconstruct(&views, &fast.with_starts(3), &mut |_| {}).unwrap();
    let per_view = report.start_losses[0] / views.len() as f32;
    eprintln!("loss per view of noise views: {per_view}");
    assert!(per_view > fast.hopeless_view_loss, "loss per view {per_view}");
    assert_eq!((report.start_losses.len(), report.starts_skipped, report.start_kept), (1, 2, 0));

    let every = fast.with_starts(3).with_hopeless_view_loss(f32::INFINITY);
    let (_, report) = reconstruct(&views, &every, &mut |_| {}).unwrap();
    assert_eq!((report.start_losses.len(), report.starts_skipped), (3, 0));

    for bad in [-1.0, f32::NAN] {
        let error = reconstruct(&views, &fast.with_hopeless_view_loss(bad), &mut |_| {}).unwrap_err().to_string();
        assert!(error.contains("hopeless_view_loss"), "{error}");
    }
}
