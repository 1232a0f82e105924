//! Untangling coarse meshes that kept crossings under the earlier progress rule.
//!
//! The fixtures are cut from coarse meshes of the accuracy bench (`docs/accuracy.md`): the
//! crossing triangles and a few rings around them, as OBJ. Before the stall counter of
//! `w3d_recon::untangle` (progress judged against the round before, one ring of smoothing at
//! most), a separation round that added a crossing and the smoothing round that removed it
//! again alternated until the rounds ran out: 3 of spot's 59 pairs and 15 of the rocker
//! arm's 618 stayed.

use w3d_core::{Mesh, load_mesh};
use w3d_recon::untangle;

fn fixture(name: &str) -> Mesh {
    load_mesh(format!("{}/tests/data/{name}", env!("CARGO_MANIFEST_DIR"))).unwrap()
}

#[test]
fn crossings_that_outlasted_the_old_rule_are_all_removed() {
    for (name, crossing) in [("spot_persp_folds.obj", 59), ("rocker_arm_shells.obj", 618)] {
        let mesh = fixture(name);
        assert_eq!(mesh.self_intersections().len(), crossing, "{name}");
        let (fixed, report) = untangle(&mesh, 400).unwrap();
        assert_eq!((report.before, report.after), (crossing, 0), "{name}: {report:?}");
        assert!(fixed.self_intersections().is_empty(), "{name}");
        assert_eq!(fixed.triangles(), mesh.triangles(), "{name}: topology kept");
    }
}

/// However few rounds it gets, untangling returns the positions with the fewest crossings it
/// saw, and reports them truthfully: never more than it started with (the first separation
/// round on spot's folds adds one, 59 → 60).
#[test]
fn untangling_never_returns_more_crossings_than_its_best_round() {
    let mesh = fixture("spot_persp_folds.obj");
    let before = mesh.self_intersections().len();
    for rounds in [1, 2, 3, 5, 8, 20] {
        let (fixed, report) = untangle(&mesh, rounds).unwrap();
        let left = fixed.self_intersections().len();
        assert_eq!(report.after, left, "{rounds} rounds: {report:?}");
        assert!(left <= before, "{rounds} rounds: {left} crossings left of {before}");
    }
}
