//! Command-line value types shared by several subcommands: presets, rigs and camera types
//! as closed lists, so a typo is refused with the accepted values before any work.

use wonder3d::{Preset, ViewRig};

/// `--preset`: a named speed/accuracy trade-off of the reconstruction (`docs/accuracy.md`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum PresetArg {
    /// Coarser mesh, 60 steps: a preview in a few seconds.
    Fast,
    /// The balance used by default.
    Default,
    /// Finer mesh, 200 steps.
    Quality,
}

impl From<PresetArg> for Preset {
    fn from(p: PresetArg) -> Preset {
        match p {
            PresetArg::Fast => Preset::Fast,
            PresetArg::Default => Preset::Default,
            PresetArg::Quality => Preset::Quality,
        }
    }
}

/// `--rig`: a camera rig of `w3d-core`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum RigArg {
    /// The Wonder3D 6-view orthographic rig.
    #[value(name = "wonder3d-ortho")]
    Wonder3dOrtho,
    /// The Wonder3D 6-view perspective rig.
    #[value(name = "wonder3d-persp")]
    Wonder3dPersp,
    /// The SyncDreamer 16-view evaluation rig.
    #[value(name = "syncdreamer16")]
    Syncdreamer16,
}

impl RigArg {
    /// The rig.
    pub fn rig(self) -> ViewRig {
        match self {
            RigArg::Wonder3dOrtho => ViewRig::wonder3d_ortho(),
            RigArg::Wonder3dPersp => ViewRig::wonder3d_persp(),
            RigArg::Syncdreamer16 => ViewRig::syncdreamer16(),
        }
    }
}

/// `--camera`: the camera type of generated views.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum CameraArg {
    /// Orthographic views (the `wonder3d-ortho` rig).
    Ortho,
    /// Perspective views (the `wonder3d-persp` rig).
    Persp,
}

/// `--scheduler`: the sampling algorithm of generation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SchedulerArg {
    /// DDIM, the authors' sampler (50 steps).
    Ddim,
    /// DPM-Solver++(2M): deterministic, about 20 steps for DDIM's 50.
    #[value(name = "dpmpp-2m")]
    DpmPp2m,
}
