//! 4×4 pose matrices across the boundary: one conversion for every binding that takes a pose.

use crate::errors::to_py;
use evcore::se3::pose_from_matrix;
use evcore::Pose;
use numpy::ndarray::ArrayView2;
use numpy::{PyReadonlyArray2, PyReadonlyArray3};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// The rigid pose of a 4×4 view (shape already checked); NaN or a non-rigid matrix → ValueError.
fn pose_of(a: ArrayView2<'_, f64>) -> PyResult<Pose> {
    let rows: [[f64; 4]; 4] = std::array::from_fn(|i| std::array::from_fn(|j| a[(i, j)]));
    pose_from_matrix(&rows).map_err(to_py)
}

/// A 4×4 float64 pose matrix (e.g. `T_c_o`, metres) as a [`Pose`].
pub fn pose_arg(m: &PyReadonlyArray2<'_, f64>) -> PyResult<Pose> {
    let a = m.as_array();
    if a.shape() != [4, 4] {
        return Err(PyValueError::new_err(format!(
            "a pose must be a 4x4 matrix, got shape {:?}",
            a.shape()
        )));
    }
    pose_of(a)
}

/// An (N, 4, 4) stack of float64 pose matrices.
pub fn poses_arg(m: &PyReadonlyArray3<'_, f64>) -> PyResult<Vec<Pose>> {
    let a = m.as_array();
    if a.shape()[1..] != [4, 4] {
        return Err(PyValueError::new_err(format!(
            "poses must be an (N, 4, 4) array, got shape {:?}",
            a.shape()
        )));
    }
    a.outer_iter().map(pose_of).collect()
}
