//! `evservo._evcore.RawReader` and `RawSlices`: Prophesee RAW (EVT 2.0/3.0) files, decoded with the
//! GIL released.

use crate::errors::to_py;
use crate::events::{to_array, PyEventCd};
use evcore::io::{RawReader, SliceRule};
use numpy::PyArray1;
use pyo3::prelude::*;
use std::fs::File;

type Events<'py> = Bound<'py, PyArray1<PyEventCd>>;

#[pyclass(name = "RawReader", module = "evservo._evcore")]
pub struct PyRawReader {
    inner: RawReader<File>,
}

#[pymethods]
impl PyRawReader {
    /// RawReader(path): opens the file and parses its header. Missing files raise
    /// FileNotFoundError, unreadable headers DecodeError.
    #[new]
    fn new(py: Python<'_>, path: std::path::PathBuf) -> PyResult<Self> {
        let file = File::open(&path)?;
        let inner = py.detach(|| RawReader::new(file)).map_err(to_py)?;
        Ok(Self { inner })
    }

    /// Sensor width in pixels.
    #[getter]
    fn width(&self) -> u32 {
        self.inner.width()
    }

    /// Sensor height in pixels.
    #[getter]
    fn height(&self) -> u32 {
        self.inner.height()
    }

    /// "EVT2" or "EVT3".
    #[getter]
    fn format(&self) -> &'static str {
        self.inner.format().name()
    }

    /// The header lines as a list of (key, value) pairs, in file order.
    #[getter]
    fn header(&self) -> Vec<(String, String)> {
        self.inner.header().fields.clone()
    }

    /// The next `n` events (fewer at the end) as an EVENT_CD array; None once the file is
    /// exhausted.
    fn read_n_events<'py>(&mut self, py: Python<'py>, n: usize) -> PyResult<Option<Events<'py>>> {
        let reader = &mut self.inner;
        let out = py.detach(|| reader.next_n_events(n)).map_err(to_py)?;
        Ok(out.map(|events| to_array(py, events)))
    }

    /// The events before the first one at or after `t_us` (in stream order), as read_n_events;
    /// None once the file is exhausted. An empty time slice inside the file gives an empty array.
    fn read_until<'py>(&mut self, py: Python<'py>, t_us: i64) -> PyResult<Option<Events<'py>>> {
        let reader = &mut self.inner;
        let out = py.detach(|| reader.next_until_t(t_us)).map_err(to_py)?;
        Ok(out.map(|events| to_array(py, events)))
    }

    /// Every remaining event as one EVENT_CD array (empty at the end of the file).
    fn read_all<'py>(&mut self, py: Python<'py>) -> PyResult<Events<'py>> {
        let reader = &mut self.inner;
        let out = py.detach(|| reader.read_rest()).map_err(to_py)?;
        Ok(to_array(py, out))
    }

    /// Time of the next event (µs) without consuming it; None at the end of the file.
    fn peek_t(&mut self, py: Python<'_>) -> PyResult<Option<i64>> {
        let reader = &mut self.inner;
        py.detach(|| reader.peek_t()).map_err(to_py)
    }

    fn __repr__(&self) -> String {
        format!(
            "RawReader(format={}, width={}, height={})",
            self.inner.format(),
            self.inner.width(),
            self.inner.height()
        )
    }
}

/// A RAW file cut into the slices of `evservo.io.open_events`, handed over a run at a time.
#[pyclass(name = "RawSlices", module = "evservo._evcore")]
pub struct PyRawSlices {
    reader: RawReader<File>,
    rule: SliceRule,
}

#[pymethods]
impl PyRawSlices {
    /// RawSlices(path, *, delta_t_us=None, n_events=None): time slices of `delta_t_us` µs or
    /// slices of `n_events` events (exactly one of them). Iterating gives `(events, ends)` runs:
    /// one EVENT_CD array holding whole slices back to back, and the end index of each in it.
    #[new]
    #[pyo3(signature = (path, *, delta_t_us=None, n_events=None))]
    fn new(
        py: Python<'_>,
        path: std::path::PathBuf,
        delta_t_us: Option<i64>,
        n_events: Option<usize>,
    ) -> PyResult<Self> {
        let rule = match (delta_t_us, n_events) {
            (Some(dt), None) => SliceRule::time(dt),
            (None, Some(n)) => SliceRule::count(n),
            _ => {
                return Err(pyo3::exceptions::PyValueError::new_err(
                    "give exactly one of delta_t_us and n_events",
                ))
            }
        }
        .map_err(to_py)?;
        let reader = PyRawReader::new(py, path)?.inner;
        Ok(Self { reader, rule })
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__<'py>(&mut self, py: Python<'py>) -> PyResult<Option<(Events<'py>, Vec<usize>)>> {
        let (reader, rule) = (&mut self.reader, &mut self.rule);
        let run = py.detach(|| reader.next_slices(rule)).map_err(to_py)?;
        Ok(run.map(|run| (to_array(py, run.events), run.ends)))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyRawReader>()?;
    m.add_class::<PyRawSlices>()
}
