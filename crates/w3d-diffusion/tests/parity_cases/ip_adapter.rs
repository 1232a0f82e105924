//! The IP-Adapter of the enhancer against diffusers / transformers (fixtures from
//! `xtask/python/fixtures_ip_adapter.py`): the image projection, a tiny SD-layout UNet with the
//! adapter loaded by diffusers' own loader (so the `ip_adapter.{k}` numbering is checked
//! independently) at two IP scales and with duplicated tokens, a CLIP vision encoder with exact
//! (erf) GELU as the ViT-H/14 image encoder, the authors' double-rescaling preprocessing, and
//! the loader's and the forward pass's errors.

use std::path::{Path, PathBuf};

use crate::common::{fixture, max_abs, max_abs_diff, max_abs_vec, tensor, test_devices, values};
use w3d_diffusion::{
    CLIP_MEAN, CLIP_STD, ClipVision, Device, IpTokens, SafetensorsFile, Tensor, UNet, UNetExtra,
    clip_preprocess_rescaled_twice,
};

fn ip_fixture(name: &str) -> PathBuf {
    fixture(&format!("ip_adapter/{name}"))
}

/// The fixture UNet's inputs and diffusers' outputs on `device`.
struct Io {
    sample: Tensor<4>,
    timesteps: Vec<f32>,
    context: Tensor<3>,
    image_embeds: Tensor<2>,
    file: SafetensorsFile,
}

impl Io {
    fn open(device: &Device) -> Self {
        let mut file = SafetensorsFile::open(ip_fixture("io.safetensors")).unwrap();
        Self {
            sample: tensor(&mut file, "sample", device),
            timesteps: values(tensor::<1>(&mut file, "timesteps", device)),
            context: tensor(&mut file, "context", device),
            image_embeds: tensor(&mut file, "image_embeds", device),
            file,
        }
    }

    fn run(&self, unet: &UNet, ip: Option<IpTokens>) -> Result<Tensor<4>, w3d_core::Error> {
        // `..Default::default()`: other fields (the ControlNet residuals) stay unset.
        let extra = UNetExtra { ip, ..Default::default() };
        unet.forward_with(self.sample.clone(), &self.timesteps, self.context.clone(), None, &extra)
    }
}

#[test]
fn image_projection_matches_diffusers() {
    for (name, device) in test_devices() {
        let mut unet = UNet::from_dir(ip_fixture("unet"), &device).unwrap();
        let projection = unet.load_ip_adapter(ip_fixture("ip_adapter.safetensors")).unwrap();
        assert_eq!((projection.tokens(), projection.embed_dim(), projection.cross_dim()), (4, 24, 32));
        let mut io = Io::open(&device);
        let out = projection.forward(tensor(&mut io.file, "proj_in", &device)).unwrap();
        let err = max_abs_diff(out, tensor(&mut io.file, "proj_out", &device));
        println!("{name}: ip image projection max-abs error {err:.2e}");
        assert!(err <= 1e-4, "{name}: image projection error {err}");
    }
}

#[test]
fn unet_with_ip_adapter_matches_diffusers() {
    for (name, device) in test_devices() {
        let mut unet = UNet::from_dir(ip_fixture("unet"), &device).unwrap();
        let mut io = Io::open(&device);
        assert!(!unet.has_ip_adapter());
        let plain = io.run(&unet, None).unwrap();
        let err = max_abs_diff(plain.clone(), tensor(&mut io.file, "out_plain", &device));
        println!("{name}: unet without adapter max-abs error {err:.2e}");
        assert!(err <= 1e-4, "{name}: unet without adapter error {err}");

        let projection = unet.load_ip_adapter(ip_fixture("ip_adapter.safetensors")).unwrap();
        assert!(unet.has_ip_adapter());
        // Loading the adapter leaves the model's output without tokens as it was.
        assert_eq!(values(io.run(&unet, None).unwrap()), values(plain.clone()));
        let tokens = projection.forward(io.image_embeds.clone()).unwrap();
        let mut four_tokens = None;
        for (key, scale) in [("out_s1", 1.0), ("out_s06", 0.6)] {
            let out = io.run(&unet, Some(IpTokens { tokens: tokens.clone(), scale })).unwrap();
            let expected: Tensor<4> = tensor(&mut io.file, key, &device);
            let change = max_abs_diff(expected.clone(), plain.clone());
            let err = max_abs_diff(out.clone(), expected);
            println!(
                "{name}: unet with ip scale {scale} max-abs error {err:.2e} (the adapter changes it by {change:.2})"
            );
            assert!(err <= 1e-4, "{name}: unet with ip scale {scale} error {err}");
            assert!(change > 0.1, "{name}: the fixture's adapter should change the output");
            four_tokens.get_or_insert(out);
        }
        let four_tokens = four_tokens.unwrap();

        // The authors' 8 tokens per row (the tokens of two identical images) = 4 tokens.
        let twice = Tensor::cat(vec![tokens.clone(), tokens.clone()], 1);
        let out = io.run(&unet, Some(IpTokens { tokens: twice, scale: 1.0 })).unwrap();
        let err_dup = max_abs_diff(out.clone(), four_tokens.clone());
        let err_ref = max_abs_diff(out, tensor(&mut io.file, "out_dup", &device));
        println!("{name}: 8 duplicated tokens vs 4 tokens {err_dup:.2e}, vs diffusers {err_ref:.2e}");
        assert!(err_dup <= 1e-5 && err_ref <= 1e-4, "{name}: duplicated tokens {err_dup}, reference {err_ref}");

        // Scale 0 is the UNet without tokens.
        let out = io.run(&unet, Some(IpTokens { tokens: tokens.clone(), scale: 0.0 })).unwrap();
        assert_eq!(values(out), values(plain), "{name}: scale 0");

        // `guided` builds the same [zero-embedding rows, embedding rows] batch.
        let embeds = io.image_embeds.clone().slice([2..4, 0..24]);
        let guided = projection.guided(embeds, 0.7).unwrap();
        assert_eq!(guided.scale, 0.7);
        let err = max_abs_diff(guided.tokens, tokens);
        assert!(err <= 1e-6, "{name}: guided tokens {err}");
    }
}

#[test]
fn clip_with_exact_gelu_matches_transformers() {
    for (name, device) in test_devices() {
        let clip = ClipVision::from_dir(ip_fixture("clip_gelu"), &device).unwrap();
        assert_eq!(clip.config().hidden_act, "gelu");
        let mut io = SafetensorsFile::open(ip_fixture("clip_gelu/io.safetensors")).unwrap();
        let embeds = clip.image_embeds(tensor(&mut io, "pixels", &device)).unwrap();
        let expected: Tensor<2> = tensor(&mut io, "embeds", &device);
        let scale = max_abs(expected.clone());
        let err = max_abs_diff(embeds, expected);
        println!("{name}: gelu clip max-abs error {err:.2e} (output max {scale:.2})");
        assert!(err <= 1e-4, "{name}: gelu clip error {err}");
    }
}

#[test]
fn double_rescaling_matches_the_image_processor() {
    let mut io = SafetensorsFile::open(ip_fixture("preprocess.safetensors")).unwrap();
    for case in ["random", "binary"] {
        let (rgb, shape) = io.read_f32(&format!("{case}_rgb")).unwrap();
        let (expected, _) = io.read_f32(&format!("{case}_pixels")).unwrap();
        let ours = clip_preprocess_rescaled_twice(&rgb, shape[1], shape[0], 20).unwrap();
        let err = max_abs_vec(&ours, &expected);
        println!("{case}: rescaled-twice preprocessing max-abs error {err:.2e}");
        assert!(err <= 1e-5, "{case}: preprocessing error {err}");
    }
    // What CLIP sees of a [0, 1] image: ≈ −mean/std per channel, the content within 1/255/std.
    // (An image of exactly 1.0 everywhere would be taken for 8-bit levels, see `binary`.)
    let white = clip_preprocess_rescaled_twice(&[0.999; 4 * 4 * 3], 4, 4, 4).unwrap();
    let black = clip_preprocess_rescaled_twice(&[0.0; 4 * 4 * 3], 4, 4, 4).unwrap();
    assert!(max_abs_vec(&white, &black) <= 1.0 / 255.0 / 0.26);
    let mean_over_std: Vec<f32> = (0..3).map(|c| -CLIP_MEAN[c] / CLIP_STD[c]).collect();
    assert!(max_abs_vec(&[black[0], black[16], black[32]], &mean_over_std) <= 1e-6);
    assert!(clip_preprocess_rescaled_twice(&[1.5; 12], 2, 2, 2).is_err());
    assert!(clip_preprocess_rescaled_twice(&[f32::NAN; 12], 2, 2, 2).is_err());
    assert!(clip_preprocess_rescaled_twice(&[0.5; 11], 2, 2, 2).is_err());
}

/// The fixture adapter's tensors, edited by `edit`, written to `dir/name`.
fn edited_adapter(dir: &Path, name: &str, edit: impl Fn(&mut Vec<(String, Vec<usize>, Vec<f32>)>)) -> PathBuf {
    let mut file = SafetensorsFile::open(ip_fixture("ip_adapter.safetensors")).unwrap();
    let keys: Vec<String> = file.shapes().map(|(k, _)| k.to_string()).collect();
    let mut tensors: Vec<(String, Vec<usize>, Vec<f32>)> = keys
        .into_iter()
        .map(|k| {
            let (v, s) = file.read_f32(&k).unwrap();
            (k, s, v)
        })
        .collect();
    edit(&mut tensors);
    let path = dir.join(name);
    write_tensors(&path, &tensors);
    path
}

/// The error message of `r` (empty when it is Ok).
fn message<T>(r: Result<T, w3d_core::Error>) -> String {
    r.err().map(|e| e.to_string()).unwrap_or_default()
}

#[test]
fn ip_adapter_errors_name_the_problem() {
    let device = w3d_diffusion::default_device();
    let dir = tempfile::tempdir().unwrap();
    let mut unet = UNet::from_dir(ip_fixture("unet"), &device).unwrap();

    let m = message(unet.load_ip_adapter(dir.path().join("absent.safetensors")));
    assert!(m.contains("absent.safetensors"), "{m}");

    let missing =
        edited_adapter(dir.path(), "missing.safetensors", |t| t.retain(|(k, _, _)| k != "ip_adapter.5.to_v_ip.weight"));
    let m = message(unet.load_ip_adapter(&missing));
    assert!(m.contains("missing") && m.contains("ip_adapter.5.to_v_ip.weight"), "{m}");

    let misshaped = edited_adapter(dir.path(), "misshaped.safetensors", |t| {
        let entry = t.iter_mut().find(|(k, _, _)| k == "ip_adapter.7.to_k_ip.weight").unwrap();
        entry.1 = vec![16, 32]; // the mid block's layer is 32 wide
        entry.2.truncate(16 * 32);
    });
    let m = message(unet.load_ip_adapter(&misshaped));
    assert!(m.contains("wrong shape") && m.contains("ip_adapter.7.to_k_ip.weight"), "{m}");

    let unexpected = edited_adapter(dir.path(), "unexpected.safetensors", |t| {
        t.push(("ip_adapter.9.to_k_ip.weight".into(), vec![16, 32], vec![0.0; 16 * 32]));
    });
    let m = message(unet.load_ip_adapter(&unexpected));
    assert!(m.contains("unexpected") && m.contains("ip_adapter.9.to_k_ip.weight"), "{m}");

    let odd_projection = edited_adapter(dir.path(), "projection.safetensors", |t| {
        let entry = t.iter_mut().find(|(k, _, _)| k == "image_proj.proj.weight").unwrap();
        entry.1 = vec![127, 24];
        entry.2.truncate(127 * 24);
    });
    let m = message(unet.load_ip_adapter(&odd_projection));
    assert!(m.contains("image_proj.proj.weight") && m.contains("127"), "{m}");

    // Failed loads leave the UNet as it was; IP tokens need an adapter.
    assert!(!unet.has_ip_adapter());
    let io = Io::open(&device);
    let tokens = Tensor::<3>::zeros([4, 4, 32], &device);
    let m = message(io.run(&unet, Some(IpTokens { tokens: tokens.clone(), scale: 1.0 })));
    assert!(m.contains("IP-Adapter"), "{m}");

    let projection = unet.load_ip_adapter(ip_fixture("ip_adapter.safetensors")).unwrap();
    let m = message(unet.load_ip_adapter(ip_fixture("ip_adapter.safetensors")));
    assert!(m.contains("already"), "{m}");
    for bad in [[3, 4, 32], [4, 4, 31], [4, 0, 32]] {
        let m = message(io.run(&unet, Some(IpTokens { tokens: Tensor::zeros(bad, &device), scale: 1.0 })));
        assert!(m.contains("ip.tokens"), "{bad:?}: {m}");
    }
    let m = message(io.run(&unet, Some(IpTokens { tokens, scale: f32::NAN })));
    assert!(m.contains("ip.scale"), "{m}");
    let m = message(projection.forward(Tensor::zeros([2, 23], &device)));
    assert!(m.contains("image_embeds"), "{m}");
}

/// Writes `tensors` (key, shape, f32 values) as a safetensors file at `path`.
fn write_tensors(path: &Path, tensors: &[(String, Vec<usize>, Vec<f32>)]) {
    let bytes: Vec<(String, Vec<usize>, Vec<u8>)> = tensors
        .iter()
        .map(|(k, s, v)| (k.clone(), s.clone(), v.iter().flat_map(|x| x.to_le_bytes()).collect()))
        .collect();
    let views = bytes.iter().map(|(k, s, b)| {
        (k.clone(), safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), b).unwrap())
    });
    std::fs::write(path, safetensors::tensor::serialize(views, None).unwrap()).unwrap();
}

/// The SD1.5 numbering of `docs/weights.md` on a UNet of SD1.5's block structure (widths
/// 8, 16, 24, 32 for 320, 640, 1280, 1280, so the mid block's layer is told apart): 16
/// cross-attention layers, k = 1, 3 down 0; 5, 7 down 1; 9, 11 down 2; 13–17 up 1; 19–23
/// up 2; 25–29 up 3; 31 mid.
#[test]
fn sd15_block_structure_takes_the_documented_key_numbers() {
    let config = w3d_diffusion::UNetConfig::from_value(serde_json::json!({
        "in_channels": 4, "out_channels": 4, "sample_size": 8,
        "down_block_types": ["CrossAttnDownBlock2D", "CrossAttnDownBlock2D", "CrossAttnDownBlock2D", "DownBlock2D"],
        "up_block_types": ["UpBlock2D", "CrossAttnUpBlock2D", "CrossAttnUpBlock2D", "CrossAttnUpBlock2D"],
        "block_out_channels": [8, 16, 24, 32], "layers_per_block": 2, "norm_num_groups": 4,
        "cross_attention_dim": 12, "attention_head_dim": 2
    }))
    .unwrap();
    let device = w3d_diffusion::default_device();
    let mut unet = UNet::random(&config, 3, &device).unwrap();
    let widths = [8, 8, 16, 16, 24, 24, 24, 24, 24, 16, 16, 16, 8, 8, 8, 32];
    let mut tensors = vec![
        ("image_proj.proj.weight".to_string(), vec![4 * 12, 10], vec![0.01; 4 * 12 * 10]),
        ("image_proj.proj.bias".to_string(), vec![4 * 12], vec![0.1; 4 * 12]),
        ("image_proj.norm.weight".to_string(), vec![12], vec![1.0; 12]),
        ("image_proj.norm.bias".to_string(), vec![12], vec![0.0; 12]),
    ];
    for (i, w) in widths.iter().enumerate() {
        for kv in ["k", "v"] {
            tensors.push((format!("ip_adapter.{}.to_{kv}_ip.weight", 2 * i + 1), vec![*w, 12], vec![0.01; w * 12]));
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sd15_layout.safetensors");
    write_tensors(&path, &tensors);
    let projection = unet.load_ip_adapter(&path).unwrap();
    assert_eq!((projection.tokens(), projection.embed_dim(), projection.cross_dim()), (4, 10, 12));
    let sample = Tensor::<4>::zeros([2, 4, 8, 8], &device);
    let context = Tensor::<3>::zeros([2, 3, 12], &device);
    let ip = projection.guided(Tensor::<2>::ones([1, 10], &device), 1.0).unwrap();
    let out =
        unet.forward_with(sample, &[10.0], context, None, &UNetExtra { ip: Some(ip), ..Default::default() }).unwrap();
    assert_eq!(out.dims(), [2, 4, 8, 8]);
}

/// The ViT-H/14 image encoder's config (`models/image_encoder/config.json` of
/// `h94/IP-Adapter`, as transformers writes a `CLIPVisionConfig`) is read as it is, and a
/// random encoder of its widths (one layer instead of 32) maps a 224² image to a 1024-d
/// embedding.
#[test]
fn vit_h_image_encoder_config_runs() {
    let config = w3d_diffusion::ClipVisionConfig::from_value(serde_json::json!({
        "architectures": ["CLIPVisionModelWithProjection"], "model_type": "clip_vision_model",
        "hidden_act": "gelu", "hidden_size": 1280, "image_size": 224, "intermediate_size": 5120,
        "layer_norm_eps": 1e-05, "num_attention_heads": 16, "num_channels": 3,
        "num_hidden_layers": 32, "patch_size": 14, "projection_dim": 1024
    }))
    .unwrap();
    assert_eq!((config.patches_per_side(), config.hidden_act.as_str()), (16, "gelu"));
    let one_layer = w3d_diffusion::ClipVisionConfig { num_hidden_layers: 1, ..config };
    let device = w3d_diffusion::default_device();
    let clip = ClipVision::random(&one_layer, 1, &device).unwrap();
    let rgb = vec![0.5f32; 300 * 260 * 3];
    let pixels = clip_preprocess_rescaled_twice(&rgb, 300, 260, 224).unwrap();
    let pixels = Tensor::<4>::from_data(w3d_diffusion::TensorData::new(pixels, [1, 3, 224, 224]), &device);
    let embeds = clip.image_embeds(pixels).unwrap();
    assert_eq!(embeds.dims(), [1, 1024]);
    assert!(values(embeds).iter().all(|v| v.is_finite()));
}
