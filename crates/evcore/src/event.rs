//! Event batches: struct of arrays in the layout of OpenEB's `EventCD` (x u16, y u16, p i16, t i64 µs).

use crate::error::{Error, Result};

/// A batch of change-detection events, struct of arrays. Coordinates are raw sensor pixels,
/// `t_us` is in microseconds, `p` is the polarity (0 = OFF, 1 = ON, as Metavision writes it;
/// any non-zero value counts as ON).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EventBatch {
    pub x: Vec<u16>,
    pub y: Vec<u16>,
    pub p: Vec<i16>,
    pub t_us: Vec<i64>,
}

impl EventBatch {
    pub fn with_capacity(n: usize) -> Self {
        Self {
            x: Vec::with_capacity(n),
            y: Vec::with_capacity(n),
            p: Vec::with_capacity(n),
            t_us: Vec::with_capacity(n),
        }
    }

    /// Build from four columns; they must have equal lengths.
    pub fn from_columns(x: Vec<u16>, y: Vec<u16>, p: Vec<i16>, t_us: Vec<i64>) -> Result<Self> {
        let n = x.len();
        if y.len() != n || p.len() != n || t_us.len() != n {
            return Err(Error::InvalidArgument(format!(
                "event columns differ in length: x {}, y {}, p {}, t {}",
                n,
                y.len(),
                p.len(),
                t_us.len()
            )));
        }
        Ok(Self { x, y, p, t_us })
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    pub fn push(&mut self, x: u16, y: u16, p: i16, t_us: i64) {
        self.x.push(x);
        self.y.push(y);
        self.p.push(p);
        self.t_us.push(t_us);
    }

    pub fn clear(&mut self) {
        self.x.clear();
        self.y.clear();
        self.p.clear();
        self.t_us.clear();
    }

    pub fn extend_from(&mut self, other: &EventBatch) {
        self.x.extend_from_slice(&other.x);
        self.y.extend_from_slice(&other.y);
        self.p.extend_from_slice(&other.p);
        self.t_us.extend_from_slice(&other.t_us);
    }

    /// Time of the last event, if any.
    pub fn last_t_us(&self) -> Option<i64> {
        self.t_us.last().copied()
    }

    /// Check that every event lies on a `width`×`height` sensor and that time never goes
    /// backwards, within the batch and relative to `prev_t_us` (the last time already accepted).
    /// Returns the first violation; the batch is then to be rejected whole.
    pub fn validate(&self, width: u32, height: u32, prev_t_us: Option<i64>) -> Result<()> {
        let mut last = prev_t_us.unwrap_or(i64::MIN);
        for i in 0..self.len() {
            let (x, y, t) = (self.x[i], self.y[i], self.t_us[i]);
            if u32::from(x) >= width || u32::from(y) >= height {
                return Err(Error::InvalidEvent {
                    index: i,
                    reason: format!("({x}, {y}) lies outside the {width}x{height} sensor"),
                });
            }
            if t < last {
                return Err(Error::InvalidEvent {
                    index: i,
                    reason: format!("time goes backwards: {t} µs after {last} µs"),
                });
            }
            last = t;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn batch(xs: &[u16], ts: &[i64]) -> EventBatch {
        let n = xs.len();
        EventBatch::from_columns(xs.to_vec(), vec![3; n], vec![1; n], ts.to_vec()).unwrap()
    }

    #[test]
    fn accepts_monotonic_in_range() {
        assert!(batch(&[0, 9, 5], &[1, 1, 2])
            .validate(10, 10, Some(1))
            .is_ok());
    }

    #[test]
    fn rejects_out_of_sensor_with_index() {
        let err = batch(&[0, 10], &[1, 2]).validate(10, 10, None).unwrap_err();
        assert!(matches!(err, Error::InvalidEvent { index: 1, .. }), "{err}");
    }

    #[test]
    fn rejects_time_going_backwards() {
        let err = batch(&[0, 1], &[5, 4]).validate(10, 10, None).unwrap_err();
        assert!(matches!(err, Error::InvalidEvent { index: 1, .. }));
        let err = batch(&[0], &[5]).validate(10, 10, Some(6)).unwrap_err();
        assert!(matches!(err, Error::InvalidEvent { index: 0, .. }));
    }

    #[test]
    fn rejects_ragged_columns() {
        assert!(EventBatch::from_columns(vec![1], vec![], vec![1], vec![1]).is_err());
    }
}
