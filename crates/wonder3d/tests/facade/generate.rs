//! `Generator` samples what `MultiViewPipeline` samples, draws included.

use wonder3d::diffusion::MultiViewPipeline;
use wonder3d::{Generator, Image, SampleOptions};

fn tiny_model() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../w3d-diffusion/tests/fixtures/wonder3d_tiny")
}

/// An RGBA disc (its alpha masks the object, so no background removal runs).
pub(crate) fn disc(side: u32) -> Image {
    let mut image = Image::filled(side, side, 4, 0.0).unwrap();
    let c = side as f32 / 2.0;
    for y in 0..side {
        for x in 0..side {
            if (x as f32 + 0.5 - c).hypot(y as f32 + 0.5 - c) < c * 0.7 {
                image.pixel_mut(x, y).copy_from_slice(&[0.8, x as f32 / side as f32, 0.3, 1.0]);
            }
        }
    }
    image
}

#[test]
fn the_generator_merges_the_draws_the_pipeline_merges() {
    let options = SampleOptions { steps: 2, seed: 3, draws: 3, ..SampleOptions::default() };
    let generator = Generator::load(tiny_model()).unwrap().with_options(options);
    let image = disc(48);
    let mut denoised = Vec::new();
    let views = generator
        .generate(&image, &mut |p| {
            if p.stage == wonder3d::Stage::Denoise {
                denoised.push((p.done, p.total));
            }
        })
        .unwrap()
        .views;
    // One progress bar over the three draws' steps.
    assert_eq!(denoised.last(), Some(&(6, 6)), "{denoised:?}");
    let device = wonder3d::diffusion::default_device();
    let pipeline = MultiViewPipeline::from_dir(tiny_model(), &device).unwrap();
    let expected = pipeline.generate(&image, &options, &device, &mut |_, _| {}).unwrap().to_view_set().unwrap();
    assert_eq!(views, expected);
    let one = generator.generate_with(&image, &SampleOptions { draws: 1, ..options }, &mut |_| {}).unwrap().views;
    assert_ne!(views, one, "three draws gave the views of one");
}
