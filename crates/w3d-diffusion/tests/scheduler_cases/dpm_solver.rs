//! DPM-Solver++(2M) against diffusers' `DPMSolverMultistepScheduler` (built from a DDIM config):
//! timesteps identical, σ within f32 rounding, and 10- and 20-step trajectories of a
//! closed-form stand-in model (ε or v prediction) within 1e-4, on every test backend.

use crate::common::{fixture, max_abs_diff, tensor, test_devices};
use w3d_diffusion::{DpmSolverMultistepScheduler, SafetensorsFile, SchedulerConfig, Tensor};

fn fixture_file() -> SafetensorsFile {
    SafetensorsFile::open(fixture("dpm_solver.safetensors")).unwrap()
}

fn config(spacing: &str, offset: usize) -> SchedulerConfig {
    SchedulerConfig { timestep_spacing: spacing.into(), steps_offset: offset, ..SchedulerConfig::stable_diffusion() }
}

#[test]
fn timesteps_and_sigmas_are_diffusers() {
    let mut file = fixture_file();
    for (name, spacing, offset, steps) in [
        ("leading20", "leading", 1, 20),
        ("leading50", "leading", 1, 50),
        ("leading1", "leading", 1, 1),
        ("trailing7", "trailing", 0, 7),
        ("linspace13", "linspace", 0, 13),
    ] {
        let ours = DpmSolverMultistepScheduler::new(config(spacing, offset), steps).unwrap();
        let expected: Vec<usize> =
            file.read_f32(&format!("timesteps_{name}")).unwrap().0.iter().map(|&t| t as usize).collect();
        assert_eq!(ours.timesteps(), expected.as_slice(), "{name}");
        let (sigmas, _) = file.read_f32(&format!("sigmas_{name}")).unwrap();
        assert_eq!(ours.sigmas().len(), sigmas.len(), "{name}: σ count");
        for (i, (a, b)) in ours.sigmas().iter().zip(&sigmas).enumerate() {
            assert!((a - *b as f64).abs() <= 1e-6 * b.abs().max(1.0) as f64, "{name} σ[{i}]: {a} vs {b}");
        }
    }
}

#[test]
fn trajectories_match_diffusers() {
    let mut file = fixture_file();
    for (device_name, device) in test_devices() {
        let a: Tensor<4> = tensor(&mut file, "model_a", &device);
        let b: Tensor<4> = tensor(&mut file, "model_b", &device);
        for (name, config, steps) in [
            ("eps_leading10", config("leading", 1), 10),
            ("eps_linspace10", config("linspace", 0), 10),
            ("v_leading10", SchedulerConfig { prediction_type: "v_prediction".into(), ..config("leading", 1) }, 10),
            ("eps_trailing20", config("trailing", 0), 20),
        ] {
            let mut scheduler = DpmSolverMultistepScheduler::new(config, steps).unwrap();
            let mut x: Tensor<4> = tensor(&mut file, &format!("start_{name}"), &device);
            let expected: Tensor<5> = tensor(&mut file, &format!("trajectory_{name}"), &device);
            let [n, s0, s1, s2, s3] = expected.dims();
            assert_eq!(n, steps);
            let timesteps = scheduler.timesteps().to_vec();
            let mut worst = 0.0f32;
            for (i, &t) in timesteps.iter().enumerate() {
                let output = (x.clone() / 2.0).tanh() * a.clone() + b.clone() * (t as f64 / 1000.0);
                x = scheduler.step(output, t, x).unwrap();
                let want = expected.clone().slice([i..i + 1, 0..s0, 0..s1, 0..s2, 0..s3]).reshape([s0, s1, s2, s3]);
                worst = worst.max(max_abs_diff(x.clone(), want));
            }
            assert!(worst <= 1e-4, "{device_name} {name}: worst step difference {worst}");
        }
    }
}

#[test]
fn steps_out_of_order_are_refused() {
    let device = w3d_diffusion::default_device();
    let mut scheduler = DpmSolverMultistepScheduler::new(SchedulerConfig::stable_diffusion(), 3).unwrap();
    let x = Tensor::<4>::zeros([1, 1, 2, 2], &device);
    let wrong = scheduler.timesteps()[1];
    let err = scheduler.step(x.clone(), wrong, x.clone()).unwrap_err().to_string();
    assert!(err.contains("next timestep"), "{err}");
    for t in scheduler.timesteps().to_vec() {
        scheduler.step(x.clone(), t, x.clone()).unwrap();
    }
    let err = scheduler.step(x.clone(), 1, x.clone()).unwrap_err().to_string();
    assert!(err.contains("reset"), "{err}");
    scheduler.reset();
    let first = scheduler.timesteps()[0];
    assert!(scheduler.step(x.clone(), first, x).is_ok());
}

/// Why the solver exists: at 20 steps it lands closer to the converged probability-flow ODE
/// solution (deterministic DDIM with 999 steps) than DDIM at 20 steps, on the closed-form
/// stand-in model of the fixture, from the same start and the same schedule (linspace spacing,
/// both ending at σ = 0).
#[test]
fn twenty_steps_are_closer_to_the_ode_solution_than_ddim() {
    use w3d_diffusion::{DdimScheduler, ddim_sample};
    let device = w3d_diffusion::default_device();
    let mut file = fixture_file();
    let a: Tensor<4> = tensor(&mut file, "model_a", &device);
    let b: Tensor<4> = tensor(&mut file, "model_b", &device);
    let start: Tensor<4> = tensor(&mut file, "start_eps_linspace10", &device);
    let model = |x: Tensor<4>, t: usize| -> Result<Tensor<4>, w3d_core::Error> {
        Ok((x / 2.0).tanh() * a.clone() + b.clone() * (t as f64 / 1000.0))
    };
    let ddim_config = SchedulerConfig { set_alpha_to_one: true, ..config("linspace", 0) };
    let reference = ddim_sample(&DdimScheduler::new(ddim_config.clone(), 999).unwrap(), start.clone(), model).unwrap();
    let ddim = ddim_sample(&DdimScheduler::new(ddim_config, 20).unwrap(), start.clone(), model).unwrap();
    let mut dpm = DpmSolverMultistepScheduler::new(config("linspace", 0), 20).unwrap();
    let mut x = start;
    for t in dpm.timesteps().to_vec() {
        x = dpm.step(model(x.clone(), t).unwrap(), t, x).unwrap();
    }
    let (ddim_err, dpm_err) = (max_abs_diff(ddim, reference.clone()), max_abs_diff(x, reference));
    assert!(dpm_err < 0.5 * ddim_err, "DPM-Solver++(2M) error {dpm_err} vs DDIM {ddim_err} at 20 steps");
}
