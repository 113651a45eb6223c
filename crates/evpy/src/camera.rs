//! `evservo.Camera`: pinhole + OpenCV distortion.

use crate::errors::to_py;
use evcore::Camera;
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

#[pyclass(name = "Camera", module = "evservo._evcore", frozen)]
#[derive(Clone)]
pub struct PyCamera {
    pub inner: Camera,
}

#[pymethods]
impl PyCamera {
    /// Camera(width, height, fx, fy, cx, cy, dist=(k1, k2, p1, p2, k3)); pixels, OpenCV convention.
    #[new]
    #[pyo3(signature = (width, height, fx, fy, cx, cy, dist=(0.0, 0.0, 0.0, 0.0, 0.0)))]
    fn new(
        width: i64,
        height: i64,
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        dist: (f64, f64, f64, f64, f64),
    ) -> PyResult<Self> {
        // Taken as i64 so that a negative or huge size is a ValueError with the size in it, not
        // PyO3's OverflowError about an unsigned conversion.
        let (Ok(width), Ok(height)) = (u32::try_from(width), u32::try_from(height)) else {
            return Err(PyValueError::new_err(format!(
                "sensor size {width}x{height} must be within 1..=16384 pixels"
            )));
        };
        let d = [dist.0, dist.1, dist.2, dist.3, dist.4];
        Ok(Self {
            inner: Camera::new(width, height, fx, fy, cx, cy, d).map_err(to_py)?,
        })
    }

    /// The Prophesee IMX636 of the paper: 1280×720, fx 1163.59, fy 1173.48, cx 658.823, cy 339.619, k1 −0.2819.
    #[staticmethod]
    fn imx636() -> Self {
        Self {
            inner: Camera::imx636(),
        }
    }

    #[getter]
    fn width(&self) -> u32 {
        self.inner.width
    }
    #[getter]
    fn height(&self) -> u32 {
        self.inner.height
    }
    #[getter]
    fn fx(&self) -> f64 {
        self.inner.fx
    }
    #[getter]
    fn fy(&self) -> f64 {
        self.inner.fy
    }
    #[getter]
    fn cx(&self) -> f64 {
        self.inner.cx
    }
    #[getter]
    fn cy(&self) -> f64 {
        self.inner.cy
    }
    /// Distortion (k1, k2, p1, p2, k3).
    #[getter]
    fn dist(&self) -> (f64, f64, f64, f64, f64) {
        let d = self.inner.dist;
        (d[0], d[1], d[2], d[3], d[4])
    }

    /// 3×3 intrinsic matrix K.
    #[getter]
    fn k<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let c = &self.inner;
        numpy::ndarray::arr2(&[[c.fx, 0.0, c.cx], [0.0, c.fy, c.cy], [0.0, 0.0, 1.0]])
            .into_pyarray(py)
    }

    /// The same camera without distortion (the rectified grid the tracker works in).
    fn rectified(&self) -> Self {
        Self {
            inner: self.inner.rectified(),
        }
    }

    /// Project (N, 3) points in the camera frame (metres) to (N, 2) raw pixels with distortion.
    /// Points at or behind the camera plane give NaN.
    #[pyo3(signature = (points_c, distort=true))]
    fn project<'py>(
        &self,
        py: Python<'py>,
        points_c: PyReadonlyArray2<'py, f64>,
        distort: bool,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let p = points_c.as_array();
        if p.ncols() != 3 {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "points must have shape (N, 3), got {:?}",
                p.shape()
            )));
        }
        let mut out = numpy::ndarray::Array2::<f64>::from_elem((p.nrows(), 2), f64::NAN);
        for (i, row) in p.rows().into_iter().enumerate() {
            let v = nalgebra::Vector3::new(row[0], row[1], row[2]);
            let uv = if distort {
                self.inner.project(&v)
            } else {
                self.inner.project_pinhole(&v)
            };
            if let Some((u, w)) = uv {
                out[(i, 0)] = u;
                out[(i, 1)] = w;
            }
        }
        Ok(out.into_pyarray(py))
    }

    /// Raw pixels (N, 2) to rectified pixels (N, 2); NaN where the distortion cannot be inverted.
    fn rectify_pixels<'py>(
        &self,
        py: Python<'py>,
        pixels: PyReadonlyArray2<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let p = pixels.as_array();
        if p.ncols() != 2 {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "pixels must have shape (N, 2), got {:?}",
                p.shape()
            )));
        }
        let mut out = numpy::ndarray::Array2::<f64>::from_elem((p.nrows(), 2), f64::NAN);
        for (i, row) in p.rows().into_iter().enumerate() {
            if let Some((u, v)) = self.inner.rectify_pixel(row[0], row[1]) {
                out[(i, 0)] = u;
                out[(i, 1)] = v;
            }
        }
        Ok(out.into_pyarray(py))
    }

    fn __repr__(&self) -> String {
        let c = &self.inner;
        format!(
            "Camera(width={}, height={}, fx={}, fy={}, cx={}, cy={}, dist={:?})",
            c.width, c.height, c.fx, c.fy, c.cx, c.cy, c.dist
        )
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyCamera>()
}
