//! `cargo xtask refine-table [--meshes a,b] [--size 512]`: the refinement loop
//! (`wonder3d::refine`) measured with the oracle and the identity enhancer, the table of
//! `docs/accuracy.md` ("Refinement").
//!
//! Per object and rig (orthographic and perspective): oracle views at 128² with Gaussian
//! normal noise σ = 0.05 (so the coarse mesh has something to gain), the default pipeline
//! (reconstruction and texture), then refinement with the oracle enhancer (renders of the
//! true mesh: the best an enhancer could do) for one and for two iterations, and with the
//! identity enhancer for one. Scores: Chamfer distance against the truth, mean PSNR of the
//! 16 SyncDreamer views at 256² (composited over white), triangles and seconds. Meshes
//! without colours get `wonder3d::dataset::procedural_colours`; spot is the bundled,
//! textured one. Writes `target/bench/refine.json` and prints the markdown table.

use std::path::Path;
use std::time::Instant;

use serde_json::{Value, json};
use wonder3d::eval::{EvalOptions, evaluate};
use wonder3d::raster::render_oracle_views;
use wonder3d::refine::{Enhancer, IdentityEnhancer, OracleEnhancer, RefineOptions, refine};
use wonder3d::{Mesh, Pipeline, ViewRig, ViewSet};

use crate::recon::{load_normalised, novel_view_fidelity, with_normal_noise};

/// The objects of the acceptance: (name, file in `../shared/data/meshes`; spot is bundled).
const OBJECTS: [(&str, &str); 5] = [
    ("spot", ""),
    ("armadillo", "armadillo.obj"),
    ("koala", "koala_low_resolution.obj"),
    ("horse", "horse.ply"),
    ("plane", "plane.obj"),
];

/// Side of the noisy input views.
const INPUT_SIZE: u32 = 128;
/// Normal noise of the input views.
const SIGMA: f32 = 0.05;

fn truth(name: &str, file: &str) -> Result<Mesh, String> {
    if file.is_empty() {
        return wonder3d::demo::bundled_spot().map_err(|e| e.to_string());
    }
    let dir = crate::workspace_root().join("../shared/data/meshes");
    let mesh = load_normalised(&dir, file)?;
    let colours = wonder3d::dataset::procedural_colours(mesh.positions(), name);
    mesh.with_colours(colours).map_err(|e| e.to_string())
}

/// Chamfer distance, novel-view PSNR and triangles of `mesh` (textured) / `geometry`.
fn scores(truth: &Mesh, geometry: &Mesh, textured: &Mesh) -> Result<Value, String> {
    let cd = evaluate(geometry, truth, &EvalOptions::default()).map_err(|e| e.to_string())?.chamfer;
    let (psnr, ssim) = novel_view_fidelity(truth, textured, 256)?;
    Ok(json!({ "chamfer": cd, "psnr": psnr, "ssim": ssim, "triangles": geometry.triangle_count() }))
}

fn refined(
    truth: &Mesh,
    geometry: &Mesh,
    views: &ViewSet,
    enhancer: &dyn Enhancer,
    options: &RefineOptions,
) -> Result<Value, String> {
    let t = Instant::now();
    let out = refine(geometry, views, enhancer, options, &mut |_| {}).map_err(|e| e.to_string())?;
    let seconds = t.elapsed().as_secs_f64();
    let crossings = out.geometry.self_intersections().len();
    let watertight = out.geometry.topology().is_watertight();
    let mut row = scores(truth, &out.geometry, &out.mesh)?;
    row["seconds"] = json!(seconds);
    row["crossings"] = json!(crossings);
    row["watertight"] = json!(watertight);
    row["fit_seconds"] = json!(out.report.iterations.iter().map(|i| i.mesh.fit.seconds).collect::<Vec<_>>());
    Ok(row)
}

pub(crate) fn run(meshes: Option<&str>, size: u32, laplacian: Option<f32>, lr: Option<f32>) -> Result<(), String> {
    let mut mesh_options = wonder3d::recon::RefineOptions::default();
    if let Some(w) = laplacian {
        mesh_options = mesh_options.with_laplacian_weight(w);
    }
    if let Some(lr) = lr {
        mesh_options = mesh_options.with_lr(lr);
    }
    let wanted: Option<Vec<&str>> = meshes.map(|m| m.split(',').collect());
    let mut rows = Vec::new();
    for (name, file) in OBJECTS {
        if wanted.as_ref().is_some_and(|w| !w.contains(&name)) {
            continue;
        }
        let truth = truth(name, file)?;
        for rig in [ViewRig::wonder3d_ortho(), ViewRig::wonder3d_persp()] {
            let clean = render_oracle_views(&truth, &rig, INPUT_SIZE).map_err(|e| e.to_string())?;
            let views = with_normal_noise(clean, SIGMA, 7)?;
            let t = Instant::now();
            let coarse = Pipeline::new().from_views(&views, &mut |_| {}).map_err(|e| e.to_string())?;
            let mut coarse_row = scores(&truth, &coarse.geometry, &coarse.mesh)?;
            coarse_row["seconds"] = json!(t.elapsed().as_secs_f64());
            let options = RefineOptions::default().with_size(size).with_mesh(mesh_options);
            let oracle = OracleEnhancer::new(truth.clone());
            let one = refined(&truth, &coarse.geometry, &views, &oracle, &options.clone().with_iterations(1))?;
            let two = refined(&truth, &coarse.geometry, &views, &oracle, &options.clone().with_iterations(2))?;
            let identity = refined(&truth, &coarse.geometry, &views, &IdentityEnhancer, &options.with_iterations(1))?;
            let row = json!({
                "mesh": name, "rig": rig.name, "coarse": coarse_row,
                "oracle_1": one, "oracle_2": two, "identity_1": identity,
            });
            eprintln!("{}", row_markdown(&row));
            rows.push(row);
        }
    }
    let out = crate::target_dir().join("bench");
    std::fs::create_dir_all(&out).map_err(|e| format!("{}: {e}", out.display()))?;
    let path = out.join("refine.json");
    let report = json!({
        "command": format!("cargo xtask refine-table --size {size}"),
        "mesh_refinement": { "lr": mesh_options.lr, "laplacian_weight": mesh_options.laplacian_weight,
                             "steps": mesh_options.steps, "edge_len_lims": mesh_options.edge_len_lims },
        "input": { "size": INPUT_SIZE, "normal_noise_sigma": SIGMA },
        "rows": rows,
    });
    write(&path, &serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?)?;
    println!("{}", table(&rows));
    println!("wrote {}", path.display());
    Ok(())
}

fn write(path: &Path, text: &str) -> Result<(), String> {
    std::fs::write(path, text).map_err(|e| format!("{}: {e}", path.display()))
}

const HEADER: &str = "| mesh | rig | CD coarse → oracle 1 → oracle 2 (identity 1) | novel-view PSNR dB coarse → oracle 1 → oracle 2 (identity 1) | triangles coarse → oracle 2 | seconds per oracle iteration |\n|---|---|---|---|---|---|";

fn row_markdown(r: &Value) -> String {
    let f = |k: &str, m: &str| crate::recon::f(r, &[k, m]);
    format!(
        "| {} | {} | {:.4} → {:.4} → {:.4} ({:.4}) | {:.2} → {:.2} → {:.2} ({:.2}) | {} → {} | {:.1} |",
        r["mesh"].as_str().unwrap_or(""),
        r["rig"].as_str().unwrap_or(""),
        f("coarse", "chamfer"),
        f("oracle_1", "chamfer"),
        f("oracle_2", "chamfer"),
        f("identity_1", "chamfer"),
        f("coarse", "psnr"),
        f("oracle_1", "psnr"),
        f("oracle_2", "psnr"),
        f("identity_1", "psnr"),
        f("coarse", "triangles"),
        f("oracle_2", "triangles"),
        f("oracle_2", "seconds") / 2.0,
    )
}

fn table(rows: &[Value]) -> String {
    let mut s = format!("{HEADER}\n");
    for r in rows {
        s.push_str(&row_markdown(r));
        s.push('\n');
    }
    s
}
