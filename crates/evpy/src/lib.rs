//! Thin PyO3 bindings of evcore, imported from Python as `evservo._evcore`.
//! Conversions and error mapping only; every algorithm lives in evcore.

use pyo3::prelude::*;

mod camera;
mod errors;
mod events;
mod evt3;
mod field;
mod io;
mod model;
mod pose;
mod replay;
mod sim;
mod simcam;
mod tracker;

#[pymodule]
fn _evcore(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("DecodeError", m.py().get_type::<errors::DecodeError>())?;
    events::register(m)?;
    camera::register(m)?;
    field::register(m)?;
    tracker::register(m)?;
    sim::register(m)?;
    simcam::register(m)?;
    model::register(m)?;
    io::register(m)?;
    evt3::register(m)?;
    replay::register(m)?;
    Ok(())
}
