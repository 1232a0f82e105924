//! Generation on a device, timed phase by phase with the device memory it holds: the GPU
//! benchmark of `cargo xtask bench gpu` (feature `wgpu`; `docs/gpu.md`).
//!
//! ```text
//! cargo bench -p w3d-diffusion --features wgpu --bench gpu -- [--model tiny|small|real|DIR]
//!     [--device wgpu|cpu] [--runs ddim:50,dpmpp-2m:20] [--json FILE]
//! ```
//!
//! `real` is the real-size Wonder3D++ model (`configs/wonder3d`: the 910.8 M-parameter
//! multi-view UNet, the SD VAE, CLIP ViT-L/14) with random weights, since the published
//! weights are not needed to measure speed; `tiny` the parity-test checkpoint and `small` the
//! shipped small model. Phases: building or loading the models, conditioning (CLIP + VAE
//! encode), the first guided step (on a GPU it includes compiling the kernels), one warm
//! guided step (24 UNet images at the model's latent size), then each full generation of
//! `--runs` (sampling + decoding of the 12 views). Device memory is what Burn's allocator has
//! reserved (`Device::memory_pool_usage`), sampled after every step: its largest value is the
//! peak of the reservations, which is what the device must hold. Prints a table and writes
//! the measurements as JSON.

#![allow(missing_docs)]

use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::module::Module;

use w3d_diffusion::{
    ClipVision, ClipVisionConfig, ComputeDevice, Device, MultiViewPipeline, SampleOptions, SamplerKind,
    SchedulerConfig, UNet, UNetConfig, Vae, VaeConfig, gaussian_noise,
};

struct Args {
    model: String,
    device: ComputeDevice,
    runs: Vec<(SamplerKind, usize)>,
    json: Option<PathBuf>,
}

fn parse_args() -> Result<Args, String> {
    let mut args = Args {
        model: "real".into(),
        device: ComputeDevice::Wgpu,
        runs: vec![(SamplerKind::Ddim, 50), (SamplerKind::DpmSolverPlusPlus2M, 20)],
        json: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        let mut value = |name: &str| it.next().ok_or(format!("{name} needs a value"));
        match a.as_str() {
            "--bench" => {} // added by `cargo bench`
            "--model" => args.model = value("--model")?,
            "--device" => args.device = ComputeDevice::from_name(&value("--device")?).map_err(|e| e.to_string())?,
            "--json" => args.json = Some(PathBuf::from(value("--json")?)),
            "--runs" => {
                args.runs = value("--runs")?
                    .split(',')
                    .filter(|r| !r.is_empty())
                    .map(|run| {
                        let (sampler, steps) =
                            run.split_once(':').ok_or(format!("--runs: SAMPLER:STEPS, got {run:?}"))?;
                        let sampler = match sampler {
                            "ddim" => SamplerKind::Ddim,
                            "dpmpp-2m" => SamplerKind::DpmSolverPlusPlus2M,
                            "unipc" => SamplerKind::UniPc,
                            other => return Err(format!("--runs: sampler ddim, dpmpp-2m or unipc, got {other:?}")),
                        };
                        let steps: usize = steps.parse().map_err(|_| format!("--runs: steps, got {steps:?}"))?;
                        if !(1..=1000).contains(&steps) {
                            return Err(format!("--runs: steps in 1..=1000, got {steps}"));
                        }
                        Ok((sampler, steps))
                    })
                    .collect::<Result<_, _>>()?;
            }
            other => return Err(format!("unknown argument {other:?} (see the header of benches/gpu.rs)")),
        }
    }
    Ok(args)
}

fn crate_dir() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The pipeline of `--model`, and how it was made.
fn build(model: &str, device: &Device) -> Result<(MultiViewPipeline, String), String> {
    let e = |e: w3d_core::Error| e.to_string();
    Ok(match model {
        "real" => {
            let config = |p: &str| crate_dir().join("configs/wonder3d").join(p);
            let unet = UNet::random(&UNetConfig::from_file(config("unet_mv/config.json")).map_err(e)?, 1, device)
                .map_err(e)?;
            let vae =
                Vae::random(&VaeConfig::from_file(config("vae/config.json")).map_err(e)?, 2, device).map_err(e)?;
            let clip = ClipVision::random(
                &ClipVisionConfig::from_file(config("image_encoder/config.json")).map_err(e)?,
                3,
                device,
            )
            .map_err(e)?;
            let scheduler = SchedulerConfig::from_file(config("scheduler/scheduler_config.json")).map_err(e)?;
            (MultiViewPipeline::new(unet, vae, clip, scheduler).map_err(e)?, "real size, random weights".into())
        }
        "tiny" => (
            MultiViewPipeline::from_dir(crate_dir().join("tests/fixtures/wonder3d_tiny"), device).map_err(e)?,
            "tiny test checkpoint".into(),
        ),
        "small" => (
            MultiViewPipeline::from_dir(crate_dir().join("../../assets/model-small"), device).map_err(e)?,
            "shipped small model".into(),
        ),
        dir => (MultiViewPipeline::from_dir(dir, device).map_err(e)?, format!("checkpoint {dir}")),
    })
}

/// Bytes Burn's allocator holds on `device` (`None` where the backend does not report it).
fn reserved(device: &Device) -> Option<u64> {
    device.memory_pool_usage().map(|u| u.bytes_reserved)
}

struct Phase {
    name: String,
    seconds: f64,
    reserved_peak: Option<u64>,
}

/// Records a phase, and names it on stderr at once, so a run stopped part-way still says what
/// it measured.
fn push(phases: &mut Vec<Phase>, phase: Phase) {
    eprintln!("{}: {:.2} s", phase.name, phase.seconds);
    phases.push(phase);
}

fn main() {
    if let Err(e) = run() {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), String> {
    let args = parse_args()?;
    let opened = args.device.open().map_err(|e| e.to_string())?;
    let device = opened.device.clone();
    eprintln!("device: {}", opened.description);
    let sync = |d: &Device| d.sync().map_err(|e| format!("device sync: {e:?}"));
    let mut phases: Vec<Phase> = Vec::new();
    // The largest reservation seen so far (`None` on a backend that reports none).
    let mut peak: Option<u64> = None;
    let note = |peak: &mut Option<u64>| *peak = (*peak).max(reserved(&device));

    let t = Instant::now();
    let (pipeline, what) = build(&args.model, &device)?;
    sync(&device)?;
    note(&mut peak);
    let unet_params = pipeline.unet().num_params();
    push(
        &mut phases,
        Phase { name: "build / load models".into(), seconds: t.elapsed().as_secs_f64(), reserved_peak: peak },
    );
    let [_, c, h, w] = pipeline.noise_shape();
    eprintln!(
        "model: {what}, MV UNet {:.1} M parameters, latents 12 x {c} x {h} x {w}, views {}²",
        unet_params as f64 / 1e6,
        pipeline.image_size()
    );

    // Conditioning from a synthetic object image (random weights do not care what it shows).
    let side = pipeline.image_size() as u32;
    let image = w3d_core::Image::new(side, side, 3, (0..side * side * 3).map(|i| (i % 7) as f32 / 7.0).collect())
        .map_err(|e| e.to_string())?;
    let t = Instant::now();
    let cond = pipeline.condition(&image, &device).map_err(|e| e.to_string())?;
    sync(&device)?;
    note(&mut peak);
    push(
        &mut phases,
        Phase { name: "condition (CLIP + VAE encode)".into(), seconds: t.elapsed().as_secs_f64(), reserved_peak: peak },
    );

    let one_step = SampleOptions { steps: 1, ..SampleOptions::default() };
    for name in ["first guided step (kernel compilation included)", "one guided step (24 UNet images)"] {
        let noise = pipeline.initial_noise(7, &device);
        let t = Instant::now();
        let x =
            pipeline.sample_from(noise, &cond, &one_step, &mut |_, _| note(&mut peak)).map_err(|e| e.to_string())?;
        let _ = x.into_data();
        note(&mut peak);
        push(&mut phases, Phase { name: name.into(), seconds: t.elapsed().as_secs_f64(), reserved_peak: peak });
    }

    for &(sampler, steps) in &args.runs {
        let options = SampleOptions { sampler, steps, ..SampleOptions::default() };
        let label = match sampler {
            SamplerKind::Ddim => "DDIM",
            SamplerKind::DpmSolverPlusPlus2M => "DPM-Solver++(2M)",
            SamplerKind::UniPc => "UniPC",
        };
        let noise = gaussian_noise([6, c, h, w], 11, &device);
        let t = Instant::now();
        let latents =
            pipeline.sample_from(noise, &cond, &options, &mut |_, _| note(&mut peak)).map_err(|e| e.to_string())?;
        let views = pipeline.decode(latents, options.camera).map_err(|e| e.to_string())?;
        note(&mut peak);
        let seconds = t.elapsed().as_secs_f64();
        let finite = views.normals.iter().chain(&views.colours).all(|i| i.data().iter().all(|v| v.is_finite()));
        if !finite {
            return Err(format!("{label} {steps} steps produced non-finite views"));
        }
        push(
            &mut phases,
            Phase {
                name: format!("generation: {steps} {label} steps + decode of 12 views"),
                seconds,
                reserved_peak: peak,
            },
        );
    }

    let gib = |b: u64| b as f64 / (1u64 << 30) as f64;
    println!("\n{} — {what} ({:.1} M-parameter MV UNet)\n", opened.description, unet_params as f64 / 1e6);
    println!("| phase | time (s) | device memory reserved, peak so far (GiB) |\n|---|---|---|");
    for p in &phases {
        let mem = p.reserved_peak.map_or("n/a".to_string(), |b| format!("{:.2}", gib(b)));
        println!("| {} | {:.2} | {mem} |", p.name, p.seconds);
    }
    if let Some(path) = &args.json {
        let report = serde_json::json!({
            "device": opened.description,
            "software_adapter": opened.software,
            "model": what,
            "unet_parameters": unet_params,
            "phases": phases.iter().map(|p| serde_json::json!({
                "phase": p.name, "seconds": p.seconds, "device_reserved_bytes": p.reserved_peak,
            })).collect::<Vec<_>>(),
        });
        std::fs::write(path, serde_json::to_string_pretty(&report).expect("json"))
            .map_err(|e| format!("{}: {e}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
