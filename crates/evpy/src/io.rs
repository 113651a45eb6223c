//! `evservo._evcore.RawReader`: Prophesee RAW (EVT 2.0/3.0) files, decoded with the GIL released.

use crate::errors::to_py;
use evcore::io::RawReader;
use evcore::EventBatch;
use numpy::IntoPyArray;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::fs::File;

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

    /// The next `n` events (fewer at the end) as a dict of numpy columns x (u16), y (u16),
    /// p (i16), t (i64 µs); None once the file is exhausted.
    fn read_n_events<'py>(
        &mut self,
        py: Python<'py>,
        n: usize,
    ) -> PyResult<Option<Bound<'py, PyDict>>> {
        let reader = &mut self.inner;
        let (more, batch) = py
            .detach(|| {
                let mut out = EventBatch::default();
                reader.read_n_events(n, &mut out).map(|more| (more, out))
            })
            .map_err(to_py)?;
        more.then(|| columns(py, batch)).transpose()
    }

    /// The events before the first one at or after `t_us`, as read_n_events; None once the file
    /// is exhausted. An empty time slice inside the file gives empty columns, not None.
    fn read_until<'py>(
        &mut self,
        py: Python<'py>,
        t_us: i64,
    ) -> PyResult<Option<Bound<'py, PyDict>>> {
        let reader = &mut self.inner;
        let (more, batch) = py
            .detach(|| {
                let mut out = EventBatch::default();
                reader.read_until_t(t_us, &mut out).map(|more| (more, out))
            })
            .map_err(to_py)?;
        more.then(|| columns(py, batch)).transpose()
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

pub(crate) fn columns(py: Python<'_>, b: EventBatch) -> PyResult<Bound<'_, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("x", b.x.into_pyarray(py))?;
    d.set_item("y", b.y.into_pyarray(py))?;
    d.set_item("p", b.p.into_pyarray(py))?;
    d.set_item("t", b.t_us.into_pyarray(py))?;
    Ok(d)
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyRawReader>()
}
