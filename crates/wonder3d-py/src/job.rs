//! Long calls: the work runs without the GIL on a scoped worker thread while the calling
//! thread watches for Ctrl-C; progress events go to an optional Python callback.
//!
//! Python only delivers a signal to the main thread, and only when that thread asks
//! (`PyErr_CheckSignals`): so the calling thread waits on the worker in short slices, asking
//! between them. On Ctrl-C (or an exception from the callback) it raises a stop flag that the
//! worker reads at its next progress event; the worker then unwinds out of the Rust call
//! (`std::panic::resume_unwind`, which prints nothing) and the exception is raised. The
//! facade's jobs compute first and write files last, through a temporary name and a rename,
//! so a call abandoned this way leaves no file behind. The delay is the time between two
//! progress events: milliseconds in reconstruction, one sampling step in generation.

use std::panic::{AssertUnwindSafe, catch_unwind, resume_unwind};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Condvar, Mutex};
use std::time::Duration;

use pyo3::prelude::*;
use wonder3d::Progress;

use crate::errors::{IntoPy, Kind, new_error};

/// How often the calling thread checks for signals while the work runs.
const SIGNAL_POLL: Duration = Duration::from_millis(20);

/// A progress event as Python sees it: `stage` (`"coarse"`, `"denoise"`, `"bake"` …),
/// `done` of `total` units, the current `loss` where the stage optimises one, and the
/// refinement `iteration` where there is one.
#[pyclass(name = "ProgressEvent", module = "wonder3d", frozen, get_all)]
#[derive(Debug, Clone)]
pub struct ProgressEvent {
    /// The stage's short name.
    pub stage: String,
    /// Units done.
    pub done: usize,
    /// Units in the stage.
    pub total: usize,
    /// The current loss, if the stage has one.
    pub loss: Option<f32>,
    /// The refinement iteration (0-based), for `refine`.
    pub iteration: Option<usize>,
}

#[pymethods]
impl ProgressEvent {
    fn __repr__(&self) -> String {
        let loss = self.loss.map(|l| format!(", loss={l:.6}")).unwrap_or_default();
        let iteration = self.iteration.map(|i| format!(", iteration={i}")).unwrap_or_default();
        format!("ProgressEvent(stage={:?}, done={}, total={}{loss}{iteration})", self.stage, self.done, self.total)
    }
}

impl From<Progress> for ProgressEvent {
    fn from(p: Progress) -> Self {
        ProgressEvent { stage: p.stage.name().to_string(), done: p.done, total: p.total, loss: p.loss, iteration: None }
    }
}

/// The unwinding payload of a stopped call.
struct Stopped;

/// What a job gets to report progress with.
pub struct Reporter<'a> {
    callback: Option<&'a Py<PyAny>>,
    stop: &'a AtomicBool,
    callback_error: &'a Mutex<Option<PyErr>>,
}

impl Reporter<'_> {
    /// Sends `event` to the callback; unwinds out of the job when the call is stopped.
    pub fn report(&self, event: ProgressEvent) {
        if self.stop.load(Ordering::Acquire) {
            resume_unwind(Box::new(Stopped));
        }
        if let Some(callback) = self.callback
            && let Err(error) = Python::attach(|py| callback.call1(py, (event,)).map(drop))
        {
            *self.callback_error.lock().unwrap_or_else(|p| p.into_inner()) = Some(error);
            self.stop.store(true, Ordering::Release);
            resume_unwind(Box::new(Stopped));
        }
    }

    /// A facade progress callback.
    pub fn facade(&self) -> impl FnMut(Progress) + '_ {
        move |p| self.report(p.into())
    }
}

/// Runs `job` without the GIL, forwarding its progress to `callback`, and stops it on
/// Ctrl-C (raising `KeyboardInterrupt`) or when the callback raises (raising that).
pub fn run<T: Send>(
    py: Python<'_>,
    callback: Option<Py<PyAny>>,
    job: impl FnOnce(&Reporter<'_>) -> wonder3d::Result<T> + Send,
) -> PyResult<T> {
    let stop = AtomicBool::new(false);
    let callback_error = Mutex::new(None);
    let finished = (Mutex::new(false), Condvar::new());
    let (interrupt, outcome) = std::thread::scope(|scope| {
        let reporter = Reporter { callback: callback.as_ref(), stop: &stop, callback_error: &callback_error };
        let finished = &finished;
        let worker = scope.spawn(move || {
            let outcome = catch_unwind(AssertUnwindSafe(|| job(&reporter)));
            *finished.0.lock().unwrap_or_else(|p| p.into_inner()) = true;
            finished.1.notify_all();
            outcome
        });
        let mut interrupt: Option<PyErr> = None;
        loop {
            let is_finished = py.detach(|| {
                let guard = finished.0.lock().unwrap_or_else(|p| p.into_inner());
                let (guard, _) =
                    finished.1.wait_timeout_while(guard, SIGNAL_POLL, |f| !*f).unwrap_or_else(|p| p.into_inner());
                *guard
            });
            if is_finished {
                break;
            }
            if interrupt.is_none()
                && let Err(signal) = py.check_signals()
            {
                interrupt = Some(signal);
                stop.store(true, Ordering::Release);
            }
        }
        let outcome = py.detach(|| worker.join());
        (interrupt, outcome)
    });
    if let Some(signal) = interrupt {
        return Err(signal);
    }
    if let Some(error) = callback_error.into_inner().unwrap_or_else(|p| p.into_inner()) {
        return Err(error);
    }
    match outcome {
        Ok(Ok(result)) => result.py_err(),
        Ok(Err(payload)) | Err(payload) => {
            Err(new_error(Kind::Internal, format!("a bug in wonder3d: {}", panic_message(&*payload))))
        }
    }
}

/// The message of a panic payload.
fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    if payload.is::<Stopped>() {
        "stopped without a reason".into()
    } else if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_string()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "a panic without a message".into()
    }
}
