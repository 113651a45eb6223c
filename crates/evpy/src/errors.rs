//! evcore errors as Python exceptions: bad arguments and bad events are `ValueError`,
//! undecodable input is `evservo.DecodeError` (a `ValueError`), tracking failures `RuntimeError`.

use evcore::Error;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::PyErr;

pyo3::create_exception!(
    _evcore,
    DecodeError,
    PyValueError,
    "An event stream or file could not be decoded."
);

pub fn to_py(err: Error) -> PyErr {
    match err {
        Error::InvalidArgument(_) | Error::InvalidEvent { .. } => {
            PyValueError::new_err(err.to_string())
        }
        Error::Decode(_) => DecodeError::new_err(err.to_string()),
        Error::Tracking(_) => PyRuntimeError::new_err(err.to_string()),
    }
}
