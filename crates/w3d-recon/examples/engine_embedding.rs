//! Mesh extraction embedded in an engine: the engine renders its own normal and coverage
//! buffers from six cameras, and `w3d-recon` turns them into a closed mesh — in memory, with
//! no file IO and no diffusion model (build `w3d-recon` with `default-features = false` and
//! it pulls no file-format or tensor crates).
//!
//! Here the "engine" ray-casts an ellipsoid analytically:
//!
//! ```sh
//! cargo run --release -p w3d-recon --example engine_embedding
//! ```

use w3d_core::glam::Vec3;
use w3d_core::{Image, ViewImages, ViewRig, ViewSet};
use w3d_recon::{Preset, ReconOptions, reconstruct};

/// Semi-axes of the ellipsoid in world units (canonical frame: y up, front camera on +z).
const RADII: Vec3 = Vec3::new(0.45, 0.3, 0.35);

/// The engine's G-buffer for one camera: world-space unit normals and coverage.
fn render(camera: &w3d_core::Camera, size: u32) -> w3d_core::Result<(Image, Image)> {
    let mut normals = vec![0.0f32; (size * size * 3) as usize];
    let mut mask = vec![0.0f32; (size * size) as usize];
    for y in 0..size {
        for x in 0..size {
            let ray = camera.ray(x as f32 + 0.5, y as f32 + 0.5, size, size);
            // In the ellipsoid's unit-sphere space: |o + t d|² = 1.
            let (o, d) = (ray.origin / RADII, ray.direction / RADII);
            let (a, b, c) = (d.dot(d), 2.0 * o.dot(d), o.dot(o) - 1.0);
            let disc = b * b - 4.0 * a * c;
            if disc < 0.0 {
                continue;
            }
            let t = (-b - disc.sqrt()) / (2.0 * a);
            let p = ray.origin + t * ray.direction;
            let n = (p / (RADII * RADII)).normalize();
            let i = (y * size + x) as usize;
            normals[3 * i..3 * i + 3].copy_from_slice(&n.to_array());
            mask[i] = 1.0;
        }
    }
    Ok((Image::new(size, size, 3, normals)?, Image::new(size, size, 1, mask)?))
}

fn main() -> w3d_core::Result<()> {
    let rig = ViewRig::wonder3d_ortho();
    let mut views = Vec::new();
    for view in &rig.views {
        let (normal, mask) = render(&view.camera, 128)?;
        views.push(ViewImages { name: view.name.clone(), normal, colour: None, mask, depth: None });
    }
    let views = ViewSet::new(rig, views)?;
    let (mesh, report) = reconstruct(&views, &ReconOptions::preset(Preset::Fast), &mut |_| {})?;

    // How far the vertices lie from the true surface (ellipsoid "radius" error, world units).
    let worst = mesh
        .positions()
        .iter()
        .map(|&p| ((Vec3::from(p) / RADII).length() - 1.0).abs() * RADII.min_element())
        .fold(0.0f32, f32::max);
    println!(
        "{} triangles, watertight: {}, genus {:?}, worst vertex off the surface by {worst:.4}, {:.1} s",
        mesh.triangle_count(),
        mesh.topology().is_watertight(),
        mesh.topology().genus(),
        report.seconds
    );
    // A pixel of the 128² views spans 1.5 / 128 ≈ 0.012 world units: ask for 2.5 pixels at worst.
    assert!(mesh.topology().is_watertight() && worst < 0.03, "the extraction should recover the ellipsoid");
    Ok(())
}
