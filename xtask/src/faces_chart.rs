//! `cargo xtask faces-chart [--meshes a,b] [--size 512]`: triangles against accuracy of the
//! refinement's meshes and of uniform-edge-length meshes fitted the same way ("model no more
//! than a scene needs", issue #22), `docs/faces_accuracy.svg`.
//!
//! Per object of the refinement table (orthographic rig, the same noisy 128² oracle views and
//! default coarse mesh as `cargo xtask refine-table`), two oracle-enhancer iterations:
//! - with the default refinement (**refined**: edge lengths adapted between 0.01 and 0.03
//!   by the remesher and bounded by the curvature, then the quadric simplification at the
//!   default tolerance);
//! - the same without the simplification (**adaptive**), and that mesh simplified at each
//!   tolerance of [`TOLERANCES`] as the refinement does it (`simplify_without_crossings`: the
//!   simplification curve);
//! - with the edge-length limits pinned to one length `e` for each `e` of [`UNIFORM`] and no
//!   simplification (**uniform**: a uniform remesh of the same object under the same fit).
//!
//! Accuracy is the exact surface Chamfer distance (sample points to the other *surface*,
//! `w3d_eval::surface_chamfer`, no sampling floor), with the usual point-sampled Chamfer
//! distance beside it. The triangles the uniform curve needs to reach the refined mesh's
//! surface CD (linear in log triangles between the two bracketing points) give the ratio of
//! the goal (refined ≤ 50 % of uniform at equal CD); the last column is the smallest
//! such share along the simplification curve. Writes `target/bench/faces.json`, the chart,
//! and prints the markdown table of `docs/accuracy.md`; `--replot` redraws both from the JSON.
//! `--curvature TOL|views:TOL|off` measures a variant of the curvature bound into
//! `target/bench/faces_variant.json` (the chart stays the defaults'), and `--uniform-from
//! JSON` takes the uniform meshes' points from an earlier run instead of fitting them again
//! (two thirds of the time).
//!
//! `--bound` measures nothing but the true meshes: per object, the share of a uniform mesh's
//! triangles that the best isotropic sizing needs for the same mean distance to the surface,
//! under the chord model of a triangle's error (an edge of length `h` where the surface's
//! largest normal curvature is `κ` deviates by about `κ h² / 8`; the mean error is the
//! area-weighted mean of `κ h²`, the triangle count the integral of `1 / h²`). Minimising the
//! count at a given mean error gives `h ∝ κ^(-1/4)` and the share `(mean √κ)² / mean κ` (at
//! most 1, by Cauchy–Schwarz); sizing to a chord tolerance (`h ∝ κ^(-1/2)`, equal error
//! everywhere) needs exactly the uniform mesh's count under this model. `κ` per vertex is the
//! remesher's estimate (`w3d_remesh::vertex_curvatures`), weighted by a third of the area of
//! the vertex's triangles.

use std::time::Instant;

use crate::curve::uniform_triangles_at;

use plotters::prelude::*;
use serde_json::{Value, json};
use wonder3d::eval::{EvalOptions, evaluate, surface_chamfer};
use wonder3d::raster::render_oracle_views;
use wonder3d::recon::simplify_without_crossings;
use wonder3d::refine::{OracleEnhancer, RefineOptions, refine};
use wonder3d::{Mesh, Pipeline, ViewRig, ViewSet};

use crate::recon::with_normal_noise;
use crate::refine_table::{INPUT_SIZE, OBJECTS, SIGMA, truth};

/// Edge lengths of the uniform meshes (world units, the unit cube), coarse to fine.
const UNIFORM: [f32; 7] = [0.05, 0.04, 0.03, 0.025, 0.02, 0.016, 0.012];

/// Tolerances of the simplification curve (world units), fine to coarse.
const TOLERANCES: [f32; 4] = [0.00025, 0.0005, 0.001, 0.002];

/// Refinement iterations of every point (the authors' `num_refine`).
const ITERATIONS: usize = 2;

/// Surface samples per mesh of the exact surface Chamfer distance.
const SURFACE_SAMPLES: usize = 100_000;

/// `--bound`: the share of the uniform mesh's triangles that the mean-error-optimal isotropic
/// sizing needs, per object (see the module documentation).
pub(crate) fn bound() -> Result<(), String> {
    println!("| object | vertices | area | mean κ | (mean √κ)² / mean κ |\n|---|---|---|---|---|");
    for (name, file) in OBJECTS {
        // Welded: a mesh with split vertices (the plane's OBJ has a vertex per face corner)
        // would show no edge leaving a face.
        let (mesh, _) = truth(name, file)?.merge_by_position();
        let kappa: Vec<f64> = wonder3d::remesh::vertex_curvatures(&mesh).into_iter().map(f64::from).collect();
        let n = mesh.vertex_count();
        let mut area = vec![0f64; n];
        for &t in mesh.triangles() {
            let a = wonder3d::core::normals::face_normal(mesh.positions(), t).length() / 2.0;
            for v in t {
                area[v as usize] += a / 3.0;
            }
        }
        let total: f64 = area.iter().sum();
        let mean_k = kappa.iter().zip(&area).map(|(k, a)| k * a).sum::<f64>() / total;
        let mean_sqrt = kappa.iter().zip(&area).map(|(k, a)| k.sqrt() * a).sum::<f64>() / total;
        println!("| {name} | {n} | {total:.3} | {mean_k:.1} | {:.0} % |", 100.0 * mean_sqrt * mean_sqrt / mean_k);
    }
    Ok(())
}

/// Both Chamfer distances and the triangles of `geometry` against `truth`, with the seconds
/// it took.
fn point(truth: &Mesh, geometry: &Mesh, seconds: f64) -> Result<Value, String> {
    let cd = evaluate(geometry, truth, &EvalOptions::default()).map_err(|e| e.to_string())?.chamfer;
    let surface = surface_chamfer(geometry, truth, SURFACE_SAMPLES, 0).map_err(|e| e.to_string())?.chamfer;
    Ok(json!({ "surface_chamfer": surface, "chamfer": cd, "triangles": geometry.triangle_count(), "seconds": seconds }))
}

/// Two oracle iterations from `coarse` with the mesh refinement `base` given the edge-length
/// limits `lims` and simplification tolerance `simplify`: the geometry and the seconds it
/// took.
fn refined(
    truth: &Mesh,
    coarse: &Mesh,
    views: &ViewSet,
    size: u32,
    base: wonder3d::recon::RefineOptions,
    (lims, simplify): ((f32, f32), Option<f32>),
) -> Result<(Mesh, f64), String> {
    let mesh = base.with_edge_len_lims(lims).with_simplify_tolerance(simplify);
    let options = RefineOptions::default().with_size(size).with_mesh(mesh).with_iterations(ITERATIONS);
    let t = Instant::now();
    let out =
        refine(coarse, views, &OracleEnhancer::new(truth.clone()), &options, &mut |_| {}).map_err(|e| e.to_string())?;
    Ok((out.geometry, t.elapsed().as_secs_f64()))
}

/// `(triangles, surface CD)` of one point.
fn xy(p: &Value) -> (f64, f64) {
    (crate::recon::f(p, &["triangles"]), crate::recon::f(p, &["surface_chamfer"]))
}

/// The ratio cell of one object: refined triangles over the uniform triangles at equal
/// surface CD.
fn ratio_cell(row: &Value) -> (String, Option<f64>) {
    let uniform: Vec<(f64, f64)> = row["uniform"].as_array().map(|a| a.iter().map(xy).collect()).unwrap_or_default();
    let (n, cd) = xy(&row["refined"]);
    match uniform_triangles_at(&uniform, cd) {
        Ok(u) => (format!("{:.0} → **{:.0} %**", u, 100.0 * n / u), Some(n / u)),
        Err(true) => {
            let finest = uniform.last().map_or(f64::NAN, |p| p.0);
            (format!("> {finest:.0} (no uniform mesh reaches it) → **< {:.0} %**", 100.0 * n / finest), None)
        }
        Err(false) => {
            let coarsest = uniform.first().map_or(f64::NAN, |p| p.0);
            (format!("< {coarsest:.0} (the coarsest is already as good) → **> {:.0} %**", 100.0 * n / coarsest), None)
        }
    }
}

/// The smallest share of the uniform curve's triangles at equal surface CD along the
/// simplification curve (the adaptive mesh and its simplifications): `(share, tolerance)`,
/// tolerance `None` for the adaptive mesh itself; `None` when no point is bracketed.
fn best_ratio(row: &Value) -> Option<(f64, Option<f64>)> {
    let uniform: Vec<(f64, f64)> = row["uniform"].as_array().map(|a| a.iter().map(xy).collect()).unwrap_or_default();
    let mut points = vec![(xy(&row["adaptive"]), None)];
    for p in row["simplified"].as_array().into_iter().flatten() {
        points.push((xy(p), p["tolerance"].as_f64()));
    }
    points
        .into_iter()
        .filter_map(|((n, cd), t)| uniform_triangles_at(&uniform, cd).ok().map(|u| (n / u, t)))
        .min_by(|a, b| a.0.total_cmp(&b.0))
}

fn best_ratio_cell(row: &Value) -> String {
    match best_ratio(row) {
        Some((r, Some(t))) => format!("{:.0} % (tolerance {t:.5})", 100.0 * r),
        Some((r, None)) => format!("{:.0} % (not simplified)", 100.0 * r),
        None => "none bracketed".into(),
    }
}

const HEADER: &str = "| mesh | coarse | adaptive | refined (simplified) | uniform, edge 0.05 → 0.012 | uniform triangles at the refined surface CD → refined / uniform | best along the simplification curve |\n|---|---|---|---|---|---|---|";

/// One point as `surface CD (sampled CD) / triangles`.
fn cell(p: &Value) -> String {
    format!(
        "{:.4} ({:.4}) / {}",
        crate::recon::f(p, &["surface_chamfer"]),
        crate::recon::f(p, &["chamfer"]),
        p["triangles"]
    )
}

fn row_markdown(row: &Value) -> String {
    let uniform: Vec<String> = row["uniform"]
        .as_array()
        .map(|a| {
            a.iter().map(|p| format!("{:.4} / {}", crate::recon::f(p, &["surface_chamfer"]), p["triangles"])).collect()
        })
        .unwrap_or_default();
    format!(
        "| {} | {} | {} | {} | {} | {} | {} |",
        row["mesh"].as_str().unwrap_or(""),
        cell(&row["coarse"]),
        cell(&row["adaptive"]),
        cell(&row["refined"]),
        uniform.join(", "),
        ratio_cell(row).0,
        best_ratio_cell(row)
    )
}

/// The uniform points of `mesh` in `report`, the faces JSON read from `path`.
fn uniform_points_from(report: &Value, path: &std::path::Path, mesh: &str) -> Result<Vec<Value>, String> {
    let row = report["rows"].as_array().into_iter().flatten().find(|r| r["mesh"] == mesh);
    let points = row.and_then(|r| r["uniform"].as_array()).cloned().unwrap_or_default();
    let edges: Vec<f32> = points.iter().filter_map(|p| p["edge_length"].as_f64()).map(|e| e as f32).collect();
    if edges != UNIFORM {
        return Err(format!(
            "{}: no uniform points of {mesh} at the edge lengths {UNIFORM:?} (found {edges:?})",
            path.display()
        ));
    }
    Ok(points)
}

pub(crate) fn run(
    meshes: Option<&str>,
    size: u32,
    curvature: Option<&str>,
    uniform_from: Option<&std::path::Path>,
) -> Result<(), String> {
    let base = crate::refine_table::mesh_options(None, None, None, None, curvature)?;
    let variant = curvature.is_some();
    let wanted: Option<Vec<&str>> = meshes.map(|m| m.split(',').collect());
    // Every reused uniform curve is read before any fitting starts.
    let mut reused = std::collections::HashMap::new();
    if let Some(path) = uniform_from {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let report: Value = serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
        for (name, _) in OBJECTS.iter().filter(|(n, _)| wanted.as_ref().is_none_or(|w| w.contains(n))) {
            reused.insert(*name, uniform_points_from(&report, path, name)?);
        }
    }
    let out_svg = crate::workspace::workspace_root().join("docs").join("faces_accuracy.svg");
    let bench = crate::workspace::target_dir().join("bench");
    std::fs::create_dir_all(&bench).map_err(|e| format!("{}: {e}", bench.display()))?;
    let start = Instant::now();
    let rig = ViewRig::wonder3d_ortho();
    let defaults = wonder3d::recon::RefineOptions::default();
    let default_lims = defaults.edge_len_lims;
    let mut rows = Vec::new();
    for (name, file) in OBJECTS {
        if wanted.as_ref().is_some_and(|w| !w.contains(&name)) {
            continue;
        }
        let truth = truth(name, file)?;
        let clean = render_oracle_views(&truth, &rig, INPUT_SIZE).map_err(|e| e.to_string())?;
        let views = with_normal_noise(clean, SIGMA, 7)?;
        let t = Instant::now();
        let coarse = Pipeline::new().from_views(&views, &mut |_| {}).map_err(|e| e.to_string())?;
        let coarse_point = point(&truth, &coarse.geometry, t.elapsed().as_secs_f64())?;
        let (mesh, seconds) =
            refined(&truth, &coarse.geometry, &views, size, base, (default_lims, defaults.simplify_tolerance))?;
        let refined_point = point(&truth, &mesh, seconds)?;
        let (adaptive, seconds) = refined(&truth, &coarse.geometry, &views, size, base, (default_lims, None))?;
        let adaptive_point = point(&truth, &adaptive, seconds)?;
        let mut simplified = Vec::new();
        for tolerance in TOLERANCES {
            let t = Instant::now();
            let (simple, report) =
                simplify_without_crossings(adaptive.clone(), tolerance).map_err(|e| e.to_string())?;
            let mut p = point(&truth, &simple, t.elapsed().as_secs_f64())?;
            p["tolerance"] = json!(tolerance);
            p["kept_unsimplified"] = json!(report.is_none());
            simplified.push(p);
        }
        let mut uniform = reused.remove(name).unwrap_or_default();
        for e in UNIFORM.into_iter().filter(|_| uniform_from.is_none()) {
            // The uniform meshes are the default refinement's with the limits pinned, whatever
            // the variant (pinned limits leave the curvature bound nothing to do), and the fit
            // kept whatever it agrees with the views: a curve of fits, not of the coarse mesh
            // an edge length too long to fit better would give back.
            let uniform_options = defaults.with_keep_input_unless_better(false);
            let (mesh, seconds) = refined(&truth, &coarse.geometry, &views, size, uniform_options, ((e, e), None))?;
            let mut p = point(&truth, &mesh, seconds)?;
            p["edge_length"] = json!(e);
            uniform.push(p);
            eprintln!("  {name} uniform {e}: {}  [{:.0} s]", uniform.last().unwrap(), start.elapsed().as_secs_f64());
        }
        let row = json!({
            "mesh": name, "rig": rig.name, "coarse": coarse_point, "refined": refined_point,
            "adaptive": adaptive_point, "simplified": simplified, "uniform": uniform,
        });
        eprintln!("{}", row_markdown(&row));
        rows.push(row);
    }
    if rows.is_empty() {
        return Err(format!("--meshes {meshes:?}: none of {:?}", OBJECTS.map(|o| o.0)));
    }
    let mut command = format!("cargo xtask faces-chart --size {size}");
    if let Some(c) = curvature {
        command.push_str(&format!(" --curvature {c}"));
    }
    if let Some(p) = uniform_from {
        command.push_str(&format!(" --uniform-from {}", p.display()));
    }
    let report = json!({
        "command": command,
        "curvature_tolerance": base.curvature_tolerance,
        "curvature_from_views": base.curvature_from_views,
        "iterations": ITERATIONS,
        "uniform_edge_lengths": UNIFORM,
        "simplify_tolerances": TOLERANCES,
        "default_simplify_tolerance": defaults.simplify_tolerance,
        "adaptive_edge_len_lims": [default_lims.0, default_lims.1],
        "surface_samples": SURFACE_SAMPLES,
        "input": { "size": INPUT_SIZE, "normal_noise_sigma": SIGMA, "rig": rig.name },
        "machine": crate::workspace::cpu_model(),
        "seconds": start.elapsed().as_secs_f64(),
        "rows": rows,
    });
    let path = bench.join(if variant { "faces_variant.json" } else { "faces.json" });
    std::fs::write(&path, serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    print_table(&rows);
    if variant {
        println!("wrote {} (a variant: the chart in docs/ is the defaults')", path.display());
    } else {
        chart(&rows, &out_svg)?;
        println!("wrote {} and {}", path.display(), out_svg.display());
    }
    Ok(())
}

fn print_table(rows: &[Value]) {
    let mut s = format!("{HEADER}\n");
    for r in rows {
        s.push_str(&row_markdown(r));
        s.push('\n');
    }
    println!("{s}");
}

/// `cargo xtask faces-chart --replot`: the chart and the table again from
/// `target/bench/faces.json`, without measuring.
pub(crate) fn replot() -> Result<(), String> {
    let path = crate::workspace::target_dir().join("bench").join("faces.json");
    let text = std::fs::read_to_string(&path)
        .map_err(|e| format!("{}: {e} (run `cargo xtask faces-chart` first)", path.display()))?;
    let report: Value = serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    let rows = report["rows"].as_array().cloned().unwrap_or_default();
    if rows.is_empty() {
        return Err(format!("{}: no rows", path.display()));
    }
    let out_svg = crate::workspace::workspace_root().join("docs").join("faces_accuracy.svg");
    chart(&rows, &out_svg)?;
    print_table(&rows);
    println!("wrote {}", out_svg.display());
    Ok(())
}

/// The chart: per object the uniform curve (solid line and dots), the simplification curve
/// of the adaptive mesh (dashed line and small triangles), the refined mesh of the defaults
/// (a large filled triangle) and the coarse mesh (a hollow square); triangles on a log axis,
/// surface Chamfer distance up.
fn chart(rows: &[Value], out: &std::path::Path) -> Result<(), String> {
    let series =
        |r: &Value, key: &str| -> Vec<(f64, f64)> { r[key].as_array().into_iter().flatten().map(xy).collect() };
    let all: Vec<(f64, f64)> = rows
        .iter()
        .flat_map(|r| {
            let mut v = vec![xy(&r["coarse"]), xy(&r["refined"]), xy(&r["adaptive"])];
            v.extend(series(r, "uniform"));
            v.extend(series(r, "simplified"));
            v
        })
        .collect();
    let (min_n, max_n) = all.iter().fold((f64::MAX, 0f64), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let max_cd = all.iter().fold(0f64, |a, p| a.max(p.1)) * 1.1;
    let root = SVGBackend::new(out, (900, 580)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let mut chart = ChartBuilder::on(&root)
        .caption("Refinement: triangles against accuracy (oracle enhancer, 2 iterations, ortho)", ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(80)
        .build_cartesian_2d((min_n * 0.8..max_n * 1.25).log_scale(), 0.0f64..max_cd)
        .map_err(|e| e.to_string())?;
    crate::chart::draw_grid(&mut chart, "triangles (log scale)", "surface Chamfer distance")?;
    for (r, &colour) in rows.iter().zip(crate::chart::OKABE_ITO.iter().cycle()) {
        let name = r["mesh"].as_str().unwrap_or("").to_string();
        let uniform = series(r, "uniform");
        chart
            .draw_series(LineSeries::new(uniform.clone(), colour.stroke_width(2)))
            .map_err(|e| e.to_string())?
            .label(format!("{name}: uniform edges"))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
        chart.draw_series(uniform.iter().map(|&p| Circle::new(p, 3, colour.filled()))).map_err(|e| e.to_string())?;
        let mut simplified = vec![xy(&r["adaptive"])];
        simplified.extend(series(r, "simplified"));
        chart
            .draw_series(DashedLineSeries::new(simplified.clone(), 5, 4, colour.stroke_width(1)))
            .map_err(|e| e.to_string())?;
        chart
            .draw_series(simplified.iter().map(|&p| TriangleMarker::new(p, 4, colour.filled())))
            .map_err(|e| e.to_string())?;
        chart
            .draw_series(std::iter::once(TriangleMarker::new(xy(&r["refined"]), 9, colour.filled())))
            .map_err(|e| e.to_string())?
            .label(format!("{name}: refined (adaptive, simplified)"))
            .legend(move |(x, y)| TriangleMarker::new((x + 10, y), 6, colour.filled()));
        let (cx, cy) = xy(&r["coarse"]);
        chart
            .draw_series(std::iter::once(
                EmptyElement::at((cx, cy)) + Rectangle::new([(-4, -4), (4, 4)], colour.stroke_width(2)),
            ))
            .map_err(|e| e.to_string())?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .label_font(("sans-serif", 12))
        .draw()
        .map_err(|e| e.to_string())?;
    root.present().map_err(|e| e.to_string())?;
    Ok(())
}
