//! Where the slices of `evservo.io.open_events` end: a grid of time boundaries or a fixed count,
//! found over a run of decoded events so that a whole run of slices crosses to Python at once.

use crate::error::{Error, Result};
use crate::EventCd;

/// Most slice ends one run holds: a long gap cut into fine time slices yields its empty slices a
/// bounded batch at a time instead of piling them all into one list.
pub const MAX_SLICES_PER_RUN: usize = 1 << 16;

/// Slices handed out together: `events` holds them back to back and slice `i` is
/// `events[ends[i - 1]..ends[i]]` (from 0 for the first). The last end is `events.len()`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SliceRun {
    pub events: Vec<EventCd>,
    pub ends: Vec<usize>,
}

/// How a stream is cut into slices, with the state the cut carries from run to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SliceRule {
    /// Time slices on a grid of multiples of `delta_t_us` (µs) starting with the one holding the
    /// first event; each ends before the first event at or after its end, in stream order.
    Time {
        delta_t_us: i64,
        /// End of the slice being cut (µs); None before the first event.
        end_us: Option<i64>,
    },
    /// Slices of this many events (the last one of the stream shorter).
    Count(usize),
}

impl SliceRule {
    /// Time slices of `delta_t_us` µs (≥ 1).
    pub fn time(delta_t_us: i64) -> Result<Self> {
        if delta_t_us < 1 {
            return Err(Error::InvalidArgument(format!(
                "delta_t_us must be >= 1, got {delta_t_us}"
            )));
        }
        Ok(Self::Time {
            delta_t_us,
            end_us: None,
        })
    }

    /// Slices of `n_events` events (≥ 1).
    pub fn count(n_events: usize) -> Result<Self> {
        if n_events < 1 {
            return Err(Error::InvalidArgument(format!(
                "n_events must be >= 1, got {n_events}"
            )));
        }
        Ok(Self::Count(n_events))
    }

    /// Appends to `ends` the end of every slice completed within `events` (which starts at a
    /// slice's start) after those already in `ends`, up to [`MAX_SLICES_PER_RUN`]. `scanned`
    /// events from the start are known to lie before the next time boundary; it is advanced so
    /// that a call after more events were appended does not look at them again. `t_bound`, when
    /// known, is at least the time of every event in `events`: no boundary above it is searched
    /// for (the scan of a run's last, incomplete slice is skipped).
    pub(crate) fn find_ends(
        &mut self,
        events: &[EventCd],
        t_bound: Option<i64>,
        scanned: &mut usize,
        ends: &mut Vec<usize>,
    ) {
        match self {
            Self::Time { delta_t_us, end_us } => {
                let Some(first) = events.first() else { return };
                let end = end_us.get_or_insert_with(|| grid_end(first.t, *delta_t_us));
                // A boundary past i64::MAX cuts nothing: the rest of the stream is one slice.
                while ends.len() < MAX_SLICES_PER_RUN && *end < i64::MAX {
                    if t_bound.is_some_and(|b| b < *end) {
                        *scanned = events.len();
                        return;
                    }
                    match first_at_or_after(&events[*scanned..], *end) {
                        Some(k) => {
                            *scanned += k;
                            ends.push(*scanned);
                            *end = end.saturating_add(*delta_t_us);
                        }
                        None => {
                            *scanned = events.len();
                            return;
                        }
                    }
                }
            }
            Self::Count(n) => {
                let mut last = ends.last().copied().unwrap_or(0);
                while ends.len() < MAX_SLICES_PER_RUN && events.len() - last >= *n {
                    last += *n;
                    ends.push(last);
                }
            }
        }
    }
}

/// End (µs) of the grid slice of `delta_t_us` holding `t_us`: the next multiple of `delta_t_us`
/// above it (i64::MAX where that overflows).
pub fn grid_end(t_us: i64, delta_t_us: i64) -> i64 {
    (t_us.div_euclid(delta_t_us) + 1)
        .checked_mul(delta_t_us)
        .unwrap_or(i64::MAX)
}

/// Index of the first event at or after `t_us`, in stream order.
fn first_at_or_after(events: &[EventCd], t_us: i64) -> Option<usize> {
    events.iter().position(|e| e.t >= t_us)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(ts: &[i64]) -> Vec<EventCd> {
        ts.iter().map(|&t| EventCd::new(0, 0, 1, t)).collect()
    }

    #[test]
    fn time_ends_follow_stream_order_and_leave_empty_slices() {
        let ev = at(&[5, 12, 9, 31, 33, 18, 40]);
        let mut rule = SliceRule::time(10).unwrap();
        let (mut scanned, mut ends) = (0, Vec::new());
        rule.find_ends(&ev, None, &mut scanned, &mut ends);
        // [5] ends at 12 (≥ 10); [12, 9] ends at 31 (≥ 20); [] ends at 31 (≥ 30); [31, 33, 18]
        // ends at 40; the slice from 40 is not complete yet.
        assert_eq!(ends, vec![1, 3, 3, 6]);
        assert_eq!(
            rule,
            SliceRule::Time {
                delta_t_us: 10,
                end_us: Some(50)
            }
        );
    }

    #[test]
    fn no_boundary_above_the_time_bound_is_searched() {
        let ev = at(&[5, 12, 9, 31]);
        let mut rule = SliceRule::time(10).unwrap();
        let (mut scanned, mut ends) = (0, Vec::new());
        // Every event lies at or below 31: the boundaries 10, 20, 30 are found, 40 is not
        // searched and the whole run counts as scanned.
        rule.find_ends(&ev, Some(31), &mut scanned, &mut ends);
        assert_eq!((ends, scanned), (vec![1, 3, 3], 4));
        let mut rule = SliceRule::time(10).unwrap();
        let (mut scanned, mut ends) = (0, Vec::new());
        rule.find_ends(&ev, Some(9), &mut scanned, &mut ends);
        assert_eq!((ends.len(), scanned), (0, 4));
    }

    #[test]
    fn negative_times_sit_on_the_same_grid() {
        assert_eq!(grid_end(-1, 10), 0);
        assert_eq!(grid_end(-10, 10), 0);
        assert_eq!(grid_end(0, 10), 10);
        assert_eq!(grid_end(i64::MAX - 3, 10), i64::MAX);
    }

    #[test]
    fn count_ends_continue_after_earlier_ones() {
        let ev = at(&[0; 7]);
        let mut rule = SliceRule::count(3).unwrap();
        let (mut scanned, mut ends) = (0, vec![3]);
        rule.find_ends(&ev, None, &mut scanned, &mut ends);
        assert_eq!(ends, vec![3, 6]);
    }

    #[test]
    fn a_boundary_past_the_end_of_time_cuts_nothing() {
        let ev = at(&[i64::MAX - 1, i64::MAX, i64::MAX]);
        let mut rule = SliceRule::time(1 << 62).unwrap();
        let (mut scanned, mut ends) = (0, Vec::new());
        rule.find_ends(&ev, None, &mut scanned, &mut ends);
        assert!(ends.is_empty());
    }

    #[test]
    fn bad_rules_are_refused() {
        assert!(SliceRule::time(0).is_err());
        assert!(SliceRule::count(0).is_err());
    }
}
