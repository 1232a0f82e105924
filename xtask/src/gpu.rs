//! `cargo xtask gpu-check` and `cargo xtask bench gpu`: the wgpu build of the workspace in its
//! own target directory (`target/wgpu`, so the test command's build is untouched), checked
//! against the CPU on whatever Vulkan adapter the machine has — Mesa's software lavapipe where
//! there is no GPU, installed on demand — and the generation benchmark on it (docs/gpu.md).

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::workspace::{run, target_dir, workspace_root};

/// The features of the wgpu build: the CLI's, which turn on the facade's and w3d-diffusion's.
const FEATURES: &str = "wonder3d-cli/wgpu";

fn wgpu_target() -> PathBuf {
    target_dir().join("wgpu")
}

fn cargo(args: &[&str]) -> Command {
    let mut cmd = Command::new("cargo");
    cmd.current_dir(workspace_root()).env("CARGO_TARGET_DIR", wgpu_target()).args(args);
    cmd
}

/// Vulkan installable client drivers the loader would find.
fn vulkan_drivers() -> Vec<PathBuf> {
    let mut found = Vec::new();
    for dir in ["/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d"] {
        if let Ok(entries) = std::fs::read_dir(dir) {
            found.extend(entries.flatten().map(|e| e.path()).filter(|p| p.extension().is_some_and(|x| x == "json")));
        }
    }
    found.sort();
    found
}

/// A Vulkan driver, or Mesa's (lavapipe, a software Vulkan implementation) installed with
/// apt-get when the machine has none.
fn ensure_vulkan_driver() -> Result<Vec<PathBuf>, String> {
    let found = vulkan_drivers();
    if !found.is_empty() {
        return Ok(found);
    }
    eprintln!("no Vulkan driver found: installing Mesa's (lavapipe) with apt-get");
    let apt = |args: &[&str]| {
        Command::new("apt-get").args(args).env("DEBIAN_FRONTEND", "noninteractive").status().is_ok_and(|s| s.success())
    };
    if !(apt(&["install", "-y", "--no-install-recommends", "mesa-vulkan-drivers"])
        || (apt(&["update"]) && apt(&["install", "-y", "--no-install-recommends", "mesa-vulkan-drivers"])))
    {
        return Err("no Vulkan driver and `apt-get install mesa-vulkan-drivers` failed: install a Vulkan driver \
                    (on Debian/Ubuntu the package mesa-vulkan-drivers, as root) and rerun"
            .into());
    }
    let found = vulkan_drivers();
    if found.is_empty() {
        return Err("mesa-vulkan-drivers installed but no Vulkan driver manifest (icd.d/*.json) appeared".into());
    }
    Ok(found)
}

/// `cargo xtask gpu-check`.
pub fn check() -> Result<(), String> {
    let start = std::time::Instant::now();
    let drivers = ensure_vulkan_driver()?;
    eprintln!("Vulkan drivers: {}", drivers.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", "));
    let out = wgpu_target().join("gpu-check");
    if out.exists() {
        std::fs::remove_dir_all(&out).map_err(|e| format!("{}: {e}", out.display()))?;
    }
    std::fs::create_dir_all(&out).map_err(|e| format!("{}: {e}", out.display()))?;

    // 1. Parity: wgpu against flex (tests/wgpu.rs) and against the diffusers / PyTorch
    //    references (the parity and multi-view suites, which add wgpu to their devices).
    eprintln!("building the wgpu feature in {} (a cold build takes ~20 min on 2 cores)", wgpu_target().display());
    let test_args = [
        "test",
        "--workspace",
        "--release",
        "--features",
        FEATURES,
        "--test",
        "wgpu",
        "--test",
        "multiview",
        "--test",
        "parity",
    ];
    let output = cargo(&test_args)
        .args(["--", "--test-threads", "1", "--nocapture"])
        .env("W3D_TEST_SOFTWARE_GPU", "1")
        .output()
        .map_err(|e| format!("cannot start cargo: {e}"))?;
    let log = format!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    std::fs::write(out.join("tests.log"), &log).map_err(|e| format!("{}: {e}", out.display()))?;
    let parity: Vec<&str> =
        log.lines().filter(|l| l.contains("wgpu") && (l.contains("error ") || l.contains("max-abs"))).collect();
    let adapter = log
        .lines()
        .find_map(|l| l.strip_prefix("adapter: "))
        .unwrap_or("wgpu: (the tests printed no adapter)")
        .to_string();
    if !output.status.success() {
        let tail: Vec<&str> = log.lines().rev().take(40).collect();
        return Err(format!(
            "the wgpu tests failed ({}); log in {}:\n{}",
            output.status,
            out.join("tests.log").display(),
            tail.into_iter().rev().collect::<Vec<_>>().join("\n")
        ));
    }
    println!("{adapter}");
    for line in &parity {
        println!("  {line}");
    }

    // 2. Photo in, views out on the GPU: `wonder3d generate` with the shipped small model (5
    //    steps) from a render of spot as a photo, on wgpu and on the CPU; every colour and
    //    normal PNG within 2/255 and the masks the same but for 0.5 % of their pixels.
    run(&mut cargo(&["build", "--workspace", "--release", "--features", FEATURES, "--bin", "wonder3d"]))?;
    let cli = wgpu_target().join("release").join("wonder3d");
    let render = out.join("spot-views");
    run(Command::new(&cli)
        .current_dir(workspace_root())
        .args(["render", "assets/spot.obj", "--size", "256", "--out"])
        .arg(&render))?;
    let generate = |device: &str| -> Result<(PathBuf, f64), String> {
        let dir = out.join(format!("generated-{device}"));
        let t = std::time::Instant::now();
        run(Command::new(&cli)
            .current_dir(workspace_root())
            .arg("generate")
            .arg(render.join("colour_front.png"))
            .args(["--weights", "assets/model-small", "--steps", "5", "--quiet", "--device", device, "--out"])
            .arg(&dir))?;
        Ok((dir, t.elapsed().as_secs_f64()))
    };
    let (gpu_dir, gpu_s) = generate("wgpu")?;
    let (cpu_dir, cpu_s) = generate("cpu")?;
    let (mut levels, mut mask_pixels, mut mask_total) = (0u32, 0usize, 0usize);
    for view in wonder3d::core::rig::WONDER3D_VIEW_NAMES {
        for kind in ["colour", "normal", "mask"] {
            let file = format!("{kind}_{view}.png");
            let read = |dir: &Path| wonder3d::Image::read_png(dir.join(&file)).map_err(|e| e.to_string());
            let (g, c) = (read(&gpu_dir)?, read(&cpu_dir)?);
            if g.data().len() != c.data().len() {
                return Err(format!("generate: {file} differs in size between wgpu and cpu"));
            }
            let diffs = g.data().iter().zip(c.data()).map(|(a, b)| (a - b).abs());
            if kind == "mask" {
                mask_pixels += diffs.filter(|d| *d > 0.5).count();
                mask_total += g.data().len();
            } else {
                levels = levels.max(diffs.map(|d| (d * 255.0).round() as u32).max().unwrap_or(0));
            }
        }
    }
    let mask_fraction = mask_pixels as f64 / mask_total.max(1) as f64;
    println!(
        "generate (small model, 5 steps): wgpu vs cpu views differ by at most {levels}/255, masks in {:.3} % of pixels; wgpu {gpu_s:.1} s, cpu {cpu_s:.1} s",
        100.0 * mask_fraction
    );
    if levels > 2 || mask_fraction > 0.005 {
        return Err(format!(
            "generate: the views made on wgpu differ from the CPU's by {levels}/255 and {:.3} % of mask pixels",
            100.0 * mask_fraction
        ));
    }

    // 3. The benchmark runs end to end (tiny checkpoint; the real size is for a real GPU).
    let bench_json = out.join("bench-tiny.json");
    bench(&["--model".into(), "tiny".into(), "--json".into(), bench_json.display().to_string()])?;

    let summary = serde_json::json!({
        "adapter": adapter,
        "vulkan_drivers": drivers.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
        "parity": parity,
        "generate": {
            "max_level_difference": levels, "mask_pixels_differing": mask_fraction,
            "wgpu_seconds": gpu_s, "cpu_seconds": cpu_s,
        },
        "bench": bench_json.display().to_string(),
        "seconds": start.elapsed().as_secs_f64(),
    });
    let path = out.join("report.json");
    std::fs::write(&path, serde_json::to_string_pretty(&summary).expect("json"))
        .map_err(|e| format!("{}: {e}", path.display()))?;
    println!("gpu-check passed in {:.0} s; wrote {}", start.elapsed().as_secs_f64(), path.display());
    Ok(())
}

/// `cargo xtask bench gpu [-- ARGS]`: benches/gpu.rs of w3d-diffusion in the wgpu build;
/// without `--model` the real-size model, JSON in target/bench/gpu.json.
pub fn bench(args: &[String]) -> Result<(), String> {
    let mut args = args.to_vec();
    if !args.iter().any(|a| a == "--json") {
        let dir = target_dir().join("bench");
        std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        args.extend(["--json".to_string(), dir.join("gpu.json").display().to_string()]);
    }
    run(cargo(&["bench", "--workspace", "--features", FEATURES, "--bench", "gpu", "--"]).args(&args))
}
