//! Bad input gets clear errors: wrong image size / channel count, wrong key sets and shapes,
//! truncated or non-safetensors files, unsupported config values.

mod common;
#[path = "../../w3d-core/tests/mutate/mod.rs"]
mod mutate;

#[path = "errors_cases/fuzz_weights.rs"]
mod fuzz_weights;

use common::fixture;
use w3d_diffusion::{
    ClipVision, ClipVisionConfig, SafetensorsFile, Tensor, UNet, UNetConfig, Vae, VaeConfig, clip_preprocess,
};

fn message<T: std::fmt::Debug>(r: Result<T, w3d_core::Error>) -> String {
    r.expect_err("an error").to_string()
}

#[test]
fn wrong_image_sizes_and_channels_are_rejected() {
    let device = w3d_diffusion::default_device();
    let vae = Vae::from_dir(fixture("vae"), &device).unwrap();
    let m = message(vae.encode_mean(Tensor::zeros([1, 3, 30, 32], &device)));
    assert!(m.contains("multiples of 4") && m.contains("30x32"), "{m}");
    let m = message(vae.encode_mean(Tensor::zeros([1, 4, 32, 32], &device)));
    assert!(m.contains("3 channels") && m.contains("found 4"), "{m}");
    let m = message(vae.decode(Tensor::zeros([1, 3, 8, 8], &device)));
    assert!(m.contains("4 channels"), "{m}");

    let unet = UNet::from_dir(fixture("unet"), &device).unwrap();
    let ctx = Tensor::zeros([1, 1, 12], &device);
    let labels = || Some(Tensor::zeros([1, 14], &device));
    let m = message(unet.forward(Tensor::zeros([1, 4, 16, 16], &device), &[1.0], ctx.clone(), labels()));
    assert!(m.contains("8 channels"), "{m}");
    let m = message(unet.forward(Tensor::zeros([1, 8, 10, 16], &device), &[1.0], ctx.clone(), labels()));
    assert!(m.contains("multiples of 4"), "{m}");
    let m = message(unet.forward(
        Tensor::zeros([1, 8, 16, 16], &device),
        &[1.0],
        Tensor::zeros([1, 1, 7], &device),
        labels(),
    ));
    assert!(m.contains("context"), "{m}");
    let m = message(unet.forward(Tensor::zeros([1, 8, 16, 16], &device), &[1.0], ctx.clone(), None));
    assert!(m.contains("class_labels"), "{m}");
    let m = message(unet.forward(Tensor::zeros([1, 8, 16, 16], &device), &[1.0, 2.0, 3.0], ctx, labels()));
    assert!(m.contains("timesteps"), "{m}");

    let clip = ClipVision::from_dir(fixture("clip"), &device).unwrap();
    let m = message(clip.image_embeds(Tensor::zeros([1, 3, 32, 32], &device)));
    assert!(m.contains("[n, 3, 30, 30]"), "{m}");
    let m = message(clip_preprocess(&[0.0; 10], 2, 2, 30));
    assert!(m.contains("2x2x3"), "{m}");
}

#[test]
fn wrong_key_sets_are_reported_by_name() {
    let device = w3d_diffusion::default_device();
    // VAE weights for a UNet: every UNet key missing, every VAE key unexpected.
    let config = UNetConfig::from_file(fixture("unet/config.json")).unwrap();
    let m = message(UNet::load(&config, fixture("vae/diffusion_pytorch_model.safetensors"), &device));
    assert!(m.contains("missing") && m.contains("conv_in.weight [16, 8, 3, 3]"), "{m}");
    assert!(m.contains("unexpected") && m.contains("encoder.conv_in.weight"), "{m}");
    // Same keys, different shapes: a config with other channel counts.
    let mut wider = config.clone();
    wider.in_channels = 4;
    let m = message(UNet::load(&wider, fixture("unet/diffusion_pytorch_model.safetensors"), &device));
    assert!(
        m.contains("wrong shape") && m.contains("conv_in.weight: expected [16, 4, 3, 3], found [16, 8, 3, 3]"),
        "{m}"
    );
    assert!(!m.contains("missing") && !m.contains("unexpected"), "{m}");
    // A config without the class embedding leaves its keys unused.
    let mut plain = config;
    plain.class_embed_type = None;
    let m = message(UNet::load(&plain, fixture("unet/diffusion_pytorch_model.safetensors"), &device));
    assert!(m.contains("4 unexpected") && m.contains("class_embedding.linear_1.weight"), "{m}");
}

#[test]
fn truncated_and_foreign_files_are_rejected() {
    let dir = std::env::temp_dir().join(format!("w3d-diffusion-errors-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bytes = std::fs::read(fixture("vae/diffusion_pytorch_model.safetensors")).unwrap();
    let truncated = dir.join("truncated.safetensors");
    std::fs::write(&truncated, &bytes[..bytes.len() - 100]).unwrap();
    let m = message(SafetensorsFile::open(&truncated));
    assert!(m.contains("truncated.safetensors") && m.contains("truncated"), "{m}");
    let config = VaeConfig::from_file(fixture("vae/config.json")).unwrap();
    let m = message(Vae::load(&config, &truncated, &w3d_diffusion::default_device()));
    assert!(m.contains("truncated"), "{m}");

    let header_cut = dir.join("header_cut.safetensors");
    std::fs::write(&header_cut, &bytes[..20]).unwrap();
    let m = message(SafetensorsFile::open(&header_cut));
    assert!(m.contains("header"), "{m}");

    let json = dir.join("not.safetensors");
    std::fs::write(&json, b"{\"hello\": 1}").unwrap();
    assert!(SafetensorsFile::open(&json).is_err());
    let m = message(SafetensorsFile::open(dir.join("absent.safetensors")));
    assert!(m.contains("absent.safetensors"), "{m}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A NaN or an infinity in a weights file is refused when the model loads, naming the file
/// and the tensor (it used to surface as a NaN output pixel, or in training as a loss blamed
/// on the learning rate).
#[test]
fn non_finite_weights_name_the_file_and_the_tensor() {
    let bytes = std::fs::read(fixture("vae/diffusion_pytorch_model.safetensors")).unwrap();
    let header_len = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + header_len]).unwrap();
    // The first tensor in the file's order (the fixture stores f16): its first value becomes
    // NaN, then +inf.
    let (key, begin) = header
        .as_object()
        .unwrap()
        .iter()
        .filter(|(k, v)| *k != "__metadata__" && v["dtype"] == "F16")
        .map(|(k, v)| (k.clone(), v["data_offsets"][0].as_u64().unwrap() as usize))
        .min_by_key(|(_, begin)| *begin)
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let config = VaeConfig::from_file(fixture("vae/config.json")).unwrap();
    for bad in [half::f16::NAN, half::f16::INFINITY] {
        let mut damaged = bytes.clone();
        let at = 8 + header_len + begin;
        damaged[at..at + 2].copy_from_slice(&bad.to_le_bytes());
        let path = dir.path().join("damaged.safetensors");
        std::fs::write(&path, &damaged).unwrap();
        let m = message(Vae::load(&config, &path, &w3d_diffusion::default_device()));
        assert!(m.contains("damaged.safetensors") && m.contains(&key) && m.contains("not finite"), "{m}");
    }
}

/// A header whose shape or offsets of one tensor do not add up names that tensor and what
/// was expected (the format's own validation only said the header was invalid).
#[test]
fn damaged_headers_name_the_tensor() {
    let bytes = std::fs::read(fixture("vae/diffusion_pytorch_model.safetensors")).unwrap();
    let header_len = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + header_len]).unwrap();
    let data = &bytes[8 + header_len..];
    let key = header.as_object().unwrap().keys().find(|k| *k != "__metadata__").unwrap().clone();
    let dir = tempfile::tempdir().unwrap();
    let write = |header: &serde_json::Value| {
        let text = serde_json::to_vec(header).unwrap();
        let mut file = (text.len() as u64).to_le_bytes().to_vec();
        file.extend(text);
        file.extend(data);
        let path = dir.path().join("damaged.safetensors");
        std::fs::write(&path, file).unwrap();
        path
    };
    let with_header = |header: &serde_json::Value| message(SafetensorsFile::open(write(header)));
    let mut wrong_shape = header.clone();
    let dim = wrong_shape[&key]["shape"][0].as_u64().unwrap();
    wrong_shape[&key]["shape"][0] = serde_json::json!(dim + 1);
    let m = with_header(&wrong_shape);
    assert!(m.contains("damaged.safetensors") && m.contains(&key) && m.contains("data_offsets"), "{m}");
    let mut wrong_dtype = header.clone();
    wrong_dtype[&key]["dtype"] = serde_json::json!("F12");
    let m = with_header(&wrong_dtype);
    assert!(m.contains(&key) && m.contains("dtype"), "{m}");
    // The untouched header, written the same way, still opens.
    assert!(SafetensorsFile::open(write(&header)).is_ok());
}

#[test]
fn configs_parse_and_unsupported_values_are_named() {
    let unet = UNetConfig::from_file(fixture("unet/config.json")).unwrap();
    assert_eq!((unet.in_channels, unet.heads(0).unwrap(), unet.time_embed_dim()), (8, 2, 64));
    let vae = VaeConfig::from_file(fixture("vae/config.json")).unwrap();
    assert_eq!(vae.downscale(), 4);
    let clip = ClipVisionConfig::from_file(fixture("clip/config.json")).unwrap();
    assert_eq!(clip.patches_per_side(), 5);

    let json = std::fs::read_to_string(fixture("unet/config.json")).unwrap();
    for (from, to, field) in [
        ("\"DownBlock2D\"", "\"SimpleDownBlock2D\"", "down_block_types[2]"),
        ("\"attention_type\": \"default\"", "\"attention_type\": \"gated\"", "attention_type"),
        ("\"time_embedding_type\": \"positional\"", "\"time_embedding_type\": \"fourier\"", "time_embedding_type"),
    ] {
        let bad: UNetConfig = serde_json::from_str(&json.replacen(from, to, 1)).unwrap();
        let m = bad.validate().unwrap_err().to_string();
        assert!(m.contains(field), "{m}");
    }
    // A full CLIPConfig (text + vision) is accepted through its vision_config.
    let full = serde_json::json!({"projection_dim": 12, "vision_config": {"hidden_size": 32, "num_attention_heads": 4,
        "image_size": 30, "patch_size": 6, "intermediate_size": 48, "num_hidden_layers": 2}});
    let from_full = ClipVisionConfig::from_value(full).unwrap();
    assert_eq!(from_full, clip);
    // A value of the wrong type is named by its key, from a value and from a file.
    let mut value: serde_json::Value = serde_json::from_str(&json).unwrap();
    value["layers_per_block"] = serde_json::json!(1e12);
    let m = message(UNetConfig::from_value(value.clone()));
    assert!(m.contains("layers_per_block") && m.contains("floating point"), "{m}");
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("config.json");
    std::fs::write(&path, serde_json::to_string(&value).unwrap()).unwrap();
    let m = message(UNetConfig::from_file(&path));
    assert!(m.contains("config.json") && m.contains("layers_per_block"), "{m}");
    let vae_json = std::fs::read_to_string(fixture("vae/config.json")).unwrap();
    let mut vae_value: serde_json::Value = serde_json::from_str(&vae_json).unwrap();
    vae_value["block_out_channels"] = serde_json::json!([16, "wide"]);
    std::fs::write(&path, serde_json::to_string(&vae_value).unwrap()).unwrap();
    let m = message(VaeConfig::from_file(&path));
    assert!(m.contains("block_out_channels[1]"), "{m}");
}
