//! `wonder3d texture MESH VIEWS_DIR --out OUT`: bake the colour views onto a mesh.

use std::path::PathBuf;

use wonder3d::outputs::{check_distinct, check_mesh_output, mesh_output_files};
use wonder3d::texture::{bake_with_progress, fuse_vertex_colours};
use wonder3d::{Progress, Result, Stage, TextureOptions, ViewSet, save_mesh};

use crate::progress;

/// Arguments of `wonder3d texture`.
#[derive(clap::Args)]
pub struct TextureArgs {
    /// Mesh in the canonical frame of the views (.obj, .ply, .glb, .gltf); its own uvs,
    /// colours and texture are ignored.
    mesh: PathBuf,
    /// View-set folder (`cameras.json`, `colour_<view>.png`, masks, normals), as written by
    /// `wonder3d render` or `wonder3d generate`.
    views: PathBuf,
    /// Output file: `.glb` (embedded PNG texture) or `.obj` (+ `.mtl` + `.png` beside it; all
    /// three are checked before any work and written together at the end).
    #[arg(long)]
    out: PathBuf,
    /// Texture width and height in texels.
    #[arg(long, default_value_t = TextureOptions::default().size, allow_hyphen_values = true, value_parser = crate::args::texture_size)]
    size: u32,
    /// Empty texels around each chart in the atlas.
    #[arg(long, default_value_t = TextureOptions::default().padding, allow_hyphen_values = true, value_parser = crate::args::texels)]
    padding: u32,
    /// Texel rings grown outwards from the charts after baking.
    #[arg(long, default_value_t = TextureOptions::default().dilation, allow_hyphen_values = true, value_parser = crate::args::texels)]
    dilation: u32,
    /// Exponent k of the view weight |cos(view, normal)|^k.
    #[arg(long, default_value_t = TextureOptions::default().view_weight_exponent, allow_hyphen_values = true, value_parser = crate::args::exponent)]
    exponent: f32,
    /// Write the fused per-vertex colours instead of a texture (no uv atlas; the fallback
    /// for viewers without texture support).
    #[arg(long)]
    vertex_colours: bool,
    /// Normalise the mesh into the unit cube first (as `wonder3d render` does by default,
    /// for views rendered from a raw mesh).
    #[arg(long)]
    normalize: bool,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

/// Runs `wonder3d texture`.
pub fn run(args: &TextureArgs) -> Result<()> {
    wonder3d::outputs::for_flag("--out", check_mesh_output(&args.out))?;
    let outputs = mesh_output_files(&args.out);
    let outputs: Vec<(&str, &std::path::Path)> = outputs.iter().map(|f| ("--out", f.as_path())).collect();
    let view_files = wonder3d::ViewSet::input_files(&args.views);
    let mut inputs = vec![("MESH", args.mesh.as_path())];
    inputs.extend(view_files.iter().map(|f| ("VIEWS", f.as_path())));
    check_distinct(&outputs, &inputs)?;
    let options = TextureOptions::default()
        .with_size(args.size)
        .with_padding(args.padding)
        .with_dilation(args.dilation)
        .with_view_weight_exponent(args.exponent);
    options.validate()?;
    let mut mesh = wonder3d::load_mesh_with_surface(&args.mesh, "MESH")?.without_attributes();
    crate::args::orient_outward(&mut mesh, &args.mesh);
    if args.normalize {
        mesh.normalize_unit_cube();
    }
    let views = ViewSet::load(&args.views)?;
    if args.vertex_colours {
        let fused = fuse_vertex_colours(&mesh, &views, &options)?;
        save_mesh(&args.out, &fused.mesh)?;
        println!(
            "wrote {}: {} views, vertex colours, seen vertices {:.1} %",
            args.out.display(),
            fused.views_used,
            100.0 * fused.seen_vertex_fraction
        );
        return Ok(());
    }
    let bar = progress::bar(args.quiet)?;
    let mut follow = progress::follow(&bar);
    // What the views see of the mesh is about both inputs: name them.
    let both = format!("MESH {} in VIEWS {}", args.mesh.display(), args.views.display());
    let textured = wonder3d::outputs::for_flag(
        &both,
        bake_with_progress(&mesh, &views, &options, &mut |stage| {
            follow(Progress::new(Stage::Texture(stage.into()), 0, 1, None))
        }),
    )?;
    bar.finish_and_clear();
    let r = textured.report;
    save_mesh(&args.out, &textured.mesh)?;
    println!(
        "wrote {}: {} views, {} charts, atlas utilisation {:.1} %, angle distortion {:.2}°, seen vertices {:.1} %, seen texels {:.1} %",
        args.out.display(),
        r.views_used,
        r.atlas.charts,
        100.0 * r.atlas.utilisation,
        r.atlas.angle_distortion_deg,
        100.0 * r.seen_vertex_fraction,
        100.0 * r.seen_texel_fraction
    );
    Ok(())
}
