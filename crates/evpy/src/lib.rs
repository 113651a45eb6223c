//! Thin PyO3 bindings of evcore, imported from Python as `evservo._evcore`.
//! Conversions and error mapping only; every algorithm lives in evcore.

use pyo3::prelude::*;

mod errors;

#[pymodule]
fn _evcore(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
