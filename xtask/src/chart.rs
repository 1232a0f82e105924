//! `cargo xtask chart`: SVG charts in `docs/` from the benchmark JSON in `target/bench/`.
//!
//! `docs/speed_accuracy.svg`: wall-clock seconds (log scale) against Chamfer distance, one
//! point per preset and mesh from `target/bench/recon.json` (orthographic oracle runs), with
//! the published Wonder3D / Wonder3D++ numbers drawn for reference.

use plotters::coord::ranged1d::ValueFormatter;
use plotters::prelude::*;
use serde_json::Value;

/// Published reference points: (label, seconds, Chamfer). The papers' numbers are on the
/// GSO-30 subset from *generated* views (not oracle views), on an A100, so they are context,
/// not a like-for-like comparison: Wonder3D++ reports init 3 s + coarse 39 s and CD 0.0193
/// (ortho); Wonder3D v1 reports CD 0.0222 (its NeuS fit takes 2–3 minutes: 150 s drawn).
const PUBLISHED: &[(&str, f64, f64)] = &[
    ("Wonder3D++ init+coarse (paper, A100, GSO)", 42.0, 0.0193),
    ("Wonder3D v1 NeuS (paper, A100, GSO)", 150.0, 0.0222),
];

/// Colour-blind-safe palette (Okabe–Ito) of the charts' series, one colour per object or preset.
pub(crate) const OKABE_ITO: [RGBColor; 5] = [
    RGBColor(0, 114, 178),
    RGBColor(230, 159, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(86, 180, 233),
];

/// The grid and axis descriptions every chart of `docs/` draws: light minor lines, grey major
/// ones.
pub(crate) fn draw_grid<DB, X, Y>(
    chart: &mut ChartContext<'_, DB, Cartesian2d<X, Y>>,
    x_desc: &str,
    y_desc: &str,
) -> Result<(), String>
where
    DB: DrawingBackend,
    X: Ranged + ValueFormatter<X::ValueType>,
    Y: Ranged + ValueFormatter<Y::ValueType>,
{
    chart
        .configure_mesh()
        .light_line_style(RGBColor(240, 240, 240))
        .bold_line_style(RGBColor(200, 200, 200))
        .x_desc(x_desc)
        .y_desc(y_desc)
        .draw()
        .map_err(|e| e.to_string())
}

/// One preset's points: (name, colour, (seconds, Chamfer) per mesh).
type Series = (&'static str, RGBColor, Vec<(f64, f64)>);

pub fn run() -> Result<(), String> {
    let path = crate::workspace::target_dir().join("bench").join("recon.json");
    let text = std::fs::read_to_string(&path)
        .map_err(|e| format!("{}: {e} (run `cargo xtask bench recon` first)", path.display()))?;
    let doc: Value = serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    let runs = doc["runs"].as_array().ok_or(format!("{}: no `runs` array", path.display()))?;
    let mut series: Vec<Series> = vec![
        ("fast", RGBColor(230, 159, 0), vec![]),
        ("default", RGBColor(0, 114, 178), vec![]),
        ("quality", RGBColor(0, 158, 115), vec![]),
    ];
    for r in runs {
        if r["case"] != "oracle" || r["rig"] != "ortho" {
            continue;
        }
        let (Some(t), Some(cd), Some(preset)) =
            (r["seconds"].as_f64(), r["metrics"]["chamfer"].as_f64(), r["preset"].as_str())
        else {
            continue;
        };
        if let Some(s) = series.iter_mut().find(|s| s.0 == preset) {
            s.2.push((t, cd));
        }
    }
    if series.iter().all(|s| s.2.is_empty()) {
        return Err(format!("{}: no orthographic oracle runs to chart", path.display()));
    }
    let out = crate::workspace::workspace_root().join("docs").join("speed_accuracy.svg");
    let max_cd = series.iter().flat_map(|s| s.2.iter().map(|p| p.1)).fold(0.025f64, f64::max) * 1.1;
    {
        let root = SVGBackend::new(&out, (820, 520)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let mut chart = ChartBuilder::on(&root)
            .caption("Reconstruction: time against accuracy (oracle views, 6-view ortho, 256²)", ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(80)
            .build_cartesian_2d((1.0f64..300.0f64).log_scale(), 0.0f64..max_cd)
            .map_err(|e| e.to_string())?;
        draw_grid(&mut chart, "wall-clock seconds, init + coarse (log scale)", "Chamfer")?;
        for (name, colour, points) in &series {
            let colour = *colour;
            chart
                .draw_series(points.iter().map(|&p| Circle::new(p, 5, colour.filled())))
                .map_err(|e| e.to_string())?
                .label(format!("wonder3d-rs {name} (2-core CPU, one point per mesh)"))
                .legend(move |(x, y)| Circle::new((x + 10, y), 5, colour.filled()));
        }
        for &(label, t, cd) in PUBLISHED {
            chart
                .draw_series(std::iter::once(TriangleMarker::new((t, cd), 7, BLACK.filled())))
                .map_err(|e| e.to_string())?
                .label(label)
                .legend(|(x, y)| TriangleMarker::new((x + 10, y), 6, BLACK.filled()));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK)
            .draw()
            .map_err(|e| e.to_string())?;
        root.present().map_err(|e| e.to_string())?;
    }
    eprintln!("wrote {}", out.display());
    Ok(())
}
