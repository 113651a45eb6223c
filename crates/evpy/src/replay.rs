//! `evservo._evcore.replay_into` / `Replay`: a RAW file decoded and fed to a tracker on a Rust
//! thread, without the GIL or any Python per batch: pushed into a running tracker's ingest, or one
//! synchronous update per slice of a stopped one (deterministic, every estimate kept).

use crate::errors::to_py;
use crate::tracker::{PyEstimate, PyTracker, State};
use evcore::io::RawReader;
use evcore::replay::{replay, Pace, ReplayProgress, TimeSlices};
use evcore::tracker::{Estimate, TrackerCore};
use evcore::{Error, Roi};
use numpy::{IntoPyArray, PyArray2};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::collections::BTreeSet;
use std::fs::File;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How often a waiting caller looks for Ctrl-C.
const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// One synchronous update of an `update` replay: the slice's end (µs), its event count and the
/// estimate after it.
type Update = (i64, usize, Estimate);

/// The full-resolution field and the projected model after an update (for overlays).
struct Snapshot {
    end_us: i64,
    field: Vec<f32>,
    roi: Roi,
    points: Vec<(f32, f32)>,
}

/// What an `update` replay keeps for the caller.
#[derive(Default)]
struct UpdateLog {
    updates: Mutex<Vec<Update>>,
    snapshots: Mutex<Vec<Snapshot>>,
    /// Wall time spent in the updates (ns).
    update_ns: AtomicU64,
}

/// A replay running on its own thread. Stopped (and joined) by `stop()`, on leaving a `with`
/// block, or when garbage-collected.
#[pyclass(name = "Replay", module = "evservo._evcore", frozen)]
pub struct PyReplay {
    stop: Arc<AtomicBool>,
    progress: Arc<ReplayProgress>,
    log: Arc<UpdateLog>,
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
        d.set_item(
            "update_seconds",
            self.log.update_ns.load(Ordering::Relaxed) as f64 * 1e-9,
        )?;
        Ok(d)
    }

    /// Mode "update": every update so far as (slice end µs, events in the slice, Estimate).
    fn updates(&self) -> Vec<(i64, usize, PyEstimate)> {
        lock(&self.log.updates)
            .iter()
            .map(|&(end, n, inner)| (end, n, PyEstimate { inner }))
            .collect()
    }

    /// Mode "update": after each slice of `snapshots_at`, (slice end µs, full-resolution field
    /// (h, w) float32, (x0, y0) of its region, model points projected (N, 2) rectified pixels).
    #[allow(clippy::type_complexity)]
    fn snapshots<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<
        Vec<(
            i64,
            Bound<'py, PyArray2<f32>>,
            (u32, u32),
            Bound<'py, PyArray2<f32>>,
        )>,
    > {
        lock(&self.log.snapshots)
            .iter()
            .map(|s| {
                let (w, h) = (s.roi.width as usize, s.roi.height as usize);
                let field = numpy::ndarray::Array2::from_shape_vec((h, w), s.field.clone())
                    .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
                let pts = numpy::ndarray::Array2::from_shape_fn((s.points.len(), 2), |(i, j)| {
                    if j == 0 {
                        s.points[i].0
                    } else {
                        s.points[i].1
                    }
                });
                Ok((
                    s.end_us,
                    field.into_pyarray(py),
                    (s.roi.x0, s.roi.y0),
                    pts.into_pyarray(py),
                ))
            })
            .collect()
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

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// One synchronous update on `batch` (ingest + one solver cycle, as `Tracker.update`), logged.
fn update_and_log(
    core: &mut TrackerCore,
    batch: &[evcore::EventCd],
    end_us: i64,
    snapshot: bool,
    log: &UpdateLog,
) -> evcore::Result<()> {
    let started = Instant::now();
    let est = core.update(batch)?;
    log.update_ns
        .fetch_add(started.elapsed().as_nanos() as u64, Ordering::Relaxed);
    lock(&log.updates).push((end_us, batch.len(), est));
    if snapshot {
        let level = core.field_level0();
        lock(&log.snapshots).push(Snapshot {
            end_us,
            field: level.value.clone(),
            roi: level.roi,
            points: core.projected_points(),
        });
    }
    Ok(())
}

/// replay_into(tracker, path, batch_us=1000, speed=1.0, mode="push", until_us=None,
/// snapshots_at=[]) -> Replay: decode the RAW file at `path`, cut it into time slices of
/// `batch_us` (clamped to non-decreasing time; none starting after `until_us`) and feed them to
/// `tracker` from a new thread; `speed` 1.0 is real time, None as fast as the tracker takes it.
/// mode "push": into the running tracker's ingest (RuntimeError unless it runs). mode "update":
/// one synchronous update per slice, empty slices included, of the stopped tracker (RuntimeError
/// while it runs), exactly as `update` per slice would; every estimate is kept (`updates()`), and
/// the field and projected model after the slices numbered in `snapshots_at` (`snapshots()`).
/// The file's header is read here (FileNotFoundError, DecodeError).
#[pyfunction]
#[pyo3(signature = (tracker, path, batch_us=1000, speed=Some(1.0), mode="push", until_us=None, snapshots_at=Vec::new()))]
#[allow(clippy::too_many_arguments)]
fn replay_into(
    py: Python<'_>,
    tracker: &PyTracker,
    path: std::path::PathBuf,
    batch_us: i64,
    speed: Option<f64>,
    mode: &str,
    until_us: Option<i64>,
    snapshots_at: Vec<usize>,
) -> PyResult<PyReplay> {
    let update = match mode {
        "push" => false,
        "update" => true,
        other => {
            return Err(PyValueError::new_err(format!(
                "mode must be 'push' or 'update', got {other:?}"
            )))
        }
    };
    let file = File::open(&path)?;
    let reader = py.detach(|| RawReader::new(file)).map_err(to_py)?;
    let mut slices = TimeSlices::new(reader, batch_us).map_err(to_py)?;
    if let Some(t) = until_us {
        slices = slices.until(t);
    }
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
    let running = py.detach(|| matches!(*lock(&state), State::Threaded(_)));
    if running == update {
        return Err(PyRuntimeError::new_err(if update {
            "replay_into(mode='update') needs a stopped tracker: call stop() first"
        } else {
            "replay_into needs a running tracker: call start() first"
        }));
    }
    let stop = Arc::new(AtomicBool::new(false));
    let progress = Arc::new(ReplayProgress::default());
    progress.end_us.store(i64::MIN, Ordering::Relaxed);
    let log = Arc::new(UpdateLog::default());
    let snapshots_at: BTreeSet<usize> = snapshots_at.into_iter().collect();
    let handle = {
        let (stop, progress, log) = (Arc::clone(&stop), Arc::clone(&progress), Arc::clone(&log));
        std::thread::Builder::new()
            .name("evservo-replay".into())
            .spawn(move || {
                let mut k = 0usize;
                replay(slices, pace, &stop, &progress, |batch, end_us| {
                    let mut state = state.lock().map_err(|_| {
                        Error::Tracking("the tracker is unusable after an internal error".into())
                    })?;
                    match (&mut *state, update) {
                        // An empty slice: the file holds no event before `end_us`, so the
                        // stream has gone on that far without one (a dropout shows as `lost`).
                        (State::Threaded(t), false) if batch.is_empty() => {
                            t.advance_time(end_us - 1)
                        }
                        (State::Threaded(t), false) => t.push(batch),
                        (State::Sync(core), true) => {
                            if batch.is_empty() {
                                core.advance_time(end_us - 1)?;
                            }
                            k += 1;
                            let snap = snapshots_at.contains(&(k - 1));
                            update_and_log(core, batch, end_us, snap, &log)
                        }
                        (_, false) => Err(Error::Tracking(
                            "the tracker was stopped while a replay was pushing into it".into(),
                        )),
                        (_, true) => Err(Error::Tracking(
                            "the tracker was started while a replay was updating it".into(),
                        )),
                    }
                })
            })
            .map_err(|e| PyRuntimeError::new_err(format!("could not start the replay: {e}")))?
    };
    Ok(PyReplay {
        stop,
        progress,
        log,
        handle: Mutex::new(Some(handle)),
        error: Mutex::new(None),
    })
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyReplay>()?;
    m.add_function(wrap_pyfunction!(replay_into, m)?)
}
