//! An RGBA image → 6 normal + 6 colour views with the Wonder3D++ multi-view diffusion model
//! (`wonder3d::Generator`; weights: `docs/weights.md`). The tiny random-weight test checkpoint
//! runs in seconds and makes noise; the published weights make views.
//!
//! ```text
//! cargo run --release -p wonder3d-examples --example generate_views -- cup.png ckpts/wonder3d_plus views/cup 50
//! ```

use wonder3d::{Generator, Image, SampleOptions};

fn main() -> wonder3d::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(image), Some(weights), Some(out)) = (args.first(), args.get(1), args.get(2)) else {
        eprintln!("usage: generate_views IMAGE.png WEIGHTS_DIR OUT_DIR [STEPS]");
        std::process::exit(2);
    };
    let rgba = Image::read_png(image)?; // alpha masks the object
    let mut options = SampleOptions::default(); // 50 DDIM steps, guidance 2, seed 42
    if let Some(steps) = args.get(3) {
        options.steps = steps.parse().map_err(|_| wonder3d::Error::invalid("STEPS", "a whole number"))?;
    }
    let model = Generator::load(weights)?.with_options(options);
    let generated = model.generate(&rgba, &mut |p| eprint!("\r{} {}/{}   ", p.stage.name(), p.done, p.total))?;
    generated.views.save(out)?; // the view-set folder `wonder3d reconstruct` reads
    generated.input.write_png(std::path::Path::new(out).join("input.png"))?;
    eprintln!("\r{out}: {} views of {}×{}", generated.views.len(), generated.views.width(), generated.views.height());
    Ok(())
}
