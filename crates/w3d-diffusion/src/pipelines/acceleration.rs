//! Training-free accelerations of a sampling loop, shared by multi-view generation
//! ([`crate::pipelines::multiview::SampleOptions`]) and the refinement enhancer
//! ([`crate::pipelines::enhancer::EnhancerOptions`]): guidance in a limited interval,
//! DeepCache, bf16 products and token merging. Each does less arithmetic per step for a small,
//! measured change of the result (`docs/benchmarks.md`, "Training-free acceleration"); the
//! default is none of them, the reference arithmetic.
//!
//! ```
//! use w3d_diffusion::pipelines::acceleration::Acceleration;
//!
//! let a = Acceleration::default().with_guidance_interval([0.1, 0.7]).with_cache_interval(3);
//! assert!(a.validate().is_ok());
//! // Timestep 900 of 1000 lies outside [0.1, 0.7]: that step runs the conditional branch only.
//! assert!(!a.guided_at(900, 1000) && a.guided_at(500, 1000));
//! assert_eq!(a.describe(), "guidance in [0.1, 0.7], DeepCache every 3 from skip 1");
//! assert!(Acceleration::default().with_cache_interval(0).validate().is_err());
//! ```

use w3d_core::Error;

use crate::compute::{PassSettings, Products};

/// The highest DeepCache interval [`Acceleration::validate`] accepts: a full pass at least
/// every this many steps.
pub const MAX_CACHE_INTERVAL: usize = 50;

/// Training-free accelerations of a sampling loop (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Acceleration {
    /// Where the unconditional branch of classifier-free guidance runs, as noise levels `t/T`
    /// (`T` the training schedule's length, 1000): steps whose timestep lies outside
    /// `[lo, hi]` run the conditional branch alone (guidance 1) and cost half a guided step
    /// (Kynkäänniemi et al. 2024, "Applying guidance in a limited interval"). `[0, 1]`: every
    /// step, the reference.
    pub guidance_interval: [f64; 2],
    /// DeepCache (Ma et al. 2023): one full UNet pass every `cache_interval` steps, and in
    /// between only the shallow branch from skip [`Acceleration::cache_depth`], the deep
    /// features taken from the last full pass ([`crate::models::unet::FeatureCache`]). 1: every
    /// pass full, the reference.
    pub cache_interval: usize,
    /// The skip the shallow branch of a cached pass starts at
    /// ([`crate::models::unet::FeatureCache`]: 0 is `conv_in`; 1 adds the first down layer).
    pub cache_depth: usize,
    /// How the model passes compute — the UNet's and, for bf16 products, the VAE's of the same
    /// call: bf16 products, token merging ([`PassSettings`]).
    pub pass: PassSettings,
}

impl Default for Acceleration {
    /// None: guidance at every step, every pass full, f32 products, no token merging.
    fn default() -> Self {
        Self { guidance_interval: [0.0, 1.0], cache_interval: 1, cache_depth: 1, pass: PassSettings::default() }
    }
}

impl Acceleration {
    w3d_core::setters! {
        with_guidance_interval(guidance_interval: [f64; 2]);
        with_cache_interval(cache_interval: usize);
        with_cache_depth(cache_depth: usize);
        with_pass(pass: PassSettings);
    }

    /// Checks the settings: a guidance interval `0 ≤ lo ≤ hi ≤ 1`, a cache interval in
    /// `1..=`[`MAX_CACHE_INTERVAL`] and valid [`PassSettings`]. (The cache depth is checked
    /// against the model's skips when sampling starts; bf16 on a CPU without it is not an
    /// error: the products stay f32, [`Products::resolve`].)
    pub fn validate(&self) -> Result<(), Error> {
        let [lo, hi] = self.guidance_interval;
        if !(0.0..=1.0).contains(&lo) || !(0.0..=1.0).contains(&hi) || lo > hi {
            return Err(Error::invalid(
                "guidance_interval",
                format!("noise levels lo ≤ hi within [0, 1] (found [{lo}, {hi}])"),
            ));
        }
        if !(1..=MAX_CACHE_INTERVAL).contains(&self.cache_interval) {
            return Err(Error::invalid(
                "cache_interval",
                format!(
                    "a full UNet pass every 1..={MAX_CACHE_INTERVAL} steps (1: no caching; found {})",
                    self.cache_interval
                ),
            ));
        }
        self.pass.validate()
    }

    /// Whether a step at timestep `t` of a schedule of `train_timesteps` lies inside the
    /// guidance interval (the caller also skips the unconditional branch at guidance 1).
    pub fn guided_at(&self, t: usize, train_timesteps: usize) -> bool {
        let level = t as f64 / train_timesteps.max(1) as f64;
        self.guidance_interval[0] <= level && level <= self.guidance_interval[1]
    }

    /// DeepCache's rule: whether a branch whose cache a full pass last filled at step
    /// `filled_at` reuses it at step `step` — caching is on, `step` is not a multiple of the
    /// interval, and the cache was filled at or after the last multiple. Every sampling loop
    /// of the crate decides its passes by this rule.
    ///
    /// ```
    /// use w3d_diffusion::Acceleration;
    ///
    /// let every_3 = Acceleration::default().with_cache_interval(3);
    /// assert!(every_3.reuses_cache(4, Some(3)) && every_3.reuses_cache(5, Some(3)));
    /// assert!(!every_3.reuses_cache(6, Some(3))); // a multiple of the interval: a full pass
    /// assert!(!every_3.reuses_cache(4, Some(0)) && !every_3.reuses_cache(1, None)); // stale, empty
    /// assert!(!Acceleration::default().reuses_cache(1, Some(0))); // interval 1: no caching
    /// ```
    pub fn reuses_cache(&self, step: usize, filled_at: Option<usize>) -> bool {
        let n = self.cache_interval.max(1);
        n > 1 && !step.is_multiple_of(n) && filled_at >= Some(step - step % n)
    }

    /// Whether every setting is the reference's.
    pub fn is_none(&self) -> bool {
        *self == Self::default()
    }

    /// A short description for run reports and logs, e.g. `"guidance in [0.1, 0.7],
    /// DeepCache every 3 from skip 1, bf16 products"`, or `"none"`.
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        if self.guidance_interval != [0.0, 1.0] {
            parts.push(format!("guidance in [{}, {}]", self.guidance_interval[0], self.guidance_interval[1]));
        }
        if self.cache_interval > 1 {
            parts.push(format!("DeepCache every {} from skip {}", self.cache_interval, self.cache_depth));
        }
        if self.pass.token_merge > 0.0 {
            parts.push(format!("token merging {}", self.pass.token_merge));
        }
        if self.pass.products != Products::F32 {
            parts.push(format!("{} products", self.pass.products.name()));
        }
        if parts.is_empty() { "none".into() } else { parts.join(", ") }
    }
}
