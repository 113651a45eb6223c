//! `evservo._evcore.Tracker`: the synchronous core and the threaded tracker behind one class.

use crate::camera::PyCamera;
use crate::errors::to_py;
use crate::events::{records, EventArray};
use crate::model::PyMesh;
use crate::pose::pose_arg;
use evcore::field::FieldParams;
use evcore::pointset::PointSetParams;
use evcore::se3::pose_to_matrix;
use evcore::solve::{LmParams, SolverMode, StepKind};
use evcore::surface::FrontEnd;
use evcore::templates::{BankParams, TemplateBank};
use evcore::tracker::{
    Estimate, IngestLimit, ThreadedTracker, TrackerConfig, TrackerCore, TrackerOutput,
};
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray2};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use std::sync::{Arc, Mutex};

/// One pose estimate. `T_c_o` is the object in the camera optical frame (4×4, metres).
#[pyclass(name = "Estimate", module = "evservo._evcore", frozen)]
pub struct PyEstimate {
    pub(crate) inner: Estimate,
}

#[pymethods]
impl PyEstimate {
    #[getter(T_c_o)]
    fn t_c_o<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        matrix_to_py(py, &pose_to_matrix(&self.inner.pose))
    }
    /// Time of the newest event behind this estimate (µs).
    #[getter]
    fn t_us(&self) -> i64 {
        self.inner.t_us
    }
    #[getter]
    fn seq(&self) -> u64 {
        self.inner.seq
    }
    /// "lm" or "search".
    #[getter]
    fn step(&self) -> &'static str {
        match self.inner.step {
            StepKind::Lm => "lm",
            StepKind::Search => "search",
        }
    }
    /// Mean distance-field value over the model points (pixels).
    #[getter]
    fn cost(&self) -> f32 {
        self.inner.cost
    }
    #[getter]
    fn inlier_fraction(&self) -> f32 {
        self.inner.inlier_fraction
    }
    /// Fraction of the model points projecting where the sensor sees (the rest leave the cost).
    #[getter]
    fn visible_fraction(&self) -> f32 {
        self.inner.visible_fraction
    }
    #[getter]
    fn n_events(&self) -> u64 {
        self.inner.n_events
    }
    /// How much better than chance the events support this pose, 0–1.
    #[getter]
    fn confidence(&self) -> f32 {
        self.inner.confidence
    }
    /// The pose is not to be trusted (not yet confirmed, low confidence, or out of view).
    #[getter]
    fn lost(&self) -> bool {
        self.inner.lost
    }
    /// When the batch holding the newest event (`t_us`) was pushed (ns on the tracker's
    /// monotonic clock; 0 before any event).
    #[getter]
    fn pushed_ns(&self) -> u64 {
        self.inner.pushed_ns
    }
    /// When this estimate was published (ns, the same clock as `pushed_ns`).
    #[getter]
    fn published_ns(&self) -> u64 {
        self.inner.published_ns
    }
    /// Event-to-pose latency of the newest event: `published_ns − pushed_ns` in seconds (None
    /// before any event).
    #[getter]
    fn latency_s(&self) -> Option<f64> {
        self.inner.latency_ns().map(|ns| ns as f64 * 1e-9)
    }
    /// When the oldest batch this estimate is the first to contain was pushed (ns; 0 when it took
    /// in no new batch).
    #[getter]
    fn oldest_pushed_ns(&self) -> u64 {
        self.inner.oldest_pushed_ns
    }
    /// `published_ns − oldest_pushed_ns` in seconds: a bound of the latency of every event this
    /// estimate is the first to use (None when it took in no new batch).
    #[getter]
    fn oldest_latency_s(&self) -> Option<f64> {
        self.inner.oldest_latency_ns().map(|ns| ns as f64 * 1e-9)
    }
    fn __repr__(&self) -> String {
        let t = self.inner.pose.translation.vector;
        format!(
            "Estimate(seq={}, t_us={}, step={}, t=({:.4}, {:.4}, {:.4}) m, cost={:.3}, inliers={:.2}, confidence={:.2}, lost={})",
            self.inner.seq,
            self.inner.t_us,
            self.step(),
            t.x,
            t.y,
            t.z,
            self.inner.cost,
            self.inner.inlier_fraction,
            self.inner.confidence,
            self.inner.lost
        )
    }
}

/// S* from an (N, 3) array (metres, object frame).
fn points_arg(points_o: &PyReadonlyArray2<'_, f64>) -> PyResult<Vec<[f32; 3]>> {
    let pts = points_o.as_array();
    if pts.ncols() != 3 {
        return Err(PyValueError::new_err(format!(
            "points_o must have shape (N, 3), got {:?}",
            pts.shape()
        )));
    }
    Ok(pts
        .rows()
        .into_iter()
        .map(|r| [r[0] as f32, r[1] as f32, r[2] as f32])
        .collect())
}

fn matrix_to_py<'py>(py: Python<'py>, m: &[[f64; 4]; 4]) -> Bound<'py, PyArray2<f64>> {
    numpy::ndarray::Array2::from_shape_fn((4, 4), |(i, j)| m[i][j]).into_pyarray(py)
}

/// A field image and the (x0, y0) of its region in the rectified image.
type FieldWithOrigin<'py> = (Bound<'py, PyArray2<f32>>, (u32, u32));

pub(crate) enum State {
    Sync(Box<TrackerCore>),
    Threaded(Box<ThreadedTracker>),
    /// Only inside `start`/`stop`, under the lock, while the core moves; never seen by a caller.
    Moving,
}

/// The tracker. Synchronous use: `update(events)`; threaded use: `start()`, `push(events)`,
/// `latest()`, `stop()`.
///
/// Frozen, so no call ever fails on a borrow: `latest()` and `stats()` read the output the solver
/// publishes to without any lock; everything else takes the state lock with the GIL released, so
/// calls from several threads wait for each other (briefly) instead of raising.
#[pyclass(name = "Tracker", module = "evservo._evcore", frozen)]
pub struct PyTracker {
    output: Arc<TrackerOutput>,
    /// Shared with a running file replay (`replay::replay_into`), which pushes through it.
    pub(crate) state: Arc<Mutex<State>>,
}

#[pymethods]
impl PyTracker {
    /// Tracker(camera, points_o (N,3) metres in the object frame or None, T_c_o (4,4) or None,
    /// solver="edft+", frontend="scarf", n_search=4, tau_px=10.0, levels=3, lm_iterations=6,
    /// roi_margin_px=48.0, ingest_core_share=0.5, max_ingest_rate=None, anti_flicker_hz=[],
    /// held_axes=None, mesh=None, view_spacing_deg=15.0, depth_range_m=(0.3, 1.5), n_points=1000,
    /// seed=0, lost_below=0.3, relock_above=0.45, search_min_t=None): held_axes (K, 6) are continuous symmetry axes of the object (unit axis, then a
    /// point on it; object frame, metres) whose rotation every update keeps at the prior.
    /// While the object is partly out of view, a search step moves only when its best candidate
    /// beats staying put by `search_min_t` standard errors of the per-point gains (None: 3 for
    /// edft+, 0 = the plain argmin otherwise).
    ///
    /// With `mesh`, a bank of viewpoint templates (S* of `n_points` every `view_spacing_deg` over
    /// the viewing sphere, searched over `depth_range_m`) lets the tracker find the object again by
    /// itself while lost and keeps S* in step with the attitude. Without `T_c_o` and `points_o` the
    /// tracker starts lost and searches; that needs `mesh`. The estimate turns lost when its
    /// confidence falls below `lost_below` and is trusted again from `relock_above` on.
    #[new]
    #[pyo3(signature = (camera, points_o, T_c_o, solver="edft+", frontend="scarf", n_search=4, tau_px=10.0, levels=3, lm_iterations=6, roi_margin_px=48.0, ingest_core_share=Some(0.5), max_ingest_rate=None, anti_flicker_hz=Vec::new(), held_axes=None, mesh=None, view_spacing_deg=15.0, depth_range_m=(0.3, 1.5), n_points=1000, seed=0, lost_below=evcore::tracker::LOST_BELOW, relock_above=evcore::tracker::RELOCK_ABOVE, search_min_t=None))]
    #[allow(non_snake_case, clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        camera: &PyCamera,
        points_o: Option<PyReadonlyArray2<'_, f64>>,
        T_c_o: Option<PyReadonlyArray2<'_, f64>>,
        solver: &str,
        frontend: &str,
        n_search: usize,
        tau_px: f32,
        levels: u32,
        lm_iterations: u32,
        roi_margin_px: f64,
        ingest_core_share: Option<f64>,
        max_ingest_rate: Option<f64>,
        anti_flicker_hz: Vec<f64>,
        held_axes: Option<PyReadonlyArray2<'_, f64>>,
        mesh: Option<PyRef<'_, PyMesh>>,
        view_spacing_deg: f64,
        depth_range_m: (f64, f64),
        n_points: usize,
        seed: u64,
        lost_below: f32,
        relock_above: f32,
        search_min_t: Option<f32>,
    ) -> PyResult<Self> {
        let pose = T_c_o.map(|m| pose_arg(&m)).transpose()?;
        let points = points_o.map(|p| points_arg(&p)).transpose()?;
        let ingest_limit = match (max_ingest_rate, ingest_core_share) {
            (Some(rate), _) => IngestLimit::EventsPerSecond(rate),
            (None, Some(share)) => IngestLimit::CoreShare(share),
            (None, None) => IngestLimit::Off,
        };
        let mut held_axes_o = Vec::new();
        if let Some(a) = held_axes {
            let a = a.as_array();
            if a.ncols() != 6 || a.iter().any(|v| !v.is_finite()) {
                return Err(PyValueError::new_err(format!(
                    "held_axes must be a finite (K, 6) array (axis, point on it), got {:?}",
                    a.shape()
                )));
            }
            for r in a.rows() {
                let axis = nalgebra::Vector3::new(r[0], r[1], r[2]);
                if axis.norm() < 1e-9 {
                    return Err(PyValueError::new_err("held_axes: an axis has zero length"));
                }
                held_axes_o.push((axis.normalize(), nalgebra::Vector3::new(r[3], r[4], r[5])));
            }
        }
        let config = TrackerConfig {
            held_axes_o,
            solver: SolverMode::parse(solver).map_err(to_py)?,
            n_search,
            frontend: FrontEnd::parse(frontend).map_err(to_py)?,
            field: FieldParams { tau_px, levels },
            lm: LmParams {
                max_iterations: lm_iterations,
                ..LmParams::default()
            },
            roi_margin_px,
            ingest_limit,
            anti_flicker_hz,
            lost_below,
            relock_above,
            search_min_t,
            ..TrackerConfig::default()
        };
        let bank_params = BankParams {
            view_spacing_deg,
            depth_min_m: depth_range_m.0,
            depth_max_m: depth_range_m.1,
            ..BankParams::default()
        };
        let point_params = PointSetParams {
            max_points: n_points,
            seed,
            ..PointSetParams::default()
        };
        let cam = camera.inner;
        let mesh = mesh.map(|m| Arc::clone(&m.inner));
        let core = py
            .detach(move || -> evcore::Result<TrackerCore> {
                let rect = cam.checked()?.rectified();
                let bank = mesh
                    .map(|m| TemplateBank::render(&m, &rect, bank_params, &point_params))
                    .transpose()?;
                match (pose, points, bank) {
                    (Some(pose), Some(points), bank) => {
                        let mut core = TrackerCore::new(&cam, points, pose, config)?;
                        if let Some(b) = bank {
                            core.set_templates(b);
                        }
                        Ok(core)
                    }
                    (None, None, Some(bank)) => TrackerCore::searching(&cam, bank, config),
                    (None, None, None) => Err(evcore::Error::InvalidArgument(
                        "starting without a pose needs the mesh to search for".into(),
                    )),
                    _ => Err(evcore::Error::InvalidArgument(
                        "give both points_o and T_c_o, or neither (to start by searching)".into(),
                    )),
                }
            })
            .map_err(to_py)?;
        Ok(Self {
            output: core.output(),
            state: Arc::new(Mutex::new(State::Sync(Box::new(core)))),
        })
    }

    /// Ingest one EVENT_CD batch (every event) and run one cycle (1 LM + N search for edft+;
    /// N+1 steps otherwise).
    fn update(&self, py: Python<'_>, events: EventArray<'_>) -> PyResult<PyEstimate> {
        let ev = records(&events)?;
        let est = self.with_core(py, |core| core.update(ev))?;
        Ok(PyEstimate {
            inner: est.map_err(to_py)?,
        })
    }

    /// Ingest one EVENT_CD batch without stepping: every event, or with `thin` the fraction the
    /// ingest limit allows under overload, as push() does.
    #[pyo3(signature = (events, thin=false))]
    fn ingest(&self, py: Python<'_>, events: EventArray<'_>, thin: bool) -> PyResult<()> {
        let ev = records(&events)?;
        self.with_core(py, |core| {
            if thin {
                core.ingest_thinned(ev)
            } else {
                core.ingest(ev)
            }
        })?
        .map_err(to_py)
    }

    /// Run `n` single updates (each one LM or one search step) on the current events.
    #[pyo3(signature = (n=1))]
    fn step(&self, py: Python<'_>, n: usize) -> PyResult<PyEstimate> {
        let est = self.with_core(py, |core| {
            let mut e = core.latest();
            for _ in 0..n {
                e = core.step();
            }
            e
        })?;
        Ok(PyEstimate { inner: est })
    }

    /// Start the solver thread; an error if it already runs. On failure the tracker stays
    /// synchronous and usable.
    fn start(&self, py: Python<'_>) -> PyResult<()> {
        self.with_state(py, |state| {
            if !matches!(state, State::Sync(_)) {
                return Err(PyRuntimeError::new_err("the tracker is already running"));
            }
            let State::Sync(core) = std::mem::replace(state, State::Moving) else {
                unreachable!("checked just above, under the same lock")
            };
            match ThreadedTracker::start(*core) {
                Ok(t) => {
                    *state = State::Threaded(Box::new(t));
                    Ok(())
                }
                Err(failed) => {
                    *state = State::Sync(failed.core);
                    Err(to_py(failed.error))
                }
            }
        })?
    }

    /// Ingest an EVENT_CD batch on the calling thread (GIL released) and wake the solver thread.
    /// Under overload a uniform fraction of the batch is kept (see stats()).
    fn push(&self, py: Python<'_>, events: EventArray<'_>) -> PyResult<()> {
        let ev = records(&events)?;
        self.with_state(py, |state| match state {
            State::Threaded(tr) => tr.push(ev).map_err(to_py),
            _ => Err(PyRuntimeError::new_err(
                "push() needs a running tracker: call start() first",
            )),
        })?
    }

    /// The stream has reached `t_us` (µs) without events after those given (threaded or not): a
    /// stretch of 20 ms of stream time without one reads as a dropout and the estimate as lost.
    fn advance_time(&self, py: Python<'_>, t_us: i64) -> PyResult<()> {
        self.with_state(py, |state| match state {
            State::Sync(core) => core.advance_time(t_us).map_err(to_py),
            State::Threaded(t) => t.advance_time(t_us).map_err(to_py),
            State::Moving => Ok(()),
        })?
    }

    /// The newest estimate (threaded or not). Lock-free.
    fn latest(&self) -> PyEstimate {
        PyEstimate {
            inner: self.output.latest(),
        }
    }

    /// Stop the solver thread (no-op when not running).
    fn stop(&self, py: Python<'_>) -> PyResult<()> {
        self.with_state(py, |state| {
            if !matches!(state, State::Threaded(_)) {
                return;
            }
            let State::Threaded(t) = std::mem::replace(state, State::Moving) else {
                unreachable!("checked just above, under the same lock")
            };
            *state = State::Sync(Box::new(t.stop()));
        })
    }

    /// Steps per cycle: 1 LM + N search for edft+, N + 1 steps of a single solver otherwise. After
    /// this many steps without new events the thread rests until the next batch.
    #[getter]
    fn cycle_len(&self, py: Python<'_>) -> PyResult<usize> {
        self.with_core(py, |core| core.cycle_len())
    }

    /// Keep the running solver thread busy at most `share` (0..=1] of the wall time while it has
    /// work, in short pauses after its steps (None: no limit). For a real-time solver thread, which
    /// Linux would otherwise stop for ~50 ms once a second to let ordinary tasks run.
    fn limit_busy_share(&self, py: Python<'_>, share: Option<f64>) -> PyResult<()> {
        self.with_state(py, |state| match state {
            State::Threaded(t) => t.limit_busy_share(share).map_err(to_py),
            _ => Err(PyRuntimeError::new_err(
                "limit_busy_share() needs a running tracker: call start() first",
            )),
        })?
    }

    /// Kernel thread id of the running solver thread (Linux), None when not running or unknown.
    #[getter]
    fn solver_thread_id(&self, py: Python<'_>) -> PyResult<Option<i64>> {
        self.with_state(py, |state| match state {
            State::Threaded(t) => t.solver_thread_id(),
            _ => None,
        })
    }

    #[getter]
    fn running(&self, py: Python<'_>) -> PyResult<bool> {
        self.with_state(
            py,
            |state| matches!(state, State::Threaded(t) if t.is_running()),
        )
    }

    /// Re-initialise the pose (4×4 T_c_o); the front-end keeps its events. Reads lost until the
    /// next update.
    #[allow(non_snake_case)]
    fn reset_pose(&self, py: Python<'_>, T_c_o: PyReadonlyArray2<'_, f64>) -> PyResult<()> {
        let pose = pose_arg(&T_c_o)?;
        self.with_core(py, |core| core.reset_pose(pose))?
            .map_err(to_py)
    }

    /// Forget every event and the time line (threaded or not); the pose stays. Needed after a
    /// camera restarted its clock.
    fn reset_events(&self, py: Python<'_>) -> PyResult<()> {
        self.with_state(py, |state| match state {
            State::Sync(core) => core.reset_events(),
            State::Threaded(t) => t.reset_events(),
            State::Moving => {}
        })
    }

    /// The parts of the last tracked pose's confidence (a dict of fractions; synchronous use):
    /// see [`put_evidence`].
    fn evidence<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let e = self.with_core(py, |core| core.evidence())?;
        let d = pyo3::types::PyDict::new(py);
        put_evidence(&d, &e)?;
        Ok(d)
    }

    /// Diagnostics (synchronous use): one global search on the current events, as the tracker
    /// runs it while lost, without changing its state. `extra` (N, 4, 4) poses are refined and
    /// scored alongside. A list of dicts: `seed` and `T_c_o` (before / after LM), `view` (bank
    /// view or None), `chamfer`, `confidence`, `acquisition` and the evidence parts (`explained`
    /// is 0 where support − chance is too low for the candidate's score to matter).
    #[pyo3(signature = (extra=None))]
    fn _global_candidates<'py>(
        &self,
        py: Python<'py>,
        extra: Option<numpy::PyReadonlyArray3<'_, f64>>,
    ) -> PyResult<Vec<Bound<'py, pyo3::types::PyDict>>> {
        let centre = self.with_core(py, |core| core.bank_centre_o())?;
        let extra = match extra {
            Some(a) => crate::pose::poses_arg(&a)?,
            None => Vec::new(),
        };
        let found = self.with_core(py, |core| core.global_candidates(&extra))?;
        found
            .into_iter()
            .map(|c| {
                let d = pyo3::types::PyDict::new(py);
                d.set_item("seed", matrix_to_py(py, &pose_to_matrix(&c.seed)))?;
                d.set_item("T_c_o", matrix_to_py(py, &pose_to_matrix(&c.pose)))?;
                d.set_item("view", c.view)?;
                d.set_item("chamfer", c.chamfer)?;
                if let Some(c0) = centre {
                    d.set_item(
                        "centre_c",
                        (c.seed * nalgebra::Point3::from(c0))
                            .coords
                            .as_slice()
                            .to_vec(),
                    )?;
                }
                let e = c.evidence;
                d.set_item("confidence", e.confidence())?;
                d.set_item("acquisition", evcore::templates::acquisition_score(&e))?;
                put_evidence(&d, &e)?;
                Ok(d)
            })
            .collect()
    }

    /// Live counters (a dict): step counts and seconds per kind, events offered / ingested /
    /// dropped (thinned under overload), rejected jumps. Lock-free.
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let s = self.output.stats();
        let d = pyo3::types::PyDict::new(py);
        d.set_item("lm_steps", s.lm_steps)?;
        d.set_item("search_steps", s.search_steps)?;
        d.set_item("lm_seconds", s.lm_seconds)?;
        d.set_item("search_seconds", s.search_seconds)?;
        d.set_item("events_offered", s.events_offered)?;
        d.set_item("events_ingested", s.events_ingested)?;
        d.set_item("events_dropped", s.events_dropped)?;
        d.set_item("jumps_rejected", s.jumps_rejected)?;
        d.set_item("reacquire_passes", s.reacquire_passes)?;
        d.set_item("reacquire_seconds", s.reacquire_seconds)?;
        Ok(d)
    }

    /// Event-to-pose latency so far, booked by the solver at each publication (a dict, seconds,
    /// lock-free): `batch_*` over every batch, the publication of the first pose containing it
    /// minus its own push (the latency of each of its events); `newest_*` over the batches that
    /// were the newest behind a pose (as `Estimate.latency_s`); `oldest_*` the bound of every
    /// batch by the oldest batch its pose took in (as `Estimate.oldest_latency_s`); `*_n`
    /// samples, `*_p50_s`, `*_p99_s` (upper edges of 10 µs bins), `*_max_s`. The quantiles are
    /// None before any sample.
    fn latency<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let lat = self.output.latency();
        let d = pyo3::types::PyDict::new(py);
        let s = |ns: Option<u64>| ns.map(|ns| ns as f64 * 1e-9);
        for (name, h) in [
            ("batch", lat.batch),
            ("newest", lat.newest),
            ("oldest", lat.oldest),
        ] {
            d.set_item(format!("{name}_n"), h.count())?;
            d.set_item(format!("{name}_p50_s"), s(h.quantile_ns(0.5)))?;
            d.set_item(format!("{name}_p99_s"), s(h.quantile_ns(0.99)))?;
            d.set_item(format!("{name}_max_s"), s(h.max_ns()))?;
        }
        Ok(d)
    }

    /// Model points projected at the current pose, (N, 2) rectified pixels.
    fn projected_points<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let pts = self.with_core(py, |core| core.projected_points())?;
        Ok(
            numpy::ndarray::Array2::from_shape_fn((pts.len(), 2), |(i, j)| {
                if j == 0 {
                    pts[i].0
                } else {
                    pts[i].1
                }
            })
            .into_pyarray(py),
        )
    }

    /// The last full-resolution field: (values (h, w) float32, (x0, y0) of its region).
    fn field<'py>(&self, py: Python<'py>) -> PyResult<FieldWithOrigin<'py>> {
        let (value, roi) = self.with_core(py, |core| {
            let lvl = core.field_level0();
            (lvl.value.clone(), lvl.roi)
        })?;
        let (w, h) = (roi.width as usize, roi.height as usize);
        let arr = numpy::ndarray::Array2::from_shape_vec((h, w), value)
            .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
        Ok((arr.into_pyarray(py), (roi.x0, roi.y0)))
    }

    /// Active pixels of the front-end in the full rectified image, (H, W) uint8.
    fn active_mask<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<u8>>> {
        let (w, h, out) = self.with_core(py, |core| {
            let (w, h) = (core.camera().width, core.camera().height);
            let mut out = vec![0u8; w as usize * h as usize];
            core.fill_mask(evcore::Roi::full(w, h), &mut out);
            (w, h, out)
        })?;
        numpy::ndarray::Array2::from_shape_vec((h as usize, w as usize), out)
            .map(|a| a.into_pyarray(py))
            .map_err(|e| PyRuntimeError::new_err(e.to_string()))
    }
}

impl PyTracker {
    /// Run `f` on the state under its lock with the GIL released (no lock holder ever waits for
    /// the GIL, so the two cannot deadlock).
    fn with_state<T: Send>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&mut State) -> T + Send,
    ) -> PyResult<T> {
        py.detach(|| {
            let mut state = self.state.lock().map_err(|_| {
                PyRuntimeError::new_err("the tracker is unusable after an internal error")
            })?;
            Ok(f(&mut state))
        })
    }

    /// As `with_state` on the synchronous core; an error while the thread runs.
    fn with_core<T: Send>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&mut TrackerCore) -> T + Send,
    ) -> PyResult<T> {
        self.with_state(py, |state| match state {
            State::Sync(core) => Ok(f(core)),
            _ => Err(PyRuntimeError::new_err(
                "the tracker thread is running: call stop() first (or use push/latest)",
            )),
        })?
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyTracker>()?;
    m.add_class::<PyEstimate>()?;
    // The names the Tracker accepts, for Python's command-line choices: parsed here only.
    m.add("SOLVERS", SolverMode::NAMES)?;
    m.add("FRONTENDS", FrontEnd::NAMES)?;
    // The default confidence thresholds of `lost`, for the bench's ROC.
    m.add("LOST_BELOW", evcore::tracker::LOST_BELOW)?;
    m.add("RELOCK_ABOVE", evcore::tracker::RELOCK_ABOVE)
}

/// The parts of a confidence into `d`: support (fresh), support_any, chance, support_tight,
/// chance_tight, visible, explained (measured for global-search candidates only, else 0), active
/// and active_around.
fn put_evidence(
    d: &Bound<'_, pyo3::types::PyDict>,
    e: &evcore::confidence::Evidence,
) -> PyResult<()> {
    d.set_item("support", e.support)?;
    d.set_item("support_any", e.support_any)?;
    d.set_item("chance", e.chance)?;
    d.set_item("support_tight", e.support_tight)?;
    d.set_item("chance_tight", e.chance_tight)?;
    d.set_item("visible", e.visible)?;
    d.set_item("explained", e.explained)?;
    d.set_item("active", e.active)?;
    d.set_item("active_around", e.active_around)?;
    Ok(())
}
