//! How the models' passes compute on this thread, and a count of the work they did.
//!
//! Two settings change the arithmetic of every layer of a pass rather than the pass's inputs,
//! so they are not arguments of `forward` but a scope around it ([`with_settings`]):
//! - [`Products`]: the precision of the large matrix products (f32, or bf16 products with
//!   f32 sums where the CPU has AVX-512 BF16);
//! - [`PassSettings::token_merge`]: the fraction of tokens merged before the multi-view
//!   self-attention of the highest-resolution level.
//!
//! [`count_work`] counts what the passes inside it evaluated (UNet passes, ResNet and
//! transformer blocks, attention scores, bf16 multiply-adds): the training-free
//! accelerations of [`crate::pipelines::multiview::SampleOptions`] are tested by the work they
//! skip, not by wall time.
//!
//! ```
//! use w3d_diffusion::compute::{self, PassSettings, Products};
//!
//! let settings = PassSettings::default().with_products(Products::Bf16);
//! let ((), work) = compute::count_work(|| {
//!     compute::with_settings(settings, || assert_eq!(compute::settings().products, Products::Bf16));
//! });
//! assert_eq!(compute::settings(), PassSettings::default()); // the scope ended
//! assert_eq!(work.unet_passes, 0);
//! ```

use std::cell::RefCell;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use w3d_core::Error;

/// The precision of the large matrix products (linear layers, convolutions as GEMMs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Products {
    /// f32 products and sums (the reference arithmetic).
    #[default]
    F32,
    /// Both factors rounded to bfloat16 (8 bits of mantissa), products summed in f32, with
    /// the CPU's AVX-512 BF16 dot-product instructions (twice the multiply-adds per
    /// instruction of f32). Where the CPU lacks them ([`Products::supported`]) the products
    /// stay f32.
    Bf16,
}

impl Products {
    /// Whether this CPU computes these products natively: always for f32; for bf16, an x86-64
    /// CPU with AVX-512F and AVX-512 BF16 (`avx512_bf16` in `/proc/cpuinfo`).
    pub fn supported(self) -> bool {
        match self {
            Products::F32 => true,
            Products::Bf16 => bf16_supported(),
        }
    }

    /// The products a run asking for `self` gets on this CPU, and a one-line note when that
    /// is not what it asked for (bf16 on a CPU without it falls back to f32).
    pub fn resolve(self) -> (Products, Option<String>) {
        if self.supported() {
            (self, None)
        } else {
            (
                Products::F32,
                Some("bf16 products need a CPU with AVX-512 BF16 (avx512_bf16); this one has none, so the products stay f32".into()),
            )
        }
    }

    /// The name used by the CLI and the run reports: `f32` or `bf16`.
    pub fn name(self) -> &'static str {
        match self {
            Products::F32 => "f32",
            Products::Bf16 => "bf16",
        }
    }
}

impl std::str::FromStr for Products {
    type Err = Error;

    /// `f32` or `bf16`.
    fn from_str(s: &str) -> Result<Self, Error> {
        match s {
            "f32" => Ok(Products::F32),
            "bf16" => Ok(Products::Bf16),
            other => Err(Error::invalid("products", format!("f32 or bf16 (found {other:?})"))),
        }
    }
}

#[cfg(target_arch = "x86_64")]
fn bf16_supported() -> bool {
    std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("avx512bf16")
}

#[cfg(not(target_arch = "x86_64"))]
fn bf16_supported() -> bool {
    false
}

/// The settings of the passes run inside [`with_settings`]. Default: f32 products, no token
/// merging — the reference arithmetic.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[non_exhaustive]
pub struct PassSettings {
    /// Precision of the matrix products.
    pub products: Products,
    /// Fraction of the tokens in `[0, 1)` merged into their most similar neighbour before
    /// the multi-view self-attention of the highest-resolution level, and copied back after
    /// it (0: none merged).
    pub token_merge: f32,
}

impl PassSettings {
    w3d_core::setters! {
        with_products(products: Products);
        with_token_merge(token_merge: f32);
    }

    /// Checks the settings: `token_merge` in `[0, 0.9]` (beyond, too few tokens are left for
    /// the attention to mean anything).
    pub fn validate(&self) -> Result<(), Error> {
        if !(0.0..=MAX_TOKEN_MERGE).contains(&self.token_merge) {
            return Err(Error::invalid(
                "token_merge",
                format!("a fraction of tokens in [0, {MAX_TOKEN_MERGE}] (found {})", self.token_merge),
            ));
        }
        Ok(())
    }
}

/// The largest accepted [`PassSettings::token_merge`].
pub const MAX_TOKEN_MERGE: f32 = 0.9;

/// What the passes inside [`count_work`] evaluated.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct Work {
    /// Evaluations of a UNet (whole, or the shallow branch of a cached step), each over a batch.
    pub unet_passes: u64,
    /// ResNet blocks evaluated (each over a batch), UNets, ControlNets and VAEs together.
    pub resnet_blocks: u64,
    /// Transformer blocks evaluated (each over a batch).
    pub transformer_blocks: u64,
    /// Query–key scores the attentions computed, summed over batch and heads.
    pub attention_scores: u64,
    /// Multiply-adds done with bf16 products.
    pub bf16_multiply_adds: u64,
}

/// One counter per field of [`Work`].
#[derive(Debug, Default)]
struct Counters {
    values: [AtomicU64; 5],
}

/// A kind of work [`record`] counts (the fields of [`Work`]).
#[derive(Clone, Copy, Debug)]
pub(crate) enum WorkKind {
    UNetPass = 0,
    ResnetBlock = 1,
    TransformerBlock = 2,
    AttentionScores = 3,
    Bf16MultiplyAdds = 4,
}

/// The scope of the current thread: its settings and the counters of the innermost
/// [`count_work`], if any.
#[derive(Clone, Debug, Default)]
pub(crate) struct Context {
    settings: PassSettings,
    counters: Option<Arc<Counters>>,
}

thread_local! {
    static CONTEXT: RefCell<Context> = RefCell::new(Context::default());
}

impl Context {
    /// This context with other settings (the counters kept).
    pub(crate) fn with_settings(mut self, settings: PassSettings) -> Self {
        self.settings = settings;
        self
    }
}

/// The current thread's context, to carry into work that runs on another thread
/// ([`within`]).
pub(crate) fn current() -> Context {
    CONTEXT.with(|c| c.borrow().clone())
}

/// Runs `f` with `context` installed on this thread, restoring the previous context after
/// (also when `f` unwinds).
pub(crate) fn within<R>(context: Context, f: impl FnOnce() -> R) -> R {
    struct Restore(Option<Context>);
    impl Drop for Restore {
        fn drop(&mut self) {
            if let Some(previous) = self.0.take() {
                CONTEXT.with(|c| *c.borrow_mut() = previous);
            }
        }
    }
    let previous = CONTEXT.with(|c| std::mem::replace(&mut *c.borrow_mut(), context));
    let _restore = Restore(Some(previous));
    f()
}

/// Runs `f` with the passes on this thread computing as `settings` says (the counters of an
/// enclosing [`count_work`] still count). The pipelines carry the settings into the threads
/// their passes run on; layers called on other threads see the default settings.
pub fn with_settings<R>(settings: PassSettings, f: impl FnOnce() -> R) -> R {
    within(current().with_settings(settings), f)
}

/// The settings of the passes on this thread.
pub fn settings() -> PassSettings {
    CONTEXT.with(|c| c.borrow().settings)
}

/// Runs `f` and counts the work of the model passes it runs (on this thread and on the
/// threads the pipelines carry the scope to). Scopes nest: an inner count's work is also
/// counted by the outer one.
pub fn count_work<R>(f: impl FnOnce() -> R) -> (R, Work) {
    let counters = Arc::new(Counters::default());
    let outer = current();
    let context = Context { settings: outer.settings, counters: Some(counters.clone()) };
    let result = within(context, f);
    let v = |k: WorkKind| counters.values[k as usize].load(Ordering::Relaxed);
    let work = Work {
        unet_passes: v(WorkKind::UNetPass),
        resnet_blocks: v(WorkKind::ResnetBlock),
        transformer_blocks: v(WorkKind::TransformerBlock),
        attention_scores: v(WorkKind::AttentionScores),
        bf16_multiply_adds: v(WorkKind::Bf16MultiplyAdds),
    };
    if let Some(outer) = &outer.counters {
        for (o, i) in outer.values.iter().zip(&counters.values) {
            o.fetch_add(i.load(Ordering::Relaxed), Ordering::Relaxed);
        }
    }
    (result, work)
}

/// Adds `amount` of `kind` to the innermost [`count_work`] of this thread (nothing outside one).
pub(crate) fn record(kind: WorkKind, amount: u64) {
    CONTEXT.with(|c| {
        if let Some(counters) = &c.borrow().counters {
            counters.values[kind as usize].fetch_add(amount, Ordering::Relaxed);
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_nest_and_scopes_restore() {
        let ((), outer) = count_work(|| {
            record(WorkKind::ResnetBlock, 2);
            let ((), inner) = count_work(|| record(WorkKind::ResnetBlock, 3));
            assert_eq!(inner.resnet_blocks, 3);
        });
        assert_eq!(outer.resnet_blocks, 5);
        record(WorkKind::ResnetBlock, 1); // outside any count: nothing to add to
        let s = PassSettings::default().with_token_merge(0.5);
        with_settings(s, || {
            assert_eq!(settings().token_merge, 0.5);
            let context = current();
            let seen = std::thread::spawn(move || within(context, settings)).join().unwrap();
            assert_eq!(seen.token_merge, 0.5);
        });
        assert_eq!(settings(), PassSettings::default());
    }

    #[test]
    fn token_merge_outside_its_range_is_refused() {
        for bad in [-0.1, 0.95, f32::NAN] {
            let e = PassSettings::default().with_token_merge(bad).validate().unwrap_err().to_string();
            assert!(e.contains("token_merge"), "{e}");
        }
        assert!(PassSettings::default().with_token_merge(0.5).validate().is_ok());
    }
}
