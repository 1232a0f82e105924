//! Command-line value types shared by several subcommands: presets, rigs and camera types
//! as closed lists, so a typo is refused with the accepted values before any work.

use wonder3d::raster::MAX_VIEW_SIZE;
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

/// `--device`: where the diffusion model runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum DeviceArg {
    /// The CPU, all cores (Burn's flex backend).
    Cpu,
    /// The GPU through wgpu: Vulkan, Metal or DirectX 12 (a build with the `wgpu` feature,
    /// docs/gpu.md).
    Wgpu,
}

#[cfg(feature = "diffusion")]
impl DeviceArg {
    /// The library's name for this device.
    pub fn compute_device(self) -> wonder3d::ComputeDevice {
        match self {
            DeviceArg::Cpu => wonder3d::ComputeDevice::Cpu,
            DeviceArg::Wgpu => wonder3d::ComputeDevice::Wgpu,
        }
    }
}

/// `--scheduler`: the sampling algorithm of generation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SchedulerArg {
    /// DDIM, the authors' sampler (50 steps).
    Ddim,
    /// DPM-Solver++(2M): deterministic, about 20 steps for DDIM's 50.
    #[value(name = "dpmpp-2m")]
    DpmPp2m,
    /// UniPC-bh2 predictor–corrector: deterministic, few steps like dpmpp-2m (the enhancer's sampler).
    #[value(name = "unipc")]
    Unipc,
}

/// Orients a closed mesh read from `path` outward ([`wonder3d::Mesh::orient_outward`]),
/// with a note on stderr when it was wound inward: normals, masks, texture visibility and
/// volume IoU all assume outward triangles.
pub fn orient_outward(mesh: &mut wonder3d::Mesh, path: &std::path::Path) {
    if mesh.orient_outward() {
        eprintln!("note: {} is a closed mesh wound inward (negative volume); using it flipped outward", path.display());
    }
}

/// Largest `--size` / `--texture-size` of a baked texture: the bake keeps several float
/// images of the atlas (~2 GB at 8192²).
pub const MAX_TEXTURE_SIZE: u32 = 8192;

/// Largest `wonder3d eval --samples`: ~1 GB of samples and k-d trees (10⁸ aborted on
/// allocation, 10¹¹ asked for 1.2 TB).
pub const MAX_EVAL_SAMPLES: usize = 10_000_000;

/// A whole number in `lo..=hi`, read as a signed value so that `-1` gets this range
/// message rather than clap's "unexpected argument" (whose `-- -1` tip cannot work for an
/// option value).
fn whole_in<T: TryFrom<i128>>(s: &str, lo: i128, hi: i128, unit: &str) -> Result<T, String> {
    let range = || format!("a whole number from {lo} to {hi}{unit}");
    let v: i128 = s.trim().parse().map_err(|_| format!("expected {}, got {s:?}", range()))?;
    if v < lo || v > hi {
        return Err(format!("expected {}, got {v}", range()));
    }
    T::try_from(v).map_err(|_| format!("expected {}, got {v}", range()))
}

/// A finite number in `lo..=hi` (NaN and infinities refused).
fn finite_in(s: &str, lo: f64, hi: f64, what: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("expected {what} from {lo} to {hi}, got {s:?}"))?;
    if !v.is_finite() || v < lo || v > hi {
        return Err(format!("expected {what} from {lo} to {hi}, got {s}"));
    }
    Ok(v)
}

/// `--size` of rendered views: 1 to [`MAX_VIEW_SIZE`] pixels.
pub fn view_size(s: &str) -> Result<u32, String> {
    whole_in(s, 1, MAX_VIEW_SIZE.into(), " pixels (memory grows with the square)")
}

/// `--size` of `wonder3d dataset`: [`wonder3d::dataset::MIN_SIZE`] to
/// [`wonder3d::dataset::MAX_SIZE`] pixels.
pub fn dataset_size(s: &str) -> Result<u32, String> {
    use wonder3d::dataset::{MAX_SIZE, MIN_SIZE};
    whole_in(s, MIN_SIZE.into(), MAX_SIZE.into(), " pixels")
}

/// `--samples` of `wonder3d dataset`: 1 to [`wonder3d::dataset::MAX_SAMPLES`] per mesh.
pub fn dataset_samples(s: &str) -> Result<usize, String> {
    whole_in(s, 1, wonder3d::dataset::MAX_SAMPLES as i128, " samples per mesh")
}

/// A texture side: 8 to [`MAX_TEXTURE_SIZE`] texels.
pub fn texture_size(s: &str) -> Result<u32, String> {
    whole_in(s, 8, MAX_TEXTURE_SIZE.into(), " texels (memory grows with the square)")
}

/// Texels of padding or dilation: 0 to 1024 (the bake also checks them against the size).
pub fn texels(s: &str) -> Result<u32, String> {
    whole_in(s, 0, 1024, " texels")
}

/// `--samples` of `wonder3d eval`: 1 to [`MAX_EVAL_SAMPLES`].
pub fn eval_samples(s: &str) -> Result<usize, String> {
    whole_in(s, 1, MAX_EVAL_SAMPLES as i128, " surface samples")
}

/// `prepare --size`: 16 to 8192 pixels.
pub fn prepared_size(s: &str) -> Result<u32, String> {
    whole_in(s, 16, 8192, " pixels")
}

/// `prepare --min-confidence`: a confidence in [0, 1].
pub fn confidence(s: &str) -> Result<f32, String> {
    finite_in(s, 0.0, 1.0, "a confidence").map(|c| c as f32)
}

/// `batch --jobs`: 1 to 256 items at once.
pub fn jobs(s: &str) -> Result<u16, String> {
    whole_in(s, 1, 256, " items at once")
}

/// A seed: 0 to 2⁶⁴ − 1.
pub fn seed(s: &str) -> Result<u64, String> {
    whole_in(s, 0, u64::MAX.into(), "")
}

/// A learning rate: finite, above 0, at most 1.
pub fn learning_rate(s: &str) -> Result<f64, String> {
    let lr = finite_in(s, 0.0, 1.0, "a learning rate")?;
    if lr == 0.0 { Err("a learning rate above 0".into()) } else { Ok(lr) }
}

/// EMA decay: finite, in [0, 1).
pub fn ema_decay(s: &str) -> Result<f64, String> {
    let d = finite_in(s, 0.0, 1.0, "an EMA decay")?;
    if d >= 1.0 { Err("an EMA decay below 1".into()) } else { Ok(d) }
}

/// Refinement iterations: 0 to 10.
pub fn refine_iterations(s: &str) -> Result<usize, String> {
    whole_in(s, 0, 10, " iterations")
}

/// `--simplify` of `wonder3d refine`: the mesh refinement's simplification tolerance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Simplify(pub Option<f32>);

/// `--simplify`: a tolerance in world units, 0 to 0.1 (the unit cube's tenth), or `off`.
pub fn simplify(s: &str) -> Result<Simplify, String> {
    if s == "off" {
        return Ok(Simplify(None));
    }
    finite_in(s, 0.0, 0.1, "a tolerance in world units (or `off`)").map(|t| Simplify(Some(t as f32)))
}

/// DDIM steps: 1 to 1000 (the scheduler's training steps).
pub fn steps(s: &str) -> Result<usize, String> {
    whole_in(s, 1, 1000, " steps")
}

/// Draws merged into one set of views: a whole number from 1 to 64.
pub fn draws(s: &str) -> Result<usize, String> {
    whole_in(s, 1, 64, " draws")
}

/// `--starts`: reconstructions tried, the best fit to the views kept; a whole number from 1 to 64.
pub fn starts(s: &str) -> Result<usize, String> {
    whole_in(s, 1, 64, " fits")
}

/// Classifier-free guidance scale: finite, 0 to 100 (1 = no unconditional branch).
pub fn guidance(s: &str) -> Result<f64, String> {
    finite_in(s, 0.0, 100.0, "a guidance scale")
}

/// DDIM eta: finite, 0 (deterministic) to 1 (the reference's stochastic sampling).
pub fn eta(s: &str) -> Result<f64, String> {
    finite_in(s, 0.0, 1.0, "an eta")
}

/// The texture view-weight exponent k of |cos|^k: finite, 0 to 64.
pub fn exponent(s: &str) -> Result<f32, String> {
    finite_in(s, 0.0, 64.0, "an exponent").map(|v| v as f32)
}

/// `--min-snr-gamma`: γ of the Min-SNR loss weighting, or none.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MinSnrGamma(pub Option<f64>);

/// Min-SNR γ: `none`, or finite, above 0, at most 1000.
pub fn min_snr_gamma(s: &str) -> Result<MinSnrGamma, String> {
    if s == "none" {
        return Ok(MinSnrGamma(None));
    }
    let gamma = finite_in(s, 0.0, 1000.0, "a Min-SNR gamma (or none)")?;
    if gamma == 0.0 { Err("a Min-SNR gamma above 0 (or none)".into()) } else { Ok(MinSnrGamma(Some(gamma))) }
}

/// `--products`: the precision of the diffusion model's large matrix products.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ProductsArg {
    /// bf16 where this CPU has AVX-512 BF16, f32 elsewhere, without a note (the default: on
    /// the small model bf16 moved the normal error by at most 0.03° and the mask IoU by at
    /// most 0.001, docs/benchmarks.md).
    Auto,
    /// f32 products and sums (the reference arithmetic).
    F32,
    /// bfloat16 products summed in f32, on a CPU with AVX-512 BF16 (elsewhere f32, with a note).
    Bf16,
}

/// Largest `--cache-interval`: a full UNet pass at least every 50 steps (the library's
/// `MAX_CACHE_INTERVAL`, checked at compile time below).
pub const MAX_CACHE_INTERVAL: usize = 50;

/// Largest `--cache-depth` the parser accepts; the model's UNet bounds it further (0..12 for
/// Stable Diffusion 1.5, 0..6 for the small model), checked once the model is loaded.
pub const MAX_CACHE_DEPTH: usize = 63;

/// Largest `--token-merge` (the library's `MAX_TOKEN_MERGE`, checked at compile time below).
pub const MAX_TOKEN_MERGE: f64 = 0.9;

#[cfg(feature = "diffusion")]
const _: () = {
    use wonder3d::diffusion::{compute, pipelines::acceleration};
    assert!(MAX_CACHE_INTERVAL == acceleration::MAX_CACHE_INTERVAL);
    assert!(MAX_TOKEN_MERGE as f32 == compute::MAX_TOKEN_MERGE);
};

/// `--guidance-interval LO,HI`: two noise levels `t/T` in [0, 1] with `LO ≤ HI`.
pub fn guidance_interval(s: &str) -> Result<[f64; 2], String> {
    const EXPECTED: &str = "two noise levels LO,HI from 0 to 1 with LO ≤ HI (e.g. 0.1,0.7)";
    let Some((lo, hi)) = s.split_once(',') else {
        return Err(format!("expected {EXPECTED}, got {s:?}"));
    };
    let level = |v: &str| finite_in(v, 0.0, 1.0, "noise levels LO,HI").map_err(|e| format!("{e} (in {s:?})"));
    let (lo, hi) = (level(lo)?, level(hi)?);
    if lo > hi {
        return Err(format!("expected {EXPECTED}, got LO {lo} above HI {hi}"));
    }
    Ok([lo, hi])
}

/// `--cache-interval`: a full UNet pass every 1 to [`MAX_CACHE_INTERVAL`] steps.
pub fn cache_interval(s: &str) -> Result<usize, String> {
    whole_in(s, 1, MAX_CACHE_INTERVAL as i128, " steps between full UNet passes (1: no caching)")
}

/// `--cache-depth`: a skip of the UNet, 0 to [`MAX_CACHE_DEPTH`] (the model bounds it further).
pub fn cache_depth(s: &str) -> Result<usize, String> {
    whole_in(s, 0, MAX_CACHE_DEPTH as i128, " (a skip of the model's UNet)")
}

/// `--token-merge`: a fraction of tokens in [0, [`MAX_TOKEN_MERGE`]].
pub fn token_merge(s: &str) -> Result<f32, String> {
    finite_in(s, 0.0, MAX_TOKEN_MERGE, "a fraction of tokens").map(|r| r as f32)
}

/// The training-free accelerations of a sampling loop (`w3d_diffusion`'s `Acceleration`),
/// shared by the sampling flags of `generate`, `run`, `batch` and `demo` and by `refine`'s
/// diffusion enhancer. Every default is the reference arithmetic; the measured speed and
/// quality of each are in docs/benchmarks.md, "Training-free acceleration".
#[derive(clap::Args, Clone, Debug)]
#[cfg_attr(not(feature = "diffusion"), allow(dead_code))]
pub struct AccelerationArgs {
    /// Classifier-free guidance only at noise levels t/T from LO to HI (0: clean, 1: pure
    /// noise; LO ≤ HI); the steps outside run the conditional branch alone, at half the cost
    /// of a guided step (0,1: guidance at every step, the reference).
    #[arg(long, value_name = "LO,HI", default_value = "0,1", allow_hyphen_values = true, value_parser = guidance_interval)]
    pub guidance_interval: [f64; 2],
    /// DeepCache: a full UNet pass every N steps, the passes between computing only the
    /// shallow layers down to --cache-depth and reusing the deep features of the last full
    /// pass; 1 to 50 (1: no caching, every pass full, the reference).
    #[arg(long, value_name = "N", default_value_t = 1, allow_hyphen_values = true, value_parser = cache_interval)]
    pub cache_interval: usize,
    /// DeepCache: the skip connection the cached passes recompute down to (0: conv_in only;
    /// deeper is slower and closer to a full pass); a skip of the model's UNet, 0–11 for
    /// Stable Diffusion 1.5 and 0–5 for the small model, checked against the model before it
    /// samples (no effect while --cache-interval is 1).
    #[arg(long, value_name = "D", default_value_t = 1, allow_hyphen_values = true, value_parser = cache_depth)]
    pub cache_depth: usize,
    /// Precision of the model's large matrix products: bf16 products summed in f32 (needs
    /// AVX-512 BF16; asked for on a CPU without it, the products stay f32 with a one-line
    /// note), f32 (the reference arithmetic), or auto: bf16 where the CPU has it, silently f32
    /// elsewhere.
    #[arg(long, value_enum, default_value_t = ProductsArg::Auto)]
    pub products: ProductsArg,
    /// Fraction of the tokens merged into their most similar neighbour before the
    /// highest-resolution multi-view self-attention and copied back after it, from 0 to 0.9
    /// (0: none merged, the reference).
    #[arg(long, value_name = "R", default_value_t = 0.0, allow_hyphen_values = true, value_parser = token_merge)]
    pub token_merge: f32,
}

impl AccelerationArgs {
    /// Checks the flags before any weights load (errors name the flag) and describes what
    /// will run, as the reports name it (`"none"`, or e.g. `"DeepCache every 2 from skip 1"`;
    /// the products as this CPU computes them).
    pub fn check(&self) -> wonder3d::Result<String> {
        #[cfg(feature = "diffusion")]
        return Ok(self.acceleration()?.0.describe());
        // Without the model the parsers' ranges are all there is to check, and nothing runs.
        #[cfg(not(feature = "diffusion"))]
        Ok("none".into())
    }
}

/// ` (acceleration: …)` for a summary line, or nothing for `"none"`.
pub fn acceleration_note(description: &str) -> String {
    if description == "none" { String::new() } else { format!(" (acceleration: {description})") }
}

/// The help of `refine`'s acceleration flags: they act on the diffusion enhancer only
/// (`#[command(mut_args(…))]` of `refine`'s arguments).
pub fn for_the_enhancer(arg: clap::Arg) -> clap::Arg {
    const IDS: [&str; 5] = ["guidance_interval", "cache_interval", "cache_depth", "products", "token_merge"];
    if !IDS.contains(&arg.get_id().as_str()) {
        return arg;
    }
    let help = arg.get_help().map(ToString::to_string).unwrap_or_default();
    arg.help(format!(
        "{help}. For the diffusion enhancer (--enhancer DIR), in every iteration; accepted and without effect \
         with identity or oracle:MESH"
    ))
}

#[cfg(feature = "diffusion")]
impl AccelerationArgs {
    /// The accelerations these flags ask for, checked (errors name the flag), with the
    /// products this CPU computes, and a one-line note when that is not what was asked
    /// (bf16 on a CPU without AVX-512 BF16 stays f32). Call it before any weights load.
    pub fn acceleration(&self) -> wonder3d::Result<(wonder3d::Acceleration, Option<String>)> {
        use wonder3d::diffusion::compute::{PassSettings, Products};
        let (products, note) = match self.products {
            ProductsArg::Auto => (Products::Bf16.resolve().0, None),
            ProductsArg::F32 => (Products::F32, None),
            ProductsArg::Bf16 => Products::Bf16.resolve(),
        };
        let acceleration = wonder3d::Acceleration::default()
            .with_guidance_interval(self.guidance_interval)
            .with_cache_interval(self.cache_interval)
            .with_cache_depth(self.cache_depth)
            .with_pass(PassSettings::default().with_products(products).with_token_merge(self.token_merge));
        name_acceleration_flags(acceleration.validate())?;
        Ok((acceleration, note))
    }
}

/// `result` with the library's names of the acceleration settings (`cache_depth`, …) in its
/// error replaced by their flags (`--cache-depth`, …), also behind a context a caller put in
/// front (`MESH … in VIEWS …: cache_depth`: the flag is what to fix); other errors pass
/// unchanged. (`refine`'s enhancer checks the cache depth against its UNet only when it
/// runs; the generation's model is checked as soon as it loads, `generate::load`.)
pub fn name_acceleration_flags<T>(result: wonder3d::Result<T>) -> wonder3d::Result<T> {
    const FLAGS: [(&str, &str); 5] = [
        ("guidance_interval", "--guidance-interval"),
        ("cache_interval", "--cache-interval"),
        ("cache_depth", "--cache-depth"),
        ("token_merge", "--token-merge"),
        ("products", "--products"),
    ];
    result.map_err(|e| match e {
        wonder3d::Error::Invalid { field, expected } => {
            let named = |name: &str| field == name || field.strip_suffix(name).is_some_and(|f| f.ends_with(": "));
            let field = FLAGS.iter().find(|(name, _)| named(name)).map_or(field, |(_, flag)| flag.to_string());
            wonder3d::Error::Invalid { field, expected }
        }
        other => other,
    })
}
