//! The event distance field: `euclidean_distance` (exact, untruncated; the oracle hook) and
//! `distance_field` (the truncated, rounded pyramid the solvers sample).

use crate::errors::to_py;
use evcore::field::{self, DistanceField, FieldParams};
use evcore::Roi;
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// A 2-D mask as a row-major vector, with its width and height.
fn mask_vec(mask: &PyReadonlyArray2<'_, u8>) -> (Vec<u8>, usize, usize) {
    let a = mask.as_array();
    let (h, w) = a.dim();
    (a.iter().copied().collect(), w, h)
}

/// euclidean_distance(mask: uint8 (H, W)) -> float32 (H, W): exact distance in pixels from each
/// pixel to the nearest nonzero pixel (inf everywhere if there is none).
#[pyfunction]
fn euclidean_distance<'py>(
    py: Python<'py>,
    mask: PyReadonlyArray2<'py, u8>,
) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let (m, w, h) = mask_vec(&mask);
    let out = py.detach(|| {
        let mut out = vec![0.0f32; w * h];
        field::euclidean_distance(&m, w, h, &mut out).map(|()| out)
    });
    let out = Array2::from_shape_vec((h, w), out.map_err(to_py)?)
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(out.into_pyarray(py))
}

/// distance_field(mask: uint8 (H, W), tau_px=10.0, levels=3, x0=0, y0=0) -> list of float32 arrays,
/// one per pyramid level (full, ½, ¼): f(D) = D²/2 below 1 px, D − ½ beyond, capped at f(tau_px).
/// (x0, y0) is the mask's top-left pixel in the full image; it sets the 2×2 pooling alignment.
#[pyfunction]
#[pyo3(signature = (mask, tau_px=field::DEFAULT_TAU_PX, levels=3, x0=0, y0=0))]
fn distance_field<'py>(
    py: Python<'py>,
    mask: PyReadonlyArray2<'py, u8>,
    tau_px: f32,
    levels: u32,
    x0: u32,
    y0: u32,
) -> PyResult<Vec<Bound<'py, PyArray2<f32>>>> {
    let (m, w, h) = mask_vec(&mask);
    let (width, height) = (u32::try_from(w), u32::try_from(h));
    let (Ok(width), Ok(height)) = (width, height) else {
        return Err(PyValueError::new_err(format!(
            "mask of {w}x{h} pixels is too large"
        )));
    };
    let roi = Roi {
        x0,
        y0,
        width,
        height,
    };
    let built = py.detach(|| {
        let mut f = DistanceField::new(FieldParams { tau_px, levels })?;
        f.build(&m, roi, levels)?;
        Ok(f)
    });
    let f = built.map_err(to_py)?;
    f.levels
        .into_iter()
        .map(|l| {
            let shape = (l.roi.height as usize, l.roi.width as usize);
            let a = Array2::from_shape_vec(shape, l.value)
                .map_err(|e| PyValueError::new_err(e.to_string()))?;
            Ok(a.into_pyarray(py))
        })
        .collect()
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(euclidean_distance, m)?)?;
    m.add_function(wrap_pyfunction!(distance_field, m)?)
}
