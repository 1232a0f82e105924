//! `wonder3d render MESH --rig … --size N --out DIR`: the oracle views.

use std::path::PathBuf;

use wonder3d::outputs::check_out_dir;
use wonder3d::{Result, load_mesh};

use crate::args::RigArg;

/// Arguments of `wonder3d render`.
#[derive(clap::Args)]
pub struct RenderArgs {
    /// Mesh file (.obj, .ply, .glb, .gltf).
    mesh: PathBuf,
    /// Camera rig.
    #[arg(long, value_enum, default_value_t = RigArg::Wonder3dOrtho)]
    rig: RigArg,
    /// Image width and height in pixels.
    #[arg(long, default_value_t = 256, allow_hyphen_values = true, value_parser = crate::args::view_size)]
    size: u32,
    /// Output folder: a new folder, or an earlier view-set folder, which is replaced once
    /// the new views are complete (a failure leaves it as it was).
    #[arg(long)]
    out: PathBuf,
    /// Render the mesh in its own coordinates instead of normalising it to the unit cube.
    #[arg(long)]
    no_normalize: bool,
}

/// Runs `wonder3d render`: normal, colour and mask PNGs, normal and depth EXRs and
/// `cameras.json` in the view-set folder layout.
pub fn run(args: &RenderArgs) -> Result<()> {
    wonder3d::outputs::for_flag("--out", check_out_dir(&args.out))?;
    wonder3d::outputs::check_inputs_outside(("--out", &args.out), &[("MESH", &args.mesh)])?;
    let rig = args.rig.rig();
    let mut mesh = load_mesh(&args.mesh)?;
    crate::args::orient_outward(&mut mesh, &args.mesh);
    if !args.no_normalize {
        mesh.normalize_unit_cube();
    }
    let views = wonder3d::raster::render_oracle_views(&mesh, &rig, args.size)?;
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
