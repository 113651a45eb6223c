//! `evservo._evcore.Tracker`: the synchronous core and the threaded tracker behind one class.

use crate::camera::PyCamera;
use crate::errors::to_py;
use evcore::field::FieldParams;
use evcore::se3::{pose_from_matrix, pose_to_matrix};
use evcore::solve::{LmParams, SolverMode, StepKind};
use evcore::surface::FrontEnd;
use evcore::tracker::{Estimate, ThreadedTracker, TrackerConfig, TrackerCore};
use evcore::EventBatch;
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

/// One pose estimate. `T_c_o` is the object in the camera optical frame (4×4, metres).
#[pyclass(name = "Estimate", module = "evservo._evcore", frozen)]
pub struct PyEstimate {
    inner: Estimate,
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
    #[getter]
    fn lost(&self) -> bool {
        self.inner.lost
    }
    fn __repr__(&self) -> String {
        let t = self.inner.pose.translation.vector;
        format!(
            "Estimate(seq={}, t_us={}, step={}, t=({:.4}, {:.4}, {:.4}) m, cost={:.3}, inliers={:.2}, lost={})",
            self.inner.seq,
            self.inner.t_us,
            self.step(),
            t.x,
            t.y,
            t.z,
            self.inner.cost,
            self.inner.inlier_fraction,
            self.inner.lost
        )
    }
}

fn matrix_to_py<'py>(py: Python<'py>, m: &[[f64; 4]; 4]) -> Bound<'py, PyArray2<f64>> {
    numpy::ndarray::Array2::from_shape_fn((4, 4), |(i, j)| m[i][j]).into_pyarray(py)
}

pub fn matrix_from_py(m: &PyReadonlyArray2<'_, f64>) -> PyResult<evcore::Pose> {
    let a = m.as_array();
    if a.shape() != [4, 4] {
        return Err(PyValueError::new_err(format!(
            "a pose must be a 4x4 matrix, got shape {:?}",
            a.shape()
        )));
    }
    let arr: [[f64; 4]; 4] = std::array::from_fn(|i| std::array::from_fn(|j| a[(i, j)]));
    pose_from_matrix(&arr).map_err(to_py)
}

/// A field image and the (x0, y0) of its region in the rectified image.
type FieldWithOrigin<'py> = (Bound<'py, PyArray2<f32>>, (u32, u32));

enum State {
    Sync(Box<TrackerCore>),
    Threaded(ThreadedTracker),
    /// Only while moving between the two.
    Moving,
}

/// The tracker. Synchronous use: `update(x, y, p, t)`; threaded use: `start()`, `push(...)`,
/// `latest()`, `stop()`.
#[pyclass(name = "Tracker", module = "evservo._evcore")]
pub struct PyTracker {
    state: State,
}

fn batch_from_columns(
    x: PyReadonlyArray1<'_, u16>,
    y: PyReadonlyArray1<'_, u16>,
    p: PyReadonlyArray1<'_, i16>,
    t: PyReadonlyArray1<'_, i64>,
) -> PyResult<EventBatch> {
    EventBatch::from_columns(
        x.as_array().to_vec(),
        y.as_array().to_vec(),
        p.as_array().to_vec(),
        t.as_array().to_vec(),
    )
    .map_err(to_py)
}

#[pymethods]
impl PyTracker {
    /// Tracker(camera, points_o (N,3) metres in the object frame, T_c_o (4,4), solver="edft+",
    /// frontend="scarf", n_search=4, tau_px=10.0, levels=3, lm_iterations=6, roi_margin_px=48.0,
    /// held_axes=None): held_axes (K, 6) are continuous symmetry axes of the object (unit axis,
    /// then a point on it; object frame, metres) whose rotation every update keeps at the prior.
    #[new]
    #[pyo3(signature = (camera, points_o, T_c_o, solver="edft+", frontend="scarf", n_search=4, tau_px=10.0, levels=3, lm_iterations=6, roi_margin_px=48.0, held_axes=None))]
    #[allow(non_snake_case)]
    fn new(
        py: Python<'_>,
        camera: &PyCamera,
        points_o: PyReadonlyArray2<'_, f64>,
        T_c_o: PyReadonlyArray2<'_, f64>,
        solver: &str,
        frontend: &str,
        n_search: usize,
        tau_px: f32,
        levels: u32,
        lm_iterations: u32,
        roi_margin_px: f64,
        held_axes: Option<PyReadonlyArray2<'_, f64>>,
    ) -> PyResult<Self> {
        let pose = matrix_from_py(&T_c_o)?;
        let pts = points_o.as_array();
        if pts.ncols() != 3 {
            return Err(PyValueError::new_err(format!(
                "points_o must have shape (N, 3), got {:?}",
                pts.shape()
            )));
        }
        let points: Vec<[f32; 3]> = pts
            .rows()
            .into_iter()
            .map(|r| [r[0] as f32, r[1] as f32, r[2] as f32])
            .collect();
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
            ..TrackerConfig::default()
        };
        let cam = camera.inner;
        let core = py
            .detach(move || TrackerCore::new(&cam, points, pose, config))
            .map_err(to_py)?;
        Ok(Self {
            state: State::Sync(Box::new(core)),
        })
    }

    /// Ingest one batch and run one cycle (1 LM + N search for edft+; N+1 steps otherwise).
    fn update(
        &mut self,
        py: Python<'_>,
        x: PyReadonlyArray1<'_, u16>,
        y: PyReadonlyArray1<'_, u16>,
        p: PyReadonlyArray1<'_, i16>,
        t: PyReadonlyArray1<'_, i64>,
    ) -> PyResult<PyEstimate> {
        let batch = batch_from_columns(x, y, p, t)?;
        let core = self.sync_core()?;
        let est = py.detach(|| core.update(&batch)).map_err(to_py)?;
        Ok(PyEstimate { inner: est })
    }

    /// Ingest one batch without stepping.
    fn ingest(
        &mut self,
        py: Python<'_>,
        x: PyReadonlyArray1<'_, u16>,
        y: PyReadonlyArray1<'_, u16>,
        p: PyReadonlyArray1<'_, i16>,
        t: PyReadonlyArray1<'_, i64>,
    ) -> PyResult<()> {
        let batch = batch_from_columns(x, y, p, t)?;
        let core = self.sync_core()?;
        py.detach(|| core.ingest(&batch)).map_err(to_py)
    }

    /// Run `n` single updates (each one LM or one search step) on the current events.
    #[pyo3(signature = (n=1))]
    fn step(&mut self, py: Python<'_>, n: usize) -> PyResult<PyEstimate> {
        let core = self.sync_core()?;
        let est = py.detach(|| {
            let mut e = core.latest();
            for _ in 0..n {
                e = core.step();
            }
            e
        });
        Ok(PyEstimate { inner: est })
    }

    /// Start the solver thread.
    fn start(&mut self) -> PyResult<()> {
        match std::mem::replace(&mut self.state, State::Moving) {
            State::Sync(core) => match ThreadedTracker::start(*core) {
                Ok(t) => {
                    self.state = State::Threaded(t);
                    Ok(())
                }
                Err(e) => Err(to_py(e)),
            },
            other => {
                self.state = other;
                Err(PyRuntimeError::new_err("the tracker is already running"))
            }
        }
    }

    /// Queue a batch for the running thread; never blocks.
    fn push(
        &mut self,
        x: PyReadonlyArray1<'_, u16>,
        y: PyReadonlyArray1<'_, u16>,
        p: PyReadonlyArray1<'_, i16>,
        t: PyReadonlyArray1<'_, i64>,
    ) -> PyResult<()> {
        let batch = batch_from_columns(x, y, p, t)?;
        match &mut self.state {
            State::Threaded(tr) => tr.push(batch).map_err(to_py),
            _ => Err(PyRuntimeError::new_err(
                "push() needs a running tracker: call start() first",
            )),
        }
    }

    /// The newest estimate (threaded or not).
    fn latest(&self) -> PyResult<PyEstimate> {
        match &self.state {
            State::Sync(core) => Ok(PyEstimate {
                inner: core.latest(),
            }),
            State::Threaded(t) => Ok(PyEstimate { inner: t.latest() }),
            State::Moving => Err(PyRuntimeError::new_err("tracker is between states")),
        }
    }

    /// Stop the solver thread (no-op when not running).
    fn stop(&mut self, py: Python<'_>) -> PyResult<()> {
        match std::mem::replace(&mut self.state, State::Moving) {
            State::Threaded(t) => {
                let core = py.detach(|| t.stop()).map_err(to_py)?;
                self.state = State::Sync(Box::new(core));
                Ok(())
            }
            other => {
                self.state = other;
                Ok(())
            }
        }
    }

    #[getter]
    fn running(&self) -> bool {
        matches!(&self.state, State::Threaded(t) if t.is_running())
    }

    /// Re-initialise the pose (4×4 T_c_o); the front-end keeps its events.
    #[allow(non_snake_case)]
    fn reset_pose(&mut self, T_c_o: PyReadonlyArray2<'_, f64>) -> PyResult<()> {
        let pose = matrix_from_py(&T_c_o)?;
        self.sync_core()?.reset_pose(pose).map_err(to_py)
    }

    /// Step counts and time per kind, dropped events, rejected jumps (a dict).
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let (s, dropped) = match &self.state {
            State::Sync(core) => (core.stats(), 0),
            State::Threaded(t) => (Default::default(), t.dropped_events()),
            State::Moving => return Err(PyRuntimeError::new_err("tracker is between states")),
        };
        let d = pyo3::types::PyDict::new(py);
        d.set_item("lm_steps", s.lm_steps)?;
        d.set_item("search_steps", s.search_steps)?;
        d.set_item("lm_seconds", s.lm_seconds)?;
        d.set_item("search_seconds", s.search_seconds)?;
        d.set_item("events_dropped", s.events_dropped + dropped)?;
        d.set_item("jumps_rejected", s.jumps_rejected)?;
        Ok(d)
    }

    /// Model points projected at the current pose, (N, 2) rectified pixels.
    fn projected_points<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let pts = self.sync_core()?.projected_points();
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
    fn field<'py>(&mut self, py: Python<'py>) -> PyResult<FieldWithOrigin<'py>> {
        let lvl = self.sync_core()?.field_level0();
        let (w, h) = (lvl.roi.width as usize, lvl.roi.height as usize);
        let arr = numpy::ndarray::Array2::from_shape_vec((h, w), lvl.value.clone())
            .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
        Ok((arr.into_pyarray(py), (lvl.roi.x0, lvl.roi.y0)))
    }

    /// Active pixels of the front-end in the full rectified image, (H, W) uint8.
    fn active_mask<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<u8>>> {
        let core = self.sync_core()?;
        let (w, h) = (core.camera().width, core.camera().height);
        let mut out = vec![0u8; w as usize * h as usize];
        core.surface().fill_mask(evcore::Roi::full(w, h), &mut out);
        numpy::ndarray::Array2::from_shape_vec((h as usize, w as usize), out)
            .map(|a| a.into_pyarray(py))
            .map_err(|e| PyRuntimeError::new_err(e.to_string()))
    }
}

impl PyTracker {
    fn sync_core(&mut self) -> PyResult<&mut TrackerCore> {
        match &mut self.state {
            State::Sync(core) => Ok(core),
            _ => Err(PyRuntimeError::new_err(
                "the tracker thread is running: call stop() first (or use push/latest)",
            )),
        }
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyTracker>()?;
    m.add_class::<PyEstimate>()
}
