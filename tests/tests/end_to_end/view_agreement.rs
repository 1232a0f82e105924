//! The per-view agreement score of a reconstruction (`ReconReport::views`, issue #62): on the
//! six meshes of the robustness table, a view set with one view of another object (the
//! table's "wrong view" row: `front_right` from the next mesh) names that view as the one
//! that disagrees, and it scores lowest; the clean views of spot all agree.

use wonder3d::recon::{Preset, ReconOptions, disagreeing_view, reconstruct};
use wonder3d::{Mesh, ViewRig, ViewSet, load_mesh};

/// The meshes of the robustness table (`xtask/src/robust.rs`).
const MESHES: [&str; 6] =
    ["spot.obj", "armadillo.obj", "koala_low_resolution.obj", "horse.ply", "plane.obj", "fandisk.obj"];

fn normalised(file: &str) -> Mesh {
    let path = wonder3d_tests::shared_meshes().join(file);
    let mut mesh = load_mesh(&path).unwrap_or_else(|e| panic!("{e}")).without_attributes();
    mesh.orient_outward();
    mesh.normalize_unit_cube();
    mesh
}

#[test]
fn a_view_of_another_object_scores_lowest_on_all_six_meshes() {
    let rig = ViewRig::wonder3d_ortho();
    let size = 256;
    let options = ReconOptions::preset(Preset::Fast);
    let views: Vec<ViewSet> =
        MESHES.iter().map(|f| wonder3d::raster::render_oracle_views(&normalised(f), &rig, size).unwrap()).collect();
    let wrong = rig.views.iter().position(|v| v.name == "front_right").unwrap();
    for (i, file) in MESHES.iter().enumerate() {
        let donor = &views[(i + 1) % MESHES.len()];
        let (set_rig, mut images) = views[i].clone().into_parts();
        images[wrong] = donor.views()[wrong].clone();
        let mixed = ViewSet::new(set_rig, images).unwrap();
        let (_, report) = reconstruct(&mixed, &options, &mut |_| {}).unwrap();
        let scores: Vec<String> = report.views.iter().map(|v| format!("{} {:.3}", v.view, v.score)).collect();
        eprintln!("{file}: {}", scores.join(", "));
        let named =
            disagreeing_view(&report.views, 0.85).unwrap_or_else(|| panic!("{file}: no view named: {scores:?}"));
        assert_eq!(named.view, "front_right", "{file}: {scores:?}");
    }
    // Spot's clean views: every view agrees, none is named.
    let (_, report) = reconstruct(&views[0], &options, &mut |_| {}).unwrap();
    assert!(report.views.iter().all(|v| v.score > 0.8), "{:?}", report.views);
    assert!(disagreeing_view(&report.views, 0.85).is_none(), "{:?}", report.views);
}
