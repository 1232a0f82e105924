//! The ControlNet against diffusers' `ControlNetModel` on a tiny SD-layout model (fixtures from
//! `xtask/python/fixtures_controlnet.py`): Wonder3D++'s variant with the cross-domain attention
//! (`controlnet/mv`) and a stock one (`controlnet/stock`, f16 weights, an odd batch), the UNet
//! with their residuals injected, and the errors of bad residuals and batches.

use crate::common::{fixture, max_abs, max_abs_diff, tensor, test_devices, values};
use w3d_diffusion::{ControlNet, ControlNetConfig, ControlResiduals, Device, SafetensorsFile, Tensor, UNet, UNetExtra};

/// The inputs of the fixture: latents, timesteps, context, control image.
struct Inputs {
    latents: Tensor<4>,
    timesteps: Vec<f32>,
    context: Tensor<3>,
    control: Tensor<4>,
}

fn inputs(io: &mut SafetensorsFile, device: &Device) -> Inputs {
    Inputs {
        latents: tensor(io, "latents", device),
        timesteps: values(tensor::<1>(io, "timesteps", device)),
        context: tensor(io, "context", device),
        control: tensor(io, "control", device),
    }
}

/// Largest error of `residuals` against the fixture's `{prefix}down.{i}` and `{prefix}mid`.
fn residual_error(residuals: &ControlResiduals, io: &mut SafetensorsFile, prefix: &str, device: &Device) -> f32 {
    let mut worst = 0.0f32;
    for (i, r) in residuals.down.iter().enumerate() {
        let expected: Tensor<4> = tensor(io, &format!("{prefix}down.{i}"), device);
        let err = max_abs_diff(r.clone(), expected.clone());
        println!("  {prefix}down.{i} {:?}: {err:.2e} (max {:.2})", r.dims(), max_abs(expected));
        worst = worst.max(err);
    }
    let expected: Tensor<4> = tensor(io, &format!("{prefix}mid"), device);
    let err = max_abs_diff(residuals.mid.clone(), expected.clone());
    println!("  {prefix}mid {:?}: {err:.2e} (max {:.2})", residuals.mid.dims(), max_abs(expected));
    worst.max(err)
}

#[test]
fn controlnet_with_cross_domain_attention_matches_diffusers() {
    for (name, device) in test_devices() {
        let controlnet = ControlNet::from_dir(fixture("controlnet/mv"), &device).unwrap();
        assert!(controlnet.has_cross_domain_attention());
        assert_eq!(controlnet.config().control_downscale(), 8);
        let unet = UNet::from_dir(fixture("controlnet/unet"), &device).unwrap();
        let mut io = SafetensorsFile::open(fixture("controlnet/io.safetensors")).unwrap();
        let x = inputs(&mut io, &device);
        let scale = values(tensor::<1>(&mut io, "scale", &device))[0];
        let residuals =
            controlnet.forward(x.latents.clone(), &x.timesteps, x.context.clone(), x.control.clone(), scale).unwrap();
        assert_eq!(residuals.down.len(), 6);
        let err = residual_error(&residuals, &mut io, "", &device);
        println!("{name}: controlnet residuals max-abs error {err:.2e}");
        assert!(err <= 1e-4, "{name}: controlnet residual error {err}");

        let extra = UNetExtra { control: Some(residuals), ..UNetExtra::default() };
        let out = unet.forward_with(x.latents.clone(), &x.timesteps, x.context.clone(), None, &extra).unwrap();
        let expected: Tensor<4> = tensor(&mut io, "unet_out", &device);
        let plain_expected: Tensor<4> = tensor(&mut io, "unet_plain", &device);
        let err = max_abs_diff(out, expected.clone());
        // The residuals must matter: the outputs with and without them differ well beyond the
        // tolerance.
        let effect = max_abs_diff(expected, plain_expected.clone());
        println!("{name}: unet with residuals max-abs error {err:.2e} (their effect {effect:.2})");
        assert!(err <= 1e-4, "{name}: unet with residuals error {err}");
        assert!(effect > 1e-2, "{name}: the residuals change the UNet output by {effect} only");

        let plain = unet.forward(x.latents.clone(), &x.timesteps, x.context.clone(), None).unwrap();
        let default = unet.forward_with(x.latents, &x.timesteps, x.context, None, &UNetExtra::default()).unwrap();
        let err = max_abs_diff(plain.clone(), plain_expected);
        println!("{name}: unet without residuals max-abs error {err:.2e}");
        assert!(err <= 1e-4, "{name}: unet without residuals error {err}");
        assert_eq!(values(plain), values(default), "{name}: forward_with(default) differs from forward");
    }
}

#[test]
fn stock_controlnet_matches_diffusers_on_an_odd_batch() {
    for (name, device) in test_devices() {
        let controlnet = ControlNet::from_dir(fixture("controlnet/stock"), &device).unwrap();
        assert!(!controlnet.has_cross_domain_attention());
        let mut io = SafetensorsFile::open(fixture("controlnet/io.safetensors")).unwrap();
        let x = inputs(&mut io, &device);
        let residuals = controlnet
            .forward(
                x.latents.narrow(0, 0, 3),
                &x.timesteps[..3],
                x.context.narrow(0, 0, 3),
                x.control.narrow(0, 0, 3),
                0.7,
            )
            .unwrap();
        let err = residual_error(&residuals, &mut io, "stock.", &device);
        println!("{name}: stock controlnet residuals max-abs error {err:.2e}");
        assert!(err <= 1e-4, "{name}: stock controlnet residual error {err}");
    }
}

#[test]
fn controlnet_and_injection_refuse_bad_inputs() {
    let device = w3d_diffusion::default_device();
    let controlnet = ControlNet::from_dir(fixture("controlnet/mv"), &device).unwrap();
    let unet = UNet::from_dir(fixture("controlnet/unet"), &device).unwrap();
    let mut io = SafetensorsFile::open(fixture("controlnet/io.safetensors")).unwrap();
    let x = inputs(&mut io, &device);
    let message = |e: w3d_core::Error| e.to_string();

    // An odd batch cannot be split into the two domains' halves.
    let e = controlnet
        .forward(
            x.latents.clone().narrow(0, 0, 3),
            &[500.0],
            x.context.clone().narrow(0, 0, 3),
            x.control.clone().narrow(0, 0, 3),
            1.0,
        )
        .unwrap_err();
    assert!(message(e).contains("even batch"));
    // The control image must be 8× the latent's side.
    let e = controlnet
        .forward(
            x.latents.clone(),
            &x.timesteps,
            x.context.clone(),
            x.control.clone().slice([0..4, 0..3, 0..32, 0..32]),
            1.0,
        )
        .unwrap_err();
    assert!(message(e).contains("control"));
    let e = controlnet
        .forward(x.latents.clone(), &x.timesteps, x.context.clone(), x.control.clone().slice([0..4, 0..1]), 1.0)
        .unwrap_err();
    assert!(message(e).contains("control"));
    let e = controlnet
        .forward(x.latents.clone(), &x.timesteps, x.context.clone(), x.control.clone(), f32::NAN)
        .unwrap_err();
    assert!(message(e).contains("scale"));

    let residuals =
        controlnet.forward(x.latents.clone(), &x.timesteps, x.context.clone(), x.control.clone(), 1.0).unwrap();
    let run = |control: ControlResiduals| {
        let extra = UNetExtra { control: Some(control), ..UNetExtra::default() };
        unet.forward_with(x.latents.clone(), &x.timesteps, x.context.clone(), None, &extra)
    };
    // One residual too few.
    let mut fewer = residuals.clone();
    fewer.down.pop();
    assert!(message(run(fewer).unwrap_err()).contains("6 residuals"));
    // A residual of the wrong level's shape.
    let mut swapped = residuals.clone();
    swapped.down.swap(2, 3);
    assert!(message(run(swapped).unwrap_err()).contains("control.down[2]"));
    // A mid residual of the wrong shape.
    let mut mid = residuals.clone();
    mid.mid = residuals.down[0].clone();
    assert!(message(run(mid).unwrap_err()).contains("control.mid"));
    // Residuals of another batch size.
    let half = ControlResiduals {
        down: residuals.down.iter().map(|r| r.clone().narrow(0, 0, 2)).collect(),
        mid: residuals.mid.clone().narrow(0, 0, 2),
    };
    assert!(message(run(half).unwrap_err()).contains("control.down[0]"));
    assert!(run(residuals).is_ok());
}

#[test]
fn controlnet_config_and_random_initialisation() {
    let device = w3d_diffusion::default_device();
    let config = ControlNetConfig::from_file(fixture("controlnet/mv/config.json")).unwrap();
    assert_eq!(config.conditioning_embedding_out_channels, [4, 8, 8, 16]);
    assert_eq!(config.unet.block_out_channels, [8, 16]);
    assert_eq!(config.unet.up_block_types, ["UpBlock2D", "CrossAttnUpBlock2D"]);
    assert_eq!(config.unet.heads(0).unwrap(), 2);

    // Unsupported values are refused by name.
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixture("controlnet/mv/config.json")).unwrap()).unwrap();
    for (field, value) in [
        ("global_pool_conditions", serde_json::json!(true)),
        ("controlnet_conditioning_channel_order", serde_json::json!("bgra")),
        ("class_embed_type", serde_json::json!("projection")),
        ("conditioning_embedding_out_channels", serde_json::json!([])),
        ("_class_name", serde_json::json!("UNet2DConditionModel")),
    ] {
        let mut bad = json.clone();
        bad[field] = value;
        let e = ControlNetConfig::from_value(bad).unwrap_err().to_string();
        assert!(e.contains(field), "{field}: {e}");
    }

    // A fresh ControlNet (zero convolutions at zero) has the loaded one's parameter names and
    // gives zero residuals of the right shapes.
    let fresh = ControlNet::random(&config, true, 3, &device).unwrap();
    let loaded = ControlNet::from_dir(fixture("controlnet/mv"), &device).unwrap();
    let keys = |m: &ControlNet| {
        let mut k: Vec<String> = m.named_parameters().iter().map(|p| p.key.clone()).collect();
        k.sort();
        k
    };
    assert_eq!(keys(&fresh), keys(&loaded));
    // 3 transformer blocks × 7 tensors (q, k, v, out weight and bias, norm weight and bias).
    assert_eq!(keys(&fresh).iter().filter(|k| k.contains("joint_mid.")).count(), 3 * 7);
    let mut io = SafetensorsFile::open(fixture("controlnet/io.safetensors")).unwrap();
    let x = inputs(&mut io, &device);
    let residuals = fresh.forward(x.latents, &x.timesteps, x.context, x.control, 1.0).unwrap();
    let shapes: Vec<[usize; 4]> = residuals.down.iter().map(|r| r.dims()).collect();
    assert_eq!(shapes, [[4, 8, 8, 8], [4, 8, 8, 8], [4, 8, 8, 8], [4, 8, 4, 4], [4, 16, 4, 4], [4, 16, 4, 4]]);
    assert_eq!(residuals.mid.dims(), [4, 16, 4, 4]);
    assert!(residuals.down.into_iter().chain([residuals.mid]).all(|r| max_abs(r) == 0.0));
}
