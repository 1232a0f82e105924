//! DDIM and DDIM inversion against diffusers: timesteps identical, ᾱ schedules, single steps
//! (eta, v-prediction, clipping), a 10-step guided sampling trajectory and a 10-step inversion
//! with the tiny UNet, and a 50-step inversion round trip. DPM-Solver++(2M) and UniPC are in
//! `scheduler_cases/`.

mod common;
// The dpm_solver and unipc tests share this test binary (one link instead of three).
#[path = "scheduler_cases/dpm_solver.rs"]
mod dpm_solver;
#[path = "scheduler_cases/unipc.rs"]
mod unipc;

use common::{fixture, max_abs_diff, tensor, test_devices, values};
use w3d_diffusion::{
    DdimInverseScheduler, DdimScheduler, Device, SafetensorsFile, SchedulerConfig, Tensor, UNet,
    classifier_free_guidance, ddim_invert, ddim_sample, gaussian_noise,
};

fn scheduler_file() -> SafetensorsFile {
    SafetensorsFile::open(fixture("scheduler.safetensors")).unwrap()
}

fn config(spacing: &str, offset: usize) -> SchedulerConfig {
    SchedulerConfig { timestep_spacing: spacing.into(), steps_offset: offset, ..SchedulerConfig::stable_diffusion() }
}

#[test]
fn timesteps_are_identical_to_diffusers() {
    let mut file = scheduler_file();
    for (name, spacing, offset, steps) in [
        ("leading50", "leading", 1, 50),
        ("leading10", "leading", 1, 10),
        ("trailing7", "trailing", 0, 7),
        ("linspace13", "linspace", 0, 13),
    ] {
        let expected: Vec<usize> =
            file.read_f32(&format!("timesteps_{name}")).unwrap().0.iter().map(|&t| t as usize).collect();
        let ours = DdimScheduler::new(config(spacing, offset), steps).unwrap();
        assert_eq!(ours.timesteps(), expected.as_slice(), "{name}");
        if spacing != "linspace" {
            let expected: Vec<usize> =
                file.read_f32(&format!("inverse_timesteps_{name}")).unwrap().0.iter().map(|&t| t as usize).collect();
            let ours = DdimInverseScheduler::new(config(spacing, offset), steps).unwrap();
            assert_eq!(ours.timesteps(), expected.as_slice(), "inverse {name}");
        }
    }
}

#[test]
fn beta_schedules_match_diffusers() {
    let mut file = scheduler_file();
    let sd = DdimScheduler::new(SchedulerConfig::stable_diffusion(), 10).unwrap();
    let cosine = SchedulerConfig { beta_schedule: "squaredcos_cap_v2".into(), ..SchedulerConfig::default() };
    let cosine = DdimScheduler::new(cosine, 10).unwrap();
    for (name, ours) in [("scaled_linear", sd.alphas_cumprod()), ("cosine", cosine.alphas_cumprod())] {
        let (expected, _) = file.read_f32(&format!("alphas_cumprod_{name}")).unwrap();
        // Bit for bit: the schedule emulates torch's float32 linspace and cumprod.
        let err = ours.iter().zip(&expected).map(|(a, b)| (a - *b as f64).abs()).fold(0.0, f64::max);
        assert_eq!(err, 0.0, "{name}");
    }
}

#[test]
fn single_steps_match_diffusers() {
    let device = w3d_diffusion::default_device();
    let mut file = scheduler_file();
    let sample: Tensor<3> = tensor(&mut file, "step_sample", &device);
    let output: Tensor<3> = tensor(&mut file, "step_model_output", &device);
    let noise: Tensor<3> = tensor(&mut file, "step_noise", &device);
    let base = SchedulerConfig::stable_diffusion();
    let cases = [
        ("eps_eta1", base.clone(), 1.0),
        ("v_eta05", SchedulerConfig { prediction_type: "v_prediction".into(), ..base.clone() }, 0.5),
        (
            "sample_clip",
            SchedulerConfig {
                prediction_type: "sample".into(),
                clip_sample: true,
                set_alpha_to_one: true,
                ..base.clone()
            },
            0.0,
        ),
        (
            "linear_eps",
            SchedulerConfig { beta_schedule: "linear".into(), beta_start: 0.0001, beta_end: 0.02, ..base.clone() },
            0.0,
        ),
    ];
    for (name, config, eta) in cases {
        let scheduler = DdimScheduler::new(config, 20).unwrap();
        let ts = scheduler.timesteps();
        for t in [ts[0], ts[ts.len() - 1]] {
            let ours = scheduler.step(output.clone(), t, sample.clone(), eta, Some(noise.clone())).unwrap();
            let expected: Tensor<3> = tensor(&mut file, &format!("step_{name}_t{t}"), &device);
            let err = max_abs_diff(ours, expected);
            assert!(err <= 1e-5, "{name} t={t}: {err}");
        }
    }
    let scheduler = DdimScheduler::new(base, 20).unwrap();
    assert!(scheduler.step(output.clone(), 951, sample.clone(), 1.0, None).is_err(), "eta > 0 needs noise");
    assert!(scheduler.step(output, 1000, sample, 0.0, None).is_err(), "timestep out of range");
}

/// Model input for the tiny UNet: latent + condition latent, Wonder3D's CFG batch
/// `[uncond (zero context, zero latent), cond]`.
struct Guided {
    unet: UNet,
    cond_latent: Tensor<4>,
    context: Tensor<3>,
    labels: Tensor<2>,
}

impl Guided {
    fn load(device: &Device) -> Self {
        let mut file = scheduler_file();
        Self {
            unet: UNet::from_dir(fixture("unet"), device).unwrap(),
            cond_latent: tensor(&mut file, "cond_latent", device),
            context: tensor(&mut file, "context", device),
            labels: tensor(&mut file, "class_labels", device),
        }
    }

    fn eps_guided(&self, latent: Tensor<4>, t: usize, scale: f64) -> Tensor<4> {
        let input = Tensor::cat(
            vec![
                Tensor::cat(vec![latent.clone(), self.cond_latent.zeros_like()], 1),
                Tensor::cat(vec![latent, self.cond_latent.clone()], 1),
            ],
            0,
        );
        let context = Tensor::cat(vec![self.context.zeros_like(), self.context.clone()], 0);
        let labels = Tensor::cat(vec![self.labels.clone(), self.labels.clone()], 0);
        let eps = self.unet.forward(input, &[t as f32], context, Some(labels)).unwrap();
        let [_, c, h, w] = eps.dims();
        let uncond = eps.clone().slice([0..1, 0..c, 0..h, 0..w]);
        let cond = eps.slice([1..2, 0..c, 0..h, 0..w]);
        classifier_free_guidance(uncond, cond, scale)
    }

    fn eps(&self, latent: Tensor<4>, t: usize) -> Tensor<4> {
        let input = Tensor::cat(vec![latent, self.cond_latent.clone()], 1);
        self.unet.forward(input, &[t as f32], self.context.clone(), Some(self.labels.clone())).unwrap()
    }
}

#[test]
fn guided_sampling_trajectory_matches_diffusers() {
    for (name, device) in test_devices() {
        let model = Guided::load(&device);
        let mut file = scheduler_file();
        let expected: Tensor<5> = tensor(&mut file, "cfg_trajectory", &device);
        let mut latent: Tensor<4> = tensor(&mut file, "cfg_start", &device);
        let scheduler = DdimScheduler::new(SchedulerConfig::stable_diffusion(), 10).unwrap();
        for (i, &t) in scheduler.timesteps().iter().enumerate() {
            let eps = model.eps_guided(latent.clone(), t, 2.0);
            latent = scheduler.step(eps, t, latent, 0.0, None).unwrap();
            let step = expected.clone().slice([i..i + 1, 0..1, 0..4, 0..16, 0..16]).reshape([1, 4, 16, 16]);
            let err = max_abs_diff(latent.clone(), step);
            assert!(err <= 1e-4, "{name}: step {i} (t={t}): {err}");
        }
    }
}

#[test]
fn inversion_trajectory_matches_diffusers() {
    for (name, device) in test_devices() {
        let model = Guided::load(&device);
        let mut file = scheduler_file();
        let expected: Tensor<5> = tensor(&mut file, "inversion_trajectory", &device);
        let mut latent: Tensor<4> = tensor(&mut file, "inversion_start", &device);
        let inverse = DdimInverseScheduler::new(SchedulerConfig::stable_diffusion(), 10).unwrap();
        for (i, &t) in inverse.timesteps().iter().enumerate() {
            let eps = model.eps(latent.clone(), t);
            latent = inverse.step(eps, t, latent).unwrap();
            let step = expected.clone().slice([i..i + 1, 0..1, 0..4, 0..16, 0..16]).reshape([1, 4, 16, 16]);
            let err = max_abs_diff(latent.clone(), step);
            assert!(err <= 1e-4, "{name}: step {i} (t={t}): {err}");
        }
    }
}

#[test]
fn fifty_step_inversion_round_trip() {
    let device = w3d_diffusion::default_device();
    let model = Guided::load(&device);
    // A clean latent of the size and scale of an SD latent (std ~1).
    let start = gaussian_noise([1, 4, 16, 16], 11, &device);
    // Inversion and sampling must use the same ᾱ before the first step.
    let config = SchedulerConfig { set_alpha_to_one: false, ..SchedulerConfig::stable_diffusion() };
    let inverse = DdimInverseScheduler::new(config.clone(), 50).unwrap();
    let sampler = DdimScheduler::new(config, 50).unwrap();
    let norm = |v: &[f32]| v.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
    let round_trip = |refinements: usize| {
        let noise = ddim_invert(&inverse, start.clone(), refinements, |x, t| Ok(model.eps(x, t))).unwrap();
        let back = ddim_sample(&sampler, noise, |x, t| Ok(model.eps(x, t))).unwrap();
        norm(&values(back - start.clone())) / norm(&values(start.clone()))
    };
    // diffusers' one-shot inversion drifts (the model is evaluated one step early); two
    // fixed-point refinements per step make it the exact inverse of DDIM sampling.
    let (plain, refined) = (round_trip(0), round_trip(2));
    println!("50-step inversion round trip: relative error {plain:.2e} one-shot, {refined:.2e} refined");
    assert!(refined <= 1e-3, "relative error {refined}");
    assert!(refined < plain / 10.0, "refinement must help: {refined} vs {plain}");
}

#[test]
fn gaussian_noise_is_seeded_and_standard() {
    let device = w3d_diffusion::default_device();
    let a = values(gaussian_noise([4, 64, 64], 3, &device));
    let b = values(gaussian_noise([4, 64, 64], 3, &device));
    let c = values(gaussian_noise([4, 64, 64], 4, &device));
    assert_eq!(a, b);
    assert_ne!(a, c);
    let n = a.len() as f64;
    let mean = a.iter().map(|&v| v as f64).sum::<f64>() / n;
    let var = a.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / n;
    assert!(mean.abs() < 0.02 && (var - 1.0).abs() < 0.03, "mean {mean}, var {var}");
}

#[test]
fn bad_scheduler_settings_are_rejected() {
    assert!(DdimScheduler::new(SchedulerConfig::stable_diffusion(), 0).is_err());
    assert!(DdimScheduler::new(SchedulerConfig::stable_diffusion(), 1001).is_err());
    let bad = SchedulerConfig { prediction_type: "flow".into(), ..SchedulerConfig::default() };
    assert!(DdimScheduler::new(bad, 10).is_err());
    assert!(DdimInverseScheduler::new(config("linspace", 0), 10).is_err());
    let path = std::env::temp_dir().join(format!("w3d-diffusion-scheduler-{}.json", std::process::id()));
    std::fs::write(&path, r#"{"beta_schedule": "sigmoid", "num_train_timesteps": 1000}"#).unwrap();
    let message = SchedulerConfig::from_file(&path).unwrap_err().to_string();
    std::fs::remove_file(&path).unwrap();
    assert!(message.contains("beta_schedule") && message.contains("sigmoid") && message.contains(".json"), "{message}");
}
