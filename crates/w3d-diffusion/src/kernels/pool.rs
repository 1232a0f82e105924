//! Running a model pass on a thread of rayon's global pool.
//!
//! The CPU kernels ([`crate::kernels::conv`], [`crate::kernels::attention`], …) and the `gemm` crate
//! split their work with rayon. Called from a thread outside the pool (the program's main
//! thread, a decoder's training thread), every one of those parallel operations is handed to
//! the pool's workers while the caller sleeps until they finish: a training step of the small
//! UNet makes hundreds of them, each paying a wake-up of the workers and of the caller, and
//! the caller's core idles meanwhile. Run from a worker instead, a parallel operation keeps
//! one half of its work on the worker that called it and wakes one other, and the serial work
//! between the operations (Burn's element-wise operations, the autodiff graph) runs on a
//! worker too. Measured on the half-width UNet's training step (2 cores): 12–17 % less wall
//! time for the same bits (`docs/benchmarks.md`, "Training step").

/// Runs `work` on a worker of rayon's global pool and returns its result; the calling thread
/// waits. From a thread already in the pool, `work` runs where it is.
pub(crate) fn on_pool<R: Send>(work: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| work())
}

#[cfg(test)]
mod tests {
    use super::on_pool;

    #[test]
    fn work_runs_on_a_pool_worker_and_returns_its_result() {
        assert!(rayon::current_thread_index().is_none(), "the test thread is outside the pool");
        let (on_worker, value) = on_pool(|| (rayon::current_thread_index().is_some(), 6 * 7));
        assert!(on_worker);
        assert_eq!(value, 42);
    }
}
