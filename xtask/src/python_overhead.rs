//! `cargo xtask bench python [-- --python PATH --runs N --size S]`: what a call through the
//! Python package costs over the same work from Rust. One reconstruction of spot's oracle
//! views (default preset, the README's example), timed in this process through the facade and
//! in a Python process through `wonder3d.reconstruct`, alternately, `runs` times each, on the
//! same machine with the same thread pool size; the medians and their ratio go to
//! `target/bench/python.json` and are printed for `docs/benchmarks.md`.

use std::io::{BufRead, BufReader, Write};
use std::process::{Command, Stdio};
use std::time::Instant;

use wonder3d::{Pipeline, Preset, ViewRig};

use crate::workspace::{cpu_model, target_dir, workspace_root};

/// The Python side: loads the views once, then times one call per line read from stdin.
const PYTHON_DRIVER: &str = r#"
import sys, time, wonder3d
views = wonder3d.ViewSet.load(sys.argv[1])
print(wonder3d.__version__, flush=True)
for line in sys.stdin:
    start = time.perf_counter()
    mesh = wonder3d.reconstruct(views, preset="default")
    print(time.perf_counter() - start, mesh.triangle_count, flush=True)
"#;

/// Parses `--python PATH --runs N --size S`.
fn parse(args: &[String]) -> Result<(String, usize, u32), String> {
    let (mut python, mut runs, mut size) = ("python3".to_string(), 7usize, 256u32);
    let mut it = args.iter();
    while let Some(flag) = it.next() {
        let value = it.next().ok_or_else(|| format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--python" => python = value.clone(),
            "--runs" => runs = value.parse().map_err(|_| format!("--runs: a count, got {value:?}"))?,
            "--size" => size = value.parse().map_err(|_| format!("--size: pixels, got {value:?}"))?,
            other => return Err(format!("unknown argument {other:?} (--python PATH, --runs N, --size S)")),
        }
    }
    if runs == 0 {
        return Err("--runs: at least 1".into());
    }
    Ok((python, runs, size))
}

/// The median of `values`.
fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

/// Runs the benchmark.
pub fn run(args: &[String]) -> Result<(), String> {
    let (python, runs, size) = parse(args)?;
    let mut spot = wonder3d::load_mesh(workspace_root().join("assets/spot.obj")).map_err(|e| e.to_string())?;
    spot.normalize_unit_cube();
    let views =
        wonder3d::raster::render_oracle_views(&spot, &ViewRig::wonder3d_ortho(), size).map_err(|e| e.to_string())?;
    let views_dir = target_dir().join("bench").join("python_views");
    if views_dir.exists() {
        std::fs::remove_dir_all(&views_dir).map_err(|e| format!("{}: {e}", views_dir.display()))?;
    }
    views.save(&views_dir).map_err(|e| e.to_string())?;
    // Both sides reconstruct from the same files.
    let views = wonder3d::ViewSet::load(&views_dir).map_err(|e| e.to_string())?;

    let mut child = Command::new(&python)
        .args(["-c", PYTHON_DRIVER])
        .arg(&views_dir)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .map_err(|e| format!("cannot start {python}: {e} (pass --python with the wheel installed)"))?;
    let mut stdin = child.stdin.take().expect("piped");
    let mut stdout = BufReader::new(child.stdout.take().expect("piped"));
    let mut line = String::new();
    stdout.read_line(&mut line).map_err(|e| e.to_string())?;
    let package_version = line.trim().to_string();
    if package_version.is_empty() {
        return Err(format!("{python} could not import wonder3d (install the wheel into it)"));
    }

    let pipeline = Pipeline::new().with_preset(Preset::Default).without_texture();
    let (mut rust, mut py) = (Vec::new(), Vec::new());
    // One warm-up call on each side, then alternate.
    for i in 0..=runs {
        let start = Instant::now();
        let output = pipeline.from_views(&views, &mut |_| {}).map_err(|e| e.to_string())?;
        let rust_seconds = start.elapsed().as_secs_f64();
        writeln!(stdin, "run").map_err(|e| e.to_string())?;
        line.clear();
        stdout.read_line(&mut line).map_err(|e| e.to_string())?;
        let mut fields = line.split_whitespace();
        let py_seconds: f64 =
            fields.next().and_then(|s| s.parse().ok()).ok_or_else(|| format!("the Python side printed {line:?}"))?;
        let py_triangles: usize = fields.next().and_then(|s| s.parse().ok()).unwrap_or(0);
        if py_triangles != output.report.triangles {
            return Err(format!("Python made {py_triangles} triangles, Rust {}", output.report.triangles));
        }
        if i > 0 {
            rust.push(rust_seconds);
            py.push(py_seconds);
        }
        eprintln!("run {i}: Rust {rust_seconds:.3} s, Python {py_seconds:.3} s");
    }
    drop(stdin);
    let _ = child.wait();
    let (rust_median, py_median) = (median(&mut rust), median(&mut py));
    let overhead = py_median / rust_median - 1.0;
    // Both sides use rayon's global pool: one thread per core unless RAYON_NUM_THREADS says.
    let threads: usize = std::env::var("RAYON_NUM_THREADS")
        .ok()
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let json = serde_json::json!({
        "what": format!("wonder3d.reconstruct vs Pipeline::from_views, spot {size}² oracle views, default preset"),
        "cpu": cpu_model(),
        "threads": threads,
        "runs": runs,
        "rust_median_s": rust_median,
        "python_median_s": py_median,
        "overhead": overhead,
        "rust_s": rust,
        "python_s": py,
        "python_package": package_version,
        "python": python,
    });
    let out = target_dir().join("bench");
    std::fs::create_dir_all(&out).map_err(|e| e.to_string())?;
    let path = out.join("python.json");
    std::fs::write(&path, serde_json::to_string_pretty(&json).expect("plain data")).map_err(|e| e.to_string())?;
    println!("| side | median of {runs} | over Rust |");
    println!("|---|---|---|");
    println!("| Rust (`Pipeline::from_views`) | {rust_median:.3} s | |");
    println!("| Python (`wonder3d.reconstruct`) | {py_median:.3} s | {:+.2} % |", 100.0 * overhead);
    println!("({}, {threads} threads; {})", cpu_model(), path.display());
    Ok(())
}
