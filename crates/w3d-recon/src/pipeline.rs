//! The whole extraction: initialisation then coarse reconstruction, with presets, a
//! progress callback and one report.

use std::fmt;
use std::str::FromStr;
use std::time::Instant;

use w3d_core::{Error, Mesh, Result, ViewSet, self_intersections};

use crate::agreement::{ViewAgreement, view_agreement};
use crate::coarse::{CoarseOptions, CoarseReport, reconstruct_coarse};
use crate::init::{InitChoice, InitOptions, InitReport, start_meshes};
use crate::polish::{PolishReport, polish};
use crate::untangle::{UntangleReport, untangle_crossing};

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

/// The default [`ReconOptions::hopeless_view_loss`]: about 3 times the highest final view
/// loss per view measured on generated views that several fits improve (the small model's
/// plane, 0.08), and a third of a random-weight model's (0.68).
pub const HOPELESS_VIEW_LOSS: f32 = 0.25;

/// Options of [`reconstruct`]: one block per stage.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct ReconOptions {
    /// The start mesh.
    pub init: InitOptions,
    /// The coarse optimisation.
    pub coarse: CoarseOptions,
    /// Most rounds (separation and smoothing) [`untangle`](fn@crate::untangle) may run on the result (0 skips it).
    pub untangle_rounds: usize,
    /// Steps of [`polish`] on the vertices [`untangle`](fn@crate::untangle) moved (0 skips it).
    pub polish_steps: usize,
    /// Independent fits from the same start mesh, each with its own remesher seed; the one
    /// that fits the views best is kept (fewest crossings left, then the lowest final view
    /// loss: nothing but the views decides). 1 in every preset. The remesher's splits and
    /// collapses make one fit a chaotic function of its input, and on views that disagree
    /// with each other (generated ones) the spread is large: on the small model's views of
    /// the plane, eight seeds gave Chamfer distances from 0.016 to 0.047, and the final view
    /// loss ranks them (`docs/accuracy.md`, "Several starts"). Costs one fit per start.
    pub starts: usize,
    /// Final view loss per view (the coarse stage's loss summed over the views, divided by
    /// their number) of the first start above which the other [`starts`](Self::starts) are
    /// skipped ([`ReconReport::starts_skipped`]). Several fits pay off on views that roughly
    /// agree: the small model's generated views end at 0.015–0.08 per view, where the best of
    /// four fits lowers the Chamfer distance by up to a third (`docs/accuracy.md`, "Several
    /// starts"). Views that no closed surface explains (a failed generation, an untrained
    /// model) end far above, 0.68 per view for a random-weight model's, and more fits only
    /// choose among equally wrong meshes at the price of a whole fit each. The loss is a mean
    /// over pixels, so the bound holds at every resolution. `f32::INFINITY` always runs every
    /// start.
    pub hopeless_view_loss: f32,
}

impl ReconOptions {
    /// The options of a named preset.
    pub fn preset(preset: Preset) -> Self {
        let base = ReconOptions {
            init: InitOptions::default(),
            coarse: CoarseOptions::default(),
            untangle_rounds: 400,
            polish_steps: 60,
            starts: 1,
            hopeless_view_loss: HOPELESS_VIEW_LOSS,
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
    w3d_core::setters! {
        with_init(init: InitOptions);
        with_coarse(coarse: CoarseOptions);
        with_untangle_rounds(untangle_rounds: usize);
        with_polish_steps(polish_steps: usize);
        /// These options with [`starts`](Self::starts) set to `value` (at least 1; [`reconstruct`]
        /// refuses 0).
        with_starts(starts: usize);
        with_hopeless_view_loss(hopeless_view_loss: f32);
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
    /// Smoothing away crossing triangles ([`untangle`](fn@crate::untangle)).
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
    /// Self-intersections of the coarse result and what [`untangle`](fn@crate::untangle) left.
    pub untangle: UntangleReport,
    /// The loss before and after [`polish`].
    pub polish: PolishReport,
    /// Per-stage wall-clock seconds.
    pub stages: Vec<StageTiming>,
    /// Times the coarse stage ran again because [`untangle`](fn@crate::untangle) left crossings (at most
    /// [`COARSE_RESEEDS`]): with the next remesher seed, from the second rerun on with the
    /// remesher's repairs on. 0 almost always on consistent views, and always 0 when
    /// [`ReconOptions::untangle_rounds`] is 0.
    pub coarse_reseeds: usize,
    /// Whether the coarse run kept is one with the remesher's repairs on (see
    /// [`ReconReport::coarse_reseeds`]).
    pub remesh_repairs: bool,
    /// The final view loss of each start ([`ReconOptions::starts`]), in seed order.
    pub start_losses: Vec<f32>,
    /// Which start was kept (an index into [`ReconReport::start_losses`]).
    pub start_kept: usize,
    /// Starts not run because the first fit's final view loss per view was above
    /// [`ReconOptions::hopeless_view_loss`]: the views contradict each other beyond what any
    /// closed surface explains (0 when every start ran).
    pub starts_skipped: usize,
    /// Triangles of the returned mesh.
    pub triangles: usize,
    /// How well each view agrees with the returned mesh, in rig order ([`view_agreement`]):
    /// the view with the lowest score is the one the others outvoted
    /// ([`disagreeing_view`](crate::disagreeing_view)).
    pub views: Vec<ViewAgreement>,
    /// Total wall-clock seconds.
    pub seconds: f64,
}

/// Reconstructs a closed mesh, in the world frame of the views' rig, from the normal maps and
/// masks of `views`: [`crate::initial_mesh`] then
/// [`reconstruct_coarse`], then [`untangle`](fn@crate::untangle) and [`polish`] (on the vertices untangling moved
/// and two rings around them). When the Poisson start misses a silhouette (IoU below
/// [`InitOptions::hull_alternative_iou`]), the coarse stage also runs from
/// [`crate::visual_hull_mesh`] and the hull result is kept when its settled loss (the mean of
/// the last 10 % of steps) is lower than the Poisson result's by more than
/// [`InitOptions::hull_alternative_margin`] (the report says which, with both losses). When
/// [`untangle`](fn@crate::untangle) leaves crossings, the coarse stage runs again from the same start with the
/// next remesher seeds, all but the first rerun with the remesher's repairs on (at most
/// [`COARSE_RESEEDS`] times; [`ReconReport::coarse_reseeds`]), and the run with the fewest
/// crossings left is kept. A crumpled coarse mesh (views that contradict each other: see
/// [`CRUMPLED_PAIRS_PER_TRIANGLE`]) is not untangled, and all its reruns have the repairs on; a rerun reports its steps to `progress` as a coarse stage of its own.
/// With [`ReconOptions::starts`] above 1, everything after the start mesh runs once per
/// start with its own remesher seeds, and the fit with the fewest crossings left, then the
/// lowest final view loss, is returned ([`ReconReport::start_losses`]); each start reports
/// its coarse, untangle and polish stages to `progress` again, and the stage timings add up
/// all starts. `progress` receives [`Progress`] events (pass `&mut |_| {}` to ignore them).
pub fn reconstruct(
    views: &ViewSet,
    options: &ReconOptions,
    progress: &mut dyn FnMut(Progress),
) -> Result<(Mesh, ReconReport)> {
    let start = Instant::now();
    if options.starts == 0 {
        return Err(Error::invalid("starts", "at least 1 fit (got 0)"));
    }
    if options.hopeless_view_loss.is_nan() || options.hopeless_view_loss < 0.0 {
        return Err(Error::invalid(
            "hopeless_view_loss",
            format!("a view loss ≥ 0 (or infinity to run every start), got {}", options.hopeless_view_loss),
        ));
    }
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
    let (init, init_report, alternative) = start_meshes(views, &options.init, true)?;
    progress(Progress { stage: Stage::Init, done: 1, total: 1, loss: None });
    let (mut kept, mut start_losses, mut start_kept) = (None::<Fit>, Vec::with_capacity(options.starts), 0);
    // Seconds of the coarse, untangle and polish stages over all starts.
    let (mut coarse_seconds, mut untangle_seconds, mut polish_seconds) = (0.0, 0.0, 0.0);
    for k in 0..options.starts {
        // Seeds far enough apart that no start repeats another's reruns.
        let seed = options.coarse.seed.wrapping_add((k * (COARSE_RESEEDS + 1)) as u64);
        let fit = fit_views(views, &init, alternative.as_ref(), init_report.clone(), options, seed, progress)?;
        start_losses.push(fit.polish.loss_after);
        coarse_seconds += fit.coarse.seconds;
        untangle_seconds += fit.untangle_seconds;
        polish_seconds += fit.polish.seconds;
        let better = kept.as_ref().is_none_or(|best| {
            (fit.untangle.after, fit.polish.loss_after) < (best.untangle.after, best.polish.loss_after)
        });
        if better {
            kept = Some(fit);
            start_kept = k;
        }
        if k == 0 && start_losses[0] / views.len() as f32 > options.hopeless_view_loss {
            break;
        }
    }
    let starts_skipped = options.starts - start_losses.len();
    let fit = kept.expect("at least one start");
    let stages = vec![
        StageTiming { stage: Stage::Init, seconds: fit.init.seconds },
        StageTiming { stage: Stage::Coarse, seconds: coarse_seconds },
        StageTiming { stage: Stage::Untangle, seconds: untangle_seconds },
        StageTiming { stage: Stage::Polish, seconds: polish_seconds },
    ];
    let report = ReconReport {
        init: fit.init,
        coarse: fit.coarse,
        untangle: fit.untangle,
        polish: fit.polish,
        coarse_reseeds: fit.reseeds,
        remesh_repairs: fit.repaired,
        stages,
        start_losses,
        start_kept,
        starts_skipped,
        triangles: fit.mesh.triangle_count(),
        views: view_agreement(views, &fit.mesh)?,
        seconds: start.elapsed().as_secs_f64(),
    };
    Ok((fit.mesh, report))
}

/// One fit of [`reconstruct`]: its mesh and what each stage reported.
struct Fit {
    mesh: Mesh,
    init: InitReport,
    coarse: CoarseReport,
    untangle: UntangleReport,
    polish: PolishReport,
    reseeds: usize,
    repaired: bool,
    untangle_seconds: f64,
}

/// The coarse stage (from `init` and, when given, also from the hull `alternative`), untangling
/// (with reruns of the coarse stage while crossings are left) and polishing, with the
/// remesher's first seed `seed`: one start of [`reconstruct`]. `init_report` describes `init`
/// and comes back amended with the choice between the two starts.
fn fit_views(
    views: &ViewSet,
    init: &Mesh,
    alternative: Option<&Mesh>,
    mut init_report: InitReport,
    options: &ReconOptions,
    seed: u64,
    progress: &mut dyn FnMut(Progress),
) -> Result<Fit> {
    let coarse_options = options.coarse.with_seed(seed);
    let runs = 1 + usize::from(alternative.is_some());
    let total = coarse_options.steps * runs;
    let (mut mesh, mut coarse_report) = reconstruct_coarse(views, init, &coarse_options, &mut |done, _, loss| {
        progress(Progress { stage: Stage::Coarse, done, total, loss: Some(loss) })
    })?;
    // The start of the result kept, for a rerun with another seed (below).
    let mut start_mesh = init;
    if let Some(hull) = alternative {
        let offset = coarse_options.steps;
        let (hull_mesh, hull_report) = reconstruct_coarse(views, hull, &coarse_options, &mut |done, _, loss| {
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
    let (mut untangled, mut untangle_report, crumpled) = untangle_unless_crumpled(&mesh, options.untangle_rounds)?;
    // Untangling that ends with crossings left (rare on consistent views: 1 of 154 coarse
    // meshes in the measurements of `untangle`'s docs, a chaotic outcome of the remesher's
    // choices) gets the coarse stage again from the same start: with the next remesher seed,
    // then with the remesher's repairs on and the seeds after (views that contradict each
    // other crumple the surface into patches of sub-floor triangles that untangling cannot
    // always clear; the repairs leave far fewer, at some cost in detail). A crumpled first
    // run (see `CRUMPLED_PAIRS_PER_TRIANGLE`) has all its reruns with the repairs: another
    // seed without them crumples the same way. The run with the fewest crossings left is kept.
    let (mut reseeds, mut reseed_seconds, mut repaired) = (0, 0.0, false);
    while untangle_report.after > 0 && options.untangle_rounds > 0 && reseeds < COARSE_RESEEDS {
        reseeds += 1;
        let coarse =
            coarse_options.with_seed(seed.wrapping_add(reseeds as u64)).with_remesh_repairs(crumpled || reseeds > 1);
        let (again, again_report) = reconstruct_coarse(views, start_mesh, &coarse, &mut |done, total, loss| {
            progress(Progress { stage: Stage::Coarse, done, total, loss: Some(loss) })
        })?;
        let (again_untangled, again_untangle, _) = untangle_unless_crumpled(&again, options.untangle_rounds)?;
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
    let (mesh, polish_report) = polish_moved(views, &mesh, &untangled, &options.coarse, options.polish_steps)?;
    progress(Progress { stage: Stage::Polish, done: 1, total: 1, loss: Some(polish_report.loss_after) });
    Ok(Fit {
        mesh,
        init: init_report,
        coarse: coarse_report,
        untangle: untangle_report,
        polish: polish_report,
        reseeds,
        repaired,
        untangle_seconds,
    })
}

/// A coarse mesh counts as crumpled when it has more than [`CRUMPLED_MIN_PAIRS`] crossing
/// triangle pairs and more than this many per triangle: its views contradict each other (a
/// diffusion model's noise) so badly that the remesher multiplied the triangles, and
/// [`reconstruct`] does not untangle it but runs the coarse stage again with the remesher's
/// repairs.
///
/// Measured on tiny-model noise views at 32² (fast preset): first runs of 64 916 triangles
/// with 186 612 pairs (2.9 per triangle; untangling took 50 s and left 419, a plain rerun the
/// same again) and of 64 698 triangles with 122 472 pairs (1.9; 28 s, 76 left), where repaired
/// runs have 6–10 k triangles and 400–1 200 pairs and untangle in about a second. The ratio
/// alone does not tell these from a view of another object, which untangles well without the
/// repairs: at 256² (default preset), one wrong view leaves 0.3–1.4 pairs per triangle on
/// spot, the armadillo, the koala, the plane and the fandisk and 2.9 on the horse (11 908
/// pairs on 4 062 triangles, untangled in seconds, CD 0.0198, where the repaired run has 544
/// triangles). Hence both limits.
pub const CRUMPLED_PAIRS_PER_TRIANGLE: f32 = 1.5;

/// The fewest crossing pairs of a crumpled coarse mesh (see [`CRUMPLED_PAIRS_PER_TRIANGLE`]).
/// The crumpled runs measured there had 120–190 k pairs and took 28–50 s to untangle; the
/// wrong views, 2–17 k pairs and seconds.
pub const CRUMPLED_MIN_PAIRS: usize = 50_000;

/// [`untangle`](fn@crate::untangle), except for a crumpled mesh (see
/// [`CRUMPLED_PAIRS_PER_TRIANGLE`]), which is returned as it is (report: no rounds) with `true`.
fn untangle_unless_crumpled(mesh: &Mesh, max_rounds: usize) -> Result<(Mesh, UntangleReport, bool)> {
    let mut positions = mesh.positions().to_vec();
    let triangles = mesh.triangles();
    let pairs = self_intersections(&positions, triangles)?;
    if pairs.len() > CRUMPLED_MIN_PAIRS && pairs.len() as f32 > CRUMPLED_PAIRS_PER_TRIANGLE * triangles.len() as f32 {
        let report = UntangleReport { before: pairs.len(), after: pairs.len(), rounds: 0 };
        return Ok((mesh.clone(), report, true));
    }
    let report = untangle_crossing(&mut positions, triangles, pairs, max_rounds)?;
    Ok((Mesh::new(positions, triangles.to_vec())?, report, false))
}

/// Most reruns of the coarse stage when [`untangle`](fn@crate::untangle) leaves crossings (see [`reconstruct`]):
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

/// Rings of neighbours around the vertices [`untangle`](fn@crate::untangle) moved that [`polish`] may move too.
/// Measured (orthographic, rocker arm, 60 steps): 2 rings CD 0.0075, 4 rings 0.0076.
const POLISH_RINGS: usize = 2;

/// [`polish`] of `untangled` (the result of untangling `fitted`) with the vertices
/// untangling moved, and [`POLISH_RINGS`] rings around them, free: the clean-up after a fit
/// that [`reconstruct`] and [`crate::refine_mesh`] share.
pub(crate) fn polish_moved(
    views: &ViewSet,
    fitted: &Mesh,
    untangled: &Mesh,
    options: &CoarseOptions,
    steps: usize,
) -> Result<(Mesh, PolishReport)> {
    let free = grow_rings(untangled, moved_vertices(fitted, untangled), POLISH_RINGS);
    polish(views, untangled, &free, options, steps)
}

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
        CoarseReport { losses, triangle_counts: Vec::new(), view_weights: Vec::new(), seconds: 0.0 }
    }

    /// `n` triangles with corners drawn uniformly in the unit cube (a deterministic LCG).
    fn random_triangles(n: usize) -> Mesh {
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = move || {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let positions: Vec<[f32; 3]> = (0..3 * n).map(|_| [next(), next(), next()]).collect();
        let triangles = (0..n as u32).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]).collect();
        Mesh::new(positions, triangles).unwrap()
    }

    /// A mesh past both limits is left as it is; one with few crossings per triangle, or
    /// too few crossings in all, is untangled.
    #[test]
    fn a_crumpled_mesh_is_not_untangled() {
        let crumpled = random_triangles(800);
        let pairs = self_intersections(crumpled.positions(), crumpled.triangles()).unwrap().len();
        assert!(pairs > CRUMPLED_MIN_PAIRS, "{pairs} pairs");
        let (same, report, is_crumpled) = untangle_unless_crumpled(&crumpled, 5).unwrap();
        assert!(is_crumpled);
        assert_eq!((report.before, report.after, report.rounds), (pairs, pairs, 0));
        assert_eq!(same.positions(), crumpled.positions());

        // Many pairs per triangle but fewer than the limit in all: untangled.
        let dense = random_triangles(100);
        let (moved, report, is_crumpled) = untangle_unless_crumpled(&dense, 5).unwrap();
        assert!(!is_crumpled && report.before as f32 > CRUMPLED_PAIRS_PER_TRIANGLE * 100.0, "{report:?}");
        assert_eq!(report.rounds, 5);
        assert_ne!(moved.positions(), dense.positions());
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
