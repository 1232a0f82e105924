//! `cargo xtask chart-generation`: the speed–quality chart of the training-free accelerations
//! of generation (`docs/generation_speed_quality.svg` and the table of `docs/benchmarks.md`,
//! "Training-free acceleration").
//!
//! Three parts, each resumable, results in `target/chart-generation/`:
//! - `timing`: the real-size multi-view model (random f16 weights: time does not depend on the
//!   values) on this machine — the input's conditioning, one conditional UNet pass of 12
//!   images whole and as DeepCache's shallow branch, for each pass setting (f32 / bf16
//!   products, with and without token merging), and the 12 VAE decodes. A setting's
//!   generation time is assembled from these, step by step, exactly as the sampling loop runs
//!   its passes (`timing.json`).
//! - `quality`: the shipped small model on its seven training objects, sampled as the demo
//!   does (4 draws), at guidance 1 and 2, per setting: normal error, mask IoU, reconstruction
//!   CD (`quality.jsonl`, one line per setting, guidance and object; a rerun replaces lines).
//! - `chart`: the SVG and the Markdown table from both files.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use plotters::prelude::*;
use serde_json::{Value, json};
use wonder3d::diffusion::compute::{PassSettings, Products};
use wonder3d::diffusion::{
    Acceleration, ClipVision, ClipVisionConfig, DdimScheduler, DpmSolverMultistepScheduler, MultiViewPipeline,
    SampleOptions, SamplerKind, SchedulerConfig, UNet, UNetConfig, UniPcMultistepScheduler, Vae, VaeConfig,
    WeightStorage,
};
use wonder3d::eval::{EvalOptions, evaluate};
use wonder3d::recon::{Preset, ReconOptions, reconstruct};
use wonder3d::{CameraType, Image};

use crate::eval_small::{object_name, scored_object};
use crate::train_small::TRAIN_MESHES;

fn err(e: impl std::fmt::Display) -> String {
    e.to_string()
}

/// One point of the chart: a sampler, its steps and the accelerations.
#[derive(Clone, Debug)]
pub(crate) struct Setting {
    pub name: &'static str,
    pub sampler: SamplerKind,
    pub steps: usize,
    pub acceleration: Acceleration,
    /// The generated images rounded to 8-bit levels before scoring, as `wonder3d generate`
    /// writes them: the same views to within 1/510, which measures how much the scores move
    /// for a change no one can see (the noise floor of the comparison).
    pub views_8bit: bool,
}

/// The guidance interval charted: Kynkäänniemi et al.'s interval for EDM2, σ in (0.28, 5.42],
/// is t/T ≈ 0.1–0.7 on Stable Diffusion's schedule (ᾱ = 1 / (1 + σ²)).
pub(crate) const GUIDANCE_INTERVAL: [f64; 2] = [0.1, 0.7];

/// Every setting of the chart: today's default first, every method alone, then combinations.
pub(crate) fn settings() -> Vec<Setting> {
    let none = Acceleration::default();
    let bf16 = PassSettings::default().with_products(Products::Bf16);
    let dpm = SamplerKind::DpmSolverPlusPlus2M;
    let unipc = SamplerKind::UniPc;
    let s = |name, sampler, steps, acceleration| Setting { name, sampler, steps, acceleration, views_8bit: false };
    vec![
        s("dpm20", dpm, 20, none),
        Setting { views_8bit: true, ..s("dpm20-8bit", dpm, 20, none) },
        s("dpm10", dpm, 10, none),
        s("unipc10", unipc, 10, none),
        s("unipc8", unipc, 8, none),
        s("dpm20-cache2", dpm, 20, none.with_cache_interval(2)),
        s("dpm20-cache3", dpm, 20, none.with_cache_interval(3)),
        s("dpm20-interval", dpm, 20, none.with_guidance_interval(GUIDANCE_INTERVAL)),
        s("dpm20-bf16", dpm, 20, none.with_pass(bf16)),
        s("dpm20-tome", dpm, 20, none.with_pass(PassSettings::default().with_token_merge(0.5))),
        s("unipc10-cache2", unipc, 10, none.with_cache_interval(2)),
        s("unipc10-cache2-interval", unipc, 10, none.with_cache_interval(2).with_guidance_interval(GUIDANCE_INTERVAL)),
        s(
            "unipc10-cache2-interval-bf16",
            unipc,
            10,
            none.with_cache_interval(2).with_guidance_interval(GUIDANCE_INTERVAL).with_pass(bf16),
        ),
        s("dpm20-cache3-interval", dpm, 20, none.with_cache_interval(3).with_guidance_interval(GUIDANCE_INTERVAL)),
        s(
            "dpm20-cache3-interval-bf16",
            dpm,
            20,
            none.with_cache_interval(3).with_guidance_interval(GUIDANCE_INTERVAL).with_pass(bf16),
        ),
        s(
            "dpm20-cache3-interval-bf16-tome",
            dpm,
            20,
            none.with_cache_interval(3).with_guidance_interval(GUIDANCE_INTERVAL).with_pass(bf16.with_token_merge(0.5)),
        ),
        s("dpm20-cache3-bf16-tome", dpm, 20, none.with_cache_interval(3).with_pass(bf16.with_token_merge(0.5))),
    ]
}

/// The settings `list` names (comma-separated), or all.
fn pick(list: Option<&str>) -> Result<Vec<Setting>, String> {
    let all = settings();
    let Some(list) = list else { return Ok(all) };
    list.split(',')
        .map(|name| {
            all.iter().find(|s| s.name == name.trim()).cloned().ok_or_else(|| {
                let names: Vec<&str> = all.iter().map(|s| s.name).collect();
                format!("--settings: no setting {:?} (one of {})", name.trim(), names.join(", "))
            })
        })
        .collect()
}

fn out_dir() -> PathBuf {
    crate::workspace::target_dir().join("chart-generation")
}

/// Runs the parts `part` names (`timing`, `quality`, `chart` or `all`).
pub(crate) fn run(part: &str, list: Option<&str>, guidances: &[f64], model: &Path) -> Result<(), String> {
    let picked = pick(list)?;
    std::fs::create_dir_all(out_dir()).map_err(|e| format!("{}: {e}", out_dir().display()))?;
    match part {
        "timing" => timing(),
        "quality" => quality(&picked, guidances, model),
        "chart" => chart(),
        "enhancer-timing" => enhancer_timing(),
        "enhancer-vae" => enhancer_vae_bf16(),
        "end-to-end" => end_to_end(),
        "all" => {
            timing()?;
            quality(&picked, guidances, model)?;
            chart()
        }
        other => Err(format!(
            "--part: timing, enhancer-timing, enhancer-vae, end-to-end, quality, chart or all (found {other:?})"
        )),
    }
}

/// Peak resident memory of this process in bytes (`VmHWM`).
fn peak_rss() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let kib = status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse::<f64>().ok())
        .unwrap_or(0.0);
    kib * 1024.0
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .unwrap_or_default()
        .split_whitespace()
        .take(3)
        .collect::<Vec<_>>()
        .join(" ")
}

/// The real-size Wonder3D++ multi-view pipeline (`configs/wonder3d`) with random f16 weights:
/// time does not depend on the values.
fn real_size_pipeline(device: &wonder3d::diffusion::Device) -> Result<MultiViewPipeline, String> {
    let root = crate::workspace::workspace_root();
    let config = |p: &str| root.join("crates/w3d-diffusion/configs/wonder3d").join(p);
    let storage = WeightStorage::F16;
    let unet =
        UNet::random_with(&UNetConfig::from_file(config("unet_mv/config.json")).map_err(err)?, 1, device, storage)
            .map_err(err)?;
    let vae = Vae::random_with(&VaeConfig::from_file(config("vae/config.json")).map_err(err)?, 2, device, storage)
        .map_err(err)?;
    let clip_config = ClipVisionConfig::from_file(config("image_encoder/config.json")).map_err(err)?;
    let clip = ClipVision::random_with(&clip_config, 3, device, storage).map_err(err)?;
    let scheduler = SchedulerConfig::from_file(config("scheduler/scheduler_config.json")).map_err(err)?;
    MultiViewPipeline::new(unet, vae, clip, scheduler).map_err(err)
}

/// The real-size timings (see the module docs).
fn timing() -> Result<(), String> {
    let device = wonder3d::diffusion::default_device();
    let t = Instant::now();
    let pipeline = real_size_pipeline(&device)?;
    eprintln!("real-size models built in {:.1} s (f16 weights, random)", t.elapsed().as_secs_f64());

    let image = Image::filled(256, 256, 3, 0.5).map_err(err)?;
    let t = Instant::now();
    let cond = pipeline.condition(&image, &device).map_err(err)?;
    let condition_s = t.elapsed().as_secs_f64();
    let noise = pipeline.initial_noise(1, &device);
    // Peak memory during sampling alone, as docs/benchmarks.md measured the guided step's
    // (the models resident, the peak reset before each run).
    let reset_peak = || std::fs::write("/proc/self/clear_refs", "5").is_ok();
    let sample = |options: &SampleOptions| -> Result<(f64, wonder3d::diffusion::Tensor<4>), String> {
        let t = Instant::now();
        let latents = pipeline.sample_from(noise.clone(), &cond, options, &mut |_, _| {}).map_err(err)?;
        let values = latents.clone().into_data().try_to_vec::<f32>().map_err(|e| format!("{e:?}"))?;
        if !values.iter().all(|v| v.is_finite()) {
            return Err("non-finite latents".into());
        }
        Ok((t.elapsed().as_secs_f64(), latents))
    };
    let one = |steps, acceleration| SampleOptions {
        sampler: SamplerKind::Ddim,
        steps,
        guidance: 1.0,
        eta: 0.0,
        acceleration,
        ..SampleOptions::default()
    };
    // Warm-up: the first pass pays for pages the later ones reuse.
    let (warm_s, latents) = sample(&one(1, Acceleration::default()))?;
    eprintln!("warm-up pass {warm_s:.1} s, load {}", load_average());
    let t = Instant::now();
    pipeline.decode(latents.clone(), CameraType::Orthographic).map_err(err)?;
    let decode_s = t.elapsed().as_secs_f64();
    let mut decode_bf16_s = decode_s;
    if Products::Bf16.supported() {
        let t = Instant::now();
        let bf16 = PassSettings::default().with_products(Products::Bf16);
        wonder3d::diffusion::compute::with_settings(bf16, || pipeline.decode(latents, CameraType::Orthographic))
            .map_err(err)?;
        decode_bf16_s = t.elapsed().as_secs_f64();
    }
    eprintln!("conditioning {condition_s:.1} s, 12 decodes {decode_s:.1} s (bf16 products: {decode_bf16_s:.1} s)");

    let mut passes = Vec::new();
    let bf16_ok = Products::Bf16.supported();
    for (products, token_merge) in
        [(Products::F32, 0.0), (Products::Bf16, 0.0), (Products::F32, 0.5), (Products::Bf16, 0.5)]
    {
        if products == Products::Bf16 && !bf16_ok {
            eprintln!("this CPU has no AVX-512 BF16: bf16 not timed");
            continue;
        }
        let pass = PassSettings::default().with_products(products).with_token_merge(token_merge);
        let accel = Acceleration::default().with_pass(pass);
        let (full_s, _) = sample(&one(1, accel))?;
        let depths: &[usize] = if products == Products::F32 && token_merge == 0.0 { &[1, 2] } else { &[1] };
        for &depth in depths {
            let (two_s, _) = sample(&one(2, accel.with_cache_interval(2).with_cache_depth(depth)))?;
            let shallow_s = (two_s - full_s).max(0.0);
            eprintln!(
                "{} products, token merging {token_merge}: full pass {full_s:.1} s, shallow from skip {depth} {shallow_s:.1} s (load {})",
                products.name(),
                load_average()
            );
            passes.push(json!({
                "products": products.name(), "token_merge": token_merge, "cache_depth": depth,
                "full_pass_s": full_s, "shallow_pass_s": shallow_s,
            }));
        }
    }
    // The pass-by-pass model checked on a short whole sampling loop with every acceleration.
    let mut record =
        json!({ "condition_s": condition_s, "decode_s": decode_s, "decode_bf16_s": decode_bf16_s, "passes": passes });
    let check = Setting {
        steps: 6,
        ..settings().into_iter().find(|s| s.name == "dpm20-cache3-interval-bf16-tome").ok_or("no check setting")?
    };
    let options = SampleOptions {
        sampler: check.sampler,
        steps: check.steps,
        guidance: 2.0,
        acceleration: check.acceleration,
        ..SampleOptions::default()
    };
    let reset = reset_peak();
    let (measured_s, _) = sample(&options)?;
    let check_peak_gib = peak_rss() / (1u64 << 30) as f64;
    // Today's default step for comparison: one guided step, every acceleration off.
    reset_peak();
    let reference = SampleOptions { sampler: check.sampler, steps: 1, guidance: 2.0, ..SampleOptions::default() };
    sample(&reference)?;
    let reference_peak_gib = peak_rss() / (1u64 << 30) as f64;
    eprintln!(
        "peak memory while sampling: {check_peak_gib:.2} GiB with the accelerations, {reference_peak_gib:.2} GiB for a guided step without (peak reset: {reset})"
    );
    let predicted_s =
        generation_seconds(&record, &check, 2.0)? - record["condition_s"].as_f64().unwrap_or(0.0) - decode_bf16_s;
    eprintln!(
        "check: 6 DPM-Solver++ steps at guidance 2 with {}: sampling {measured_s:.1} s measured, {predicted_s:.1} s assembled from the passes",
        check.acceleration.describe()
    );
    let passes = record["passes"].take();
    let record = json!({
        "date": date(), "cpu": crate::workspace::cpu_model(), "threads": rayon_threads(),
        "model": "Wonder3D++ MV UNet (configs/wonder3d/unet_mv), f16 weights, random; 12 images at 32² a pass",
        "condition_s": condition_s, "decode_s": decode_s, "decode_bf16_s": decode_bf16_s, "passes": passes,
        "check": {
            "setting": check.acceleration.describe(), "steps": 6, "guidance": 2.0, "measured_s": measured_s,
            "assembled_s": predicted_s, "peak_gib": check_peak_gib, "reference_step_peak_gib": reference_peak_gib,
        },
        "peak_rss_gib": peak_rss() / (1u64 << 30) as f64, "load_average_end": load_average(),
    });
    let path = out_dir().join("timing.json");
    std::fs::write(&path, serde_json::to_vec_pretty(&record).map_err(err)?)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    eprintln!("wrote {}", path.display());
    Ok(())
}

/// The refinement enhancer at real size (Stable Diffusion 1.5 UNet with f16 weights and
/// Wonder3D++'s cross-domain ControlNet, random weights) on two 1024² grids (128² latents): one
/// denoising step — ControlNet then UNet — on the 4 guidance rows and on the 2 conditional
/// rows, whole and as DeepCache's shallow branch from skip 1, per pass setting, and the VAE's
/// encode and decode of the grids. `enhancer_timing.json`; about 30 min on 2 cores.
fn enhancer_timing() -> Result<(), String> {
    use wonder3d::diffusion::{ControlNet, ControlNetConfig, FeatureCache, Tensor, UNetExtra, compute};
    let root = crate::workspace::workspace_root();
    let config = |p: &str| root.join("crates/w3d-diffusion/configs/enhancer").join(p);
    let device = wonder3d::diffusion::default_device();
    let t = Instant::now();
    let unet_config = UNetConfig::from_file(config("unet/config.json")).map_err(err)?;
    let unet = UNet::random_with(&unet_config, 1, &device, WeightStorage::F16).map_err(err)?;
    let control_config = ControlNetConfig::from_file(config("controlnet/config.json")).map_err(err)?;
    let controlnet = ControlNet::random(&control_config, true, 2, &device).map_err(err)?;
    let vae = Vae::random_with(
        &VaeConfig::from_file(config("vae/config.json")).map_err(err)?,
        3,
        &device,
        WeightStorage::F16,
    )
    .map_err(err)?;
    eprintln!("real-size enhancer models built in {:.1} s", t.elapsed().as_secs_f64());
    let grids: Tensor<4> = wonder3d::diffusion::gaussian_noise([2, 3, 1024, 1024], 4, &device).clamp(-1.0, 1.0);
    let t = Instant::now();
    let (mean, _) = vae.encode_moments(grids).map_err(err)?;
    let encode_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    for i in 0..2 {
        vae.decode(mean.clone().narrow(0, i, 1)).map_err(err)?;
    }
    let decode_s = t.elapsed().as_secs_f64();
    eprintln!("VAE: encode of two 1024² grids {encode_s:.1} s, two decodes {decode_s:.1} s (load {})", load_average());
    let timestep = [180.0f32];
    // One step of 4 rows whole (filling DeepCache's feature), then one from skip 1 that
    // reuses it: ControlNet, then UNet.
    let rows = 4;
    let latents: Tensor<4> = wonder3d::diffusion::gaussian_noise([rows, 4, 128, 128], 5, &device);
    let control: Tensor<4> = wonder3d::diffusion::gaussian_noise([rows, 3, 1024, 1024], 6, &device).clamp(0.0, 1.0);
    let context: Tensor<3> = wonder3d::diffusion::gaussian_noise([rows, 77, 768], 7, &device);
    let step = |pass: PassSettings, cache: &mut FeatureCache, reuse: bool| -> Result<f64, String> {
        let t = Instant::now();
        compute::with_settings(pass, || -> Result<(), String> {
            let (l, c, x) = (latents.clone(), context.clone(), control.clone());
            let residuals = if reuse {
                controlnet.forward_shallow(l.clone(), &timestep, c.clone(), x, 0.7, cache.depth())
            } else {
                controlnet.forward(l.clone(), &timestep, c.clone(), x, 0.7)
            }
            .map_err(err)?;
            let extra = UNetExtra { control: Some(residuals), ip: None };
            let out = unet.forward_cached(l, &timestep, c, None, &extra, cache, reuse).map_err(err)?;
            out.into_data().try_to_vec::<f32>().map_err(|e| format!("{e:?}"))?;
            Ok(())
        })?;
        Ok(t.elapsed().as_secs_f64())
    };
    let mut steps = Vec::new();
    let bf16_ok = Products::Bf16.supported();
    for (products, token_merge) in [(Products::F32, 0.0), (Products::Bf16, 0.0), (Products::Bf16, 0.5)] {
        if products == Products::Bf16 && !bf16_ok {
            continue;
        }
        let pass = PassSettings::default().with_products(products).with_token_merge(token_merge);
        let mut cache = FeatureCache::new(1);
        let full_s = step(pass, &mut cache, false)?;
        let shallow_s = step(pass, &mut cache, true)?;
        eprintln!(
            "enhancer step, 4 rows, {} products, token merging {token_merge}: full {full_s:.1} s, shallow from skip 1 {shallow_s:.1} s (load {})",
            products.name(),
            load_average()
        );
        steps.push(json!({
            "rows": rows, "products": products.name(), "token_merge": token_merge, "cache_depth": 1,
            "full_s": full_s, "shallow_s": shallow_s,
        }));
    }
    let record = json!({
        "date": date(), "cpu": crate::workspace::cpu_model(), "threads": rayon_threads(),
        "model": "SD 1.5 UNet (f16 weights) + Wonder3D++ ControlNet with cross-domain attention (f32), random; 128² latents",
        "vae_encode_s": encode_s, "vae_decode_s": decode_s, "steps": steps,
        "peak_rss_gib": peak_rss() / (1u64 << 30) as f64,
    });
    let path = out_dir().join("enhancer_timing.json");
    std::fs::write(&path, serde_json::to_vec_pretty(&record).map_err(err)?)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    eprintln!("wrote {}", path.display());
    Ok(())
}

/// Two whole real-size generations side by side in one process (random f16 weights): today's
/// default (20 DPM-Solver++(2M) steps at guidance 2, f32 products) and the recommended fast
/// setting (DeepCache every 3, bf16 products, token merging 0.5), each conditioning, sampling
/// and the 12 decodes, with the peak memory of each (`end_to_end.json`; about 14 min).
fn end_to_end() -> Result<(), String> {
    let device = wonder3d::diffusion::default_device();
    let pipeline = real_size_pipeline(&device)?;
    let image = Image::filled(256, 256, 3, 0.5).map_err(err)?;
    let all = settings();
    let mut runs = Vec::new();
    for name in ["dpm20-cache3-bf16-tome", "dpm20"] {
        let setting = all.iter().find(|s| s.name == name).ok_or("no setting")?;
        let options = SampleOptions {
            sampler: setting.sampler,
            steps: setting.steps,
            guidance: 2.0,
            acceleration: setting.acceleration,
            ..SampleOptions::default()
        };
        let reset = std::fs::write("/proc/self/clear_refs", "5").is_ok();
        let t = Instant::now();
        let cond = pipeline.condition(&image, &device).map_err(err)?;
        let views = pipeline.sample_views(&cond, &options, &device, &mut |_, _| {}).map_err(err)?;
        let seconds = t.elapsed().as_secs_f64();
        if views.normals.len() != 6 {
            return Err("expected 6 normal views".into());
        }
        let peak = peak_rss() / (1u64 << 30) as f64;
        eprintln!(
            "{name} ({}): whole generation {seconds:.1} s = {:.2} min, peak {peak:.2} GiB (reset {reset}; load {})",
            describe(setting),
            seconds / 60.0,
            load_average()
        );
        runs.push(json!({"setting": name, "description": describe(setting), "seconds": seconds, "peak_gib": peak}));
    }
    let record = json!({
        "date": date(), "cpu": crate::workspace::cpu_model(), "threads": rayon_threads(), "guidance": 2.0,
        "runs": runs,
    });
    let path = out_dir().join("end_to_end.json");
    std::fs::write(&path, serde_json::to_vec_pretty(&record).map_err(err)?)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    eprintln!("wrote {}", path.display());
    Ok(())
}

fn date() -> String {
    std::process::Command::new("date")
        .arg("-u")
        .arg("+%Y-%m-%d %H:%M UTC")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default()
}

fn rayon_threads() -> usize {
    std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
}

/// The timesteps a sampler runs for `steps` steps of `config`.
fn timesteps(config: &SchedulerConfig, sampler: SamplerKind, steps: usize) -> Result<Vec<usize>, String> {
    Ok(match sampler {
        SamplerKind::Ddim => DdimScheduler::new(config.clone(), steps).map_err(err)?.timesteps().to_vec(),
        SamplerKind::DpmSolverPlusPlus2M => {
            DpmSolverMultistepScheduler::new(config.clone(), steps).map_err(err)?.timesteps().to_vec()
        }
        SamplerKind::UniPc => {
            UniPcMultistepScheduler::new(config.clone(), steps).map_err(err)?.run_timesteps().to_vec()
        }
    })
}

/// The passes a setting runs, as the sampling loop decides them: per step the conditional
/// branch and, inside the guidance interval, the unconditional one; each full or shallow.
/// Returns (full passes, shallow passes).
pub(crate) fn pass_counts(setting: &Setting, guidance: f64, timesteps: &[usize]) -> (usize, usize) {
    let a = &setting.acceleration;
    let mut filled: [Option<usize>; 2] = [None; 2];
    let (mut full, mut shallow) = (0, 0);
    for (step, &t) in timesteps.iter().enumerate() {
        let guided = guidance != 1.0 && a.guided_at(t, 1000);
        for (branch, fill) in filled.iter_mut().enumerate() {
            if branch == 1 && !guided {
                continue;
            }
            let reuse = a.reuses_cache(step, *fill);
            if reuse {
                shallow += 1;
            } else {
                full += 1;
                *fill = Some(step);
            }
        }
    }
    (full, shallow)
}

/// The real-size generation time of `setting` at `guidance` from `timing.json`, in seconds.
fn generation_seconds(timing: &Value, setting: &Setting, guidance: f64) -> Result<f64, String> {
    let pass = &setting.acceleration.pass;
    let products = pass.products.resolve().0.name();
    let depth = setting.acceleration.cache_depth;
    let entry = timing["passes"]
        .as_array()
        .and_then(|p| {
            p.iter().find(|e| {
                e["products"] == products
                    && (e["token_merge"].as_f64().unwrap_or(-1.0) - f64::from(pass.token_merge)).abs() < 1e-6
                    && e["cache_depth"] == depth
            })
        })
        .ok_or(format!(
            "timing.json has no pass timing for {} products, token merging {}",
            products, pass.token_merge
        ))?;
    let steps = timesteps(&SchedulerConfig::stable_diffusion(), setting.sampler, setting.steps)?;
    let (full, shallow) = pass_counts(setting, guidance, &steps);
    let f = |k: &str| entry[k].as_f64().unwrap_or(f64::NAN);
    // The decodes run with the sampling's products.
    let decode = if products == "bf16" { &timing["decode_bf16_s"] } else { &timing["decode_s"] };
    Ok(timing["condition_s"].as_f64().unwrap_or(0.0)
        + full as f64 * f("full_pass_s")
        + shallow as f64 * f("shallow_pass_s")
        + decode.as_f64().unwrap_or(0.0))
}

/// The small model's scores per setting, guidance and training object (see the module docs).
fn quality(picked: &[Setting], guidances: &[f64], model: &Path) -> Result<(), String> {
    let root = crate::workspace::workspace_root();
    let device = wonder3d::diffusion::default_device();
    let pipeline = MultiViewPipeline::from_dir_with(root.join(model), &device, WeightStorage::AsStored).map_err(err)?;
    let size = pipeline.image_size() as u32;
    let path = out_dir().join("quality.jsonl");
    let demo = wonder3d::demo::small_model_sampling();
    // The truth of every object, prepared once.
    let mut objects = Vec::new();
    for mesh_path in TRAIN_MESHES {
        let o = scored_object(&root.join(mesh_path), size)?;
        objects.push((object_name(mesh_path), o.rgba, o.camera, o.truth, o.posed));
    }
    for setting in picked {
        for &guidance in guidances {
            if guidance == 1.0 && setting.acceleration.guidance_interval != [0.0, 1.0] {
                continue; // no unconditional branch to limit
            }
            for (name, rgba, camera, truth, posed) in &objects {
                let options = SampleOptions {
                    sampler: setting.sampler,
                    steps: setting.steps,
                    guidance,
                    eta: 0.0,
                    camera: *camera,
                    seed: 42,
                    draws: demo.draws,
                    acceleration: setting.acceleration,
                };
                let t = Instant::now();
                let mut generated = pipeline.generate(rgba, &options, &device, &mut |_, _| {}).map_err(err)?;
                let generate_s = t.elapsed().as_secs_f64();
                if setting.views_8bit {
                    for image in generated.normals.iter_mut().chain(generated.colours.iter_mut()) {
                        let levels = image.data().iter().map(|v| (v.clamp(0.0, 1.0) * 255.0).round() / 255.0).collect();
                        *image = Image::new(image.width(), image.height(), 3, levels).map_err(err)?;
                    }
                }
                let views = generated.to_view_set().map_err(err)?;
                let agreement = wonder3d::eval::view_agreement(truth, &views).map_err(err)?;
                let recon_options = ReconOptions::preset(Preset::Default).with_starts(wonder3d::GENERATED_VIEW_STARTS);
                let chamfer = match reconstruct(&views, &recon_options, &mut |_| {}) {
                    Ok((mesh, _)) => Some(
                        evaluate(&mesh, posed, &EvalOptions::default().with_normalize_pred(true)).map_err(err)?.chamfer,
                    ),
                    Err(e) => {
                        eprintln!("{name}: reconstruction failed: {e}");
                        None
                    }
                };
                eprintln!(
                    "{:>30} g{guidance} {name:>22}: normal {:5.2}°, IoU {:.4}, CD {}, generation {generate_s:.1} s",
                    setting.name,
                    agreement.normal_angle_deg,
                    agreement.mask_iou,
                    chamfer.map_or("-".into(), |c| format!("{c:.4}"))
                );
                let line = json!({
                    "setting": setting.name, "guidance": guidance, "object": name,
                    "normal_angle_deg": agreement.normal_angle_deg, "mask_iou": agreement.mask_iou,
                    "chamfer": chamfer, "generate_seconds": generate_s, "draws": demo.draws,
                    "acceleration": setting.acceleration.describe(), "date": date(),
                });
                let mut file = std::fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(&path)
                    .map_err(|e| format!("{}: {e}", path.display()))?;
                writeln!(file, "{line}").map_err(|e| format!("{}: {e}", path.display()))?;
            }
        }
    }
    Ok(())
}

/// The latest quality line per (setting, guidance, object).
fn read_quality() -> Result<Vec<Value>, String> {
    let path = out_dir().join("quality.jsonl");
    let text = std::fs::read_to_string(&path)
        .map_err(|e| format!("{}: {e} (run `cargo xtask chart-generation --part quality` first)", path.display()))?;
    let mut lines: Vec<Value> = Vec::new();
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        let v: Value = serde_json::from_str(line).map_err(|e| format!("{}: {e}", path.display()))?;
        lines.retain(|o| {
            !(o["setting"] == v["setting"] && o["guidance"] == v["guidance"] && o["object"] == v["object"])
        });
        lines.push(v);
    }
    Ok(lines)
}

/// One row of the table: a setting at a guidance, its time and its scores against the default's.
struct Row {
    setting: Setting,
    guidance: f64,
    seconds: f64,
    objects: usize,
    mean_angle: f64,
    mean_iou: f64,
    mean_cd: f64,
    worst_angle: f64,
    worst_iou: f64,
    worst_cd_ratio: f64,
}

/// The SVG and the Markdown table (printed) from `timing.json` and `quality.jsonl`.
fn chart() -> Result<(), String> {
    let path = out_dir().join("timing.json");
    let timing: Value = serde_json::from_slice(
        &std::fs::read(&path).map_err(|e| format!("{}: {e} (run `--part timing` first)", path.display()))?,
    )
    .map_err(|e| format!("{}: {e}", path.display()))?;
    let quality = read_quality()?;
    let all = settings();
    let baseline = &all[0];
    let scores = |setting: &str, guidance: f64| -> Vec<(String, f64, f64, Option<f64>)> {
        quality
            .iter()
            .filter(|q| q["setting"] == setting && q["guidance"].as_f64() == Some(guidance))
            .map(|q| {
                (
                    q["object"].as_str().unwrap_or("").to_string(),
                    q["normal_angle_deg"].as_f64().unwrap_or(f64::NAN),
                    q["mask_iou"].as_f64().unwrap_or(f64::NAN),
                    q["chamfer"].as_f64(),
                )
            })
            .collect()
    };
    let mut rows = Vec::new();
    for guidance in [2.0, 1.0] {
        let base = scores(baseline.name, guidance);
        for setting in &all {
            // Token merging changes no bit of the small model's output (its first level has no
            // attention; tests/token_merge.rs checks it): its rows carry the scores of the same
            // setting without it.
            let scored = scored_as(setting, &all);
            let s = scores(scored, guidance);
            if s.is_empty() {
                continue;
            }
            let n = s.len() as f64;
            let mut row = Row {
                setting: setting.clone(),
                guidance,
                seconds: generation_seconds(&timing, setting, guidance)?,
                objects: s.len(),
                mean_angle: s.iter().map(|o| o.1).sum::<f64>() / n,
                mean_iou: s.iter().map(|o| o.2).sum::<f64>() / n,
                mean_cd: s.iter().filter_map(|o| o.3).sum::<f64>() / n,
                worst_angle: f64::NEG_INFINITY,
                worst_iou: f64::NEG_INFINITY,
                worst_cd_ratio: 0.0,
            };
            for (object, angle, iou, cd) in &s {
                if let Some(b) = base.iter().find(|b| &b.0 == object) {
                    row.worst_angle = row.worst_angle.max(angle - b.1);
                    row.worst_iou = row.worst_iou.max(b.2 - iou);
                    if let (Some(cd), Some(bcd)) = (cd, b.3) {
                        row.worst_cd_ratio = row.worst_cd_ratio.max(cd / bcd);
                    }
                }
            }
            rows.push(row);
        }
    }
    let base_seconds = generation_seconds(&timing, baseline, 2.0)?;
    println!(
        "| setting | guidance | real-size generation (min) | × default | normal error (mean, °) | mask IoU (mean) | CD (mean) | worst object: normal Δ° / IoU drop / CD ratio |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for r in &rows {
        let base = generation_seconds(&timing, baseline, r.guidance)?;
        let proxy = if scored_as(&r.setting, &all) == r.setting.name { "" } else { " †" };
        println!(
            "| {}{proxy} ({}) | {} | {:.1} | {:.2} | {:.2} | {:.3} | {:.4} | {:+.2} / {:.3} / {:.2} |",
            r.setting.name,
            describe(&r.setting),
            r.guidance,
            r.seconds / 60.0,
            r.seconds / base,
            r.mean_angle,
            r.mean_iou,
            r.mean_cd,
            r.worst_angle,
            r.worst_iou,
            r.worst_cd_ratio
        );
        if r.objects != TRAIN_MESHES.len() {
            println!("|  (only {} objects scored) |", r.objects);
        }
    }
    enhancer_table()?;
    let out = crate::workspace::workspace_root().join("docs").join("generation_speed_quality.svg");
    let (y_lo, y_hi) =
        rows.iter().fold((f64::MAX, f64::MIN), |(lo, hi), r| (lo.min(r.mean_angle), hi.max(r.mean_angle)));
    let x_hi = rows.iter().map(|r| r.seconds / 60.0).fold(base_seconds / 60.0, f64::max) * 1.08;
    {
        let root = SVGBackend::new(&out, (900, 560)).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                "Generation: real-size time (2-core CPU) against the small model's normal error",
                ("sans-serif", 17),
            )
            .margin(14)
            .x_label_area_size(42)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..x_hi, (y_lo - 0.6)..(y_hi + 0.6))
            .map_err(err)?;
        crate::chart::draw_grid(
            &mut chart,
            "minutes for one real-size generation (Wonder3D++ UNet, f16 weights, 2 cores)",
            "normal error, mean of 7 training objects (°)",
        )?;
        for (k, guidance) in [2.0, 1.0].into_iter().enumerate() {
            let colour = crate::chart::OKABE_ITO[k];
            let points: Vec<(f64, f64, &str)> = rows
                .iter()
                .filter(|r| r.guidance == guidance)
                .map(|r| (r.seconds / 60.0, r.mean_angle, r.setting.name))
                .collect();
            chart
                .draw_series(points.iter().map(|&(x, y, _)| Circle::new((x, y), 5, colour.filled())))
                .map_err(err)?
                .label(format!("guidance {guidance}"))
                .legend(move |(x, y)| Circle::new((x + 10, y), 5, colour.filled()));
            chart
                .draw_series(points.iter().map(|&(x, y, name)| {
                    Text::new(name.to_string(), (x, y), ("sans-serif", 10).into_font().color(&colour))
                }))
                .map_err(err)?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK)
            .draw()
            .map_err(err)?;
        root.present().map_err(err)?;
    }
    eprintln!("wrote {}", out.display());
    Ok(())
}

/// The enhancer's VAE encode and decode of two 1024² grids with bf16 products, added to
/// `enhancer_timing.json` (`vae_bf16_encode_s`, `vae_bf16_decode_s`): the call runs its VAE with
/// the denoising's products.
fn enhancer_vae_bf16() -> Result<(), String> {
    let path = out_dir().join("enhancer_timing.json");
    let mut timing: Value = serde_json::from_slice(
        &std::fs::read(&path).map_err(|e| format!("{}: {e} (run `--part enhancer-timing` first)", path.display()))?,
    )
    .map_err(|e| format!("{}: {e}", path.display()))?;
    if !Products::Bf16.supported() {
        return Err("this CPU has no AVX-512 BF16".into());
    }
    let root = crate::workspace::workspace_root();
    let config = root.join("crates/w3d-diffusion/configs/enhancer/vae/config.json");
    let device = wonder3d::diffusion::default_device();
    let vae =
        Vae::random_with(&VaeConfig::from_file(config).map_err(err)?, 3, &device, WeightStorage::F16).map_err(err)?;
    let grids: wonder3d::diffusion::Tensor<4> =
        wonder3d::diffusion::gaussian_noise([2, 3, 1024, 1024], 4, &device).clamp(-1.0, 1.0);
    let bf16 = PassSettings::default().with_products(Products::Bf16);
    let (encode_s, decode_s) = wonder3d::diffusion::compute::with_settings(bf16, || -> Result<(f64, f64), String> {
        let t = Instant::now();
        let (mean, _) = vae.encode_moments(grids).map_err(err)?;
        let encode_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        for i in 0..2 {
            vae.decode(mean.clone().narrow(0, i, 1)).map_err(err)?;
        }
        Ok((encode_s, t.elapsed().as_secs_f64()))
    })?;
    eprintln!("VAE with bf16 products: encode {encode_s:.1} s, two decodes {decode_s:.1} s (load {})", load_average());
    timing["vae_bf16_encode_s"] = json!(encode_s);
    timing["vae_bf16_decode_s"] = json!(decode_s);
    std::fs::write(&path, serde_json::to_vec_pretty(&timing).map_err(err)?)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(())
}

/// The first refinement iteration's time per enhancer setting, from `enhancer_timing.json`
/// (printed; nothing when the file is missing): the VAE's encode and decode of the two grids
/// and the 10 UniPC steps of strength 0.2 (timesteps 200, 180, …, 20), each step's rows (4
/// guided, 2 conditional) and pass (whole or shallow) decided as the enhancer decides them.
fn enhancer_table() -> Result<(), String> {
    let path = out_dir().join("enhancer_timing.json");
    let Ok(bytes) = std::fs::read(&path) else { return Ok(()) };
    let timing: Value = serde_json::from_slice(&bytes).map_err(|e| format!("{}: {e}", path.display()))?;
    let bf16 = PassSettings::default().with_products(Products::Bf16);
    let none = Acceleration::default();
    let interval = none.with_guidance_interval(GUIDANCE_INTERVAL);
    let settings: Vec<(&str, Acceleration)> = vec![
        ("none (today)", none),
        ("bf16 products", none.with_pass(bf16)),
        ("guidance in [0.1, 0.7]", interval),
        ("DeepCache every 2", none.with_cache_interval(2)),
        ("DeepCache every 3", none.with_cache_interval(3)),
        ("token merging 0.5, bf16", none.with_pass(bf16.with_token_merge(0.5))),
        ("DeepCache every 3, bf16", none.with_cache_interval(3).with_pass(bf16)),
        (
            "DeepCache every 3, token merging 0.5, bf16",
            none.with_cache_interval(3).with_pass(bf16.with_token_merge(0.5)),
        ),
        (
            "guidance in [0.1, 0.7], DeepCache every 3, token merging 0.5, bf16",
            interval.with_cache_interval(3).with_pass(bf16.with_token_merge(0.5)),
        ),
    ];
    let timesteps: Vec<usize> = (1..=10).rev().map(|k| 20 * k).collect();
    let fixed = timing["vae_encode_s"].as_f64().unwrap_or(0.0) + timing["vae_decode_s"].as_f64().unwrap_or(0.0);
    let mut base = None;
    println!();
    println!(
        "| enhancer setting (first iteration: 10 UniPC steps, two 1024² grids) | full / shallow steps | minutes | × today |"
    );
    println!("|---|---|---|---|");
    for (name, a) in settings {
        let products = a.pass.products.resolve().0.name();
        let Some(entry) = timing["steps"].as_array().and_then(|steps| {
            steps.iter().find(|e| {
                e["products"] == products
                    && (e["token_merge"].as_f64().unwrap_or(0.0) - f64::from(a.pass.token_merge)).abs() < 1e-6
            })
        }) else {
            continue;
        };
        let (full_s, shallow_s) =
            (entry["full_s"].as_f64().unwrap_or(f64::NAN), entry["shallow_s"].as_f64().unwrap_or(f64::NAN));
        let fixed = match (products, timing["vae_bf16_encode_s"].as_f64(), timing["vae_bf16_decode_s"].as_f64()) {
            ("bf16", Some(e), Some(d)) => e + d,
            _ => fixed,
        };
        let (mut seconds, mut full, mut shallow) = (fixed, 0, 0);
        let (mut cached_rows, mut last_full) = (None, None);
        for (step, &t) in timesteps.iter().enumerate() {
            let rows = if a.guided_at(t, 1000) { 4 } else { 2 };
            let reuse = cached_rows == Some(rows) && a.reuses_cache(step, last_full);
            let scale = rows as f64 / 4.0;
            if reuse {
                shallow += 1;
                seconds += shallow_s * scale;
            } else {
                full += 1;
                seconds += full_s * scale;
                last_full = Some(step);
                cached_rows = Some(rows);
            }
        }
        let base_s = *base.get_or_insert(seconds);
        println!("| {name} | {full} / {shallow} | {:.1} | {:.2} |", seconds / 60.0, seconds / base_s);
    }
    Ok(())
}

/// The setting whose scores stand for `setting`'s: itself, or without token merging (a no-op
/// on the small model).
fn scored_as<'a>(setting: &'a Setting, all: &'a [Setting]) -> &'a str {
    let pass = setting.acceleration.pass;
    if pass.token_merge == 0.0 {
        return setting.name;
    }
    let plain = setting.acceleration.with_pass(pass.with_token_merge(0.0));
    all.iter()
        .find(|o| o.sampler == setting.sampler && o.steps == setting.steps && o.acceleration == plain && !o.views_8bit)
        .map_or(setting.name, |o| o.name)
}

/// The sampler, steps and accelerations of a setting in words.
fn describe(s: &Setting) -> String {
    let sampler = match s.sampler {
        SamplerKind::Ddim => "DDIM",
        SamplerKind::DpmSolverPlusPlus2M => "DPM-Solver++(2M)",
        SamplerKind::UniPc => "UniPC",
    };
    let accel = s.acceleration.describe();
    if accel == "none" { format!("{sampler} {}", s.steps) } else { format!("{sampler} {}, {accel}", s.steps) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pass_counts_follow_the_sampling_loop() {
        let all = settings();
        let steps = timesteps(&SchedulerConfig::stable_diffusion(), SamplerKind::DpmSolverPlusPlus2M, 20).unwrap();
        // Today's default: 20 steps × 2 branches, all full.
        assert_eq!(pass_counts(&all[0], 2.0, &steps), (40, 0));
        assert_eq!(pass_counts(&all[0], 1.0, &steps), (20, 0));
        assert!(all[1].views_8bit && all[1].acceleration.is_none());
        // DeepCache every 3: steps 0, 3, …, 18 full (7 of 20).
        let cache3 = all.iter().find(|s| s.name == "dpm20-cache3").unwrap();
        assert_eq!(pass_counts(cache3, 2.0, &steps), (14, 26));
        let interval = all.iter().find(|s| s.name == "dpm20-interval").unwrap();
        let (full, shallow) = pass_counts(interval, 2.0, &steps);
        assert_eq!(shallow, 0);
        let guided = steps.iter().filter(|&&t| interval.acceleration.guided_at(t, 1000)).count();
        assert_eq!(full, 20 + guided);
        assert!(guided < 20);
        assert!(pick(Some("dpm20,nope")).is_err());
    }
}
