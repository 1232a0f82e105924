//! `cargo xtask refine-table [--meshes a,b] [--size 512]`: the refinement loop
//! (`wonder3d::refine`) measured with the oracle and the identity enhancer, the table of
//! `docs/accuracy.md` ("Refinement").
//!
//! Per object and rig (orthographic and perspective): oracle views at 128² with Gaussian
//! normal noise σ = 0.05 (so the coarse mesh has something to gain), the default pipeline
//! (reconstruction and texture), then refinement with the oracle enhancer (renders of the
//! true mesh: the best an enhancer could do) for one and for two iterations, and with the
//! identity enhancer for one, once as the defaults run it and once with the fit's result kept
//! whatever its agreement with the views (`RefineOptions::keep_input_unless_better` off: the
//! drift of the fit itself). Scores: Chamfer distance against the truth, mean PSNR of the
//! 16 SyncDreamer views at 256² (composited over white), triangles and seconds. Meshes
//! without colours get `wonder3d::dataset::procedural_colours`; spot is the bundled,
//! textured one. Writes `target/bench/refine.json` and prints the markdown table.
//!
//! `--all` is the robustness sweep of issue #22 ("no self-intersections or NaN after
//! refinement"): the same protocol on every mesh of `crate::recon::CLOSED` and
//! `crate::recon::CONCAVE` (the 14 closed meshes, the teapot and both teacups), both rigs,
//! oracle refinement for 2 iterations and identity for 1 (no PSNR, no 1-iteration run; the
//! identity run with `keep_input_unless_better` off, so that it checks a fit, not the coarse
//! mesh the guard would return). Every
//! refined mesh is checked for non-finite coordinates, watertightness and crossing triangle
//! pairs; an error or a panic is recorded in its row (with the iteration it happened in) and
//! the sweep goes on. `--meshes` filters by file stem. Writes `target/bench/refine_all_<size>.json`
//! after every row, prints the markdown table, and fails at the end if any row broke one of
//! those checks. `--rig ortho|persp` runs one rig only.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;
use std::time::Instant;

use serde_json::{Value, json};
use wonder3d::eval::{EvalOptions, evaluate, surface_chamfer};
use wonder3d::raster::render_oracle_views;
use wonder3d::refine::{Enhancer, IdentityEnhancer, OracleEnhancer, RefineOptions, refine};
use wonder3d::{Mesh, Pipeline, ViewRig, ViewSet};

use crate::recon::{CLOSED, CONCAVE, load_concave, load_normalised, novel_view_fidelity, with_normal_noise};

/// The objects of the acceptance: (name, file in `../shared/data/meshes`; spot is bundled).
pub(crate) const OBJECTS: [(&str, &str); 5] = [
    ("spot", ""),
    ("armadillo", "armadillo.obj"),
    ("koala", "koala_low_resolution.obj"),
    ("horse", "horse.ply"),
    ("plane", "plane.obj"),
];

/// Side of the noisy input views.
pub(crate) const INPUT_SIZE: u32 = 128;
/// Normal noise of the input views.
pub(crate) const SIGMA: f32 = 0.05;

pub(crate) fn truth(name: &str, file: &str) -> Result<Mesh, String> {
    if file.is_empty() {
        return wonder3d::demo::bundled_spot().map_err(|e| e.to_string());
    }
    let dir = crate::workspace::workspace_root().join("../shared/data/meshes");
    let mesh = load_normalised(&dir, file)?;
    let colours = wonder3d::dataset::procedural_colours(mesh.positions(), name);
    mesh.with_colours(colours).map_err(|e| e.to_string())
}

/// Chamfer distance, novel-view PSNR and triangles of `mesh` (textured) / `geometry`.
fn scores(truth: &Mesh, geometry: &Mesh, textured: &Mesh) -> Result<Value, String> {
    let cd = evaluate(geometry, truth, &EvalOptions::default()).map_err(|e| e.to_string())?.chamfer;
    let surface = surface_chamfer(geometry, truth, 100_000, 0).map_err(|e| e.to_string())?.chamfer;
    let (psnr, ssim) = novel_view_fidelity(truth, textured, 256)?;
    Ok(json!({ "chamfer": cd, "surface_chamfer": surface, "psnr": psnr, "ssim": ssim,
               "triangles": geometry.triangle_count() }))
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
    row["kept_input"] = json!(out.report.iterations.iter().map(|i| i.mesh.kept_input).collect::<Vec<_>>());
    Ok(row)
}

/// The mesh refinement's options with the command line's changes to the defaults.
pub(crate) fn mesh_options(
    laplacian: Option<f32>,
    lr: Option<f32>,
    edges: Option<&[f32]>,
    simplify: Option<&str>,
    curvature: Option<&str>,
) -> Result<wonder3d::recon::RefineOptions, String> {
    let mut mesh_options = wonder3d::recon::RefineOptions::default();
    if let Some(w) = laplacian {
        mesh_options = mesh_options.with_laplacian_weight(w);
    }
    if let Some(lr) = lr {
        mesh_options = mesh_options.with_lr(lr);
    }
    if let Some(edges) = edges {
        match *edges {
            [lo, hi] if lo > 0.0 && lo <= hi => mesh_options = mesh_options.with_edge_len_lims((lo, hi)),
            _ => return Err(format!("--edges {edges:?}: MIN,MAX with 0 < MIN ≤ MAX")),
        }
    }
    match simplify {
        None => {}
        Some("off") => mesh_options = mesh_options.with_simplify_tolerance(None),
        Some(t) => {
            let t: f32 = t.parse().map_err(|_| format!("--simplify {t}: a tolerance in world units, or `off`"))?;
            mesh_options = mesh_options.with_simplify_tolerance(Some(t));
        }
    }
    match curvature {
        None => {}
        Some("off") => mesh_options = mesh_options.with_curvature_tolerance(None),
        Some(arg) => {
            // `views:TOL` reads the curvature from the views (`curvature_from_views`).
            let (from_views, t) = match arg.strip_prefix("views:") {
                Some(t) => (true, t),
                None => (false, arg),
            };
            match t.parse::<f32>() {
                Ok(t) if t > 0.0 && t.is_finite() => {
                    mesh_options = mesh_options.with_curvature_tolerance(Some(t)).with_curvature_from_views(from_views)
                }
                _ => {
                    return Err(format!(
                        "--curvature {arg}: a tolerance > 0 in world units (`views:TOL` to read the \
                         curvature from the views), or `off`"
                    ));
                }
            }
        }
    }
    Ok(mesh_options)
}

pub(crate) fn run(
    meshes: Option<&str>,
    all: bool,
    rig: Option<&str>,
    size: u32,
    mesh_options: wonder3d::recon::RefineOptions,
) -> Result<(), String> {
    let wanted: Option<Vec<&str>> = meshes.map(|m| m.split(',').collect());
    if all {
        return sweep(wanted.as_deref(), rig, size, mesh_options);
    }
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
            let identity =
                refined(&truth, &coarse.geometry, &views, &IdentityEnhancer, &options.clone().with_iterations(1))?;
            // The fit itself, without the guard that keeps the input: its drift.
            let unguarded = options.with_iterations(1).with_mesh(mesh_options.with_keep_input_unless_better(false));
            let identity_fit = refined(&truth, &coarse.geometry, &views, &IdentityEnhancer, &unguarded)?;
            let row = json!({
                "mesh": name, "rig": rig.name, "coarse": coarse_row,
                "oracle_1": one, "oracle_2": two, "identity_1": identity, "identity_1_fit": identity_fit,
            });
            eprintln!("{}", row_markdown(&row));
            rows.push(row);
        }
    }
    let out = crate::workspace::target_dir().join("bench");
    std::fs::create_dir_all(&out).map_err(|e| format!("{}: {e}", out.display()))?;
    let path = out.join("refine.json");
    let report = json!({
        "command": format!("cargo xtask refine-table --size {size}"),
        "mesh_refinement": mesh_refinement_json(&mesh_options),
        "input": { "size": INPUT_SIZE, "normal_noise_sigma": SIGMA },
        "rows": rows,
    });
    write(&path, &serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?)?;
    println!("{}", table(&rows));
    println!("wrote {}", path.display());
    Ok(())
}

/// The mesh refinement settings a report records.
fn mesh_refinement_json(o: &wonder3d::recon::RefineOptions) -> Value {
    json!({ "lr": o.lr, "laplacian_weight": o.laplacian_weight, "steps": o.steps,
            "edge_len_lims": o.edge_len_lims, "simplify_tolerance": o.simplify_tolerance,
            "curvature_tolerance": o.curvature_tolerance, "curvature_from_views": o.curvature_from_views,
            "keep_input_unless_better": o.keep_input_unless_better })
}

fn write(path: &Path, text: &str) -> Result<(), String> {
    std::fs::write(path, text).map_err(|e| format!("{}: {e}", path.display()))
}

const HEADER: &str = "| mesh | rig | CD coarse → oracle 1 → oracle 2 (identity 1; its fit alone) | surface CD coarse → oracle 1 → oracle 2 (identity 1; its fit alone) | novel-view PSNR dB coarse → oracle 1 → oracle 2 (identity 1) | triangles coarse → oracle 2 | input kept: oracle 2's iterations, identity | seconds per oracle iteration |\n|---|---|---|---|---|---|---|---|";

/// `yes`/`no` per iteration of a stage's `kept_input`.
fn kept(stage: &Value) -> String {
    let kept = stage["kept_input"].as_array().map(Vec::as_slice).unwrap_or_default();
    let words: Vec<&str> = kept.iter().map(|k| if k.as_bool() == Some(true) { "yes" } else { "no" }).collect();
    if words.is_empty() { "–".into() } else { words.join(", ") }
}

fn row_markdown(r: &Value) -> String {
    let f = |k: &str, m: &str| crate::recon::f(r, &[k, m]);
    format!(
        "| {} | {} | {:.4} → {:.4} → {:.4} ({:.4}; {:.4}) | {:.5} → {:.5} → {:.5} ({:.5}; {:.5}) | {:.2} → {:.2} → {:.2} ({:.2}) | {} → {} | {}; {} | {:.1} |",
        r["mesh"].as_str().unwrap_or(""),
        r["rig"].as_str().unwrap_or(""),
        f("coarse", "chamfer"),
        f("oracle_1", "chamfer"),
        f("oracle_2", "chamfer"),
        f("identity_1", "chamfer"),
        f("identity_1_fit", "chamfer"),
        f("coarse", "surface_chamfer"),
        f("oracle_1", "surface_chamfer"),
        f("oracle_2", "surface_chamfer"),
        f("identity_1", "surface_chamfer"),
        f("identity_1_fit", "surface_chamfer"),
        f("coarse", "psnr"),
        f("oracle_1", "psnr"),
        f("oracle_2", "psnr"),
        f("identity_1", "psnr"),
        f("coarse", "triangles"),
        f("oracle_2", "triangles"),
        kept(&r["oracle_2"]),
        kept(&r["identity_1"]),
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

/// The meshes of the sweep: (table name, truth with procedural colours).
fn sweep_meshes(wanted: Option<&[&str]>) -> Result<Vec<(String, Mesh)>, String> {
    let dir = crate::workspace::workspace_root().join("../shared/data/meshes");
    let keep = |file: &str| wanted.is_none_or(|w| w.iter().any(|m| file.split('.').next() == Some(m)));
    let mut out = Vec::new();
    for file in CLOSED.iter().filter(|f| keep(f)) {
        let name = file.split('.').next().unwrap_or(file).to_string();
        out.push((name, load_normalised(&dir, file)?));
    }
    for &(file, turned) in CONCAVE.iter().filter(|(f, _)| keep(f)) {
        out.push(load_concave(&dir, file, turned)?);
    }
    out.into_iter()
        .map(|(name, mesh)| {
            let colours = wonder3d::dataset::procedural_colours(mesh.positions(), &name);
            Ok((name, mesh.with_colours(colours).map_err(|e| e.to_string())?))
        })
        .collect()
}

/// The checks of one mesh: CD, triangles, finite coordinates, watertight, crossing pairs.
fn checks(truth: &Mesh, mesh: &Mesh) -> Result<Value, String> {
    let finite = mesh.positions().iter().flatten().all(|v| v.is_finite());
    let cd = evaluate(mesh, truth, &EvalOptions::default()).map_err(|e| e.to_string())?.chamfer;
    Ok(json!({
        "chamfer": cd, "triangles": mesh.triangle_count(), "finite": finite,
        "watertight": mesh.topology().is_watertight(), "crossings": mesh.self_intersections().len(),
    }))
}

/// The message of a caught panic.
fn panic_message(panic: Box<dyn std::any::Any + Send>) -> String {
    panic
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_else(|| "a panic without a message".into())
}

/// One refinement of the sweep, checked; an error or a panic becomes the row's `error`, with
/// the iteration the loop had reached (from 1; 0: before the first, in the initial bake).
fn checked_refine(
    truth: &Mesh,
    geometry: &Mesh,
    views: &ViewSet,
    enhancer: &dyn Enhancer,
    options: &RefineOptions,
) -> Value {
    let t = Instant::now();
    let mut reached = 0;
    let result = catch_unwind(AssertUnwindSafe(|| {
        let out = refine(geometry, views, enhancer, options, &mut |p| reached = p.iteration + 1)
            .map_err(|e| e.to_string())?;
        let mut row = checks(truth, &out.geometry)?;
        // Per iteration: crossing pairs untangling left in the fit kept, and the fit's reruns.
        let iterations = &out.report.iterations;
        row["untangle_left"] = json!(iterations.iter().map(|i| i.mesh.untangle.after).collect::<Vec<_>>());
        row["reseeds"] = json!(iterations.iter().map(|i| i.mesh.reseeds).collect::<Vec<_>>());
        row["curvature_bound_dropped"] =
            json!(iterations.iter().map(|i| i.mesh.curvature_bound_dropped).collect::<Vec<_>>());
        row["kept_input"] = json!(iterations.iter().map(|i| i.mesh.kept_input).collect::<Vec<_>>());
        Ok::<_, String>(row)
    }));
    let mut row = match result {
        Ok(Ok(row)) => row,
        Ok(Err(e)) => json!({ "error": e, "iteration": reached }),
        Err(panic) => json!({ "error": format!("panic: {}", panic_message(panic)), "iteration": reached }),
    };
    row["seconds"] = json!(t.elapsed().as_secs_f64());
    row
}

/// What broke in one stage of a sweep row (empty when nothing did).
fn broken(stage: &Value) -> Vec<String> {
    let mut out = Vec::new();
    if stage.is_null() {
        return out; // not run: the coarse stage before it failed and is reported
    }
    if let Some(e) = stage.get("error") {
        out.push(format!("error in iteration {}: {}", stage["iteration"], e.as_str().unwrap_or("?")));
        return out;
    }
    if stage["finite"].as_bool() != Some(true) {
        out.push("non-finite coordinates".into());
    }
    if stage["watertight"].as_bool() != Some(true) {
        out.push("not watertight".into());
    }
    if let Some(n) = stage["crossings"].as_u64().filter(|&n| n > 0) {
        out.push(format!("{n} crossing pairs"));
    }
    out
}

/// `--all`: the robustness sweep (see the module documentation).
fn sweep(
    wanted: Option<&[&str]>,
    only_rig: Option<&str>,
    size: u32,
    mesh_options: wonder3d::recon::RefineOptions,
) -> Result<(), String> {
    let meshes = sweep_meshes(wanted)?;
    let rigs: Vec<ViewRig> = [ViewRig::wonder3d_ortho(), ViewRig::wonder3d_persp()]
        .into_iter()
        .filter(|r| only_rig.is_none_or(|o| r.name == format!("wonder3d_{o}")))
        .collect();
    if rigs.is_empty() {
        return Err(format!("--rig {only_rig:?}: expected ortho or persp"));
    }
    let rig_arg = only_rig.map(|r| format!(" --rig {r}")).unwrap_or_default();
    let path = crate::workspace::target_dir().join("bench");
    std::fs::create_dir_all(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let path = path.join(format!("refine_all_{size}.json"));
    let start = Instant::now();
    let mut rows: Vec<Value> = Vec::new();
    for rig in rigs {
        for (name, truth) in &meshes {
            let t = Instant::now();
            // The last stage the pipeline reported, to name where it failed.
            let mut stage = String::from("rendering the views");
            let coarse = catch_unwind(AssertUnwindSafe(|| -> Result<_, String> {
                let clean = render_oracle_views(truth, &rig, INPUT_SIZE).map_err(|e| e.to_string())?;
                let views = with_normal_noise(clean, SIGMA, 7)?;
                let coarse = Pipeline::new()
                    .from_views(&views, &mut |p| stage = format!("{:?} {}/{}", p.stage, p.done, p.total))
                    .map_err(|e| e.to_string())?;
                Ok((views, coarse))
            }))
            .unwrap_or_else(|panic| Err(format!("panic: {}", panic_message(panic))));
            let mut row = json!({ "mesh": name, "rig": rig.name });
            match coarse.and_then(|(views, coarse)| Ok((checks(truth, &coarse.geometry)?, views, coarse))) {
                Err(e) => row["coarse"] = json!({ "error": format!("{e} (after {stage})"), "iteration": "coarse" }),
                Ok((mut coarse_row, views, coarse)) => {
                    coarse_row["seconds"] = json!(t.elapsed().as_secs_f64());
                    row["coarse"] = coarse_row;
                    let options = RefineOptions::default().with_size(size).with_mesh(mesh_options);
                    let oracle = OracleEnhancer::new(truth.clone());
                    row["oracle_2"] =
                        checked_refine(truth, &coarse.geometry, &views, &oracle, &options.clone().with_iterations(2));
                    // The identity run checks the fit itself: with the guard it would return
                    // the coarse mesh, checked above.
                    let unguarded =
                        options.with_iterations(1).with_mesh(mesh_options.with_keep_input_unless_better(false));
                    row["identity_1"] = checked_refine(truth, &coarse.geometry, &views, &IdentityEnhancer, &unguarded);
                }
            }
            eprintln!("{}  [{:.0} s]", sweep_row(&row), start.elapsed().as_secs_f64());
            rows.push(row);
            let report = json!({
                "command": format!("cargo xtask refine-table --all{rig_arg} --size {size}"),
                "mesh_refinement": mesh_refinement_json(&mesh_options),
                "input": { "size": INPUT_SIZE, "normal_noise_sigma": SIGMA },
                "machine": crate::workspace::cpu_model(),
                "seconds": start.elapsed().as_secs_f64(),
                "rows": rows,
            });
            write(&path, &serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?)?;
        }
    }
    let mut s = format!("{SWEEP_HEADER}\n");
    for r in &rows {
        s.push_str(&sweep_row(r));
        s.push('\n');
    }
    println!("{s}");
    println!("wrote {}", path.display());
    let failed: Vec<String> = rows
        .iter()
        .flat_map(|r| {
            ["coarse", "oracle_2", "identity_1"].into_iter().flat_map(move |stage| {
                broken(&r[stage]).into_iter().map(move |b| format!("{}, {}, {stage}: {b}", r["mesh"], r["rig"]))
            })
        })
        .collect();
    if !failed.is_empty() {
        return Err(format!("refined meshes broke an invariant:\n{}", failed.join("\n")));
    }
    Ok(())
}

const SWEEP_HEADER: &str = "| mesh | rig | CD coarse → oracle 2 (identity 1) | triangles coarse → oracle 2 (identity 1) | watertight / crossings / non-finite after oracle 2, identity 1 | seconds oracle 2 + identity 1 |\n|---|---|---|---|---|---|";

fn sweep_row(r: &Value) -> String {
    let stage = |k: &str| -> (String, String, String) {
        let v = &r[k];
        if v.is_null() {
            return ("–".into(), "–".into(), "–".into());
        }
        if let Some(e) = v.get("error") {
            let e = format!("**error (iteration {}): {}**", v["iteration"], e.as_str().unwrap_or("?"));
            return (e.clone(), "–".into(), e);
        }
        let ok = |b: bool, yes: &str, no: &str| if b { yes.to_string() } else { format!("**{no}**") };
        let checks = format!(
            "{} / {} / {}",
            ok(v["watertight"].as_bool() == Some(true), "yes", "no"),
            ok(v["crossings"].as_u64() == Some(0), "0", &v["crossings"].to_string()),
            ok(v["finite"].as_bool() == Some(true), "none", "NaN"),
        );
        (format!("{:.4}", v["chamfer"].as_f64().unwrap_or(f64::NAN)), v["triangles"].to_string(), checks)
    };
    let (c_cd, c_tri, _) = stage("coarse");
    let (o_cd, o_tri, o_ok) = stage("oracle_2");
    let (i_cd, i_tri, i_ok) = stage("identity_1");
    let secs = |k: &str| r[k]["seconds"].as_f64().unwrap_or(f64::NAN);
    format!(
        "| {} | {} | {c_cd} → {o_cd} ({i_cd}) | {c_tri} → {o_tri} ({i_tri}) | {o_ok}, {i_ok} | {:.0} + {:.0} |",
        r["mesh"].as_str().unwrap_or(""),
        r["rig"].as_str().unwrap_or(""),
        secs("oracle_2"),
        secs("identity_1"),
    )
}
