//! `evservo._evcore.replay_into` / `Replay`: a RAW file decoded and pushed into a running
//! tracker's ingest on a Rust thread, without the GIL or any Python per batch.

use crate::errors::to_py;
use crate::tracker::{PyTracker, State};
use evcore::io::RawReader;
use evcore::replay::{replay, Pace, ReplayProgress, TimeSlices};
use evcore::Error;
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::fs::File;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How often a waiting caller looks for Ctrl-C.
const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// A replay running on its own thread. Stopped (and joined) by `stop()`, on leaving a `with`
/// block, or when garbage-collected.
#[pyclass(name = "Replay", module = "evservo._evcore", frozen)]
pub struct PyReplay {
    stop: Arc<AtomicBool>,
    progress: Arc<ReplayProgress>,
    handle: Mutex<Option<JoinHandle<evcore::Result<()>>>>,
    /// The thread's error once joined, handed to the next `wait()`.
    error: Mutex<Option<Error>>,
}

impl PyReplay {
    /// Join the thread if it has finished (or `force`, after asking it to stop).
    fn join(&self, force: bool) {
        let mut handle = self.handle.lock().unwrap_or_else(PoisonError::into_inner);
        if handle.as_ref().is_some_and(|h| force || h.is_finished()) {
            let h = handle.take().expect("checked just above");
            let outcome = h
                .join()
                .unwrap_or_else(|_| Err(Error::Tracking("the replay thread panicked".into())));
            if let Err(e) = outcome {
                *self.error.lock().unwrap_or_else(PoisonError::into_inner) = Some(e);
            }
        }
    }

    fn finished(&self) -> bool {
        self.handle
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .is_none()
    }

    fn halt(&self) {
        self.stop.store(true, Ordering::Release);
        self.join(true);
    }
}

#[pymethods]
impl PyReplay {
    /// True while the replay thread runs.
    #[getter]
    fn running(&self) -> bool {
        self.join(false);
        !self.finished()
    }

    /// Wait up to `timeout` s (None: until the file ends) with the GIL released. True once the
    /// replay has ended; raises the replay's error (DecodeError for a corrupt file, RuntimeError
    /// from the tracker). Ctrl-C stops the replay and raises KeyboardInterrupt.
    #[pyo3(signature = (timeout=None))]
    fn wait(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<bool> {
        let deadline = timeout.map(|s| Instant::now() + Duration::from_secs_f64(s.max(0.0)));
        loop {
            py.detach(|| {
                let slice = match deadline {
                    Some(d) => d.saturating_duration_since(Instant::now()).min(SIGNAL_POLL),
                    None => SIGNAL_POLL,
                };
                let until = Instant::now() + slice;
                while Instant::now() < until && !self.handle_finished() {
                    std::thread::sleep(Duration::from_millis(1));
                }
                self.join(false);
            });
            if let Err(e) = py.check_signals() {
                py.detach(|| self.halt());
                return Err(e);
            }
            if self.finished() {
                return match self
                    .error
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .take()
                {
                    Some(e) => Err(to_py(e)),
                    None => Ok(true),
                };
            }
            if deadline.is_some_and(|d| Instant::now() >= d) {
                return Ok(false);
            }
        }
    }

    /// Stop the replay and wait for its thread (the tracker keeps running). Errors are left
    /// for `wait()`.
    fn stop(&self, py: Python<'_>) {
        py.detach(|| self.halt());
    }

    /// Live counters: slices and events pushed, events clamped to the newest time, and the end
    /// time of the last slice pushed (µs; None before the first).
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let p = &self.progress;
        let d = PyDict::new(py);
        d.set_item("slices", p.slices.load(Ordering::Relaxed))?;
        d.set_item("events", p.events.load(Ordering::Relaxed))?;
        d.set_item("clamped", p.clamped.load(Ordering::Relaxed))?;
        let end = p.end_us.load(Ordering::Acquire);
        d.set_item("end_us", (end != i64::MIN).then_some(end))?;
        Ok(d)
    }

    fn __enter__(slf: Py<Self>) -> Py<Self> {
        slf
    }

    fn __exit__(
        &self,
        py: Python<'_>,
        _exc_type: Option<&Bound<'_, PyAny>>,
        _exc: Option<&Bound<'_, PyAny>>,
        _tb: Option<&Bound<'_, PyAny>>,
    ) -> bool {
        self.stop(py);
        false
    }
}

impl PyReplay {
    fn handle_finished(&self) -> bool {
        self.handle
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .as_ref()
            .is_none_or(|h| h.is_finished())
    }
}

impl Drop for PyReplay {
    fn drop(&mut self) {
        self.halt();
    }
}

/// replay_into(tracker, path, batch_us=1000, speed=1.0) -> Replay: decode the RAW file at
/// `path` and push it in time slices of `batch_us` (clamped to non-decreasing time) into the
/// running `tracker` from a new thread; `speed` 1.0 is real time, None as fast as ingest takes
/// it. The file's header is read here (FileNotFoundError, DecodeError); the tracker must be
/// running (RuntimeError).
#[pyfunction]
#[pyo3(signature = (tracker, path, batch_us=1000, speed=Some(1.0)))]
fn replay_into(
    py: Python<'_>,
    tracker: &PyTracker,
    path: std::path::PathBuf,
    batch_us: i64,
    speed: Option<f64>,
) -> PyResult<PyReplay> {
    let file = File::open(&path)?;
    let reader = py.detach(|| RawReader::new(file)).map_err(to_py)?;
    let slices = TimeSlices::new(reader, batch_us).map_err(to_py)?;
    let pace = match speed {
        None => Pace::AsFastAsPossible,
        Some(s) if s.is_finite() && s > 0.0 => Pace::Speed(s),
        Some(s) => {
            return Err(to_py(Error::InvalidArgument(format!(
                "speed must be a finite number > 0 or None, got {s}"
            ))))
        }
    };
    let state = Arc::clone(&tracker.state);
    let running = py.detach(|| {
        matches!(
            *state.lock().unwrap_or_else(PoisonError::into_inner),
            State::Threaded(_)
        )
    });
    if !running {
        return Err(PyRuntimeError::new_err(
            "replay_into needs a running tracker: call start() first",
        ));
    }
    let stop = Arc::new(AtomicBool::new(false));
    let progress = Arc::new(ReplayProgress::default());
    progress.end_us.store(i64::MIN, Ordering::Relaxed);
    let handle = {
        let (stop, progress) = (Arc::clone(&stop), Arc::clone(&progress));
        std::thread::Builder::new()
            .name("evservo-replay".into())
            .spawn(move || {
                replay(slices, pace, &stop, &progress, |batch| {
                    match &mut *state.lock().map_err(|_| {
                        Error::Tracking("the tracker is unusable after an internal error".into())
                    })? {
                        State::Threaded(t) => t.push(batch),
                        _ => Err(Error::Tracking(
                            "the tracker was stopped while a replay was pushing into it".into(),
                        )),
                    }
                })
            })
            .map_err(|e| PyRuntimeError::new_err(format!("could not start the replay: {e}")))?
    };
    Ok(PyReplay {
        stop,
        progress,
        handle: Mutex::new(Some(handle)),
        error: Mutex::new(None),
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyReplay>()?;
    m.add_function(wrap_pyfunction!(replay_into, m)?)
}
