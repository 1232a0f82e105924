//! Texture fidelity with ground-truth geometry: spot and bob (textured, CC0) are rendered
//! into the 6 orthographic views at 256², their geometry alone is baked at 1024² from
//! those colour views, and the result is rendered again — in the 6 input views and in
//! the 16 SyncDreamer views (novel viewpoints) — and compared with renders of the
//! original textured mesh (PSNR, SSIM).

use w3d_core::{Image, Mesh, ViewRig, load_mesh};
use w3d_eval::{psnr, ssim};
use w3d_raster::{render_colours, render_oracle_views};
use w3d_texture::{RefineTextureOptions, TextureOptions, bake, refine_texture};

const VIEW_SIZE: u32 = 256;

fn mesh(path: &str) -> Mesh {
    let mut mesh = load_mesh(format!("{}/../../{path}", env!("CARGO_MANIFEST_DIR"))).unwrap();
    mesh.normalize_unit_cube();
    mesh
}

/// Mean PSNR and SSIM of `ours` against `reference`, view by view.
fn compare(reference: &[Image], ours: &[Image]) -> (f64, f64, f64) {
    let psnrs: Vec<f64> = reference.iter().zip(ours).map(|(a, b)| psnr(a, b).unwrap()).collect();
    let ssims: Vec<f64> = reference.iter().zip(ours).map(|(a, b)| ssim(a, b).unwrap()).collect();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    (mean(&psnrs), psnrs.iter().copied().fold(f64::INFINITY, f64::min), mean(&ssims))
}

fn check(name: &str, path: &str) {
    let truth = mesh(path);
    let rig = ViewRig::wonder3d_ortho();
    let views = render_oracle_views(&truth, &rig, VIEW_SIZE).unwrap();
    let geometry = truth.clone().without_attributes();
    let start = std::time::Instant::now();
    let textured = bake(&geometry, &views, &TextureOptions::default()).unwrap();
    let seconds = start.elapsed().as_secs_f64();
    let report = textured.report;
    assert_eq!(report.views_used, 6);
    assert_eq!(textured.mesh.triangle_count(), truth.triangle_count());

    let inputs: Vec<Image> = views.views().iter().map(|v| v.colour.clone().unwrap()).collect();
    let (input_psnr, input_min, input_ssim) =
        compare(&inputs, &render_colours(&textured.mesh, &rig, VIEW_SIZE).unwrap());
    let novel_rig = ViewRig::syncdreamer16();
    let novel_truth = render_colours(&truth, &novel_rig, VIEW_SIZE).unwrap();
    let (novel_psnr, novel_min, novel_ssim) =
        compare(&novel_truth, &render_colours(&textured.mesh, &novel_rig, VIEW_SIZE).unwrap());
    let (vc_psnr, _, vc_ssim) =
        compare(&novel_truth, &render_colours(&textured.vertex_coloured, &novel_rig, VIEW_SIZE).unwrap());
    println!(
        "{name}: bake {seconds:.2} s, {} charts, utilisation {:.3}, seen texels {:.3}, seen vertices {:.3}\n  \
         6 input views: PSNR {input_psnr:.2} dB (min {input_min:.2}), SSIM {input_ssim:.4}\n  \
         16 novel views: PSNR {novel_psnr:.2} dB (min {novel_min:.2}), SSIM {novel_ssim:.4}\n  \
         vertex-colour fallback, 16 views: PSNR {vc_psnr:.2} dB, SSIM {vc_ssim:.4}",
        report.atlas.charts, report.atlas.utilisation, report.seen_texel_fraction, report.seen_vertex_fraction,
    );
    assert!(input_psnr >= 30.0, "{name}: input-view PSNR {input_psnr:.2} dB");
    assert!(novel_psnr >= 24.0, "{name}: novel-view PSNR {novel_psnr:.2} dB");
    assert!(vc_psnr < novel_psnr, "{name}: the texture should beat vertex colours");
}

#[test]
fn spot_fidelity() {
    check("spot", "assets/spot.obj");
}

#[test]
fn bob_fidelity() {
    check("bob", "assets/bob_tri.obj");
}

/// Texture refinement: spot baked from blurry views (64²), then refined with sharp ones
/// (256², standing in for an enhancer's output) into the same atlas, gains on the 16 novel
/// views; refined again with renders of itself (an enhancer that changes nothing), it stays
/// as it was.
#[test]
fn refining_with_sharper_views_improves_the_texture() {
    let truth = mesh("assets/spot.obj");
    let rig = ViewRig::wonder3d_ortho();
    let blurry = render_oracle_views(&truth, &rig, 64).unwrap();
    let geometry = truth.clone().without_attributes();
    let textured = bake(&geometry, &blurry, &TextureOptions::default().with_size(512)).unwrap();
    let sharp = render_oracle_views(&truth, &rig, VIEW_SIZE).unwrap();
    let (refined, report) = refine_texture(&textured.mesh, &sharp, &RefineTextureOptions::default()).unwrap();
    assert_eq!((refined.uvs(), refined.triangles()), (textured.mesh.uvs(), textured.mesh.triangles()));
    let novel_rig = ViewRig::syncdreamer16();
    let novel_truth = render_colours(&truth, &novel_rig, VIEW_SIZE).unwrap();
    let (before, _, before_ssim) =
        compare(&novel_truth, &render_colours(&textured.mesh, &novel_rig, VIEW_SIZE).unwrap());
    let (after, _, after_ssim) = compare(&novel_truth, &render_colours(&refined, &novel_rig, VIEW_SIZE).unwrap());
    eprintln!(
        "spot, 16 novel views: baked from 64² PSNR {before:.2} dB, SSIM {before_ssim:.4}; refined from 256² \
         {after:.2} dB, SSIM {after_ssim:.4}; {report:?}"
    );
    assert!(after > before + 1.0, "PSNR {before:.2} → {after:.2} dB");
    assert!(report.replaced_fraction > 0.2 && report.unchanged_fraction < 0.1, "{report:?}");

    let own = render_oracle_views(&refined, &rig, VIEW_SIZE).unwrap();
    let (again, _) = refine_texture(&refined, &own, &RefineTextureOptions::default()).unwrap();
    let (same, _, _) = compare(
        &render_colours(&refined, &novel_rig, VIEW_SIZE).unwrap(),
        &render_colours(&again, &novel_rig, VIEW_SIZE).unwrap(),
    );
    eprintln!("refined with its own renders: PSNR {same:.2} dB against itself");
    assert!(same > 35.0, "PSNR {same:.2} dB");

    // Bad options are named.
    let wrong = RefineTextureOptions::default().with_view_weights(vec![1.0; 4]);
    assert!(refine_texture(&refined, &own, &wrong).unwrap_err().to_string().contains("view_weights"));
    assert!(
        refine_texture(&geometry, &own, &RefineTextureOptions::default()).unwrap_err().to_string().contains("mesh")
    );
}
