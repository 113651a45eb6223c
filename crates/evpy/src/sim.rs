//! `evservo.EventSimulator`: the evcore sensor model, returning EventCD structured arrays.

use crate::errors::to_py;
use evcore::sim::{adaptive_dt_us, EventSimulator, SimParams};
use evcore::{EventBatch, Roi};
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::borrow::Cow;

/// A batch as EventCD records (padding zeroed, so output bytes are deterministic too).
pub(crate) fn pack_event_cd(ev: &EventBatch) -> Vec<evcore::EventCd> {
    ev.to_records()
}

pub(crate) fn to_event_cd(
    py: Python<'_>,
    records: Vec<evcore::EventCd>,
) -> PyResult<Bound<'_, PyAny>> {
    Ok(crate::events::to_array(py, records).into_any())
}

/// A frame as a contiguous row-major slice, checked against the expected (height, width);
/// copied only when the array is not C-contiguous.
fn frame_slice<'a>(
    frame: &'a PyReadonlyArray2<'_, f32>,
    h: u32,
    w: u32,
) -> PyResult<Cow<'a, [f32]>> {
    let shape = frame.shape();
    if shape != [h as usize, w as usize] {
        return Err(PyValueError::new_err(format!(
            "frame must have shape ({h}, {w}), got {shape:?}"
        )));
    }
    Ok(match frame.as_slice() {
        Ok(s) => Cow::Borrowed(s),
        Err(_) => Cow::Owned(frame.as_array().iter().copied().collect()),
    })
}

/// Sensor parameters from a preset name, a seed and keyword overrides (shared by every binding
/// that owns a simulator).
pub(crate) fn params_from(
    preset: &str,
    seed: u64,
    overrides: Option<&Bound<'_, PyDict>>,
) -> PyResult<SimParams> {
    let mut params = SimParams::preset(preset).map_err(to_py)?;
    params.seed = seed;
    if let Some(kw) = overrides {
        for (key, value) in kw.iter() {
            apply_override(&mut params, &key.extract::<String>()?, &value)?;
        }
    }
    Ok(params)
}

fn apply_override(p: &mut SimParams, key: &str, value: &Bound<'_, PyAny>) -> PyResult<()> {
    match key {
        "c_pos" => p.c_pos = value.extract()?,
        "c_neg" => p.c_neg = value.extract()?,
        "sigma_c" => p.sigma_c = value.extract()?,
        "refractory_us" => p.refractory_us = value.extract()?,
        "leak_rate_hz" => p.leak_rate_hz = value.extract()?,
        "leak_rate_spread_decades" => p.leak_rate_spread_decades = value.extract()?,
        "shot_noise_rate_hz" => p.shot_noise_rate_hz = value.extract()?,
        "shot_noise_bright_factor" => p.shot_noise_bright_factor = value.extract()?,
        "log_eps" => p.log_eps = value.extract()?,
        _ => {
            return Err(PyTypeError::new_err(format!(
                "EventSimulator got an unexpected parameter {key:?}"
            )))
        }
    }
    Ok(())
}

type Grid<'py, T> = Bound<'py, PyArray2<T>>;

#[pyclass(name = "EventSimulator", module = "evservo._evcore")]
pub struct PyEventSimulator {
    inner: EventSimulator,
}

impl PyEventSimulator {
    /// A row-major per-pixel vector as a (height, width) array.
    fn grid<'py, T: numpy::Element>(&self, py: Python<'py>, v: Vec<T>) -> PyResult<Grid<'py, T>> {
        let shape = (self.inner.height() as usize, self.inner.width() as usize);
        numpy::ndarray::Array2::from_shape_vec(shape, v)
            .map(|a| a.into_pyarray(py))
            .map_err(|e| PyValueError::new_err(e.to_string()))
    }
}

#[pymethods]
impl PyEventSimulator {
    /// EventSimulator(width, height, preset="imx636", seed=0, **overrides)
    ///
    /// Event-camera sensor model on a width×height grid. `preset` is "clean", "imx636" or
    /// "noisy"; keyword overrides set single parameters: c_pos, c_neg, sigma_c (log units),
    /// refractory_us, leak_rate_hz, leak_rate_spread_decades, shot_noise_rate_hz,
    /// shot_noise_bright_factor, log_eps.
    #[new]
    #[pyo3(signature = (width, height, preset="imx636", seed=0, **overrides))]
    fn new(
        width: i64,
        height: i64,
        preset: &str,
        seed: u64,
        overrides: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let params = params_from(preset, seed, overrides)?;
        let size = |v: i64, what: &str| {
            u32::try_from(v)
                .map_err(|_| PyValueError::new_err(format!("{what} must be in 1..=65535, got {v}")))
        };
        let inner = EventSimulator::new(size(width, "width")?, size(height, "height")?, params)
            .map_err(to_py)?;
        Ok(Self { inner })
    }

    #[getter]
    fn width(&self) -> u32 {
        self.inner.width()
    }

    #[getter]
    fn height(&self) -> u32 {
        self.inner.height()
    }

    /// Time (µs) of the last frame taken, or None before the first.
    #[getter]
    fn time_us(&self) -> Option<i64> {
        self.inner.time_us()
    }

    /// The parameters in effect, as a dict.
    #[getter]
    fn params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let p = self.inner.params();
        let d = PyDict::new(py);
        d.set_item("c_pos", p.c_pos)?;
        d.set_item("c_neg", p.c_neg)?;
        d.set_item("sigma_c", p.sigma_c)?;
        d.set_item("refractory_us", p.refractory_us)?;
        d.set_item("leak_rate_hz", p.leak_rate_hz)?;
        d.set_item("leak_rate_spread_decades", p.leak_rate_spread_decades)?;
        d.set_item("shot_noise_rate_hz", p.shot_noise_rate_hz)?;
        d.set_item("shot_noise_bright_factor", p.shot_noise_bright_factor)?;
        d.set_item("log_eps", p.log_eps)?;
        d.set_item("seed", p.seed)?;
        Ok(d)
    }

    /// Per-pixel (ON, OFF) thresholds in log units, each (height, width) float32.
    #[getter]
    fn thresholds<'py>(&self, py: Python<'py>) -> PyResult<(Grid<'py, f32>, Grid<'py, f32>)> {
        let (on, off) = self.inner.thresholds();
        Ok((self.grid(py, on)?, self.grid(py, off)?))
    }

    /// Per-pixel static leak-event rate in Hz, (height, width) float64.
    #[getter]
    fn leak_rates_hz<'py>(&self, py: Python<'py>) -> PyResult<Grid<'py, f64>> {
        self.grid(py, self.inner.leak_rates_hz())
    }

    /// Take `frame` ((height, width) float32 linear intensity) at `t_us` as the new state.
    fn reset(
        &mut self,
        py: Python<'_>,
        frame: PyReadonlyArray2<'_, f32>,
        t_us: i64,
    ) -> PyResult<()> {
        let f = frame_slice(&frame, self.inner.height(), self.inner.width())?;
        let sim = &mut self.inner;
        py.detach(|| sim.reset(&f, t_us)).map_err(to_py)
    }

    /// Advance to `frame` ((height, width) float32) at `t_us`; returns the interval's events as
    /// a time-sorted EventCD structured array (x, y, p, t). The first frame only initialises.
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        frame: PyReadonlyArray2<'py, f32>,
        t_us: i64,
    ) -> PyResult<Bound<'py, PyAny>> {
        let f = frame_slice(&frame, self.inner.height(), self.inner.width())?;
        let sim = &mut self.inner;
        let bytes = py
            .detach(|| {
                let mut out = EventBatch::default();
                sim.step(&f, t_us, &mut out).map(|()| pack_event_cd(&out))
            })
            .map_err(to_py)?;
        to_event_cd(py, bytes)
    }

    /// Advance only `roi` = (x0, y0, width, height) to `frame` (shape (height, width) of the
    /// ROI) at `t_us`; pixels outside emit nothing and keep their state.
    fn step_roi<'py>(
        &mut self,
        py: Python<'py>,
        frame: PyReadonlyArray2<'py, f32>,
        roi: (u32, u32, u32, u32),
        t_us: i64,
    ) -> PyResult<Bound<'py, PyAny>> {
        let roi = Roi {
            x0: roi.0,
            y0: roi.1,
            width: roi.2,
            height: roi.3,
        };
        let f = frame_slice(&frame, roi.height, roi.width)?;
        let sim = &mut self.inner;
        let bytes = py
            .detach(|| {
                let mut out = EventBatch::default();
                sim.step_roi(&f, roi, t_us, &mut out)
                    .map(|()| pack_event_cd(&out))
            })
            .map_err(to_py)?;
        to_event_cd(py, bytes)
    }

    fn __repr__(&self) -> String {
        format!(
            "EventSimulator({}x{}, {:?})",
            self.inner.width(),
            self.inner.height(),
            self.inner.params()
        )
    }
}

/// adaptive_dt_us(max_flow_px_per_s, lam=0.5, min_rate_hz=30.0) -> int
///
/// ESIM's sampling rule: the frame interval (µs) that keeps motion under `lam` pixels per
/// frame, capped at 1 / min_rate_hz.
#[pyfunction(name = "adaptive_dt_us")]
#[pyo3(signature = (max_flow_px_per_s, lam=0.5, min_rate_hz=30.0))]
fn py_adaptive_dt_us(max_flow_px_per_s: f64, lam: f64, min_rate_hz: f64) -> PyResult<i64> {
    adaptive_dt_us(max_flow_px_per_s, lam, min_rate_hz).map_err(to_py)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyEventSimulator>()?;
    m.add_function(wrap_pyfunction!(py_adaptive_dt_us, m)?)
}
