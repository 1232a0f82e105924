//! One whole enhancer call against diffusers / transformers on a tiny enhancer directory
//! (`tests/fixtures/enhancer`, written by `xtask/python/fixtures_enhancer.py`): the prompts
//! through the tokenizer and text encoder, the IP tokens through the image encoder (the
//! authors' twice-rescaled image) and projection, the VAE posterior sample, the SDEdit
//! noising at strength 0.2 and ten UniPC steps of ControlNet + UNet with guidance, in the
//! corrected batch order and in the authors' released one, then the decode. The noise is
//! injected (torch's generator cannot be reproduced).

use crate::common::{fixture, max_abs, max_abs_diff, tensor, test_devices};
use w3d_diffusion::pipelines::enhancer::{
    EnhancerConditioning, EnhancerOptions, EnhancerPipeline, ImageTokens, PromptEmbeddings, make_grid, split_grid,
};
use w3d_diffusion::{SafetensorsFile, Tensor};

fn check<const D: usize>(name: &str, what: &str, ours: Tensor<D>, expected: Tensor<D>, tolerance: f32) {
    let scale = max_abs(expected.clone());
    let err = max_abs_diff(ours, expected);
    println!("{name}: {what} max-abs error {err:.2e} (values up to {scale:.2})");
    assert!(err <= tolerance, "{name}: {what} max-abs error {err}");
}

#[test]
fn one_enhancer_call_matches_the_authors_pipeline() {
    for (name, device) in test_devices() {
        let pipeline = EnhancerPipeline::from_dir(fixture("enhancer"), &device).unwrap();
        let mut io = SafetensorsFile::open(fixture("enhancer/io.safetensors")).unwrap();
        let options = EnhancerOptions::default();
        assert_eq!((options.strength, options.control_scale, options.steps), (0.2, 0.7, 50));

        let prompts = pipeline.encode_prompts(&options).unwrap();
        check(name, "empty prompt", prompts.uncond.clone(), tensor(&mut io, "prompt_uncond", &device), 1e-4);
        check(name, "colour prompt", prompts.colour.clone(), tensor(&mut io, "prompt_colour", &device), 1e-4);
        check(name, "normal prompt", prompts.normal.clone(), tensor(&mut io, "prompt_normal", &device), 1e-4);

        let (ip_values, ip_shape) = io.read_f32("ip_image").unwrap();
        let ip_image = w3d_core::Image::new(ip_shape[1] as u32, ip_shape[0] as u32, 3, ip_values).unwrap();
        let tokens = pipeline.image_tokens(&ip_image, &options, &device).unwrap();
        check(name, "uncond IP tokens", tokens.uncond.clone(), tensor(&mut io, "ip_uncond", &device), 1e-4);
        check(name, "cond IP tokens", tokens.cond.clone(), tensor(&mut io, "ip_cond", &device), 1e-4);

        let grids: Tensor<4> = tensor(&mut io, "grids", &device);
        let init = pipeline.encode_grids(grids.clone(), tensor(&mut io, "posterior_noise", &device)).unwrap();
        check(name, "init latents", init.clone(), tensor(&mut io, "init", &device), 1e-4);

        // The denoising from the reference's own init latents, so each stage is checked alone.
        let reference_init: Tensor<4> = tensor(&mut io, "init", &device);
        let noise: Tensor<4> = tensor(&mut io, "noise", &device);
        let prompts = PromptEmbeddings {
            uncond: tensor(&mut io, "prompt_uncond", &device),
            colour: tensor(&mut io, "prompt_colour", &device),
            normal: tensor(&mut io, "prompt_normal", &device),
        };
        let image =
            ImageTokens { uncond: tensor(&mut io, "ip_uncond", &device), cond: tensor(&mut io, "ip_cond", &device) };
        let conditioning = EnhancerConditioning { prompts, image };
        for (key, upstream) in [("latents_fixed", false), ("latents_upstream", true)] {
            let options = options.clone().with_upstream_cfg_bugs(upstream);
            let mut steps = Vec::new();
            let latents = pipeline
                .denoise(reference_init.clone(), noise.clone(), grids.clone(), &conditioning, &options, &mut |d, n| {
                    steps.push((d, n))
                })
                .unwrap();
            assert_eq!(steps.len(), 10, "strength 0.2 of 50 steps runs 10");
            assert_eq!(steps.last(), Some(&(10, 10)));
            check(name, key, latents.clone(), tensor(&mut io, key, &device), 1e-4);
            if !upstream {
                let decoded = pipeline.decode_grids(latents).unwrap();
                check(name, "decoded grids", decoded, tensor(&mut io, "decoded_fixed", &device), 1e-4);
            }
        }
    }
}

#[test]
fn grids_are_front_right_over_back_left_and_split_back() {
    let tile = |v: f32| w3d_core::Image::filled(3, 2, 3, v).unwrap();
    let tiles = [tile(0.1), tile(0.2), tile(0.3), tile(0.4)];
    let grid = make_grid(&tiles).unwrap();
    assert_eq!((grid.width(), grid.height()), (6, 4));
    assert_eq!(grid.pixel(0, 0)[0], 0.1);
    assert_eq!(grid.pixel(5, 0)[0], 0.2);
    assert_eq!(grid.pixel(0, 3)[0], 0.3);
    assert_eq!(grid.pixel(5, 3)[0], 0.4);
    assert_eq!(split_grid(&grid).unwrap(), tiles.to_vec());
    assert!(make_grid(&tiles[..3]).is_err());
    assert!(split_grid(&w3d_core::Image::filled(5, 4, 3, 0.0).unwrap()).is_err());
}

#[test]
fn a_missing_enhancer_file_is_named_with_the_docs_section() {
    let dir = tempfile::tempdir().unwrap();
    let err = EnhancerPipeline::from_dir(dir.path(), &w3d_diffusion::default_device()).unwrap_err().to_string();
    assert!(err.contains("unet") && err.contains("config.json") && err.contains("docs/weights.md"), "{err}");
    // Everything but the IP-Adapter: that file is named.
    let copy = dir.path().join("enhancer");
    copy_dir(&fixture("enhancer"), &copy);
    std::fs::remove_file(copy.join("ip_adapter/ip-adapter_sd15.safetensors")).unwrap();
    let err = EnhancerPipeline::from_dir(&copy, &w3d_diffusion::default_device()).unwrap_err().to_string();
    assert!(err.contains("ip-adapter_sd15.safetensors") && err.contains("docs/weights.md"), "{err}");
}

fn copy_dir(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}
