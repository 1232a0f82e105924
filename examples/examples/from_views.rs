//! Views → textured GLB with the facade alone: the whole extraction in a few lines.
//!
//! ```text
//! cargo run --release -p wonder3d-cli --no-default-features -- render assets/spot.obj --out views/spot
//! cargo run --release -p wonder3d-examples --example from_views -- views/spot spot.glb
//! ```

use wonder3d::{Pipeline, Preset, ViewSet};

fn main() -> wonder3d::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [views, out] = &args[..] else {
        eprintln!("usage: from_views VIEWS_DIR OUT.glb");
        std::process::exit(2);
    };
    wonder3d::outputs::check_mesh_output(out)?; // fail now, not after the work
    let views = ViewSet::load(views)?; // cameras.json + normal / mask / colour images
    let pipeline = Pipeline::new().with_preset(Preset::Default).with_texture_size(1024);
    let output = pipeline.from_views(&views, &mut |p| eprint!("\r{:>10} {}/{}   ", p.stage.name(), p.done, p.total))?;
    output.save(out)?; // GLB with the texture embedded
    let r = &output.report;
    eprintln!("\r{out}: {} triangles in {:.1} s (texture {:.1} s)", r.triangles, r.seconds.total, r.seconds.texture);
    Ok(())
}
