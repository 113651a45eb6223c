//! `evservo._evcore.Evt3Decoder` / `Evt3Encoder`: EVT 3.0 byte streams that arrive or leave in
//! packets (ROS `event_camera_msgs/EventPacket`), decoded and encoded with the GIL released.

use crate::errors::to_py;
use crate::events::{records, to_array, EventArray, PyEventCd};
use evcore::io::{Evt3Decoder, Evt3Encoder};
use evcore::EventBatch;
use pyo3::prelude::*;
use pyo3::types::PyBytes;

#[pyclass(name = "Evt3Decoder", module = "evservo._evcore")]
pub struct PyEvt3Decoder {
    inner: Evt3Decoder,
}

#[pymethods]
impl PyEvt3Decoder {
    /// Evt3Decoder(width, height): a streaming decoder for a `width`×`height` px sensor. Its
    /// state (time base and wraps, row, vector base, a partial word) carries from one decode
    /// call to the next, so packets cut anywhere decode like the whole stream.
    #[new]
    fn new(width: u32, height: u32) -> PyResult<Self> {
        let inner = Evt3Decoder::with_geometry(width, height).map_err(to_py)?;
        Ok(Self { inner })
    }

    /// The events of the next chunk of the stream as an EVENT_CD array. Events outside the sensor
    /// raise DecodeError, and so does every later call.
    fn decode<'py>(
        &mut self,
        py: Python<'py>,
        data: &[u8],
    ) -> PyResult<Bound<'py, numpy::PyArray1<PyEventCd>>> {
        let dec = &mut self.inner;
        let batch = py
            .detach(|| {
                let mut out = Vec::new();
                dec.decode(data, &mut out).map(|()| out)
            })
            .map_err(to_py)?;
        Ok(to_array(py, batch))
    }

    /// Bytes of an incomplete word held for the next call.
    #[getter]
    fn pending_bytes(&self) -> usize {
        self.inner.pending_bytes()
    }
}

#[pyclass(name = "Evt3Encoder", module = "evservo._evcore")]
pub struct PyEvt3Encoder {
    inner: Evt3Encoder,
}

#[pymethods]
impl PyEvt3Encoder {
    /// Evt3Encoder(width, height): a streaming EVT 3.0 encoder for a `width`×`height` px sensor;
    /// the bytes of successive encode calls concatenate to one stream.
    #[new]
    fn new(width: u32, height: u32) -> PyResult<Self> {
        let inner = Evt3Encoder::with_geometry(width, height).map_err(to_py)?;
        Ok(Self { inner })
    }

    /// The EVT 3.0 words of an EVENT_CD array (x, y pixels, p 0/1, t µs ≥ 0) continuing the
    /// stream. Events the format cannot carry back exactly (off the sensor, other
    /// polarities, negative times, steps back across a 2^24 µs period) raise ValueError and
    /// leave the encoder as it was.
    fn encode<'py>(
        &mut self,
        py: Python<'py>,
        events: EventArray<'py>,
    ) -> PyResult<Bound<'py, PyBytes>> {
        let mut batch = EventBatch::default();
        for e in records(&events)? {
            batch.push(e.x, e.y, e.p, e.t);
        }
        let enc = &mut self.inner;
        let bytes = py
            .detach(|| {
                let mut out = Vec::new();
                enc.encode(&batch, &mut out).map(|()| out)
            })
            .map_err(to_py)?;
        Ok(PyBytes::new(py, &bytes))
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyEvt3Decoder>()?;
    m.add_class::<PyEvt3Encoder>()
}
