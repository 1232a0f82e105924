//! `wonder3d render MESH --rig … --size N --out DIR`: the oracle views.

use std::path::PathBuf;

use w3d_core::{Result, ViewRig, load_mesh};

/// Arguments of `wonder3d render`.
#[derive(clap::Args)]
pub struct RenderArgs {
    /// Mesh file (.obj, .ply, .glb, .gltf).
    mesh: PathBuf,
    /// Camera rig: wonder3d-ortho, wonder3d-persp or syncdreamer16.
    #[arg(long, default_value = "wonder3d-ortho")]
    rig: String,
    /// Image width and height in pixels.
    #[arg(long, default_value_t = 256)]
    size: u32,
    /// Output folder (created if needed).
    #[arg(long)]
    out: PathBuf,
    /// Render the mesh in its own coordinates instead of normalising it to the unit cube.
    #[arg(long)]
    no_normalize: bool,
}

/// Runs `wonder3d render`: normal, colour and mask PNGs, normal and depth EXRs and
/// `cameras.json` in the view-set folder layout.
pub fn run(args: &RenderArgs) -> Result<()> {
    let rig = ViewRig::by_name(&args.rig)?;
    let mut mesh = load_mesh(&args.mesh)?;
    if !args.no_normalize {
        mesh.normalize_unit_cube();
    }
    let views = w3d_raster::render_oracle_views(&mesh, &rig, args.size)?;
    views.save(&args.out)?;
    println!(
        "wrote {} views of {} ({}×{}) to {}",
        rig.len(),
        args.mesh.display(),
        args.size,
        args.size,
        args.out.display()
    );
    Ok(())
}
