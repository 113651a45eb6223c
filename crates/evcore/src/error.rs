//! One error type for the whole core; the Python bindings map each variant to a Python exception.

use thiserror::Error;

#[derive(Debug, Error, Clone, PartialEq)]
pub enum Error {
    /// A parameter is out of its valid range (zero focal length, NaN pose, empty mesh, ...).
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// An event batch failed validation; `index` is the first offending event.
    #[error("invalid event at index {index}: {reason}")]
    InvalidEvent { index: usize, reason: String },
    /// A byte stream could not be decoded (truncated, wrong magic, unknown format).
    #[error("decode error: {0}")]
    Decode(String),
    /// The tracker lost the object or its state became unusable.
    #[error("tracking: {0}")]
    Tracking(String),
}

pub type Result<T> = std::result::Result<T, Error>;

/// `Err(InvalidArgument)` unless `cond`; keeps argument checks one line each.
pub fn ensure(cond: bool, msg: impl FnOnce() -> String) -> Result<()> {
    if cond {
        Ok(())
    } else {
        Err(Error::InvalidArgument(msg()))
    }
}
