//! UniPC (bh2, order 2) against diffusers' `UniPCMultistepScheduler.from_config` of the SD1.5
//! scheduler config (`xtask/python/fixtures_unipc.py`): timesteps identical, σ within one f32
//! ulp, full trajectories of a closed-form stand-in model (ε, v and x₀ prediction;
//! linspace, leading and trailing spacing), and the enhancer's img2img runs (strength 0.2 and
//! 0.1 at 50 steps: `add_noise` at the first timestep, then 10 resp. 5 steps), compared at
//! every step.

use crate::common::{fixture, max_abs, max_abs_diff, tensor, test_devices, values};
use w3d_diffusion::{Device, SafetensorsFile, SchedulerConfig, Tensor, UniPcMultistepScheduler, img2img_begin_index};

fn fixture_file() -> SafetensorsFile {
    SafetensorsFile::open(fixture("unipc.safetensors")).unwrap()
}

/// The authors' config (linspace) or one of the spacing variants of the fixture.
fn config(spacing: &str) -> SchedulerConfig {
    SchedulerConfig { timestep_spacing: spacing.into(), ..UniPcMultistepScheduler::stable_diffusion_config() }
}

fn read_usize(file: &mut SafetensorsFile, key: &str) -> Vec<usize> {
    file.read_f32(key).unwrap().0.iter().map(|&t| t as usize).collect()
}

/// The fixture's stand-in model: `tanh(x / 2)·a + b·t/1000`.
struct StandIn {
    a: Tensor<4>,
    b: Tensor<4>,
}

impl StandIn {
    fn load(file: &mut SafetensorsFile, device: &Device) -> Self {
        Self { a: tensor(file, "model_a", device), b: tensor(file, "model_b", device) }
    }

    fn output(&self, x: Tensor<4>, t: usize) -> Tensor<4> {
        (x / 2.0).tanh() * self.a.clone() + self.b.clone() * (t as f64 / 1000.0)
    }
}

/// Runs `scheduler` from `x` through its run timesteps and returns the worst per-step
/// difference to `expected` (`[steps, ...]`) relative to max(1, max |expected step|), after
/// checking that no step is NaN; panics naming the first step over `tolerance`.
fn run_and_compare(
    scheduler: &mut UniPcMultistepScheduler,
    model: &StandIn,
    mut x: Tensor<4>,
    expected: Tensor<5>,
    tolerance: f32,
    name: &str,
) -> f32 {
    let [n, s0, s1, s2, s3] = expected.dims();
    let timesteps = scheduler.run_timesteps().to_vec();
    assert_eq!(n, timesteps.len(), "{name}: step count");
    let mut worst = 0.0f32;
    for (i, &t) in timesteps.iter().enumerate() {
        x = scheduler.step(model.output(x.clone(), t), t, x).unwrap();
        assert!(values(x.clone()).iter().all(|v| v.is_finite()), "{name}: step {i} (t={t}) is not finite");
        let want = expected.clone().slice([i..i + 1, 0..s0, 0..s1, 0..s2, 0..s3]).reshape([s0, s1, s2, s3]);
        let scale = max_abs(want.clone()).max(1.0);
        let err = max_abs_diff(x.clone(), want) / scale;
        assert!(err <= tolerance, "{name}: first diverging step {i} (t={t}): relative difference {err}");
        worst = worst.max(err);
    }
    worst
}

#[test]
fn unipc_timesteps_and_sigmas_are_diffusers() {
    let mut file = fixture_file();
    for spacing in ["linspace", "leading", "trailing"] {
        for steps in [50, 13] {
            let name = format!("{spacing}{steps}");
            let ours = UniPcMultistepScheduler::new(config(spacing), steps).unwrap();
            assert_eq!(ours.timesteps(), read_usize(&mut file, &format!("timesteps_{name}")).as_slice(), "{name}");
            let (sigmas, _) = file.read_f32(&format!("sigmas_{name}")).unwrap();
            assert_eq!(ours.sigmas().len(), sigmas.len(), "{name}: σ count");
            let worst = ours
                .sigmas()
                .iter()
                .zip(&sigmas)
                .map(|(a, b)| (a - *b as f64).abs() / (*b as f64).abs().max(1e-30))
                .fold(0.0, f64::max);
            println!("σ {name}: max relative difference {worst:.1e}");
            // ᾱ is bit-identical to diffusers'; σ = √((1−ᾱ)/ᾱ) is the correctly rounded f32,
            // and torch's CPU float32 sqrt is not always (t = 779: √21.624224 = 4.65018534…,
            // torch gives 4.6501856, ours 4.6501851): at most one f32 ulp apart.
            assert!(worst <= f64::from(f32::EPSILON), "{name}: σ relative difference {worst}");
            assert_eq!(*ours.sigmas().last().unwrap(), 0.0, "{name}: final σ");
        }
    }
    // The authors' enhancer: 50 linspace steps end 200, 180, …, 20.
    let authors = UniPcMultistepScheduler::new(UniPcMultistepScheduler::stable_diffusion_config(), 50).unwrap();
    assert_eq!(authors.timesteps()[..2], [999, 979]);
    assert_eq!(authors.timesteps()[40..], [200, 180, 160, 140, 120, 100, 80, 60, 40, 20]);
}

#[test]
fn unipc_trajectories_match_diffusers() {
    let mut file = fixture_file();
    for (device_name, device) in test_devices() {
        let model = StandIn::load(&mut file, &device);
        for (name, config, steps) in [
            ("eps_linspace50", config("linspace"), 50),
            ("eps_leading13", config("leading"), 13),
            ("eps_trailing13", config("trailing"), 13),
            ("v_linspace20", SchedulerConfig { prediction_type: "v_prediction".into(), ..config("linspace") }, 20),
            ("sample_linspace20", SchedulerConfig { prediction_type: "sample".into(), ..config("linspace") }, 20),
        ] {
            let mut scheduler = UniPcMultistepScheduler::new(config, steps).unwrap();
            let start: Tensor<4> = tensor(&mut file, &format!("start_{name}"), &device);
            let expected: Tensor<5> = tensor(&mut file, &format!("trajectory_{name}"), &device);
            let name = format!("{device_name} {name}");
            let worst = run_and_compare(&mut scheduler, &model, start, expected, 1e-5, &name);
            println!("{name}: worst relative step difference {worst:.1e}");
        }
    }
}

#[test]
fn unipc_img2img_matches_diffusers() {
    let mut file = fixture_file();
    for (device_name, device) in test_devices() {
        let model = StandIn::load(&mut file, &device);
        let x0: Tensor<4> = tensor(&mut file, "img2img_x0", &device);
        let noise: Tensor<4> = tensor(&mut file, "img2img_noise", &device);
        for (tag, strength, begin, count) in [("s02", 0.2, 40, 10), ("s01", 0.1, 45, 5)] {
            assert_eq!(img2img_begin_index(50, strength).unwrap(), begin, "strength {strength}");
            let mut scheduler =
                UniPcMultistepScheduler::new(UniPcMultistepScheduler::stable_diffusion_config(), 50).unwrap();
            scheduler.set_begin_index(begin).unwrap();
            assert_eq!(scheduler.run_timesteps().len(), count);
            assert_eq!(
                scheduler.run_timesteps(),
                read_usize(&mut file, &format!("img2img_timesteps_{tag}")).as_slice()
            );
            let start = scheduler.add_noise(x0.clone(), noise.clone()).unwrap();
            let expected_start: Tensor<4> = tensor(&mut file, &format!("img2img_start_{tag}"), &device);
            let start_err = max_abs_diff(start.clone(), expected_start);
            assert!(start_err <= 1e-6, "{device_name} {tag}: add_noise difference {start_err}");
            let expected: Tensor<5> = tensor(&mut file, &format!("img2img_trajectory_{tag}"), &device);
            let name = format!("{device_name} img2img {tag}");
            let worst = run_and_compare(&mut scheduler, &model, start, expected, 1e-5, &name);
            println!("{name}: add_noise difference {start_err:.1e}, worst relative step difference {worst:.1e}");
        }
    }
    // add_noise is SDEdit's √ᾱ·x₀ + √(1−ᾱ)·ε at the first timestep run (ᾱ_200 ≈ 0.75369).
    let device = w3d_diffusion::default_device();
    let mut scheduler = UniPcMultistepScheduler::new(UniPcMultistepScheduler::stable_diffusion_config(), 50).unwrap();
    scheduler.set_begin_index(40).unwrap();
    let one = Tensor::<4>::ones([1, 1, 1, 1], &device);
    let signal = values(scheduler.add_noise(one.clone(), one.zeros_like()).unwrap())[0];
    let noise = values(scheduler.add_noise(one.zeros_like(), one).unwrap())[0];
    assert!((signal - 0.75369f32.sqrt()).abs() < 1e-4 && (noise - 0.24631f32.sqrt()).abs() < 1e-4, "{signal} {noise}");
}

#[test]
fn unipc_bad_input_is_refused() {
    let device = w3d_diffusion::default_device();
    for (steps, strength) in [(50, 0.0), (50, -0.1), (50, 1.5), (50, f64::NAN), (10, 0.05), (0, 0.5)] {
        assert!(img2img_begin_index(steps, strength).is_err(), "steps {steps}, strength {strength}");
    }
    assert_eq!(img2img_begin_index(50, 1.0).unwrap(), 0);
    assert_eq!(img2img_begin_index(13, 0.5).unwrap(), 7);
    assert!(UniPcMultistepScheduler::new(config("linspace"), 0).is_err());
    assert!(UniPcMultistepScheduler::new(config("linspace"), 1001).is_err());
    // 1000 leading steps would all be t = 1: the solver divides by their λ differences.
    assert!(UniPcMultistepScheduler::new(config("leading"), 1000).is_err());

    let mut scheduler = UniPcMultistepScheduler::new(config("linspace"), 5).unwrap();
    assert!(scheduler.set_begin_index(5).is_err());
    let x = Tensor::<4>::zeros([1, 2, 2, 2], &device);
    let other = Tensor::<4>::zeros([1, 2, 2, 3], &device);
    assert!(scheduler.add_noise(x.clone(), other.clone()).is_err());
    let wrong = scheduler.timesteps()[1];
    let err = scheduler.step(x.clone(), wrong, x.clone()).unwrap_err().to_string();
    assert!(err.contains("next timestep"), "{err}");
    let first = scheduler.timesteps()[0];
    let err = scheduler.step(other.clone(), first, x.clone()).unwrap_err().to_string();
    assert!(err.contains("model_output"), "{err}");
    scheduler.step(x.clone(), first, x.clone()).unwrap();
    let second = scheduler.timesteps()[1];
    let err = scheduler.step(other.clone(), second, other).unwrap_err().to_string();
    assert!(err.contains("previous steps"), "{err}");
    let rest: Vec<usize> = scheduler.timesteps()[1..].into();
    for t in rest {
        scheduler.step(x.clone(), t, x.clone()).unwrap();
    }
    let err = scheduler.step(x.clone(), 1, x.clone()).unwrap_err().to_string();
    assert!(err.contains("reset"), "{err}");
    scheduler.reset();
    assert!(scheduler.step(x.clone(), first, x).is_ok());
}

/// The last step goes to σ = 0, where λ is infinite: it must return the x₀ prediction, finite,
/// also for a one-step run and for a run that starts at the last timestep.
#[test]
fn unipc_final_step_is_the_x0_prediction() {
    let device = w3d_diffusion::default_device();
    let x = Tensor::<4>::ones([1, 1, 2, 2], &device) * 0.7;
    let eps = Tensor::<4>::ones([1, 1, 2, 2], &device) * -0.3;
    for (steps, begin) in [(1, 0), (5, 4), (50, 0)] {
        let mut scheduler = UniPcMultistepScheduler::new(config("linspace"), steps).unwrap();
        scheduler.set_begin_index(begin).unwrap();
        let mut sample = x.clone();
        let timesteps = scheduler.run_timesteps().to_vec();
        for &t in &timesteps {
            sample = scheduler.step(eps.clone(), t, sample).unwrap();
        }
        let last = *timesteps.last().unwrap();
        let sigma = scheduler.sigmas()[scheduler.timesteps().len() - 1];
        assert!(values(sample.clone()).iter().all(|v| v.is_finite()), "{steps} steps from {begin}: not finite");
        if timesteps.len() == 1 {
            // One step: x₀ = (x − σ_t·ε)/α_t exactly.
            let alpha = 1.0 / (sigma * sigma + 1.0).sqrt();
            let want = (0.7 - sigma * alpha * -0.3) / alpha;
            let got = values(sample)[0] as f64;
            assert!((got - want).abs() < 1e-5, "t={last}: {got} vs {want}");
        }
    }
}

#[test]
fn unipc_is_a_sampler_kind() {
    use w3d_diffusion::SamplerKind;
    let kind: SamplerKind = "unipc".parse().unwrap();
    assert_eq!(kind, SamplerKind::UniPc);
    assert_eq!(kind.to_string(), "unipc");
    let err = "uni-pc".parse::<SamplerKind>().unwrap_err().to_string();
    assert!(err.contains("unipc"), "{err}");
}

/// At 20 linspace steps UniPC lands closer to the converged probability-flow ODE solution
/// (deterministic DDIM with 999 steps) than DDIM at 20 steps, on the fixture's closed-form
/// stand-in model from the same start (as DPM-Solver++(2M) does, `dpm_solver.rs`).
#[test]
fn unipc_twenty_steps_are_closer_to_the_ode_solution_than_ddim() {
    use w3d_diffusion::{DdimScheduler, DpmSolverMultistepScheduler, ddim_sample};
    let device = w3d_diffusion::default_device();
    let mut file = fixture_file();
    let model = StandIn::load(&mut file, &device);
    let start: Tensor<4> = tensor(&mut file, "start_eps_linspace50", &device);
    let f = |x: Tensor<4>, t: usize| -> Result<Tensor<4>, w3d_core::Error> { Ok(model.output(x, t)) };
    let ddim_config = SchedulerConfig { set_alpha_to_one: true, ..config("linspace") };
    let reference = ddim_sample(&DdimScheduler::new(ddim_config.clone(), 999).unwrap(), start.clone(), f).unwrap();
    let ddim = ddim_sample(&DdimScheduler::new(ddim_config, 20).unwrap(), start.clone(), f).unwrap();
    let mut unipc = UniPcMultistepScheduler::new(config("linspace"), 20).unwrap();
    let mut dpm = DpmSolverMultistepScheduler::new(config("linspace"), 20).unwrap();
    let (mut x, mut y) = (start.clone(), start);
    for t in unipc.timesteps().to_vec() {
        x = unipc.step(model.output(x.clone(), t), t, x).unwrap();
        y = dpm.step(model.output(y.clone(), t), t, y).unwrap();
    }
    let ddim_err = max_abs_diff(ddim, reference.clone());
    let (unipc_err, dpm_err) = (max_abs_diff(x, reference.clone()), max_abs_diff(y, reference));
    println!(
        "20 steps, max |x − ODE solution|: DDIM {ddim_err:.2e}, DPM-Solver++(2M) {dpm_err:.2e}, UniPC {unipc_err:.2e}"
    );
    assert!(unipc_err < 0.5 * ddim_err, "UniPC error {unipc_err} vs DDIM {ddim_err} at 20 steps");
}
