//! `evservo._evcore.SimCamera`: the rendered event camera (object + background → distorted
//! frame → sensor model), returning EventCD structured arrays.

use crate::camera::PyCamera;
use crate::errors::to_py;
use crate::model::PyMesh;
use crate::pose::{pose_arg, poses_arg};
use crate::sim::{pack_event_cd, params_from, to_event_cd};
use evcore::render::RenderOptions;
use evcore::sim::camera::{Background, BackgroundPlane, SimCamera};
use evcore::EventBatch;
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray2, PyReadonlyArray3};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::Arc;

#[pyclass(name = "SimCamera", module = "evservo._evcore")]
pub struct PySimCamera {
    inner: SimCamera,
    out: EventBatch,
}

#[pymethods]
impl PySimCamera {
    /// SimCamera(camera, mesh, preset="imx636", seed=0, T_c_bg=None, cell_m=0.04,
    ///           background_intensity=0.1, ambient=0.35, diffuse=0.65, margin_px=4, sparse=True,
    ///           **overrides)
    ///
    /// A rendered event camera. `camera`: the sensor, with distortion. `mesh`: the object.
    /// Background: with `T_c_bg` (4×4, plane frame in camera; the plane is its z = 0) a plane
    /// of `cell_m`-metre cells of high-contrast albedo, else the uniform `background_intensity`.
    /// `preset` and `overrides` configure the sensor model as for `EventSimulator`; `seed`
    /// seeds the sensor and the background texture. `margin_px`: ROI growth in pixels.
    /// `sparse`: redraw only the tiles that can change (default); False is the full-frame
    /// reference path, with the same events (see `SimCamera::set_sparse`).
    #[new]
    #[pyo3(signature = (camera, mesh, preset="imx636", seed=0, T_c_bg=None, cell_m=0.04,
        background_intensity=0.1, ambient=0.35, diffuse=0.65, margin_px=4, sparse=true,
        **overrides))]
    #[allow(non_snake_case, clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        camera: &PyCamera,
        mesh: &PyMesh,
        preset: &str,
        seed: u64,
        T_c_bg: Option<PyReadonlyArray2<'_, f64>>,
        cell_m: f64,
        background_intensity: f32,
        ambient: f32,
        diffuse: f32,
        margin_px: u32,
        sparse: bool,
        overrides: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let params = params_from(preset, seed, overrides)?;
        let background = match T_c_bg {
            Some(m) => Background::Plane(BackgroundPlane {
                t_c_bg: pose_arg(&m)?,
                cell_m,
                seed,
            }),
            None => Background::Uniform(background_intensity),
        };
        let opts = RenderOptions {
            ambient,
            diffuse,
            background: 0.0,
        };
        let (cam, m) = (camera.inner, mesh.inner.clone());
        let mut inner = py
            .detach(move || SimCamera::new(cam, m, opts, background, params, margin_px))
            .map_err(to_py)?;
        inner.set_sparse(sparse);
        Ok(Self {
            inner,
            out: EventBatch::default(),
        })
    }

    /// Render the object at `T_c_o` (4×4) at `t_us`, moving the background plane to `T_c_bg`
    /// if given (a change forces a full frame), and step the sensor. With occluders set,
    /// `occluders` is their (N, 4, 4) poses in the camera. `ticks` (µs, increasing, strictly
    /// between the previous frame and `t_us`): also step the sensor at these times on the
    /// intensities interpolated linearly between the previous render and this one (one render,
    /// several sensor steps). Returns the interval's events, time-sorted EventCD. The first
    /// call only initialises the sensor.
    #[pyo3(signature = (T_c_o, t_us, T_c_bg=None, occluders=None, ticks=None))]
    #[allow(non_snake_case)]
    fn advance<'py>(
        &mut self,
        py: Python<'py>,
        T_c_o: PyReadonlyArray2<'py, f64>,
        t_us: i64,
        T_c_bg: Option<PyReadonlyArray2<'py, f64>>,
        occluders: Option<PyReadonlyArray3<'py, f64>>,
        ticks: Option<Vec<i64>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let pose = pose_arg(&T_c_o)?;
        let bg = T_c_bg.map(|m| pose_arg(&m)).transpose()?;
        let occ = occluders
            .map(|a| poses_arg(&a))
            .transpose()?
            .unwrap_or_default();
        let (inner, out) = (&mut self.inner, &mut self.out);
        let bytes = py
            .detach(|| {
                inner
                    .advance_ticks(
                        &pose,
                        &occ,
                        (ticks.as_deref().unwrap_or_default(), t_us),
                        bg.as_ref(),
                        out,
                    )
                    .map(|_| pack_event_cd(out))
            })
            .map_err(to_py)?;
        to_event_cd(py, bytes)
    }

    /// Replace the occluders: meshes drawn with the object and z-tested against it (e.g. the
    /// robot arms). Every later `advance` must pose them all. The next frame is a full frame.
    fn set_occluders(&mut self, meshes: Vec<PyRef<'_, PyMesh>>) {
        self.inner
            .set_occluders(meshes.iter().map(|m| Arc::clone(&m.inner)).collect());
    }

    /// Number of occluder meshes.
    #[getter]
    fn n_occluders(&self) -> usize {
        self.inner.occluders().len()
    }

    /// Largest raw-pixel displacement (px) of the occluders' visible vertices between poses
    /// `A` and `B` ((N, 4, 4) each, in camera); vertices behind the camera or off the canvas
    /// do not count. 0 with no occluders.
    #[allow(non_snake_case)]
    fn occluder_displacement_px(
        &self,
        py: Python<'_>,
        A: PyReadonlyArray3<'_, f64>,
        B: PyReadonlyArray3<'_, f64>,
    ) -> PyResult<f64> {
        let (a, b) = (poses_arg(&A)?, poses_arg(&B)?);
        let inner = &self.inner;
        py.detach(|| inner.occluder_displacement_px(&a, &b))
            .map_err(to_py)
    }

    /// Largest raw-pixel displacement (px) of any mesh vertex between poses `T_a` and `T_b`;
    /// inf if a vertex is at or behind the camera plane in either.
    #[allow(non_snake_case)]
    fn max_displacement_px(
        &self,
        py: Python<'_>,
        T_a: PyReadonlyArray2<'_, f64>,
        T_b: PyReadonlyArray2<'_, f64>,
    ) -> PyResult<f64> {
        let (a, b) = (pose_arg(&T_a)?, pose_arg(&T_b)?);
        let inner = &self.inner;
        Ok(py.detach(|| inner.max_displacement_px(&a, &b)))
    }

    /// The current raw frame, (height, width) float32 linear intensity.
    fn frame<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let c = self.inner.camera();
        Array2::from_shape_vec(
            (c.height as usize, c.width as usize),
            self.inner.frame().to_vec(),
        )
        .map(|a| a.into_pyarray(py))
        .map_err(|e| PyValueError::new_err(e.to_string()))
    }

    /// (x0, y0, width, height, full_frame) of the last step's raw region, None before the first.
    #[getter]
    fn last_roi(&self) -> Option<(u32, u32, u32, u32, bool)> {
        self.inner
            .last_frame()
            .map(|f| (f.roi.x0, f.roi.y0, f.roi.width, f.roi.height, f.full_frame))
    }

    /// Time (µs) of the last frame, None before the first.
    #[getter]
    fn time_us(&self) -> Option<i64> {
        self.inner.simulator().time_us()
    }

    #[getter]
    fn camera(&self) -> PyCamera {
        PyCamera {
            inner: *self.inner.camera(),
        }
    }

    /// The pinhole canvas the scene is rendered in before distortion.
    #[getter]
    fn canvas(&self) -> PyCamera {
        PyCamera {
            inner: *self.inner.canvas(),
        }
    }

    fn __repr__(&self) -> String {
        let c = self.inner.camera();
        let bg = match self.inner.background() {
            Background::Uniform(v) => format!("uniform {v}"),
            Background::Plane(p) => format!("plane, {} m cells", p.cell_m),
        };
        format!(
            "SimCamera({}x{}, background {bg}, {:?})",
            c.width,
            c.height,
            self.inner.simulator().params()
        )
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PySimCamera>()
}
