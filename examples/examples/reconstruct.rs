//! A view folder → a closed, untextured mesh with the reconstruction stage alone
//! (`wonder3d::recon`, the `w3d-recon` crate), printing the per-stage report.
//!
//! ```text
//! cargo run --release -p wonder3d-cli --no-default-features -- render assets/spot.obj --out views/spot
//! cargo run --release -p wonder3d-examples --example reconstruct -- views/spot spot.ply fast
//! ```

use wonder3d::recon::{Preset, ReconOptions, reconstruct};
use wonder3d::{ViewSet, save_mesh};

fn main() -> wonder3d::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(views), Some(out)) = (args.first(), args.get(1)) else {
        eprintln!("usage: reconstruct VIEWS_DIR OUT.(glb|obj|ply) [fast|default|quality]");
        std::process::exit(2);
    };
    let preset: Preset = args.get(2).map_or(Ok(Preset::Default), |p| p.parse())?;
    wonder3d::outputs::check_mesh_output(out)?;
    let views = ViewSet::load(views)?;
    let options = ReconOptions::preset(preset);
    let (mesh, report) = reconstruct(&views, &options, &mut |p| {
        if p.done == p.total {
            eprintln!("{:?} done{}", p.stage, p.loss.map(|l| format!(", loss {l:.5}")).unwrap_or_default());
        }
    })?;
    save_mesh(out, &mesh)?;
    println!("start mesh: {}", report.init.reason);
    for stage in &report.stages {
        println!("{:>10?} {:6.2} s", stage.stage, stage.seconds);
    }
    let topology = mesh.topology();
    println!(
        "{out}: {} triangles, watertight {}, genus {:?}, crossings left {}",
        mesh.triangle_count(),
        topology.is_watertight(),
        topology.genus(),
        report.untangle.after
    );
    Ok(())
}
