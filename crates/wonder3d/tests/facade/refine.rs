//! The refinement loop on spot: a coarse mesh reconstructed from noisy 128² oracle views
//! (normal noise σ = 0.05, so there is something to refine), refined once at 256² with the
//! oracle enhancer (renders of spot itself: geometry and novel-view texture must improve) and
//! with the identity enhancer (the loop must not make the mesh worse). The full table (five
//! objects, both rigs, two iterations at 512²) is `cargo xtask refine-table`
//! (`docs/accuracy.md`).

use wonder3d::eval::{EvalOptions, evaluate, novel_view_fidelity, with_normal_noise};
use wonder3d::recon::RefineOptions as MeshRefineOptions;
use wonder3d::refine::{IdentityEnhancer, OracleEnhancer, RefineOptions, refine};
use wonder3d::{Mesh, Pipeline, ViewRig, ViewSet};

/// Spot, its noisy 128² views and the coarse mesh (default preset) reconstructed from them.
fn coarse() -> (Mesh, ViewSet, Mesh, Mesh) {
    let spot = wonder3d::demo::bundled_spot().unwrap();
    let clean = wonder3d::raster::render_oracle_views(&spot, &ViewRig::wonder3d_ortho(), 128).unwrap();
    let views = with_normal_noise(clean, 0.05, 7).unwrap();
    let output = Pipeline::new().with_texture_size(512).from_views(&views, &mut |_| {}).unwrap();
    (spot, views, output.geometry, output.mesh)
}

fn options() -> RefineOptions {
    RefineOptions::default()
        .with_iterations(1)
        .with_size(256)
        .with_mesh(MeshRefineOptions::default().with_steps(60).with_edge_len_lims((0.012, 0.02)))
        .with_texture(wonder3d::TextureOptions::default().with_size(512))
}

fn chamfer(mesh: &Mesh, truth: &Mesh) -> f64 {
    evaluate(mesh, truth, &EvalOptions::default()).unwrap().chamfer
}

/// Mean PSNR over the 16 SyncDreamer views at 128², composited over white.
fn novel_psnr(mesh: &Mesh, truth: &Mesh) -> f64 {
    novel_view_fidelity(truth, mesh, 128).unwrap().psnr
}

#[test]
fn the_oracle_enhancer_sharpens_geometry_and_texture_and_identity_does_no_harm() {
    let (spot, views, geometry, textured) = coarse();
    let (cd_before, psnr_before) = (chamfer(&geometry, &spot), novel_psnr(&textured, &spot));

    let oracle = refine(&geometry, &views, &OracleEnhancer::new(spot.clone()), &options(), &mut |_| {}).unwrap();
    let (cd, psnr) = (chamfer(&oracle.geometry, &spot), novel_psnr(&oracle.mesh, &spot));
    let report = &oracle.report.iterations[0];
    eprintln!(
        "coarse: CD {cd_before:.5}, PSNR {psnr_before:.2} dB, {} triangles\noracle, 1 iteration: CD {cd:.5}, PSNR \
         {psnr:.2} dB, {} triangles, {:.1} s (fit {:.1} s)",
        geometry.triangle_count(),
        oracle.report.triangles,
        report.seconds,
        report.mesh.fit.seconds
    );
    assert!(oracle.geometry.topology().is_watertight() && oracle.geometry.self_intersections().is_empty());
    // The fit's surplus triangles are simplified away, and the mesh that comes back is the
    // simplified one.
    let simplified = report.mesh.simplify.expect("the default refinement simplifies");
    assert!(simplified.triangles_after < simplified.triangles_before, "{simplified:?}");
    assert_eq!(simplified.triangles_after, oracle.geometry.triangle_count());
    assert!(cd < 0.9 * cd_before, "oracle refinement: CD {cd_before:.5} -> {cd:.5}");
    assert!(psnr > psnr_before + 0.5, "oracle refinement: PSNR {psnr_before:.2} -> {psnr:.2} dB");
    assert!(!report.mesh.kept_input && report.mesh.loss_refined < report.mesh.loss_input, "{:?}", report.mesh);

    // Views that show nothing new: the fit moves the surface a little, agrees worse with
    // them than the mesh they were rendered from, and the input comes back.
    let identity = refine(&geometry, &views, &IdentityEnhancer, &options(), &mut |_| {}).unwrap();
    let report = &identity.report.iterations[0].mesh;
    assert!(report.kept_input && report.loss_refined >= report.loss_input, "{report:?}");
    assert_eq!(identity.geometry, geometry.clone().without_attributes());
    assert_eq!(identity.report.enhancer, "identity");
    // The fit alone, kept whatever it agrees: closed, uncrossed, within 5 % of the CD.
    let fit_only = options().with_mesh(options().mesh.with_keep_input_unless_better(false));
    let fitted = refine(&geometry, &views, &IdentityEnhancer, &fit_only, &mut |_| {}).unwrap();
    let cd_fitted = chamfer(&fitted.geometry, &spot);
    eprintln!("identity, 1 iteration, the fit kept: CD {cd_fitted:.5}");
    assert!(!fitted.report.iterations[0].mesh.kept_input);
    assert!(fitted.geometry.topology().is_watertight() && fitted.geometry.self_intersections().is_empty());
    assert!(cd_fitted <= 1.05 * cd_before, "identity refinement: CD {cd_before:.5} -> {cd_fitted:.5}");
}

/// Sizing by the mesh's own curvature instead of the one the enhanced views show
/// (`RefineOptions::curvature_from_views` off) gives another mesh, as closed and uncrossed,
/// that still gains on the coarse one.
#[test]
fn sizing_by_the_mesh_curvature_refines_too() {
    let (spot, views, geometry, _) = coarse();
    let cd_before = chamfer(&geometry, &spot);
    let mesh_options = MeshRefineOptions::default().with_steps(60).with_edge_len_lims((0.012, 0.03));
    let run = |from_views: bool| {
        let options = options().with_mesh(mesh_options.with_curvature_from_views(from_views));
        refine(&geometry, &views, &OracleEnhancer::new(spot.clone()), &options, &mut |_| {}).unwrap()
    };
    let (by_mesh, by_views) = (run(false), run(true));
    let cd = chamfer(&by_mesh.geometry, &spot);
    eprintln!(
        "sized by the views: {} triangles; by the mesh: {} triangles, CD {cd_before:.5} -> {cd:.5}",
        by_views.geometry.triangle_count(),
        by_mesh.geometry.triangle_count()
    );
    assert_ne!(by_mesh.geometry.triangle_count(), by_views.geometry.triangle_count());
    assert!(by_mesh.geometry.topology().is_watertight() && by_mesh.geometry.self_intersections().is_empty());
    assert!(cd < 0.9 * cd_before, "CD {cd_before:.5} -> {cd:.5}");
}

#[test]
fn no_iterations_keep_the_mesh_and_a_wrong_enhancer_is_named() {
    let spot = wonder3d::demo::bundled_spot().unwrap();
    let views = wonder3d::raster::render_oracle_views(&spot, &ViewRig::wonder3d_ortho(), 64).unwrap();
    let geometry = spot.clone().without_attributes();
    let none = refine(&geometry, &views, &IdentityEnhancer, &options().with_iterations(0), &mut |_| {}).unwrap();
    assert_eq!(none.geometry, geometry);
    assert!(none.report.iterations.is_empty() && none.mesh.texture().is_some());

    /// Returns its renders at half the size.
    struct Shrinking;
    impl wonder3d::refine::Enhancer for Shrinking {
        fn name(&self) -> String {
            "shrinking".into()
        }
        fn enhance(&self, request: &wonder3d::refine::EnhanceRequest<'_>) -> wonder3d::Result<ViewSet> {
            let spot = wonder3d::demo::bundled_spot()?;
            wonder3d::raster::render_oracle_views(&spot, request.renders.rig(), request.renders.width() / 2)
        }
    }
    let err = refine(&geometry, &views, &Shrinking, &options(), &mut |_| {}).unwrap_err().to_string();
    assert!(err.contains("enhancer shrinking") && err.contains("256×256") && err.contains("128×128"), "{err}");

    // Views without the refinement cameras.
    let three = views.subset(["front", "front_right", "back"]).unwrap();
    let err = refine(&geometry, &three, &IdentityEnhancer, &options(), &mut |_| {}).unwrap_err().to_string();
    assert!(err.contains("refinement views") && err.contains("\"right\""), "{err}");
}

/// The diffusion enhancer in the loop, on the tiny random-weight enhancer of w3d-diffusion's
/// parity fixtures (its views are noise, so this checks the wiring and that the loop stays
/// closed and intersection-free whatever an enhancer returns; the arithmetic is checked
/// against diffusers in `w3d-diffusion`'s `parity::enhancer`).
#[test]
fn the_diffusion_enhancer_runs_in_the_loop() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../w3d-diffusion/tests/fixtures/enhancer");
    let enhancer = wonder3d::refine::DiffusionEnhancer::load(&dir).unwrap();
    let spot = wonder3d::demo::bundled_spot().unwrap();
    let views = wonder3d::raster::render_oracle_views(&spot, &ViewRig::wonder3d_ortho(), 64).unwrap();
    let coarse =
        Pipeline::new().with_preset(wonder3d::Preset::Fast).without_texture().from_views(&views, &mut |_| {}).unwrap();
    let options = RefineOptions::default()
        .with_iterations(2)
        .with_size(32)
        .with_mesh(MeshRefineOptions::default().with_steps(10).with_edge_len_lims((0.03, 0.05)))
        .with_texture(wonder3d::TextureOptions::default().with_size(512));
    let refined = refine(&coarse.geometry, &views, &enhancer, &options, &mut |_| {}).unwrap();
    assert_eq!(refined.report.enhancer, "diffusion");
    assert_eq!(refined.report.iterations.len(), 2);
    assert!(refined.geometry.topology().is_watertight() && refined.geometry.self_intersections().is_empty());
    assert!(refined.mesh.texture().is_some());
}
