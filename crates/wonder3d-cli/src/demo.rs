//! `wonder3d demo [--out DIR]`: the whole mesh-extraction pipeline on the bundled spot (CC0),
//! with no downloads: oracle views → reconstruction → texture → GLB, a contact sheet and a
//! report scored against the original.

use std::path::PathBuf;
use std::time::Instant;

use crate::progress::{recon_progress, stage_bar};
use serde_json::json;
use w3d_core::{Error, Image, Mesh, Result, ViewRig, io::write_atomic, load_mesh, save_mesh};
use w3d_eval::{EvalOptions, composite_over_white, evaluate, psnr, ssim};
use w3d_recon::{Preset, ReconOptions, reconstruct};
use w3d_texture::{TextureOptions, bake};

/// The bundled demo object: Keenan Crane's spot (CC0), mesh, material and texture.
const SPOT_OBJ: &[u8] = include_bytes!("../../../assets/spot.obj");
const SPOT_MTL: &[u8] = include_bytes!("../../../assets/spot.mtl");
const SPOT_TEXTURE: &[u8] = include_bytes!("../../../assets/spot_texture.png");

/// Arguments of `wonder3d demo`.
#[derive(clap::Args)]
pub struct DemoArgs {
    /// Output folder (created if needed): spot.glb, views.png, report.json.
    #[arg(long, default_value = "wonder3d-demo")]
    out: PathBuf,
    /// Reconstruction preset: fast, default or quality.
    #[arg(long, default_value = "default")]
    preset: String,
    /// Side of the rendered views in pixels.
    #[arg(long, default_value_t = 256)]
    size: u32,
    /// Side of the baked texture in texels.
    #[arg(long, default_value_t = 1024)]
    texture_size: u32,
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
}

/// The bundled spot, normalised to the unit cube (written to a temporary folder so the
/// regular OBJ + MTL + texture loader reads it).
fn bundled_spot() -> Result<Mesh> {
    let dir = tempfile::tempdir().map_err(|e| Error::io(std::env::temp_dir(), e))?;
    for (name, bytes) in [("spot.obj", SPOT_OBJ), ("spot.mtl", SPOT_MTL), ("spot_texture.png", SPOT_TEXTURE)] {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).map_err(|e| Error::io(&path, e))?;
    }
    let mut spot = load_mesh(dir.path().join("spot.obj"))?;
    spot.normalize_unit_cube();
    Ok(spot)
}

/// Normals as RGB = (n + 1) / 2 with their mask as alpha.
fn normal_rgba(normal: &Image, mask: &Image) -> Result<Image> {
    let rgb: Vec<f32> = normal.data().iter().map(|v| 0.5 * (v + 1.0)).collect();
    Image::new(normal.width(), normal.height(), 3, rgb)?.with_alpha(mask)
}

/// A grid of equally sized RGBA images composited over white (rows × columns).
fn contact_sheet(rows: &[Vec<Image>]) -> Result<Image> {
    let (w, h) = (rows[0][0].width() as usize, rows[0][0].height() as usize);
    let columns = rows.iter().map(Vec::len).max().unwrap_or(0);
    let (sw, sh) = (columns * w, rows.len() * h);
    let mut data = vec![1.0f32; sw * sh * 3];
    for (r, row) in rows.iter().enumerate() {
        for (c, image) in row.iter().enumerate() {
            let flat = composite_over_white(image)?;
            for y in 0..h {
                for x in 0..w {
                    let src = &flat.data()[3 * (y * w + x)..3 * (y * w + x) + 3];
                    let dst = 3 * ((r * h + y) * sw + c * w + x);
                    data[dst..dst + 3].copy_from_slice(src);
                }
            }
        }
    }
    Image::new(sw as u32, sh as u32, 3, data)
}

/// Runs `wonder3d demo`.
pub fn run(args: &DemoArgs) -> Result<()> {
    let preset: Preset = args.preset.parse()?;
    let start = Instant::now();
    std::fs::create_dir_all(&args.out).map_err(|e| Error::io(&args.out, e))?;
    let rig = ViewRig::wonder3d_ortho();

    let b = stage_bar(args.quiet, "views")?;
    let t = Instant::now();
    let spot = bundled_spot()?;
    let views = w3d_raster::render_oracle_views(&spot, &rig, args.size)?;
    let views_seconds = t.elapsed().as_secs_f64();
    b.finish_with_message(format!("6 oracle views of spot at {0}×{0}", args.size));

    let b = stage_bar(args.quiet, "reconstruct")?;
    let (mesh, recon) = reconstruct(&views, &ReconOptions::preset(preset), &mut recon_progress(&b))?;
    b.finish_with_message(format!("{} triangles", mesh.triangle_count()));

    let b = stage_bar(args.quiet, "texture")?;
    b.enable_steady_tick(std::time::Duration::from_millis(200));
    let t = Instant::now();
    let textured = bake(&mesh, &views, &TextureOptions::default().with_size(args.texture_size))?;
    let texture_seconds = t.elapsed().as_secs_f64();
    b.finish_with_message(format!("{0}×{0} atlas, {1} charts", args.texture_size, textured.report.atlas.charts));

    let b = stage_bar(args.quiet, "evaluate")?;
    b.enable_steady_tick(std::time::Duration::from_millis(200));
    let t = Instant::now();
    let metrics = evaluate(&mesh, &spot, &EvalOptions::default())?;
    let result_views = w3d_raster::render_oracle_views(&textured.mesh, &rig, args.size)?;
    let (mut psnrs, mut ssims) = (Vec::new(), Vec::new());
    let mut sheet = vec![Vec::new(), Vec::new(), Vec::new(), Vec::new()];
    for (input, result) in views.views().iter().zip(result_views.views()) {
        let (Some(ci), Some(cr)) = (&input.colour, &result.colour) else {
            return Err(Error::invalid("views", "colour images in the oracle views"));
        };
        let a = composite_over_white(&ci.with_alpha(&input.mask)?)?;
        let r = composite_over_white(&cr.with_alpha(&result.mask)?)?;
        psnrs.push(psnr(&a, &r)?);
        ssims.push(ssim(&a, &r)?);
        sheet[0].push(ci.with_alpha(&input.mask)?);
        sheet[1].push(normal_rgba(&input.normal, &input.mask)?);
        sheet[2].push(cr.with_alpha(&result.mask)?);
        sheet[3].push(normal_rgba(&result.normal, &result.mask)?);
    }
    let eval_seconds = t.elapsed().as_secs_f64();
    b.finish_with_message(format!("Chamfer {:.4}, IoU {:.3}", metrics.chamfer, metrics.iou_64));

    let glb = args.out.join("spot.glb");
    save_mesh(&glb, &textured.mesh)?;
    contact_sheet(&sheet)?.write_png(args.out.join("views.png"))?;
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let report = json!({
        "object": "spot (Keenan Crane, CC0), bundled",
        "preset": preset,
        "view_size": args.size,
        "texture_size": args.texture_size,
        "seconds": {
            "views": views_seconds,
            "init": recon.init.seconds,
            "coarse": recon.coarse.seconds,
            "texture": texture_seconds,
            "evaluate": eval_seconds,
            "total": start.elapsed().as_secs_f64(),
        },
        "triangles": mesh.triangle_count(),
        "init": recon.init,
        "geometry": metrics,
        "texture_psnr_input_views": mean(&psnrs),
        "texture_ssim_input_views": mean(&ssims),
        "texture_psnr_per_view": psnrs,
        "texture": textured.report,
    });
    let json = serde_json::to_vec_pretty(&report).map_err(|e| Error::invalid("report", e.to_string()))?;
    let report_path = args.out.join("report.json");
    write_atomic(&report_path, |w| std::io::Write::write_all(w, &json).map_err(|e| Error::io(&report_path, e)))?;
    println!(
        "spot: {} triangles, Chamfer {:.4}, F@0.02 {:.3}, IoU {:.3}, texture PSNR {:.1} dB, {:.1} s in all",
        mesh.triangle_count(),
        metrics.chamfer,
        metrics.fscore_002,
        metrics.iou_64,
        mean(&psnrs),
        start.elapsed().as_secs_f64()
    );
    println!("wrote {}, {} and {}", glb.display(), args.out.join("views.png").display(), report_path.display());
    Ok(())
}
