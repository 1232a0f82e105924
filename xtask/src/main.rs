//! `cargo xtask <command>`: project automation that needs more than cargo.
//!
//! - `cargo xtask deny`: runs `cargo deny check licenses bans sources` (advisories need a
//!   network), installing cargo-deny 0.20.2 into `target/tools` first if it is not on `PATH`.
//! - `cargo xtask bench SUITE [-- CRITERION ARGS]`: runs the criterion bench `SUITE` of the
//!   crate `w3d-SUITE` (e.g. `raster`, `remesh`, `eval`), then writes the medians of the
//!   benchmarks it ran to `target/bench/SUITE.json` and prints them as a markdown table for
//!   `docs/benchmarks.md`.
//! - `cargo xtask bench recon [-- --meshes a,b --cases ortho,persp,presets,concave,stability,robustness]`:
//!   the reconstruction accuracy harness (oracle views of `../shared/data/meshes`), writing
//!   `target/bench/recon.json` and, on a full run, `docs/accuracy.md`.
//! - `cargo xtask bench python [-- --python PATH --runs N --size S]`: the Python package's
//!   overhead: `wonder3d.reconstruct` against `Pipeline::from_views` on spot, alternately in
//!   one run (`target/bench/python.json`; the wheel must be installed in that Python).
//! - `cargo xtask chart`: `docs/speed_accuracy.svg` from `target/bench/recon.json`.
//! - `cargo xtask training-chart`: `docs/training_time.svg` (the small model's recipe hours
//!   against its normal error) from the measured points in `docs/training_time.json`.
//! - `cargo xtask faces-chart [--meshes a,b] [--size 512] [--curvature TOL|views:TOL|off]
//!   [--uniform-from JSON]`: `docs/faces_accuracy.svg` and `target/bench/faces.json`, triangles
//!   against Chamfer distance of the refinement's adaptive mesh and of uniform-edge-length
//!   meshes fitted the same way (a `--curvature` variant: `target/bench/faces_variant.json`
//!   only); `--bound`: the share of the uniform triangles the best isotropic sizing needs,
//!   from the true meshes' curvature.
//! - `cargo xtask refine-table [--meshes a,b] [--all] [--size 512] [--edges MIN,MAX]
//!   [--simplify TOL|off] [--curvature TOL|views:TOL|off]`: the refinement loop with
//!   the oracle and identity enhancers on noisy oracle views, `target/bench/refine.json` and the
//!   refinement table of `docs/accuracy.md`; `--all`: the NaN / crossing sweep over every
//!   closed mesh, the teapot and the teacups (`target/bench/refine_all_<size>.json`).
//! - `cargo xtask build-parity`: fails if a dependency of the README's demo build would be
//!   compiled again, with other features, by the test command.
//! - `cargo xtask hostile [--quick] [--filter SUBSTR] [--jobs N] [--list]`: the hostile-input
//!   campaign against every `wonder3d` subcommand (damaged files of every format, bad numbers,
//!   aliased and unwritable outputs, …), each run classified; `target/hostile/report.md` and
//!   `report.json`, failing on any panic, signal, timeout, success on bad input or error
//!   naming nothing (`src/hostile.rs`).
//! - `cargo xtask layers [--root DIR] [--verbose]`: the import-layering check over every
//!   package's `src/` (`crates/*`, `xtask`): fails on a module importing a module declared in a
//!   higher `mod` group of a common ancestor (groups: runs of `mod` lines split by blank or
//!   comment lines, listed bottom-up), on a module importing its ancestor's own file, and on
//!   any import circle between files (`src/layers.rs` has the rules); `--verbose` lists each
//!   crate's files by level.
//! - `cargo xtask package [--verify]`: `cargo package` of every publishable crate in
//!   dependency order (what `cargo publish` would upload); `--verify` also builds each from
//!   its archive (CI runs it without, the full check is run by hand before a release).
//! - `cargo xtask fixtures eval`: regenerates the peer-parity fixtures of `w3d-eval`
//!   (Python: a venv in `target/tools/evalvenv` with trimesh, point-cloud-utils, mesh2sdf,
//!   scikit-image from PyPI). The outputs are committed; tests never need Python.
//! - `cargo xtask fixtures diffusion`: regenerates the parity fixtures of `w3d-diffusion`
//!   (tiny random-weight diffusers / transformers models: `xtask/python/fixtures_diffusion.py`,
//!   then the UniPC, CLIP text, IP-Adapter, ControlNet and whole-enhancer scripts
//!   `fixtures_{unipc,clip_text,ip_adapter,controlnet,enhancer}.py`, in that order)
//! - `cargo xtask fixtures photo`: builds the background-removal composite set (the RGBA
//!   examples of `../shared/data/images` over six backdrops at two scales), scores
//!   `w3d-photo` on it and writes `target/composites/composites.{json,md}` (the tables of
//!   `docs/input.md`); the composites stay in memory, the images may not be redistributed
//!   with the Python named by `W3D_PYTHON`, or a venv in `target/tools/diffusionvenv` with
//!   torch (CPU), diffusers, transformers, safetensors and pillow from PyPI.
//! - `cargo xtask bench diffusion` also times diffusers' UNet on torch CPU (same config and
//!   input, `xtask/python/bench_diffusion_torch.py`) with that Python, and records it and the
//!   burn / torch ratios in `target/bench/diffusion.json`; `cargo xtask bench train` times
//!   one training step of the tiny and the small multi-view UNet on flex and ndarray, and the
//!   same step in PyTorch (`xtask/python/bench_train_torch.py`), with the ratios.
//! - `cargo xtask validate-glb FILE...`: runs the Khronos glTF validator (npm package
//!   `gltf-validator`, installed into `target/tools/node` on first use; needs `node` and
//!   `npm`) and fails if any file has an error.
//! - `cargo xtask load-glb FILE... [--vertices N] [--triangles M]`: loads each file with
//!   three.js' `GLTFLoader` in node (npm package `three`, installed into
//!   `target/tools/node-three` on first use) and fails unless the loaded scene has the
//!   vertex and index counts of the file's accessors (and the given counts), uvs on every
//!   mesh, and a base-colour texture wherever the file has one. Node has no image decoder,
//!   so texture images are checked for being present, not decoded.
//! - `cargo xtask train-small [--out DIR] [--quick] [--resume] [--phase-steps N,…]`, `cargo xtask eval-small [--model DIR] [--objects spot,…] [--sheet PNG]`,
//!   `cargo xtask ship-small [--model DIR]`: the small model's recipe, its scores
//!   (`--sheet docs/img/small_model.png` for the committed picture) and its f16 copy in `assets/model-small`
//!   (`docs/training.md`); `cargo xtask tune-decoder --data DIR --out DIR [--model DIR]
//!   [--steps N] [--lr LR]`: a small model's VAE decoder fine-tuned on its frozen encoder's
//!   latents.
//! - `cargo xtask recon-spread --views DIR|truth --objects spot,… [--seeds N] [--starts K] [--repairs]`:
//!   the spread of one reconstruction's Chamfer distance over remesher seeds, on the views
//!   `eval-small` saved (`docs/accuracy.md`, "Several starts").
//! - `cargo xtask slurm-check [--script-only]`: the Slurm job array of `docs/scale.md`, taken
//!   from the document, run on a one-node Slurm cluster started on loopback (installed with
//!   apt-get when missing; needs root): every item done once, a broken one reported, a
//!   resubmission resumes (`src/slurm.rs`).

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

use clap::{Parser, Subcommand};
use workspace::{cpu_model, run, target_dir, workspace_root};

// Where the workspace is and how commands run; every task below uses it.
mod workspace;

// The tasks.
mod chart;
mod chart_generation;
mod curve;
mod eval_small;
mod faces_chart;
mod gpu;
mod hostile;
mod layers;
mod python_overhead;
mod recon;
mod recon_spread;
mod refine_table;
mod robust;
mod slurm;
mod train_small;
mod training_chart;

#[derive(Parser)]
#[command(about = "wonder3d-rs project automation")]
struct Cli {
    #[command(subcommand)]
    command: Task,
}

#[derive(Subcommand)]
enum Task {
    /// Check licences, duplicate crates and sources with cargo-deny (installed on demand).
    Deny,
    /// Run a criterion suite and collect its medians into target/bench/SUITE.json.
    Bench {
        /// Suite name: the bench target `SUITE` (of the crate `w3d-SUITE`; `train` and `gpu` are
        /// w3d-diffusion's, `gpu` in the wgpu build: `-- --model tiny|small|real --device wgpu|cpu`).
        suite: String,
        /// Extra arguments passed to criterion (e.g. a filter, `--measurement-time 5`).
        #[arg(last = true)]
        criterion_args: Vec<String>,
    },
    /// Check the GPU path (docs/gpu.md): builds the `wgpu` feature in target/wgpu, installs
    /// Mesa's software Vulkan driver (lavapipe) when the machine has no Vulkan driver, runs
    /// the model parity tests on wgpu against flex and the references, `wonder3d generate`
    /// with the small model on wgpu and on the CPU (views compared), and the GPU benchmark on
    /// the tiny checkpoint.
    GpuCheck,
    /// Train the small multi-view model (docs/training.md): dataset, VAE, three UNet stages,
    /// seven joint phases with a cool-down after each but the first, the decoder's fine-tune
    /// beside them (about 2 h 27 min on 2 cores).
    TrainSmall {
        /// Output folder (dataset, stage checkpoints and logs, final model).
        #[arg(long, default_value = "target/train-small")]
        out: PathBuf,
        /// A few steps of each phase only (checks the recipe and times its steps).
        #[arg(long)]
        quick: bool,
        /// Continue the run in `--out`: reuse its training set and VAE, load finished
        /// stages, resume the first unfinished one from its checkpoint (the result is the
        /// uninterrupted run's).
        #[arg(long)]
        resume: bool,
        /// Steps of the UNet phases (stages 1, 2, 3, joint, joint2, cool-down, joint3,
        /// cool-down 2, joint4, cool-down 3, joint5, cool-down 4, joint6, cool-down 5, joint7,
        /// cool-down 6), comma separated, instead of the recipe's; to try a shorter schedule. At least the three stages' counts; 0 leaves
        /// a later phase out, and so does ending the list before it. Recorded in `recipe.json`.
        #[arg(long, value_delimiter = ',')]
        phase_steps: Option<Vec<usize>>,
        /// Passes of the decoder's fine-tune as STEPS:LR, comma separated, instead of the
        /// recipe's `1500:3e-4,4500:2e-4,4500:1e-4` (each pass starts with fresh optimizer moments).
        /// Recorded in `recipe.json`.
        #[arg(long, value_delimiter = ',', value_parser = train_small::parse_decoder_pass)]
        decoder_passes: Option<Vec<(usize, f64)>>,
        /// The UNet's `config.json` instead of the recipe's
        /// (`crates/w3d-diffusion/configs/small/unet-half`), e.g. the full-width
        /// `configs/small/unet/config.json` (docs/training.md). Used when the run starts; a resumed
        /// run keeps its UNet.
        #[arg(long)]
        unet_config: Option<PathBuf>,
    },
    /// Fine-tune the VAE decoder of a small model (encoder frozen, so its UNet keeps
    /// working) on a training set's views on white (docs/training.md, "The decoder").
    TuneDecoder {
        /// Model directory to start from.
        #[arg(long, default_value = "assets/model-small")]
        model: PathBuf,
        /// Training set (a `wonder3d dataset` folder at the model's size).
        #[arg(long)]
        data: PathBuf,
        /// Output model directory (written whole at the end).
        #[arg(long)]
        out: PathBuf,
        /// Optimizer steps (batch 4).
        #[arg(long, default_value_t = 2000)]
        steps: usize,
        /// Learning rate (constant).
        #[arg(long, default_value_t = 3e-4)]
        lr: f64,
    },
    /// How far one reconstruction's Chamfer distance moves with the remesher's seed alone,
    /// on saved views of the small model's objects (docs/accuracy.md, "Several starts").
    ReconSpread {
        /// Folder with one view-set folder per object (as eval-small's --out leaves them), or
        /// `truth` for the true views of the same samples.
        #[arg(long)]
        views: PathBuf,
        /// Objects, comma-separated (spot, bob_tri, boot, hammer, wingnut, plane,
        /// koala_low_resolution, torus).
        #[arg(long)]
        objects: String,
        /// Remesher seeds tried, 0..seeds.
        #[arg(long, default_value_t = 8)]
        seeds: u64,
        /// Fits per reconstruction (ReconOptions::starts).
        #[arg(long, default_value_t = 1)]
        starts: usize,
        /// The remesher's repairs on from the first coarse run (CoarseOptions::remesh_repairs).
        #[arg(long)]
        repairs: bool,
    },
    /// Put a trained model into assets/model-small with f16 weights (the model the
    /// repository ships; provenance in assets/model-small.md).
    ShipSmall {
        /// Model directory (f32, as train-small writes it).
        #[arg(long, default_value = "target/train-small/model")]
        model: PathBuf,
    },
    /// The speed–quality chart of generation's training-free accelerations
    /// (`docs/generation_speed_quality.svg`, the table of `docs/benchmarks.md`, "Training-free
    /// acceleration"): real-size step timings with random weights, and the shipped small
    /// model's scores on its 7 training objects per setting. Results in
    /// `target/chart-generation/`; the timing part takes about 6 min, the quality part about
    /// 4 min per setting and guidance on 2 cores.
    ChartGeneration {
        /// Which part: `timing`, `quality`, `chart` or `all`.
        #[arg(long, default_value = "all")]
        part: String,
        /// Only these settings of the quality part (comma-separated names; default: all).
        #[arg(long)]
        settings: Option<String>,
        /// Guidance scales of the quality part (comma-separated).
        #[arg(long, default_value = "2,1", value_delimiter = ',')]
        guidance: Vec<f64>,
        /// The model the quality part scores.
        #[arg(long, default_value = "assets/model-small")]
        model: PathBuf,
    },
    /// Score the small model: generated views and reconstructed meshes of training objects
    /// and the held-out one against the truth, with a contact sheet of them.
    EvalSmall {
        /// Model directory.
        #[arg(long, default_value = "target/train-small/model")]
        model: PathBuf,
        /// Output folder (generated views, meshes, eval.json).
        #[arg(long, default_value = "target/eval-small")]
        out: PathBuf,
        /// Sampling steps.
        #[arg(long, default_value_t = 50)]
        steps: usize,
        /// Sampler: ddim, dpmpp-2m or unipc.
        #[arg(long, default_value = "ddim")]
        sampler: String,
        /// Classifier-free guidance scale [default: 1, as `wonder3d demo --from-image` samples
        /// the small model (`wonder3d::demo::small_model_sampling`); the authors' is 2].
        #[arg(long)]
        guidance: Option<f64>,
        /// DDIM eta (0 deterministic, 1 the authors' stochastic sampling, as `wonder3d demo
        /// --from-image` samples).
        #[arg(long, default_value_t = 1.0)]
        eta: f64,
        /// Initial noise independent per domain (as in training) instead of one latent per
        /// view shared by both domains (the authors' inference).
        #[arg(long)]
        independent_noise: bool,
        /// Draws merged into their consensus (`SampleOptions::draws`; seeds 42, 43, …)
        /// [default: 4, as the demo samples the small model; 1 with `--independent-noise`].
        #[arg(long)]
        draws: Option<usize>,
        /// Only these objects (comma-separated file stems, e.g. `spot,koala`; default: every
        /// training object, then the held-out one).
        #[arg(long)]
        objects: Option<String>,
        /// Contact sheet to write, relative to the workspace root (default: `small_model.png`
        /// in the output folder; the committed picture is `--sheet docs/img/small_model.png`,
        /// written only when asked so that a sweep of sampling settings cannot replace it).
        #[arg(long)]
        sheet: Option<PathBuf>,
        /// The training set the model was trained on: also measure how much its denoising
        /// uses the condition (x₀ error with its own, another's and no condition).
        #[arg(long)]
        data: Option<PathBuf>,
    },
    /// The refinement loop with the oracle and identity enhancers on noisy 128² oracle views
    /// (five objects, both rigs): target/bench/refine.json and the table of docs/accuracy.md.
    RefineTable {
        /// Only these objects (comma-separated: spot, armadillo, koala, horse, plane; with
        /// `--all`, file stems of the sweep's meshes).
        #[arg(long)]
        meshes: Option<String>,
        /// The robustness sweep: every closed mesh, the teapot and the teacups, both rigs,
        /// oracle 2 iterations and identity 1, checked for NaN, crossings and watertightness
        /// (`target/bench/refine_all_<size>.json`).
        #[arg(long)]
        all: bool,
        /// With `--all`: only this rig (`ortho` or `persp`).
        #[arg(long)]
        rig: Option<String>,
        /// Side of the enhanced views in pixels.
        #[arg(long, default_value_t = 512)]
        size: u32,
        /// Laplacian weight of the mesh refinement (default: `w3d_recon::RefineOptions`'s).
        #[arg(long)]
        laplacian: Option<f32>,
        /// Learning rate of the mesh refinement (default: `w3d_recon::RefineOptions`'s).
        #[arg(long)]
        lr: Option<f32>,
        /// Edge-length limits `MIN,MAX` of the mesh refinement (default:
        /// `w3d_recon::RefineOptions`'s).
        #[arg(long, value_delimiter = ',')]
        edges: Option<Vec<f32>>,
        /// Simplification tolerance of the mesh refinement, or `off` (default:
        /// `w3d_recon::RefineOptions`'s).
        #[arg(long)]
        simplify: Option<String>,
        /// Curvature tolerance of the mesh refinement's edge lengths, or `off` (default:
        /// `w3d_recon::RefineOptions`'s).
        #[arg(long)]
        curvature: Option<String>,
    },
    /// Regenerate committed test fixtures with the Python peer tools.
    Fixtures {
        /// Which fixtures: `eval`, `diffusion` or `photo`.
        which: String,
    },
    /// Draw the SVG charts in docs/ (speed against accuracy) from target/bench/*.json.
    Chart,
    /// The small model's recipe wall time against its normal error on the scored objects:
    /// docs/training_time.svg from the measured points in docs/training_time.json.
    TrainingChart,
    /// Triangles against Chamfer distance of the refined (adaptive, simplified) mesh and of
    /// uniform-edge meshes fitted the same way (five objects, oracle enhancer):
    /// target/bench/faces.json and docs/faces_accuracy.svg.
    FacesChart {
        /// Only these objects (comma-separated: spot, armadillo, koala, horse, plane).
        #[arg(long)]
        meshes: Option<String>,
        /// Side of the enhanced views in pixels.
        #[arg(long, default_value_t = 512)]
        size: u32,
        /// Redraw the chart and the table from target/bench/faces.json instead of measuring.
        #[arg(long)]
        replot: bool,
        /// A variant of the refinement's curvature bound (as `refine-table --curvature`:
        /// TOL, `views:TOL` or `off`): measured into target/bench/faces_variant.json, the
        /// chart in docs/ left as it is.
        #[arg(long)]
        curvature: Option<String>,
        /// Take the uniform meshes' points from this earlier faces JSON instead of fitting
        /// them again (they do not depend on the curvature bound: their edge limits are
        /// pinned to one length).
        #[arg(long)]
        uniform_from: Option<std::path::PathBuf>,
        /// Print, per object, the share of a uniform mesh's triangles the best isotropic
        /// sizing needs at equal mean error, from the true meshes' curvature (no fitting).
        #[arg(long)]
        bound: bool,
    },
    /// Check that every dependency the README's demo command compiles is compiled with the
    /// same features by the test command (so the tests reuse it instead of rebuilding it).
    BuildParity,
    /// Drive every `wonder3d` subcommand with hostile input (issue #63, docs/robustness.md):
    /// each run classified (panic, signal, timeout, success on bad input, error naming
    /// nothing, …) into target/hostile/report.{md,json}; fails unless every case is ok.
    Hostile(hostile::Options),
    /// Check the import layering of every package's `src/`: no module imports one declared in
    /// a higher `mod` group, or its ancestor's file, and no files import each other in a circle.
    Layers {
        /// The checkout to check (default: this repository).
        #[arg(long)]
        root: Option<PathBuf>,
        /// Also list each crate's files by level (level 0 imports nothing of its crate).
        #[arg(long)]
        verbose: bool,
    },
    /// Package every publishable crate in dependency order (`cargo package --workspace`),
    /// as `cargo publish` would; `--verify` also builds each packaged crate from its archive.
    Package {
        /// Build every packaged crate from its `.crate` archive (a cold build of all
        /// dependencies, Burn included, in `target/package`: about 15 minutes on 2 cores).
        #[arg(long)]
        verify: bool,
    },
    /// Validate GLB / glTF files with the Khronos glTF validator (installed on demand).
    ValidateGlb {
        /// Files to validate.
        #[arg(required = true)]
        files: Vec<PathBuf>,
    },
    /// Load GLB files with three.js' GLTFLoader in node and check their counts.
    LoadGlb {
        /// Files to load.
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// Expected vertex count of every file.
        #[arg(long)]
        vertices: Option<usize>,
        /// Expected triangle count of every file.
        #[arg(long)]
        triangles: Option<usize>,
    },
    /// Run the Slurm job array of docs/scale.md on a one-node Slurm cluster started here on
    /// loopback (Slurm installed with apt-get when missing; needs root): six view folders, one
    /// broken, over three array tasks, then resubmitted to check that it resumes.
    SlurmCheck {
        /// Only print the script as it would be submitted here and its differences from the
        /// documented one (no Slurm, no root).
        #[arg(long)]
        script_only: bool,
    },
}

/// `cargo-deny` from `PATH`, if it runs.
fn cargo_deny_on_path() -> Option<PathBuf> {
    let ok = Command::new("cargo-deny").arg("--version").output().is_ok_and(|o| o.status.success());
    ok.then(|| PathBuf::from("cargo-deny"))
}

fn deny() -> Result<(), String> {
    let root = workspace_root();
    let tools = root.join("target").join("tools");
    let bin = cargo_deny_on_path().unwrap_or_else(|| tools.join("bin").join("cargo-deny"));
    if bin.is_absolute() && !bin.is_file() {
        eprintln!("installing cargo-deny 0.20.2 into {}", tools.display());
        run(Command::new("cargo")
            .args(["install", "--locked", "--version", "0.20.2", "--root"])
            .arg(&tools)
            .arg("cargo-deny"))?;
    }
    run(Command::new(&bin).current_dir(&root).args([
        "deny",
        "check",
        "--hide-inclusion-graph",
        "licenses",
        "bans",
        "sources",
    ]))
}

/// Every `new/estimates.json` under `dir` written after `since`, with its benchmark id.
fn fresh_estimates(dir: &Path, since: std::time::SystemTime, out: &mut Vec<(String, PathBuf)>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            fresh_estimates(&path, since, out);
        } else if path.ends_with("new/estimates.json")
            && entry.metadata().and_then(|m| m.modified()).is_ok_and(|t| t >= since)
        {
            let bench = path.with_file_name("benchmark.json");
            let id = std::fs::read_to_string(&bench)
                .ok()
                .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
                .and_then(|v| v["full_id"].as_str().map(String::from))
                .unwrap_or_else(|| path.display().to_string());
            out.push((id, path));
        }
    }
}

/// The UNet forward rows of the diffusion suite as GFLOP/s and as a fraction of the f32 GEMM
/// peak measured now on this machine (`xtask/python/unet_flops.py`: the forward's FLOPs by
/// torch's counter, `torch.mm` at 2048²–4096²), added to `rows` (issue #20, item 6).
fn gemm_fraction(rows: &mut Vec<serde_json::Value>) -> Result<(), String> {
    let script = "xtask/python/unet_flops.py";
    let v = python_json(script)?.pop().expect("python_json returns at least one object");
    let gflop = v["unet_forward_gflop"].as_f64().ok_or(format!("{script}: no unet_forward_gflop"))?;
    let peak = v["sgemm_gflops"]
        .as_object()
        .and_then(|m| m.values().filter_map(|x| x.as_f64()).reduce(f64::max))
        .ok_or(format!("{script}: no sgemm_gflops"))?;
    let forwards: Vec<(String, f64)> = rows
        .iter()
        .filter_map(|r| {
            let id = r["id"].as_str()?;
            (id.starts_with("unet_forward_b2_32x32/") && !id.contains(" / "))
                .then_some((id.to_string(), r["median_ms"].as_f64()?))
        })
        .collect();
    println!("UNet forward: {gflop:.1} GFLOP; f32 GEMM peak on this machine {peak:.0} GFLOP/s");
    rows.push(serde_json::json!({ "id": "sgemm_peak", "gflops": peak, "unet_forward_gflop": gflop, "torch": v }));
    for (id, ms) in forwards {
        let gflops = gflop / (ms / 1e3);
        println!("{id}: {gflops:.0} GFLOP/s = {:.2} of the GEMM peak", gflops / peak);
        rows.push(serde_json::json!({ "id": format!("{id} / sgemm peak"), "ratio": gflops / peak, "gflops": gflops }));
    }
    Ok(())
}

/// Runs the peer script `script` (relative to the workspace root, which it gets as its
/// argument) with the torch + diffusers Python and returns every JSON object it printed, one
/// per line (at least one).
fn python_json(script: &str) -> Result<Vec<serde_json::Value>, String> {
    let root = workspace_root();
    let output = Command::new(diffusion_python()?)
        .current_dir(&root)
        .arg(script)
        .arg(&root)
        .output()
        .map_err(|e| format!("cannot run the peer script {script}: {e}"))?;
    if !output.status.success() {
        return Err(format!("peer script {script} failed: {}", String::from_utf8_lossy(&output.stderr)));
    }
    let stdout = String::from_utf8_lossy(&output.stdout);
    let results: Vec<serde_json::Value> =
        stdout.lines().filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok()).collect();
    if results.is_empty() {
        return Err(format!("peer script {script} printed no JSON: {stdout}"));
    }
    Ok(results)
}

/// Runs `script` (torch CPU, the same work as a burn benchmark suite) and adds each of its
/// JSON result lines, plus the burn / torch ratio of every burn row of the same benchmark
/// (`<group>/<backend>` against `<group>/torch`), to `rows`.
fn torch_comparison(script: &str, rows: &mut Vec<serde_json::Value>) -> Result<(), String> {
    for torch in python_json(script)? {
        let id = torch["id"].as_str().ok_or("torch benchmark: no id")?.to_string();
        let torch_ms = torch["median_ms"].as_f64().ok_or("torch benchmark: no median_ms")?;
        let group = id.strip_suffix("/torch").ok_or("torch benchmark: an id ending in /torch")?.to_string();
        let ratios: Vec<serde_json::Value> = rows
            .iter()
            .filter(|r| r["id"].as_str().is_some_and(|i| i.strip_prefix(&group).is_some_and(|b| b.starts_with('/'))))
            .filter_map(|r| {
                let ms = r["median_ms"].as_f64()?;
                Some(serde_json::json!({ "id": format!("{} / torch", r["id"].as_str()?), "ratio": ms / torch_ms }))
            })
            .collect();
        rows.push(serde_json::json!({ "id": id, "median_ms": torch_ms, "mean_ms": null, "torch": torch }));
        for r in ratios {
            println!("{}: {:.2}", r["id"].as_str().unwrap_or(""), r["ratio"].as_f64().unwrap_or(f64::NAN));
            rows.push(r);
        }
    }
    Ok(())
}

fn bench(suite: &str, criterion_args: &[String]) -> Result<(), String> {
    if suite == "recon" {
        return recon::run(criterion_args);
    }
    if suite == "gpu" {
        return gpu::bench(criterion_args);
    }
    if suite == "python" {
        return python_overhead::run(criterion_args);
    }
    let start = std::time::SystemTime::now();
    let mut cmd = Command::new("cargo");
    // `--workspace` resolves features as the test command does, so the bench reuses its builds.
    cmd.current_dir(workspace_root()).args(["bench", "--workspace", "--bench", suite, "--"]).args(criterion_args);
    run(&mut cmd)?;
    let mut found = Vec::new();
    fresh_estimates(&target_dir().join("criterion"), start, &mut found);
    found.sort();
    let mut rows = Vec::new();
    for (id, path) in &found {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
        let ms = |k: &str| v[k]["point_estimate"].as_f64().map(|ns| ns / 1e6);
        rows.push(serde_json::json!({ "id": id, "median_ms": ms("median"), "mean_ms": ms("mean") }));
    }
    match suite {
        "diffusion" => {
            torch_comparison("xtask/python/bench_diffusion_torch.py", &mut rows)?;
            gemm_fraction(&mut rows)?;
        }
        "train" => torch_comparison("xtask/python/bench_train_torch.py", &mut rows)?,
        _ => {}
    }
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let report = serde_json::json!({
        "suite": suite,
        "command": format!("cargo xtask bench {suite} {}", criterion_args.join(" ")).trim_end().to_string(),
        "machine": { "cpu": cpu_model(), "cores": cores },
        "results": rows,
    });
    let out_dir = target_dir().join("bench");
    std::fs::create_dir_all(&out_dir).map_err(|e| format!("{}: {e}", out_dir.display()))?;
    let out = out_dir.join(format!("{suite}.json"));
    std::fs::write(&out, serde_json::to_string_pretty(&report).expect("json"))
        .map_err(|e| format!("{}: {e}", out.display()))?;
    println!("\n{} ({} cores), `{}`\n", cpu_model(), cores, report["command"].as_str().unwrap_or(""));
    println!("| benchmark | median (ms) |\n|---|---|");
    for r in &rows {
        match (r["median_ms"].as_f64(), r["ratio"].as_f64()) {
            (Some(ms), _) => println!("| {} | {ms:.3} |", r["id"].as_str().unwrap_or("")),
            (None, Some(ratio)) => println!("| {} | ratio {ratio:.2} |", r["id"].as_str().unwrap_or("")),
            (None, None) => {}
        }
    }
    println!("\nwrote {}", out.display());
    Ok(())
}

/// `(package, features)` pairs that `cargo tree ARGS` resolves, one per built unit: a
/// dependency built for the host and for the target with different features appears twice.
fn resolved_units(args: &[&str]) -> Result<std::collections::BTreeSet<(String, String)>, String> {
    let out = Command::new("cargo")
        .current_dir(workspace_root())
        .arg("tree")
        .args(args)
        .args(["-f", "{p}|{f}", "--prefix", "none"])
        .output()
        .map_err(|e| format!("cannot run cargo tree: {e}"))?;
    if !out.status.success() {
        return Err(format!("cargo tree {args:?} failed: {}", String::from_utf8_lossy(&out.stderr)));
    }
    Ok(String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.split_once('|'))
        // Workspace crates print their path (`name v0.1.0 (/path)`): they are rebuilt by
        // design when the facade gains the diffusion feature.
        .filter(|(p, _)| !p.contains('('))
        .map(|(p, f)| (p.trim().to_string(), f.trim_end_matches(" (*)").trim().to_string()))
        .collect())
}

/// The demo build (`wonder3d-cli --no-default-features`) must be a subset of the test build
/// (`--workspace` with dev-dependencies), unit by unit: otherwise the test command compiles
/// that dependency again and everything that depends on it. The CLI's manifest lists the
/// features Burn adds to shared dependencies ("build parity"); this finds a missing one.
fn build_parity() -> Result<(), String> {
    let tests = resolved_units(&["--workspace", "-e", "normal,build,dev"])?;
    let mut missing = 0;
    for (what, args) in [
        ("the README's demo command", &["-p", "wonder3d-cli", "--no-default-features", "-e", "normal,build"][..]),
        ("`cargo xtask`", &["-p", "xtask", "-e", "normal,build"][..]),
        ("the Python wheel (maturin)", &["-p", "wonder3d-py", "-e", "normal,build"][..]),
    ] {
        let units = resolved_units(args)?;
        let before = missing;
        for (package, features) in units.difference(&tests) {
            let test_features: Vec<&str> =
                tests.iter().filter(|(p, _)| p == package).map(|(_, f)| f.as_str()).collect();
            eprintln!("{what}: {package} with [{features}], the tests with {test_features:?}");
            missing += 1;
        }
        if missing == before {
            println!("build parity: {what} builds {} dependency units, all reused by the test command", units.len());
        }
    }
    if missing == 0 {
        Ok(())
    } else {
        Err(format!(
            "{missing} dependency builds differ from the test build: add the features above to the \
             build-parity list in crates/wonder3d-cli/Cargo.toml, xtask/Cargo.toml or \
             crates/wonder3d-py/Cargo.toml"
        ))
    }
}

/// The workspace members that are not published (their manifests say `publish = false`).
/// The Python package's crate is published to PyPI as a wheel, not to crates.io.
const UNPUBLISHED: &[&str] = &["wonder3d-examples", "wonder3d-py", "wonder3d-tests", "xtask"];

/// `cargo package` for every publishable crate, in dependency order: cargo resolves the
/// crates' dependencies on each other through a local registry of the archives it just
/// made, so this checks what `cargo publish` would upload (manifests, readmes, included
/// files, versioned path dependencies) before anything is on crates.io.
fn package(verify: bool) -> Result<(), String> {
    let mut cmd = Command::new("cargo");
    cmd.current_dir(workspace_root()).args(["package", "--workspace", "--allow-dirty", "--quiet"]);
    for name in UNPUBLISHED {
        cmd.args(["--exclude", name]);
    }
    if !verify {
        cmd.arg("--no-verify");
    }
    run(&mut cmd)?;
    let dir = target_dir().join("package");
    let mut crates: Vec<String> = std::fs::read_dir(&dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok())
        .filter_map(|e| e.file_name().into_string().ok())
        .filter(|n| n.ends_with(".crate"))
        .collect();
    crates.sort();
    for name in &crates {
        let size = std::fs::metadata(dir.join(name)).map(|m| m.len()).unwrap_or(0);
        println!("{name}: {:.1} KiB", size as f64 / 1024.0);
        if size > 10 * 1024 * 1024 {
            return Err(format!("{name} is over crates.io's 10 MiB limit"));
        }
    }
    println!("packaged {} crates{}", crates.len(), if verify { " and built each from its archive" } else { "" });
    Ok(())
}

/// Python packages the eval fixture script needs.
const EVAL_FIXTURE_PACKAGES: &[&str] =
    &["numpy", "scipy", "pillow", "trimesh", "point-cloud-utils", "mesh2sdf", "scikit-image"];

/// Python packages of the diffusion fixtures and the torch benchmark.
const DIFFUSION_PACKAGES: &[&str] = &["torch", "diffusers", "transformers", "safetensors", "pillow", "numpy"];

/// The Python with torch + diffusers: `W3D_PYTHON`, or a venv under `target/tools` (created on
/// first use; torch from the CPU wheel index when reachable, else PyPI).
fn diffusion_python() -> Result<PathBuf, String> {
    if let Some(python) = std::env::var_os("W3D_PYTHON") {
        return Ok(PathBuf::from(python));
    }
    let venv = workspace_root().join("target").join("tools").join("diffusionvenv");
    let python = venv.join("bin").join("python");
    if !python.is_file() {
        run(Command::new("python3").args(["-m", "venv"]).arg(&venv))?;
        let cpu_torch = run(Command::new(&python).args([
            "-m",
            "pip",
            "install",
            "--quiet",
            "torch",
            "--index-url",
            "https://download.pytorch.org/whl/cpu",
        ]));
        if cpu_torch.is_err() {
            eprintln!("CPU torch wheel index unreachable; installing torch from PyPI");
        }
        run(Command::new(&python).args(["-m", "pip", "install", "--quiet"]).args(DIFFUSION_PACKAGES))?;
    }
    Ok(python)
}

fn fixtures(which: &str) -> Result<(), String> {
    if which == "photo" {
        // `--workspace` resolves features as the test build does, so nothing is rebuilt.
        let root = workspace_root();
        run(Command::new("cargo").current_dir(&root).args([
            "build",
            "--release",
            "--workspace",
            "--example",
            "composites",
        ]))?;
        return run(Command::new(target_dir().join("release").join("examples").join("composites"))
            .current_dir(&root)
            .arg(root.join("..").join("shared").join("data").join("images"))
            .arg(target_dir().join("composites")));
    }
    if which == "diffusion" {
        let root = workspace_root();
        let python = diffusion_python()?;
        // The enhancer's fixture reuses the clip_text fixture's tokenizer and text encoder and
        // the ControlNet script's joint attention, so it runs last.
        for script in ["diffusion", "unipc", "clip_text", "ip_adapter", "controlnet", "enhancer"] {
            run(Command::new(&python).current_dir(&root).arg(format!("xtask/python/fixtures_{script}.py")))?;
        }
        return Ok(());
    }
    if which != "eval" {
        return Err(format!("unknown fixture set {which:?}; expected `eval`, `diffusion` or `photo`"));
    }
    let root = workspace_root();
    let venv = root.join("target").join("tools").join("evalvenv");
    let python = venv.join("bin").join("python");
    if !python.is_file() {
        run(Command::new("python3").args(["-m", "venv"]).arg(&venv))?;
        run(Command::new(&python).args(["-m", "pip", "install", "--quiet"]).args(EVAL_FIXTURE_PACKAGES))?;
    }
    run(Command::new(&python).current_dir(&root).arg("crates/w3d-eval/fixtures/make_fixtures.py"))
}

/// The pinned validator release and the script that runs it on each file.
const GLTF_VALIDATOR: &str = "gltf-validator@2.0.0-dev.3.10";
const VALIDATE_SCRIPT: &str = r#"import validator from 'gltf-validator';
import fs from 'fs';
let failed = false;
for (const f of process.argv.slice(2)) {
  const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(f)));
  const i = report.issues;
  console.log(`${f}: ${i.numErrors} errors, ${i.numWarnings} warnings, ${i.numInfos} infos`);
  for (const m of i.messages.filter((m) => m.severity <= 1)) console.log(`  ${m.code}: ${m.message} ${m.pointer ?? ''}`);
  if (i.numErrors > 0) failed = true;
}
process.exit(failed ? 1 : 0);
"#;

fn validate_glb(files: &[PathBuf]) -> Result<(), String> {
    let dir = workspace_root().join("target").join("tools").join("node");
    if !dir.join("node_modules").join("gltf-validator").is_dir() {
        std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        eprintln!("installing {GLTF_VALIDATOR} into {}", dir.display());
        run(Command::new("npm").args(["install", "--silent", "--no-save", "--prefix"]).arg(&dir).arg(GLTF_VALIDATOR))?;
    }
    let script = dir.join("validate.mjs");
    std::fs::write(&script, VALIDATE_SCRIPT).map_err(|e| format!("{}: {e}", script.display()))?;
    let files: Vec<PathBuf> = files.iter().map(|f| std::path::absolute(f).unwrap_or_else(|_| f.clone())).collect();
    run(Command::new("node").current_dir(&dir).arg(&script).args(&files))
}

/// The pinned three.js release and the script that loads each file with its GLTFLoader.
const THREE: &str = "three@0.180.0";
const LOAD_SCRIPT: &str = r#"import fs from 'fs';
// GLTFLoader reads `self.URL`; node has no DOM image decoder, so images resolve to a stub
// (their presence is checked, not their pixels: the Khronos validator checks the PNG).
globalThis.self = globalThis;
const THREE = await import('three');
const { GLTFLoader } = await import('three/examples/jsm/loaders/GLTFLoader.js');
THREE.ImageLoader.prototype.load = function (url, onLoad) {
  const image = { width: 1, height: 1, src: url };
  setTimeout(() => onLoad && onLoad(image), 0);
  return image;
};
const args = process.argv.slice(2);
const [expectVertices, expectTriangles, ...files] = args;
let failed = false;
for (const f of files) {
  let json, gltf;
  let fileVertices = 0, fileIndices = 0;
  try {
    const buf = fs.readFileSync(f);
    if (buf.toString('latin1', 0, 4) !== 'glTF') throw new Error('not a GLB file');
    json = JSON.parse(buf.subarray(20, 20 + buf.readUInt32LE(12)).toString());
    for (const m of json.meshes) for (const p of m.primitives) {
      fileVertices += json.accessors[p.attributes.POSITION].count;
      fileIndices += json.accessors[p.indices].count;
    }
    const data = buf.buffer.slice(buf.byteOffset, buf.byteOffset + buf.byteLength);
    gltf = await new Promise((resolve, reject) => new GLTFLoader().parse(data, '', resolve, reject));
  } catch (e) {
    console.log(`${f}: not loaded: ${e.message ?? e}`);
    failed = true;
    continue;
  }
  let vertices = 0, indices = 0, meshes = 0, uv = true, textured = false;
  gltf.scene.traverse((o) => {
    if (!o.isMesh) return;
    meshes += 1;
    vertices += o.geometry.attributes.position.count;
    indices += o.geometry.index ? o.geometry.index.count : 0;
    uv = uv && !!o.geometry.attributes.uv;
    textured = textured || !!(o.material && o.material.map);
  });
  const wantTexture = (json.textures ?? []).length > 0;
  const problems = [];
  if (meshes === 0) problems.push('no meshes');
  if (vertices !== fileVertices || indices !== fileIndices) problems.push(`file has ${fileVertices} vertices / ${fileIndices} indices`);
  if (expectVertices !== '-' && vertices !== Number(expectVertices)) problems.push(`expected ${expectVertices} vertices`);
  if (expectTriangles !== '-' && indices !== 3 * Number(expectTriangles)) problems.push(`expected ${expectTriangles} triangles`);
  if (wantTexture && !(uv && textured)) problems.push('texture or uvs not loaded');
  console.log(`${f}: ${meshes} meshes, ${vertices} vertices, ${indices / 3} triangles, uv ${uv}, texture ${textured}${problems.length ? ' -- ' + problems.join('; ') : ''}`);
  if (problems.length) failed = true;
}
process.exit(failed ? 1 : 0);
"#;

fn load_glb(files: &[PathBuf], vertices: Option<usize>, triangles: Option<usize>) -> Result<(), String> {
    let dir = workspace_root().join("target").join("tools").join("node-three");
    if !dir.join("node_modules").join("three").is_dir() {
        std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        eprintln!("installing {THREE} into {}", dir.display());
        run(Command::new("npm").args(["install", "--silent", "--no-save", "--prefix"]).arg(&dir).arg(THREE))?;
    }
    let script = dir.join("load.mjs");
    std::fs::write(&script, LOAD_SCRIPT).map_err(|e| format!("{}: {e}", script.display()))?;
    let count = |n: Option<usize>| n.map_or_else(|| "-".to_string(), |n| n.to_string());
    let files: Vec<PathBuf> = files.iter().map(|f| std::path::absolute(f).unwrap_or_else(|_| f.clone())).collect();
    run(Command::new("node").current_dir(&dir).arg(&script).arg(count(vertices)).arg(count(triangles)).args(&files))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Task::Deny => deny(),
        Task::GpuCheck => gpu::check(),
        Task::Chart => chart::run(),
        Task::TrainingChart => training_chart::run(),
        Task::FacesChart { meshes, size, replot, curvature, uniform_from, bound } => {
            if bound {
                faces_chart::bound()
            } else if replot {
                faces_chart::replot()
            } else {
                faces_chart::run(meshes.as_deref(), size, curvature.as_deref(), uniform_from.as_deref())
            }
        }
        Task::Package { verify } => package(verify),
        Task::BuildParity => build_parity(),
        Task::Hostile(options) => hostile::run(&options),
        Task::Layers { root, verbose } => layers::run(&root.unwrap_or_else(workspace_root), verbose),
        Task::ValidateGlb { files } => validate_glb(&files),
        Task::LoadGlb { files, vertices, triangles } => load_glb(&files, vertices, triangles),
        Task::SlurmCheck { script_only } => slurm::run(script_only),
        Task::Fixtures { which } => fixtures(&which),
        Task::TrainSmall { out, quick, resume, phase_steps, decoder_passes, unet_config } => {
            let overrides = train_small::Overrides { phase_steps, decoder_passes, unet_config };
            train_small::run(&out, quick, resume, &overrides)
        }
        Task::ChartGeneration { part, settings, guidance, model } => {
            chart_generation::run(&part, settings.as_deref(), &guidance, &model)
        }
        Task::EvalSmall {
            model,
            out,
            steps,
            sampler,
            guidance,
            eta,
            independent_noise,
            draws,
            objects,
            sheet,
            data,
        } => {
            let demo = wonder3d::demo::small_model_sampling();
            let sampling = eval_small::Sampling {
                sampler,
                steps,
                guidance: guidance.unwrap_or(demo.guidance),
                eta,
                independent_noise,
                draws: draws.unwrap_or(if independent_noise { 1 } else { demo.draws }),
            };
            eval_small::run(&model, &out, &sampling, objects.as_deref(), sheet.as_deref(), data.as_deref())
        }
        Task::ReconSpread { views, objects, seeds, starts, repairs } => {
            recon_spread::run(&views, &objects, seeds, starts, repairs)
        }
        Task::ShipSmall { model } => train_small::ship(&model),
        Task::TuneDecoder { model, data, out, steps, lr } => {
            train_small::tune_decoder_command(&model, &data, &out, steps, lr)
        }
        Task::Bench { suite, criterion_args } => bench(&suite, &criterion_args),
        Task::RefineTable { meshes, all, rig, size, laplacian, lr, edges, simplify, curvature } => {
            refine_table::mesh_options(laplacian, lr, edges.as_deref(), simplify.as_deref(), curvature.as_deref())
                .and_then(|mesh| refine_table::run(meshes.as_deref(), all, rig.as_deref(), size, mesh))
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xtask: {e}");
            ExitCode::FAILURE
        }
    }
}
