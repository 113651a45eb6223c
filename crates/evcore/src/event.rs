//! Events: [`EventCd`], one record in the layout of OpenEB's `EventCD` (x u16, y u16, p i16,
//! t i64 µs; 16 bytes), and [`EventBatch`], the same fields as a struct of arrays. Both are
//! [`EventRecords`], which is what validation and the tracker's ingest read.

use crate::error::{Error, Result};

/// One change-detection event exactly as OpenEB's `EventCD` lays it out in memory (and as numpy's
/// structured dtype of the same name): x u16 @0, y u16 @2, p i16 @4, two bytes of padding, t i64 @8.
/// The padding is a real (zeroed) field so that every byte of a record is initialised and a
/// slice of records can be handed to Python or written to a file as it is.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EventCd {
    /// Sensor column (pixels).
    pub x: u16,
    /// Sensor row (pixels).
    pub y: u16,
    /// Polarity: 0 OFF, non-zero ON.
    pub p: i16,
    pad: u16,
    /// Time (µs).
    pub t: i64,
}

impl EventCd {
    /// Size of one record in bytes.
    pub const SIZE: usize = 16;
    /// (name, numpy format, byte offset) of each field, in record order: the one description of
    /// the layout that the Python bindings turn into the `EventCD` dtype.
    pub const FIELDS: [(&'static str, &'static str, usize); 4] = [
        ("x", "<u2", std::mem::offset_of!(EventCd, x)),
        ("y", "<u2", std::mem::offset_of!(EventCd, y)),
        ("p", "<i2", std::mem::offset_of!(EventCd, p)),
        ("t", "<i8", std::mem::offset_of!(EventCd, t)),
    ];

    #[inline]
    pub fn new(x: u16, y: u16, p: i16, t: i64) -> Self {
        Self { x, y, p, pad: 0, t }
    }
}

const _: () = assert!(std::mem::size_of::<EventCd>() == EventCd::SIZE);
const _: () = assert!(
    cfg!(target_endian = "little"),
    "EventCd mirrors a little-endian layout"
);

/// Read access to a sequence of events, whatever its memory layout.
pub trait EventRecords {
    fn n_events(&self) -> usize;
    /// (x, y) of event `i` (`i < n_events()`).
    fn xy(&self, i: usize) -> (u16, u16);
    /// Time of event `i` (µs).
    fn t_at(&self, i: usize) -> i64;
    /// Polarity of event `i` (0 OFF, non-zero ON).
    fn p_at(&self, i: usize) -> i16;
    /// Time of the last event, if any.
    fn last_t(&self) -> Option<i64> {
        self.n_events().checked_sub(1).map(|i| self.t_at(i))
    }
    /// True when [`validate_events`] would accept the events: the fast check, without finding
    /// the culprit. No early exit, so it compiles to straight-line (vectorisable) code.
    fn all_plausible(&self, width: u32, height: u32, prev_t_us: Option<i64>) -> bool {
        let n = self.n_events();
        let mut bad = false;
        for i in 0..n {
            let ((x, y), t) = (self.xy(i), self.t_at(i));
            let before = if i > 0 {
                Some(self.t_at(i - 1))
            } else {
                prev_t_us
            };
            bad |= !plausible(x, y, t, before, width, height);
        }
        !bad
    }
}

/// One event against the sensor size and the previous event's time (branch-free).
#[inline(always)]
fn plausible(x: u16, y: u16, t: i64, before: Option<i64>, width: u32, height: u32) -> bool {
    let in_time = t.wrapping_add(MAX_ABS_T_US) as u64 <= 2 * MAX_ABS_T_US as u64;
    let ordered = before.is_none_or(|b| t >= b && t.wrapping_sub(b) <= MAX_TIME_JUMP_US);
    (u32::from(x) < width) & (u32::from(y) < height) & in_time & ordered
}

impl EventRecords for [EventCd] {
    fn all_plausible(&self, width: u32, height: u32, prev_t_us: Option<i64>) -> bool {
        let Some(first) = self.first() else {
            return true;
        };
        let first_ok = plausible(first.x, first.y, first.t, prev_t_us, width, height);
        // Pairs of neighbours instead of a running "last": no loop-carried state to serialise on.
        let rest_ok = self.iter().zip(&self[1..]).fold(true, |ok, (a, b)| {
            ok & plausible(b.x, b.y, b.t, Some(a.t), width, height)
        });
        first_ok & rest_ok
    }
    #[inline]
    fn n_events(&self) -> usize {
        self.len()
    }
    #[inline]
    fn xy(&self, i: usize) -> (u16, u16) {
        (self[i].x, self[i].y)
    }
    #[inline]
    fn t_at(&self, i: usize) -> i64 {
        self[i].t
    }
    #[inline]
    fn p_at(&self, i: usize) -> i16 {
        self[i].p
    }
}

impl EventRecords for EventBatch {
    #[inline]
    fn n_events(&self) -> usize {
        self.len()
    }
    #[inline]
    fn xy(&self, i: usize) -> (u16, u16) {
        (self.x[i], self.y[i])
    }
    #[inline]
    fn t_at(&self, i: usize) -> i64 {
        self.t_us[i]
    }
    #[inline]
    fn p_at(&self, i: usize) -> i16 {
        self.p[i]
    }
}

/// Where decoded events go: columns ([`EventBatch`]) or records (`Vec<EventCd>`).
pub trait EventSink {
    /// Append `events`.
    fn extend_from_records(&mut self, events: &[EventCd]);
}

impl EventSink for EventBatch {
    fn extend_from_records(&mut self, events: &[EventCd]) {
        self.x.extend(events.iter().map(|e| e.x));
        self.y.extend(events.iter().map(|e| e.y));
        self.p.extend(events.iter().map(|e| e.p));
        self.t_us.extend(events.iter().map(|e| e.t));
    }
}

impl EventSink for Vec<EventCd> {
    fn extend_from_records(&mut self, events: &[EventCd]) {
        self.extend_from_slice(events);
    }
}

/// Largest accepted |t| (µs): 2^53 µs is 285 years, so any clock (sensor counter, Unix time in
/// µs) fits, while a garbage word such as 2^63 − 1 is refused instead of ending the time line.
pub const MAX_ABS_T_US: i64 = 1 << 53;

/// Largest accepted step forward in time between consecutive events (µs): one hour. A larger
/// jump is a corrupt stamp, not a pause; a restarted clock needs an explicit reset of the time line.
pub const MAX_TIME_JUMP_US: i64 = 3_600_000_000;

/// Check that every event lies on a `width`×`height` sensor, that its time is plausible (within
/// ±[`MAX_ABS_T_US`], at most [`MAX_TIME_JUMP_US`] after the previous event) and that time never
/// goes backwards, within the batch and relative to `prev_t_us` (the last time already accepted).
/// Returns the first violation; the batch is then to be rejected whole.
pub fn validate_events<E: EventRecords + ?Sized>(
    events: &E,
    width: u32,
    height: u32,
    prev_t_us: Option<i64>,
) -> Result<()> {
    if events.all_plausible(width, height, prev_t_us) {
        return Ok(());
    }
    let mut last = prev_t_us;
    for i in 0..events.n_events() {
        let ((x, y), t) = (events.xy(i), events.t_at(i));
        let reason = if u32::from(x) >= width || u32::from(y) >= height {
            format!("({x}, {y}) lies outside the {width}x{height} sensor")
        } else if t.unsigned_abs() > MAX_ABS_T_US as u64 {
            format!("time {t} µs is outside ±2^53 µs (a corrupt time stamp)")
        } else if last.is_some_and(|l| t < l) {
            format!(
                "time goes backwards: {t} µs after {} µs (after a clock restart, reset the tracker's events)",
                last.unwrap_or_default()
            )
        } else if last.is_some_and(|l| t - l > MAX_TIME_JUMP_US) {
            format!(
                "time jumps forward by {} µs (more than an hour) after {} µs: a corrupt time stamp \
                 (after a clock restart, reset the tracker's events)",
                t - last.unwrap_or_default(),
                last.unwrap_or_default()
            )
        } else {
            last = Some(t);
            continue;
        };
        return Err(Error::InvalidEvent { index: i, reason });
    }
    Ok(())
}

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

    /// See [`validate_events`].
    pub fn validate(&self, width: u32, height: u32, prev_t_us: Option<i64>) -> Result<()> {
        validate_events(self, width, height, prev_t_us)
    }

    /// The events as records, in order.
    pub fn to_records(&self) -> Vec<EventCd> {
        (0..self.len())
            .map(|i| EventCd::new(self.x[i], self.y[i], self.p[i], self.t_us[i]))
            .collect()
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
    fn rejects_absurd_times_and_jumps() {
        let err = batch(&[0, 1], &[5, i64::MAX])
            .validate(10, 10, None)
            .unwrap_err();
        assert!(matches!(err, Error::InvalidEvent { index: 1, .. }), "{err}");
        assert!(batch(&[0], &[-(1 << 60)]).validate(10, 10, None).is_err());
        // Unix time in µs is fine; an hour's gap is the most that passes.
        let now = 1_800_000_000_000_000;
        assert!(batch(&[0, 1], &[now, now + MAX_TIME_JUMP_US])
            .validate(10, 10, None)
            .is_ok());
        let err = batch(&[0], &[now + MAX_TIME_JUMP_US + 1])
            .validate(10, 10, Some(now))
            .unwrap_err();
        assert!(err.to_string().contains("jumps forward"), "{err}");
    }

    #[test]
    fn records_and_columns_validate_alike() {
        let b = batch(&[0, 9, 12], &[1, 1, 0]);
        let recs = b.to_records();
        assert_eq!(recs[1], EventCd::new(9, 3, 1, 1));
        let cols = b.validate(10, 10, None).unwrap_err().to_string();
        let rows = validate_events(recs.as_slice(), 10, 10, None)
            .unwrap_err()
            .to_string();
        assert_eq!(cols, rows);
        assert!(cols.contains("index 2"), "{cols}");
    }

    #[test]
    fn rejects_ragged_columns() {
        assert!(EventBatch::from_columns(vec![1], vec![], vec![1], vec![1]).is_err());
    }
}
