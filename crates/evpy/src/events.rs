//! The `EventCD` record across the Python boundary: numpy structured arrays of dtype
//! `evservo._evcore.EVENT_CD` are viewed in place as `&[evcore::EventCd]` (one buffer, no copy),
//! and event vectors go back to Python as such arrays without repacking. The dtype is built from
//! [`EventCd::FIELDS`], the one description of the layout in the code base.

use evcore::EventCd;
use numpy::{Element, PyArray1, PyArrayDescr, PyReadonlyArray1};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::PyDict;

/// [`EventCd`] as a numpy element (the orphan rule needs a local type; same layout).
#[repr(transparent)]
#[derive(Debug, Clone, Copy)]
pub struct PyEventCd(pub EventCd);

fn build_dtype(py: Python<'_>) -> PyResult<Py<PyArrayDescr>> {
    let spec = PyDict::new(py);
    spec.set_item("names", EventCd::FIELDS.map(|f| f.0))?;
    spec.set_item("formats", EventCd::FIELDS.map(|f| f.1))?;
    spec.set_item("offsets", EventCd::FIELDS.map(|f| f.2))?;
    spec.set_item("itemsize", EventCd::SIZE)?;
    Ok(PyArrayDescr::new(py, &spec)?.unbind())
}

/// The `EventCD` dtype, built once per interpreter.
pub fn event_cd_dtype(py: Python<'_>) -> Bound<'_, PyArrayDescr> {
    static DTYPE: PyOnceLock<Py<PyArrayDescr>> = PyOnceLock::new();
    DTYPE
        .get_or_init(py, || {
            build_dtype(py).expect("numpy accepts a fixed, valid structured dtype")
        })
        .bind(py)
        .clone()
}

// SAFETY: PyEventCd is plain old data with exactly the layout `event_cd_dtype` describes
// (repr(transparent) over a repr(C) struct whose size and offsets that dtype is built from).
unsafe impl Element for PyEventCd {
    const IS_COPY: bool = true;

    fn get_dtype(py: Python<'_>) -> Bound<'_, PyArrayDescr> {
        event_cd_dtype(py)
    }

    fn clone_ref(&self, _py: Python<'_>) -> Self {
        *self
    }
}

/// An EventCD array accepted by the bindings: read in place when C-contiguous.
pub type EventArray<'py> = PyReadonlyArray1<'py, PyEventCd>;

/// The records of a contiguous EventCD array, borrowed (no copy).
pub fn records<'a>(events: &'a EventArray<'_>) -> PyResult<&'a [EventCd]> {
    let slice = events.as_slice().map_err(|_| {
        PyValueError::new_err("events must be a C-contiguous EVENT_CD array (np.ascontiguousarray)")
    })?;
    // SAFETY: PyEventCd is repr(transparent) over EventCd.
    Ok(unsafe { std::slice::from_raw_parts(slice.as_ptr().cast::<EventCd>(), slice.len()) })
}

/// Records as a new EVENT_CD array (the vector's buffer is handed over, not copied).
pub fn to_array(py: Python<'_>, events: Vec<EventCd>) -> Bound<'_, PyArray1<PyEventCd>> {
    PyArray1::from_vec(py, events.into_iter().map(PyEventCd).collect())
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("EVENT_CD", event_cd_dtype(m.py()))
}
