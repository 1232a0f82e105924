//! `cargo xtask faces-chart [--meshes a,b] [--size 512]`: triangles against Chamfer distance
//! of the refinement's adaptive mesh and of uniform-edge-length meshes fitted the same way
//! ("model no more than a scene needs", issue #22), `docs/faces_accuracy.svg`.
//!
//! Per object of the refinement table (orthographic rig, the same noisy 128² oracle views and
//! default coarse mesh as `cargo xtask refine-table`): two oracle-enhancer iterations with the
//! default mesh refinement (edge lengths adapted between 0.01 and 0.016 by the remesher), and
//! two with the edge-length limits pinned to one length `e` for each `e` of [`UNIFORM`], the
//! uniform remesh of the same object under the same fit. The uniform points make a curve of
//! triangles against CD; the triangles the uniform curve needs to reach the adaptive mesh's
//! CD (linear in log triangles between the two bracketing points) give the ratio of the
//! issue's goal (adaptive ≤ 50 % of uniform at equal CD). Writes `target/bench/faces.json`,
//! the chart, and prints the markdown table of `docs/accuracy.md`.

use std::time::Instant;

use plotters::prelude::*;
use serde_json::{Value, json};
use wonder3d::eval::{EvalOptions, evaluate};
use wonder3d::raster::render_oracle_views;
use wonder3d::refine::{OracleEnhancer, RefineOptions, refine};
use wonder3d::{Mesh, Pipeline, ViewRig, ViewSet};

use crate::recon::with_normal_noise;
use crate::refine_table::{INPUT_SIZE, OBJECTS, SIGMA, truth};

/// Edge lengths of the uniform meshes (world units, the unit cube), coarse to fine.
const UNIFORM: [f32; 5] = [0.02, 0.016, 0.012, 0.009, 0.007];

/// Refinement iterations of every point (the authors' `num_refine`).
const ITERATIONS: usize = 2;

/// CD and triangles of `geometry` against `truth`, with the seconds it took.
fn point(truth: &Mesh, geometry: &Mesh, seconds: f64) -> Result<Value, String> {
    let cd = evaluate(geometry, truth, &EvalOptions::default()).map_err(|e| e.to_string())?.chamfer;
    Ok(json!({ "chamfer": cd, "triangles": geometry.triangle_count(), "seconds": seconds }))
}

/// Two oracle iterations from `coarse` with the mesh refinement's edge-length limits `lims`.
fn refined(truth: &Mesh, coarse: &Mesh, views: &ViewSet, size: u32, lims: (f32, f32)) -> Result<Value, String> {
    let mesh = wonder3d::recon::RefineOptions::default().with_edge_len_lims(lims);
    let options = RefineOptions::default().with_size(size).with_mesh(mesh).with_iterations(ITERATIONS);
    let t = Instant::now();
    let out =
        refine(coarse, views, &OracleEnhancer::new(truth.clone()), &options, &mut |_| {}).map_err(|e| e.to_string())?;
    let mut p = point(truth, &out.geometry, t.elapsed().as_secs_f64())?;
    p["edge_len_lims"] = json!([lims.0, lims.1]);
    Ok(p)
}

/// Triangles the uniform curve needs to reach `cd`: `Ok(n)` interpolated between the two
/// uniform points that bracket it, `Err(true)` when even the finest uniform mesh stays above
/// it, `Err(false)` when the coarsest is already below it.
fn uniform_triangles_at(uniform: &[(f64, f64)], cd: f64) -> Result<f64, bool> {
    // `uniform`: (triangles, CD), coarse to fine.
    if uniform.first().is_some_and(|&(_, c)| c <= cd) {
        return Err(false);
    }
    for w in uniform.windows(2) {
        let ((n0, c0), (n1, c1)) = (w[0], w[1]);
        if c1 <= cd && c0 > cd {
            let t = (c0 - cd) / (c0 - c1);
            return Ok((n0.ln() + t * (n1.ln() - n0.ln())).exp());
        }
    }
    Err(true)
}

/// The ratio cell of one object: adaptive triangles over the uniform triangles at equal CD.
fn ratio_cell(row: &Value) -> (String, Option<f64>) {
    let uniform: Vec<(f64, f64)> = row["uniform"]
        .as_array()
        .map(|a| a.iter().map(|p| (crate::recon::f(p, &["triangles"]), crate::recon::f(p, &["chamfer"]))).collect())
        .unwrap_or_default();
    let (n, cd) = (crate::recon::f(row, &["refined", "triangles"]), crate::recon::f(row, &["refined", "chamfer"]));
    match uniform_triangles_at(&uniform, cd) {
        Ok(u) => (format!("{:.0} → **{:.0} %**", u, 100.0 * n / u), Some(n / u)),
        Err(true) => {
            let finest = uniform.last().map_or(f64::NAN, |p| p.0);
            (format!("> {finest:.0} (no uniform mesh reaches it) → **< {:.0} %**", 100.0 * n / finest), None)
        }
        Err(false) => {
            let coarsest = uniform.first().map_or(f64::NAN, |p| p.0);
            (format!("< {coarsest:.0} → **> {:.0} %**", 100.0 * n / coarsest), None)
        }
    }
}

const HEADER: &str = "| mesh | coarse CD / triangles | adaptive refined CD / triangles | uniform refined CD / triangles, edge 0.02 → 0.007 | uniform triangles at the adaptive CD → adaptive / uniform |\n|---|---|---|---|---|";

fn row_markdown(row: &Value) -> String {
    let cell = |p: &Value| format!("{:.4} / {}", crate::recon::f(p, &["chamfer"]), p["triangles"]);
    let uniform: Vec<String> = row["uniform"].as_array().map(|a| a.iter().map(cell).collect()).unwrap_or_default();
    format!(
        "| {} | {} | {} | {} | {} |",
        row["mesh"].as_str().unwrap_or(""),
        cell(&row["coarse"]),
        cell(&row["refined"]),
        uniform.join(", "),
        ratio_cell(row).0
    )
}

pub(crate) fn run(meshes: Option<&str>, size: u32) -> Result<(), String> {
    let wanted: Option<Vec<&str>> = meshes.map(|m| m.split(',').collect());
    let out_svg = crate::workspace_root().join("docs").join("faces_accuracy.svg");
    let bench = crate::target_dir().join("bench");
    std::fs::create_dir_all(&bench).map_err(|e| format!("{}: {e}", bench.display()))?;
    let start = Instant::now();
    let rig = ViewRig::wonder3d_ortho();
    let default_lims = wonder3d::recon::RefineOptions::default().edge_len_lims;
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
        let adaptive = refined(&truth, &coarse.geometry, &views, size, default_lims)?;
        let mut uniform = Vec::new();
        for e in UNIFORM {
            uniform.push(refined(&truth, &coarse.geometry, &views, size, (e, e))?);
            eprintln!("  {name} uniform {e}: {}  [{:.0} s]", uniform.last().unwrap(), start.elapsed().as_secs_f64());
        }
        let row =
            json!({ "mesh": name, "rig": rig.name, "coarse": coarse_point, "refined": adaptive, "uniform": uniform });
        eprintln!("{}", row_markdown(&row));
        rows.push(row);
    }
    if rows.is_empty() {
        return Err(format!("--meshes {meshes:?}: none of {:?}", OBJECTS.map(|o| o.0)));
    }
    let report = json!({
        "command": format!("cargo xtask faces-chart --size {size}"),
        "iterations": ITERATIONS,
        "uniform_edge_lengths": UNIFORM,
        "adaptive_edge_len_lims": [default_lims.0, default_lims.1],
        "input": { "size": INPUT_SIZE, "normal_noise_sigma": SIGMA, "rig": rig.name },
        "machine": crate::cpu_model(),
        "seconds": start.elapsed().as_secs_f64(),
        "rows": rows,
    });
    let path = bench.join("faces.json");
    std::fs::write(&path, serde_json::to_string_pretty(&report).map_err(|e| e.to_string())?)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    chart(&rows, &out_svg)?;
    let mut s = format!("{HEADER}\n");
    for r in &rows {
        s.push_str(&row_markdown(r));
        s.push('\n');
    }
    println!("{s}");
    println!("wrote {} and {}", path.display(), out_svg.display());
    Ok(())
}

/// Colour-blind-safe palette (Okabe–Ito), one colour per object.
const COLOURS: [RGBColor; 5] = [
    RGBColor(0, 114, 178),
    RGBColor(230, 159, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(86, 180, 233),
];

/// The chart: per object the uniform curve (line and dots), the adaptive refined mesh (a
/// filled diamond) and the coarse mesh (a hollow square), triangles on a log axis.
fn chart(rows: &[Value], out: &std::path::Path) -> Result<(), String> {
    let pts = |p: &Value| (crate::recon::f(p, &["triangles"]), crate::recon::f(p, &["chamfer"]));
    let all: Vec<(f64, f64)> = rows
        .iter()
        .flat_map(|r| {
            let mut v = vec![pts(&r["coarse"]), pts(&r["refined"])];
            v.extend(r["uniform"].as_array().into_iter().flatten().map(pts));
            v
        })
        .collect();
    let (min_n, max_n) = all.iter().fold((f64::MAX, 0f64), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let max_cd = all.iter().fold(0f64, |a, p| a.max(p.1)) * 1.1;
    let root = SVGBackend::new(out, (860, 540)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let mut chart = ChartBuilder::on(&root)
        .caption("Refinement: triangles against accuracy (oracle enhancer, 2 iterations, ortho)", ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(80)
        .build_cartesian_2d((min_n * 0.8..max_n * 1.25).log_scale(), 0.0f64..max_cd)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .light_line_style(RGBColor(240, 240, 240))
        .bold_line_style(RGBColor(200, 200, 200))
        .x_desc("triangles (log scale)")
        .y_desc("Chamfer")
        .draw()
        .map_err(|e| e.to_string())?;
    for (r, &colour) in rows.iter().zip(COLOURS.iter().cycle()) {
        let name = r["mesh"].as_str().unwrap_or("").to_string();
        let uniform: Vec<(f64, f64)> = r["uniform"].as_array().into_iter().flatten().map(pts).collect();
        chart
            .draw_series(LineSeries::new(uniform.clone(), colour.stroke_width(2)))
            .map_err(|e| e.to_string())?
            .label(format!("{name}: uniform edge 0.02 → 0.007"))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
        chart.draw_series(uniform.iter().map(|&p| Circle::new(p, 3, colour.filled()))).map_err(|e| e.to_string())?;
        chart
            .draw_series(std::iter::once(TriangleMarker::new(pts(&r["refined"]), 8, colour.filled())))
            .map_err(|e| e.to_string())?
            .label(format!("{name}: adaptive (0.01–0.016)"))
            .legend(move |(x, y)| TriangleMarker::new((x + 10, y), 6, colour.filled()));
        let (cx, cy) = pts(&r["coarse"]);
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

#[cfg(test)]
mod tests {
    use super::uniform_triangles_at;

    #[test]
    fn uniform_triangles_interpolate_in_log_space() {
        let curve = [(1000.0, 0.004), (4000.0, 0.002)];
        let n = uniform_triangles_at(&curve, 0.003).unwrap();
        assert!((n - 2000.0).abs() < 1e-6, "{n}");
        assert_eq!(uniform_triangles_at(&curve, 0.001), Err(true));
        assert_eq!(uniform_triangles_at(&curve, 0.005), Err(false));
    }
}
