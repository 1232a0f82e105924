//! Bake colour views onto a mesh in the same frame: UV atlas, baked texture, dilation
//! (`wonder3d::texture`, the `w3d-texture` crate).
//!
//! ```text
//! cargo run --release -p wonder3d-cli --no-default-features -- render assets/spot.obj --out views/spot
//! cargo run --release -p wonder3d-examples --example bake_texture -- assets/spot.obj views/spot spot_textured.glb 512
//! ```

use wonder3d::texture::bake;
use wonder3d::{TextureOptions, ViewSet, load_mesh};

fn main() -> wonder3d::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(mesh), Some(views), Some(out)) = (args.first(), args.get(1), args.get(2)) else {
        eprintln!("usage: bake_texture MESH VIEWS_DIR OUT.(glb|obj) [TEXELS]");
        std::process::exit(2);
    };
    wonder3d::outputs::check_mesh_output(out)?;
    // The views of `wonder3d render` are of the mesh normalised into the unit cube.
    let mut mesh = load_mesh(mesh)?.without_attributes();
    mesh.normalize_unit_cube();
    let views = ViewSet::load(views)?;
    let mut options = TextureOptions::default();
    if let Some(size) = args.get(3) {
        options.size = size.parse().map_err(|_| wonder3d::Error::invalid("TEXELS", "a whole number"))?;
    }
    let textured = bake(&mesh, &views, &options)?;
    wonder3d::save_mesh(out, &textured.mesh)?;
    let r = textured.report;
    println!(
        "{out}: {} charts, {:.0} % of the atlas used, {:.1} % of the vertices seen by a view",
        r.atlas.charts,
        100.0 * r.atlas.utilisation,
        100.0 * r.seen_vertex_fraction
    );
    Ok(())
}
