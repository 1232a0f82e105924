//! The whole extraction: initialisation then coarse reconstruction, with presets, a
//! progress callback and one report.

use std::fmt;
use std::str::FromStr;
use std::time::Instant;

use serde::Serialize;
use w3d_core::{Error, Mesh, Result, ViewRig, ViewSet};

use crate::coarse::{CoarseOptions, CoarseReport, reconstruct_coarse};
use crate::init::{InitOptions, InitReport, initial_mesh};

/// Named speed/accuracy trade-offs of [`ReconOptions`] (numbers in `docs/accuracy.md`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
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
pub struct ReconOptions {
    /// The start mesh.
    pub init: InitOptions,
    /// The coarse optimisation.
    pub coarse: CoarseOptions,
}

impl ReconOptions {
    /// The options of a named preset.
    pub fn preset(preset: Preset) -> Self {
        let base = ReconOptions { init: InitOptions::default(), coarse: CoarseOptions::default() };
        match preset {
            Preset::Default => ReconOptions {
                init: InitOptions { edge_length: 0.05, ..base.init },
                coarse: CoarseOptions { steps: 120, lr_decay: 0.99, edge_len_lims: (0.02, 0.1), ..base.coarse },
            },
            Preset::Fast => ReconOptions {
                init: InitOptions { edge_length: 0.06, ..base.init },
                coarse: CoarseOptions { steps: 60, lr_decay: 0.985, edge_len_lims: (0.03, 0.1), ..base.coarse },
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

/// A pipeline stage, as reported to the progress callback and in [`ReconReport`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// Normal integration, concave check, Poisson, hull carving, simplification.
    Init,
    /// The coarse optimisation with continuous remeshing.
    Coarse,
}

/// A progress event: `done` of `total` units of `stage` (the init stage reports 0/1 and
/// 1/1; the coarse stage one unit per step, with the loss before that step).
#[derive(Debug, Clone, Copy, PartialEq)]
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
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StageTiming {
    /// Which stage.
    pub stage: Stage,
    /// Seconds.
    pub seconds: f64,
}

/// Everything [`reconstruct`] measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReconReport {
    /// The start mesh: which one and why.
    pub init: InitReport,
    /// Per-step losses and triangle counts of the coarse stage.
    pub coarse: CoarseReport,
    /// Per-stage wall-clock seconds.
    pub stages: Vec<StageTiming>,
    /// Triangles of the returned mesh.
    pub triangles: usize,
    /// Total wall-clock seconds.
    pub seconds: f64,
}

/// Reconstructs a closed mesh, in the rig's world frame, from the normal maps and masks of
/// `views` (one per view of `rig`, same order): [`initial_mesh`] then
/// [`reconstruct_coarse`]. `progress` receives [`Progress`] events (pass `&mut |_| {}` to
/// ignore them).
pub fn reconstruct(
    views: &ViewSet,
    rig: &ViewRig,
    options: &ReconOptions,
    progress: &mut dyn FnMut(Progress),
) -> Result<(Mesh, ReconReport)> {
    let start = Instant::now();
    progress(Progress { stage: Stage::Init, done: 0, total: 1, loss: None });
    let (init, init_report) = initial_mesh(views, rig, &options.init)?;
    progress(Progress { stage: Stage::Init, done: 1, total: 1, loss: None });
    let (mesh, coarse_report) = reconstruct_coarse(views, rig, &init, &options.coarse, &mut |done, total, loss| {
        progress(Progress { stage: Stage::Coarse, done, total, loss: Some(loss) })
    })?;
    let stages = vec![
        StageTiming { stage: Stage::Init, seconds: init_report.seconds },
        StageTiming { stage: Stage::Coarse, seconds: coarse_report.seconds },
    ];
    let report = ReconReport {
        init: init_report,
        coarse: coarse_report,
        stages,
        triangles: mesh.triangle_count(),
        seconds: start.elapsed().as_secs_f64(),
    };
    Ok((mesh, report))
}
