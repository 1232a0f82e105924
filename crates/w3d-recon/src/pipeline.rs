//! The whole extraction: initialisation then coarse reconstruction, with presets, a
//! progress callback and one report.

use std::fmt;
use std::str::FromStr;
use std::time::Instant;

use w3d_core::{Error, Mesh, Result, ViewSet};

use crate::coarse::{CoarseOptions, CoarseReport, reconstruct_coarse};
use crate::init::{InitChoice, InitOptions, InitReport, start_meshes};
use crate::polish::{PolishReport, polish};
use crate::untangle::{UntangleReport, untangle};

/// Named speed/accuracy trade-offs of [`ReconOptions`] (numbers in `docs/accuracy.md`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum Preset {
    /// Coarser mesh (edges from 0.03), 60 steps: a preview in a few seconds.
    Fast,
    /// Edges from 0.02, 120 steps: the balance used by `wonder3d reconstruct` and the demo.
    Default,
    /// Finer mesh (edges down to 0.015), 200 steps.
    Quality,
}

impl Preset {
    /// All presets, fastest first.
    pub const ALL: [Preset; 3] = [Preset::Fast, Preset::Default, Preset::Quality];

    /// The lower-case name (`fast`, `default`, `quality`).
    pub fn name(self) -> &'static str {
        match self {
            Preset::Fast => "fast",
            Preset::Default => "default",
            Preset::Quality => "quality",
        }
    }
}

impl fmt::Display for Preset {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Preset {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self> {
        Preset::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| Error::invalid("preset", format!("one of fast, default, quality; got `{s}`")))
    }
}

/// Options of [`reconstruct`]: one block per stage.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct ReconOptions {
    /// The start mesh.
    pub init: InitOptions,
    /// The coarse optimisation.
    pub coarse: CoarseOptions,
    /// Most rounds (separation and smoothing) [`untangle`] may run on the result (0 skips it).
    pub untangle_rounds: usize,
    /// Steps of [`polish`] on the vertices [`untangle`] moved (0 skips it).
    pub polish_steps: usize,
}

impl ReconOptions {
    /// The options of a named preset.
    pub fn preset(preset: Preset) -> Self {
        let base = ReconOptions {
            init: InitOptions::default(),
            coarse: CoarseOptions::default(),
            untangle_rounds: 400,
            polish_steps: 60,
        };
        match preset {
            Preset::Default => ReconOptions {
                init: InitOptions { edge_length: 0.05, ..base.init },
                coarse: CoarseOptions { steps: 120, lr_decay: 0.99, edge_len_lims: (0.02, 0.1), ..base.coarse },
                polish_steps: 40,
                ..base
            },
            Preset::Fast => ReconOptions {
                init: InitOptions { edge_length: 0.06, ..base.init },
                coarse: CoarseOptions { steps: 60, lr_decay: 0.985, edge_len_lims: (0.03, 0.1), ..base.coarse },
                polish_steps: 20,
                ..base
            },
            Preset::Quality => base,
        }
    }
}

impl Default for ReconOptions {
    fn default() -> Self {
        ReconOptions::preset(Preset::Default)
    }
}

/// Chainable setters, one per field: `ReconOptions::default().with_…(…)` (the struct is
/// `#[non_exhaustive]`, so code outside this crate cannot use struct-literal syntax).
impl ReconOptions {
    /// These options with [`init`](Self::init) set to `value`.
    #[must_use]
    pub fn with_init(mut self, value: InitOptions) -> Self {
        self.init = value;
        self
    }

    /// These options with [`coarse`](Self::coarse) set to `value`.
    #[must_use]
    pub fn with_coarse(mut self, value: CoarseOptions) -> Self {
        self.coarse = value;
        self
    }

    /// These options with [`untangle_rounds`](Self::untangle_rounds) set to `value`.
    #[must_use]
    pub fn with_untangle_rounds(mut self, value: usize) -> Self {
        self.untangle_rounds = value;
        self
    }

    /// These options with [`polish_steps`](Self::polish_steps) set to `value`.
    #[must_use]
    pub fn with_polish_steps(mut self, value: usize) -> Self {
        self.polish_steps = value;
        self
    }

    /// These options with the coarse stage's step count ([`CoarseOptions::steps`]) set to
    /// `steps`: the main speed/accuracy knob after the preset.
    #[must_use]
    pub fn with_coarse_steps(mut self, steps: usize) -> Self {
        self.coarse.steps = steps;
        self
    }

    /// These options with the seed of the remesher's random choices ([`CoarseOptions::seed`])
    /// set to `seed`; the rest of the pipeline is deterministic.
    #[must_use]
    pub fn with_seed(mut self, seed: u64) -> Self {
        self.coarse.seed = seed;
        self
    }
}

/// A pipeline stage, as reported to the progress callback and in [`ReconReport`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum Stage {
    /// Normal integration, concave check, Poisson, hull carving, simplification.
    Init,
    /// The coarse optimisation with continuous remeshing.
    Coarse,
    /// Smoothing away crossing triangles ([`untangle`]).
    Untangle,
    /// Fitting the untangled vertices to the views again without crossings ([`polish`]).
    Polish,
}

/// A progress event: `done` of `total` units of `stage` (the init stage reports 0/1 and
/// 1/1; the coarse stage one unit per step, with the loss before that step).
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct Progress {
    /// The stage running.
    pub stage: Stage,
    /// Units done.
    pub done: usize,
    /// Units in the stage.
    pub total: usize,
    /// The current loss, when the stage has one.
    pub loss: Option<f32>,
}

/// Wall-clock time of one stage.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct StageTiming {
    /// Which stage.
    pub stage: Stage,
    /// Seconds.
    pub seconds: f64,
}

/// Everything [`reconstruct`] measured.
#[derive(Debug, Clone, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct ReconReport {
    /// The start mesh: which one and why.
    pub init: InitReport,
    /// Per-step losses and triangle counts of the coarse stage.
    pub coarse: CoarseReport,
    /// Self-intersections of the coarse result and what [`untangle`] left.
    pub untangle: UntangleReport,
    /// The loss before and after [`polish`].
    pub polish: PolishReport,
    /// Per-stage wall-clock seconds.
    pub stages: Vec<StageTiming>,
    /// Times the coarse stage ran again because [`untangle`] left crossings (at most
    /// [`COARSE_RESEEDS`]): with the next remesher seed, from the second rerun on with the
    /// remesher's repairs on. 0 almost always on consistent views, and always 0 when
    /// [`ReconOptions::untangle_rounds`] is 0.
    pub coarse_reseeds: usize,
    /// Whether the coarse run kept is one with the remesher's repairs on (see
    /// [`ReconReport::coarse_reseeds`]).
    pub remesh_repairs: bool,
    /// Triangles of the returned mesh.
    pub triangles: usize,
    /// Total wall-clock seconds.
    pub seconds: f64,
}

/// Reconstructs a closed mesh, in the world frame of the views' rig, from the normal maps and
/// masks of `views`: [`crate::initial_mesh`] then
/// [`reconstruct_coarse`], then [`untangle`] and [`polish`] (on the vertices untangling moved
/// and two rings around them). When the Poisson start misses a silhouette (IoU below
/// [`InitOptions::hull_alternative_iou`]), the coarse stage also runs from
/// [`crate::visual_hull_mesh`] and the hull result is kept when its settled loss (the mean of
/// the last 10 % of steps) is lower than the Poisson result's by more than
/// [`InitOptions::hull_alternative_margin`] (the report says which, with both losses). When
/// [`untangle`] leaves crossings, the coarse stage runs again from the same start with the
/// next remesher seeds, all but the first rerun with the remesher's repairs on (at most
/// [`COARSE_RESEEDS`] times; [`ReconReport::coarse_reseeds`]), and the run with the fewest
/// crossings left is kept; a rerun reports its steps to `progress` as a coarse stage of its own. `progress` receives [`Progress`] events (pass
/// `&mut |_| {}` to ignore them).
pub fn reconstruct(
    views: &ViewSet,
    options: &ReconOptions,
    progress: &mut dyn FnMut(Progress),
) -> Result<(Mesh, ReconReport)> {
    let start = Instant::now();
    // Every view must see the object: name the empty one (integration would only say "mask").
    for (i, (rv, v)) in views.iter().enumerate() {
        if v.mask.data().iter().all(|&m| m < 0.5) {
            return Err(Error::invalid(
                format!("views[{i}].mask ({})", rv.name),
                "a silhouette (at least one pixel with mask ≥ 0.5), got an empty mask: the object is outside \
                 this view, or the views were rendered from a mesh without area",
            ));
        }
    }
    progress(Progress { stage: Stage::Init, done: 0, total: 1, loss: None });
    // A Poisson start that misses a silhouette badly may sit in the wrong basin: also
    // optimise from the visual hull and keep the hull result if its loss is clearly lower.
    let (init, mut init_report, alternative) = start_meshes(views, &options.init, true)?;
    progress(Progress { stage: Stage::Init, done: 1, total: 1, loss: None });
    let runs = 1 + usize::from(alternative.is_some());
    let total = options.coarse.steps * runs;
    let (mut mesh, mut coarse_report) = reconstruct_coarse(views, &init, &options.coarse, &mut |done, _, loss| {
        progress(Progress { stage: Stage::Coarse, done, total, loss: Some(loss) })
    })?;
    // The start of the result kept, for a rerun with another seed (below).
    let mut start_mesh = init;
    if let Some(hull) = alternative {
        let offset = options.coarse.steps;
        let (hull_mesh, hull_report) = reconstruct_coarse(views, &hull, &options.coarse, &mut |done, _, loss| {
            progress(Progress { stage: Stage::Coarse, done: offset + done, total, loss: Some(loss) })
        })?;
        let (poisson_loss, hull_loss) = (settled_loss(&coarse_report), settled_loss(&hull_report));
        let margin = options.init.hull_alternative_margin;
        let seconds = coarse_report.seconds + hull_report.seconds;
        let kept = if hull_loss < (1.0 - margin) * poisson_loss {
            mesh = hull_mesh;
            coarse_report = hull_report;
            init_report.choice = InitChoice::VisualHull;
            init_report.triangles = hull.triangle_count();
            start_mesh = hull;
            "visual hull"
        } else {
            "Poisson"
        };
        coarse_report.seconds = seconds;
        init_report.reason = format!(
            "{}; silhouette IoU below {}: also optimised from the visual hull (settled loss, the mean of the last \
             10 % of steps, {hull_loss:.5} vs Poisson {poisson_loss:.5}; the hull needs {:.0} % less): kept the \
             {kept} result",
            init_report.reason,
            options.init.hull_alternative_iou,
            100.0 * margin
        );
    }
    let t = Instant::now();
    progress(Progress { stage: Stage::Untangle, done: 0, total: 1, loss: None });
    let (mut untangled, mut untangle_report) = untangle(&mesh, options.untangle_rounds)?;
    // Untangling that ends with crossings left (rare on consistent views: 1 of 154 coarse
    // meshes in the measurements of `untangle`'s docs, a chaotic outcome of the remesher's
    // choices) gets the coarse stage again from the same start: with the next remesher seed,
    // then with the remesher's repairs on and the seeds after (views that contradict each
    // other crumple the surface into patches of sub-floor triangles that untangling cannot
    // always clear; the repairs leave far fewer, at some cost in detail). The run with the
    // fewest crossings left is kept.
    let (mut reseeds, mut reseed_seconds, mut repaired) = (0, 0.0, false);
    while untangle_report.after > 0 && options.untangle_rounds > 0 && reseeds < COARSE_RESEEDS {
        reseeds += 1;
        // The first rerun as before with the next seed; the others with the repairs on.
        let coarse =
            options.coarse.with_seed(options.coarse.seed.wrapping_add(reseeds as u64)).with_remesh_repairs(reseeds > 1);
        let (again, again_report) = reconstruct_coarse(views, &start_mesh, &coarse, &mut |done, total, loss| {
            progress(Progress { stage: Stage::Coarse, done, total, loss: Some(loss) })
        })?;
        let (again_untangled, again_untangle) = untangle(&again, options.untangle_rounds)?;
        reseed_seconds += again_report.seconds;
        let seconds = coarse_report.seconds + again_report.seconds;
        if again_untangle.after < untangle_report.after {
            (mesh, coarse_report, untangled, untangle_report) = (again, again_report, again_untangled, again_untangle);
            repaired = coarse.remesh_repairs;
        }
        coarse_report.seconds = seconds;
    }
    progress(Progress { stage: Stage::Untangle, done: 1, total: 1, loss: None });
    let untangle_seconds = t.elapsed().as_secs_f64() - reseed_seconds;
    progress(Progress { stage: Stage::Polish, done: 0, total: 1, loss: None });
    let free = grow_rings(&untangled, moved_vertices(&mesh, &untangled), POLISH_RINGS);
    let (mesh, polish_report) = polish(views, &untangled, &free, &options.coarse, options.polish_steps)?;
    progress(Progress { stage: Stage::Polish, done: 1, total: 1, loss: Some(polish_report.loss_after) });
    let stages = vec![
        StageTiming { stage: Stage::Init, seconds: init_report.seconds },
        StageTiming { stage: Stage::Coarse, seconds: coarse_report.seconds },
        StageTiming { stage: Stage::Untangle, seconds: untangle_seconds },
        StageTiming { stage: Stage::Polish, seconds: polish_report.seconds },
    ];
    let report = ReconReport {
        init: init_report,
        coarse: coarse_report,
        untangle: untangle_report,
        polish: polish_report,
        coarse_reseeds: reseeds,
        remesh_repairs: repaired,
        stages,
        triangles: mesh.triangle_count(),
        seconds: start.elapsed().as_secs_f64(),
    };
    Ok((mesh, report))
}

/// Most reruns of the coarse stage when [`untangle`] leaves crossings (see [`reconstruct`]):
/// each with the next remesher seed, all but the first with
/// [`CoarseOptions::remesh_repairs`] on.
pub const COARSE_RESEEDS: usize = 3;

/// The loss a coarse run settled at: the mean of its last 10 % of steps (at least one).
/// The last step's loss alone moves by up to ±25 % from step to step as the remesher
/// splits and collapses (measured on the plane: 0.0398 at the last step, 0.0319 over the
/// last twelve), too much to choose between two starts by.
fn settled_loss(report: &CoarseReport) -> f32 {
    let losses = &report.losses;
    let k = (losses.len() / 10).max(1).min(losses.len());
    if k == 0 {
        return f32::INFINITY;
    }
    losses[losses.len() - k..].iter().sum::<f32>() / k as f32
}

/// Rings of neighbours around the vertices [`untangle`] moved that [`polish`] may move too.
/// Measured (orthographic, rocker arm, 60 steps): 2 rings CD 0.0075, 4 rings 0.0076.
const POLISH_RINGS: usize = 2;

/// `true` for each vertex whose position differs between `a` and `b` (same topology).
fn moved_vertices(a: &Mesh, b: &Mesh) -> Vec<bool> {
    a.positions().iter().zip(b.positions()).map(|(p, q)| p != q).collect()
}

/// `flags` grown by `rings` rings of triangle neighbours in `mesh`.
fn grow_rings(mesh: &Mesh, mut flags: Vec<bool>, rings: usize) -> Vec<bool> {
    for _ in 0..rings {
        let mut grown = flags.clone();
        for t in mesh.triangles() {
            if t.iter().any(|&v| flags[v as usize]) {
                for &v in t {
                    grown[v as usize] = true;
                }
            }
        }
        flags = grown;
    }
    flags
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report(losses: Vec<f32>) -> CoarseReport {
        CoarseReport { losses, triangle_counts: Vec::new(), seconds: 0.0 }
    }

    /// Two starts are compared by where their losses settled, not by the last step alone.
    #[test]
    fn the_settled_loss_is_the_mean_of_the_last_tenth_of_the_steps() {
        let mut losses = vec![1.0; 18];
        losses.extend([0.2, 0.4]);
        assert!((settled_loss(&report(losses)) - 0.3).abs() < 1e-6);
        assert_eq!(settled_loss(&report(vec![0.5, 0.25])), 0.25);
        assert_eq!(settled_loss(&report(Vec::new())), f32::INFINITY);
    }
}
