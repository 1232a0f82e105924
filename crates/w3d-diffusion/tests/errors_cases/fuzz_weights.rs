//! Byte-mutation tests of the model loaders: the tiny fixtures' `.safetensors` files and
//! `config.json` files (UNet, VAE, CLIP, scheduler) are damaged with the mutations of
//! w3d-core's loader fuzzing, and every load must return within a time bound without
//! panicking or allocating what a damaged header or config merely claims; an `Ok` file must
//! read back tensors of the sizes its header declares, and an `Ok` config must either build
//! the model from the fixture weights or fail with an error.
//!
//! 64 cases per property by default; `W3D_FUZZ_CASES=5000 cargo test --release -p
//! w3d-diffusion --test errors fuzz_weights::` runs a campaign (`docs/robustness.md`).

use std::path::Path;
use std::time::{Duration, Instant};

use crate::common::fixture;
use crate::mutate::{self, Mutation, apply, mutations};
use proptest::prelude::*;
use w3d_diffusion::{
    ClipVision, ClipVisionConfig, SafetensorsFile, SchedulerConfig, UNet, UNetConfig, Vae, VaeConfig, default_device,
};

fn config() -> ProptestConfig {
    let cases = std::env::var("W3D_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(64);
    ProptestConfig { cases, failure_persistence: None, ..ProptestConfig::default() }
}

/// How long one damaged load (files of at most 815 kB, models of a few thousand
/// parameters) may take.
const TIME_BOUND: Duration = Duration::from_secs(5);

/// Writes `bytes` as `name` in a fresh folder and runs `load` on it within [`TIME_BOUND`].
fn timed<T>(name: &str, bytes: &[u8], load: impl FnOnce(&Path) -> T) -> T {
    mutate::timed(name, bytes, TIME_BOUND, load)
}

fn seed(name: &str) -> Vec<u8> {
    std::fs::read(fixture(name)).unwrap()
}

/// A damaged safetensors file either fails to open, or every tensor reads back with the
/// element count of its declared shape (or fails to read).
fn fuzz_safetensors(name: &str, mutations: &[Mutation]) {
    let bytes = apply(&seed(name), mutations);
    timed("model.safetensors", &bytes, |path| {
        if let Ok(mut file) = SafetensorsFile::open(path) {
            let tensors: Vec<(String, Vec<usize>)> = file.shapes().map(|(k, s)| (k.to_string(), s.to_vec())).collect();
            for (key, shape) in tensors {
                if let Ok((values, read_shape)) = file.read_f32(&key) {
                    assert_eq!(read_shape, shape);
                    assert_eq!(values.len(), shape.iter().product::<usize>());
                }
            }
        }
    });
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn damaged_vae_weights(m in mutations()) {
        fuzz_safetensors("vae/diffusion_pytorch_model.safetensors", &m);
        // The whole model load on damaged weights: an error, or a model.
        let bytes = apply(&seed("vae/diffusion_pytorch_model.safetensors"), &m);
        let config = VaeConfig::from_file(fixture("vae/config.json")).unwrap();
        let _ = timed("vae.safetensors", &bytes, |p| Vae::load(&config, p, &default_device()));
    }

    #[test]
    fn damaged_clip_weights(m in mutations()) {
        fuzz_safetensors("clip/model.safetensors", &m);
    }

    #[test]
    fn damaged_unet_config(m in mutations()) {
        let bytes = apply(&seed("wonder3d_tiny/unet/config.json"), &m);
        let weights = fixture("wonder3d_tiny/unet/diffusion_pytorch_model.safetensors");
        if let Ok(config) = timed("config.json", &bytes, |p| UNetConfig::from_file(p)) {
            let _ = timed("unet", &bytes, |_| UNet::load(&config, &weights, &default_device()));
        }
    }

    #[test]
    fn damaged_vae_config(m in mutations()) {
        let bytes = apply(&seed("vae/config.json"), &m);
        let weights = fixture("vae/diffusion_pytorch_model.safetensors");
        if let Ok(config) = timed("config.json", &bytes, |p| VaeConfig::from_file(p)) {
            let _ = timed("vae", &bytes, |_| Vae::load(&config, &weights, &default_device()));
        }
    }

    #[test]
    fn damaged_clip_config(m in mutations()) {
        let bytes = apply(&seed("clip/config.json"), &m);
        let weights = fixture("clip/model.safetensors");
        if let Ok(config) = timed("config.json", &bytes, |p| ClipVisionConfig::from_file(p)) {
            let _ = timed("clip", &bytes, |_| ClipVision::load(&config, &weights, &default_device()));
        }
    }

    #[test]
    fn damaged_scheduler_config(m in mutations()) {
        let bytes = apply(&seed("wonder3d_tiny/scheduler/scheduler_config.json"), &m);
        let _ = timed("scheduler_config.json", &bytes, |p| SchedulerConfig::from_file(p));
    }
}

/// The hostile-input campaign's case: a CLIP config claiming a 400000-wide model (640 GB of
/// attention weights) against the tiny weights is an error naming the shapes, at once.
#[test]
fn a_config_claiming_a_huge_model_is_refused_without_allocating() {
    let text = std::fs::read_to_string(fixture("clip/config.json")).unwrap();
    let mut value: serde_json::Value = serde_json::from_str(&text).unwrap();
    value["hidden_size"] = 400_000.into();
    let m = ClipVisionConfig::from_value(value.clone()).unwrap_err().to_string();
    assert!(m.contains("hidden_size") && m.contains("8192"), "{m}");
    // Within the bounds but wrong for the weights: every misshaped tensor is named, and
    // nothing of the config's size is allocated (8192² per projection would be 256 MB each).
    value["hidden_size"] = 8192.into();
    value["num_attention_heads"] = 8.into();
    value["intermediate_size"] = 32768.into();
    let config = ClipVisionConfig::from_value(value).unwrap();
    let start = Instant::now();
    let m = ClipVision::load(&config, fixture("clip/model.safetensors"), &default_device()).unwrap_err().to_string();
    assert!(m.contains("expected [8192") || m.contains("expected [32768"), "{m}");
    assert!(start.elapsed() < TIME_BOUND);
}
