//! Which sampler a generation run uses.

use w3d_core::Error;

/// The sampling algorithm of a generation run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum SamplerKind {
    /// DDIM ([`DdimScheduler`](crate::DdimScheduler)), the authors' choice: 50 steps, eta 1.
    #[default]
    Ddim,
    /// DPM-Solver++(2M) ([`DpmSolverMultistepScheduler`](crate::DpmSolverMultistepScheduler)): deterministic, about 20 steps.
    DpmSolverPlusPlus2M,
    /// UniPC-bh2 ([`UniPcMultistepScheduler`](crate::UniPcMultistepScheduler)): deterministic predictor–corrector, second
    /// order, the sampler of Wonder3D++'s enhancer; few steps, like DPM-Solver++(2M).
    UniPc,
}

impl SamplerKind {
    /// The name used on the command line and in reports: `ddim`, `dpmpp-2m` or `unipc`.
    pub fn name(self) -> &'static str {
        match self {
            SamplerKind::Ddim => "ddim",
            SamplerKind::DpmSolverPlusPlus2M => "dpmpp-2m",
            SamplerKind::UniPc => "unipc",
        }
    }
}

impl std::fmt::Display for SamplerKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for SamplerKind {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self, Error> {
        match s {
            "ddim" => Ok(SamplerKind::Ddim),
            "dpmpp-2m" | "dpm++2m" | "dpmsolver++" => Ok(SamplerKind::DpmSolverPlusPlus2M),
            "unipc" => Ok(SamplerKind::UniPc),
            other => Err(Error::invalid("scheduler", format!("ddim, dpmpp-2m or unipc (found {other:?})"))),
        }
    }
}
