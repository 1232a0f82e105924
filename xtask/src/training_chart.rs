//! `cargo xtask training-chart`: the small model's recipe wall time against its normal error,
//! `docs/training_time.svg`, from the measured points in `docs/training_time.json`.
//!
//! The JSON holds what `docs/training.md` reports (items 6, 9, 11, 12 and 13 of "Where the error comes
//! from"): per series of models (a schedule and its continuations), per model the hours its
//! recipe took or takes from `cargo xtask train-small` to the model folder and the mean
//! normal error inside the true mask of each scored object with the demo's sampling
//! (`cargo xtask eval-small --draws 4 --guidance 1`). The chart draws one colour per object
//! and one line style and marker per series, with the two limits (15°, 3 h) as grey lines: where
//! the objects cross 15° against where 3 h ends is the question the chart answers.

use plotters::prelude::*;
use serde_json::Value;

/// One colour per object: the first four of the charts' palette.
const COLOURS: &[RGBColor] = crate::chart::OKABE_ITO.split_at(4).0;

/// One series: its legend, whether it is drawn dashed, and per object its (hours, degrees).
struct Series {
    name: String,
    dashed: bool,
    marker: Marker,
    per_object: Vec<Vec<(f64, f64)>>,
}

/// The marker of a series' points.
#[derive(Clone, Copy)]
enum Marker {
    Circle,
    Triangle,
    Square,
    Cross,
    Ring,
    /// A filled square.
    Block,
}

pub(crate) fn run() -> Result<(), String> {
    let docs = crate::workspace::workspace_root().join("docs");
    let path = docs.join("training_time.json");
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let doc: Value = serde_json::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    let bad = |what: &str| format!("{}: {what}", path.display());
    let objects: Vec<String> = doc["objects"]
        .as_array()
        .ok_or_else(|| bad("no `objects` array"))?
        .iter()
        .map(|o| o.as_str().map(str::to_string).ok_or_else(|| bad("`objects` holds a non-string")))
        .collect::<Result<_, _>>()?;
    if objects.is_empty() || objects.len() > COLOURS.len() {
        return Err(bad(&format!("`objects` must name 1 to {} objects", COLOURS.len())));
    }
    let target = doc["target_deg"].as_f64().ok_or_else(|| bad("no number `target_deg`"))?;
    let budget = doc["budget_hours"].as_f64().ok_or_else(|| bad("no number `budget_hours`"))?;
    let markers = [Marker::Circle, Marker::Triangle, Marker::Square, Marker::Cross, Marker::Ring, Marker::Block];
    let mut series = Vec::new();
    for (k, s) in doc["series"].as_array().ok_or_else(|| bad("no `series` array"))?.iter().enumerate() {
        let name = s["name"].as_str().ok_or_else(|| bad(&format!("series {k}: no `name`")))?.to_string();
        let points = s["points"].as_array().ok_or_else(|| bad(&format!("series `{name}`: no `points`")))?;
        let mut per_object = vec![Vec::new(); objects.len()];
        for (i, p) in points.iter().enumerate() {
            let hours = p["hours"].as_f64().ok_or_else(|| bad(&format!("series `{name}`, point {i}: no `hours`")))?;
            for (o, object) in objects.iter().enumerate() {
                let deg = p["normal_error_deg"][object.as_str()]
                    .as_f64()
                    .ok_or_else(|| bad(&format!("series `{name}`, point {i}: no `normal_error_deg.{object}`")))?;
                per_object[o].push((hours, deg));
            }
        }
        let dashed = s["dashed"].as_bool().unwrap_or(false);
        series.push(Series { name, dashed, marker: markers[k % markers.len()], per_object });
    }
    if series.is_empty() {
        return Err(bad("no series"));
    }
    let all = series.iter().flat_map(|s| s.per_object.iter().flatten());
    let (max_h, min_d, max_d) =
        all.fold((budget, target, target), |(h, lo, hi), &(x, y)| (h.max(x), lo.min(y), hi.max(y)));
    let out = docs.join("training_time.svg");
    let root = SVGBackend::new(&out, (900, 580)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let (x1, y0, y1) = ((max_h * 1.05).ceil(), (min_d - 1.0).floor(), (max_d + 1.0).ceil());
    let mut chart = ChartBuilder::on(&root)
        .caption("Small model: recipe wall time against normal error (4 draws, no guidance)", ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..x1, y0..y1)
        .map_err(|e| e.to_string())?;
    crate::chart::draw_grid(
        &mut chart,
        "hours from `cargo xtask train-small` to the model, 2 CPU cores",
        "normal error inside the true mask (°)",
    )?;
    let grey = RGBColor(120, 120, 120);
    chart
        .draw_series(DashedLineSeries::new(vec![(0.0, target), (x1, target)], 6, 4, grey.stroke_width(1)))
        .map_err(|e| e.to_string())?
        .label(format!("the issue's limits: {target}° and {budget} h"))
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], grey.stroke_width(1)));
    chart
        .draw_series(DashedLineSeries::new(vec![(budget, y0), (budget, y1)], 6, 4, grey.stroke_width(1)))
        .map_err(|e| e.to_string())?;
    for s in &series {
        for (o, points) in s.per_object.iter().enumerate() {
            let colour = COLOURS[o];
            let style = colour.stroke_width(2);
            if s.dashed {
                chart.draw_series(DashedLineSeries::new(points.clone(), 5, 4, style)).map_err(|e| e.to_string())?;
            } else {
                chart.draw_series(LineSeries::new(points.clone(), style)).map_err(|e| e.to_string())?;
            }
            draw_markers(&mut chart, points, s.marker, colour)?;
        }
        let dashed = s.dashed;
        let entry = chart
            .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())
            .map_err(|e| e.to_string())?
            .label(s.name.clone());
        let style = BLACK.stroke_width(2);
        let marker = s.marker;
        entry.legend(move |(x, y)| {
            let [a, b] = legend_line(dashed);
            EmptyElement::at((x + 10, y))
                + PathElement::new(a, style)
                + PathElement::new(b, style)
                + marker_shape(marker, BLACK)
        });
    }
    for (o, object) in objects.iter().enumerate() {
        let colour = COLOURS[o];
        chart
            .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())
            .map_err(|e| e.to_string())?
            .label(object.clone())
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 20, y + 5)], colour.filled()));
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
    eprintln!("wrote {}", out.display());
    Ok(())
}

type Chart<'a> = ChartContext<
    'a,
    SVGBackend<'a>,
    Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
>;

/// The points of one object in one series.
fn draw_markers(chart: &mut Chart<'_>, points: &[(f64, f64)], marker: Marker, colour: RGBColor) -> Result<(), String> {
    chart
        .draw_series(points.iter().map(|&p| EmptyElement::at(p) + marker_shape(marker, colour)))
        .map(|_| ())
        .map_err(|e| e.to_string())
}

/// The shape of `marker` in `colour`, centred on its anchor: the one drawing of each marker,
/// for the points and for the legend alike.
fn marker_shape<DB: DrawingBackend>(marker: Marker, colour: RGBColor) -> DynElement<'static, DB, (i32, i32)> {
    let stroke = colour.stroke_width(2);
    match marker {
        Marker::Circle => Circle::new((0, 0), 4, colour.filled()).into_dyn(),
        Marker::Triangle => TriangleMarker::new((0, 0), 5, colour.filled()).into_dyn(),
        Marker::Square => Rectangle::new([(-4, -4), (4, 4)], stroke).into_dyn(),
        Marker::Cross => Cross::new((0, 0), 4, stroke).into_dyn(),
        Marker::Ring => Circle::new((0, 0), 4, stroke).into_dyn(),
        Marker::Block => Rectangle::new([(-4, -4), (4, 4)], colour.filled()).into_dyn(),
    }
}

/// A series' legend line, solid or two dashes, relative to the legend marker's centre (the
/// marker is added by the caller).
fn legend_line(dashed: bool) -> [Vec<(i32, i32)>; 2] {
    if dashed {
        [vec![(-10, 0), (-4, 0)], vec![(4, 0), (10, 0)]]
    } else {
        [vec![(-10, 0), (0, 0)], vec![(0, 0), (10, 0)]]
    }
}
