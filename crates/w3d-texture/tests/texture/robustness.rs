//! Open meshes, faces no view sees, partial view sets, export and bad input.

use w3d_core::io::{read_gltf, read_obj, write_glb, write_obj};
use w3d_core::{Mesh, ViewRig, ViewSet, load_mesh};
use w3d_raster::render_oracle_views;
use w3d_texture::{BakeStage, TextureOptions, bake, bake_with_progress, fuse_vertex_colours};

/// The teacup (open: the handle is a separate tube open at both ends; the cup's inside is
/// concave) with vertex colours that vary smoothly with position.
fn teacup() -> Mesh {
    let path = format!("{}/../../../shared/data/meshes/teacup.obj", env!("CARGO_MANIFEST_DIR"));
    let mut mesh = load_mesh(path).unwrap();
    mesh.normalize_unit_cube();
    assert!(mesh.merge_by_position().0.topology().boundary_edges > 0, "the test needs an open mesh");
    let colours = mesh.positions().iter().map(|p| [p[0] + 0.5, p[1] + 0.5, 0.5 - p[2]]).collect();
    mesh.with_colours(colours).unwrap()
}

/// The front and back views of the Wonder3D rig only.
fn front_and_back() -> ViewRig {
    let rig = ViewRig::wonder3d_ortho();
    ViewRig { name: "front_back".into(), views: vec![rig.views[0].clone(), rig.views[3].clone()] }
}

#[test]
fn open_mesh_seen_from_two_views_bakes_with_propagated_colours() {
    let truth = teacup();
    let rig = front_and_back();
    let views = render_oracle_views(&truth, &rig, 128).unwrap();
    let geometry = truth.clone().without_attributes();
    let options = TextureOptions::default().with_size(512);
    let mut stages = Vec::new();
    let textured = bake_with_progress(&geometry, &views, &options, &mut |s| stages.push(s)).unwrap();
    assert_eq!(
        stages,
        [BakeStage::FusingVertexColours, BakeStage::BuildingAtlas, BakeStage::Baking, BakeStage::Dilating]
    );
    let r = textured.report;
    println!(
        "teacup, 2 views: seen vertices {:.3}, seen texels {:.3}, {} charts, utilisation {:.3}",
        r.seen_vertex_fraction, r.seen_texel_fraction, r.atlas.charts, r.atlas.utilisation
    );
    assert_eq!(r.views_used, 2);
    assert!(r.seen_vertex_fraction > 0.2 && r.seen_vertex_fraction < 0.9, "{}", r.seen_vertex_fraction);
    assert!(r.seen_texel_fraction < 0.95);
    let texture = textured.mesh.texture().unwrap();
    assert!(texture.data().iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v)));
    // Propagated vertex colours stay within the range of what the views show, and are
    // close to the (smooth) truth: the colour field is linear in position.
    let fused = textured.vertex_coloured.colours().unwrap();
    let truth_colours = truth.colours().unwrap();
    let error: f64 = fused
        .iter()
        .zip(truth_colours)
        .map(|(a, b)| (0..3).map(|k| f64::from((a[k] - b[k]).abs())).sum::<f64>() / 3.0)
        .sum::<f64>()
        / fused.len() as f64;
    println!("teacup: mean vertex colour error {error:.4}");
    assert!(error < 0.1, "mean vertex colour error {error}");
}

/// A mesh with a component shrunk to a point (four distinct vertices at one position, a
/// closed tetrahedron: what the coarse reconstruction of the fandisk in the perspective rig
/// left, `cargo xtask refine-table --all`) is valid input: it bakes, each face of the point
/// keeps three distinct vertices, and the rest of the mesh is unchanged.
#[test]
fn a_component_shrunk_to_a_point_bakes() {
    let truth = teacup();
    let views = render_oracle_views(&truth, &front_and_back(), 64).unwrap();
    let mut positions = truth.positions().to_vec();
    let mut triangles = truth.triangles().to_vec();
    let n = positions.len() as u32;
    positions.extend([[0.1, 0.2, 0.05]; 4]);
    triangles.extend([[0, 1, 2], [3, 2, 1], [1, 0, 3], [3, 0, 2]].map(|t: [u32; 3]| t.map(|v| v + n)));
    let geometry = Mesh::new(positions, triangles).unwrap();
    let textured = bake(&geometry, &views, &TextureOptions::default().with_size(256)).unwrap();
    let mesh = &textured.mesh;
    assert_eq!(mesh.triangle_count(), geometry.triangle_count());
    for (t, source) in mesh.triangles().iter().zip(geometry.triangles()) {
        assert_eq!(t.map(|v| mesh.positions()[v as usize]), source.map(|v| geometry.positions()[v as usize]));
    }
}

#[test]
fn exports_round_trip() {
    let truth = teacup();
    let rig = ViewRig::wonder3d_ortho();
    let views = render_oracle_views(&truth, &rig, 96).unwrap();
    let options = TextureOptions::default().with_size(256);
    let geometry = truth.clone().without_attributes();
    let textured = bake(&geometry, &views, &options).unwrap();
    let fused = fuse_vertex_colours(&geometry, &views, &options).unwrap();
    assert_eq!(fused.mesh, textured.vertex_coloured);
    assert_eq!(fused.seen_vertex_fraction, textured.report.seen_vertex_fraction);
    let dir = tempfile::tempdir().unwrap();
    let glb = dir.path().join("teacup.glb");
    write_glb(&glb, &textured.mesh).unwrap();
    let back = read_gltf(&glb).unwrap();
    assert_eq!(back.vertex_count(), textured.mesh.vertex_count());
    assert_eq!(back.triangle_count(), textured.mesh.triangle_count());
    assert_eq!(back.texture().unwrap().width(), 256);
    // v is flipped on write and back on read.
    for (a, b) in back.uvs().unwrap().iter().zip(textured.mesh.uvs().unwrap()) {
        assert!((a[0] - b[0]).abs() < 1e-6 && (a[1] - b[1]).abs() < 1e-6);
    }
    let obj = dir.path().join("teacup.obj");
    write_obj(&obj, &textured.mesh).unwrap();
    assert!(dir.path().join("teacup.mtl").is_file() && dir.path().join("teacup.png").is_file());
    let back = read_obj(&obj).unwrap();
    assert_eq!(back.triangle_count(), textured.mesh.triangle_count());
    assert!(back.texture().is_some());
    let colour_glb = dir.path().join("teacup_vertex_colours.glb");
    write_glb(&colour_glb, &textured.vertex_coloured).unwrap();
    let back = read_gltf(&colour_glb).unwrap();
    assert_eq!(back.vertex_count(), truth.vertex_count());
    assert!(back.colours().is_some() && back.texture().is_none());
}

#[test]
fn views_without_colour_are_skipped_and_bad_input_is_an_error() {
    let truth = teacup();
    let rig = ViewRig::wonder3d_ortho();
    let (rig, mut images) = render_oracle_views(&truth, &rig, 64).unwrap().into_parts();
    let geometry = truth.clone().without_attributes();
    let options = TextureOptions::default().with_size(128);
    images[1].colour = None;
    images[4].colour = None;
    let views = ViewSet::new(rig.clone(), images).unwrap();
    assert_eq!(bake(&geometry, &views, &options).unwrap().report.views_used, 4);

    let without_colour = views
        .views()
        .iter()
        .cloned()
        .map(|mut v| {
            v.colour = None;
            v
        })
        .collect();
    let no_colour = ViewSet::new(rig.clone(), without_colour).unwrap();
    let err = bake(&geometry, &no_colour, &options).unwrap_err().to_string();
    assert!(err.contains("colour"), "{err}");
    // Six views cannot be paired with a two-view rig.
    let err = ViewSet::new(front_and_back(), views.views().to_vec()).unwrap_err().to_string();
    assert!(err.contains("views"), "{err}");
    for bad in [
        options.with_size(4),
        options.with_view_weight_exponent(f32::NAN),
        options.with_max_chart_angle_deg(90.0),
        options.with_padding(100),
    ] {
        assert!(bake(&geometry, &views, &bad).is_err(), "{bad:?}");
    }
    // A zero size is reported as the size (it was reported as a dilation problem).
    let err = bake(&geometry, &views, &options.with_size(0)).unwrap_err().to_string();
    assert!(err.contains("size") && err.contains("8 to 16384") && !err.contains("dilation"), "{err}");
    // A mesh outside every view's frame: nothing is seen.
    let mut far = geometry.clone();
    far.map_positions(|p| p + w3d_core::glam::Vec3::new(0.0, 5.0, 0.0)).unwrap();
    let err = bake(&far, &views, &options).unwrap_err().to_string();
    assert!(err.contains("sees"), "{err}");
}
