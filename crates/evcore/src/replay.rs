//! File replay without Python: a RAW recording cut into time slices and fed to a consumer (the
//! threaded tracker's ingest) on a Rust thread, in real time or as fast as possible.
//!
//! The slices are those of `evservo.io.open_events(path, delta_t_us=batch_us)`: a grid of
//! multiples of `batch_us` starting with the one holding the first event, each slice ending
//! before the first event at or after its end in stream order. Events whose time steps back
//! below the newest one already fed are stamped with that newest time (a clamp, never a drop),
//! as `evservo.events.clamp_time` does, because ingest needs a non-decreasing stream.

use crate::error::{Error, Result};
use crate::io::{grid_end, RawReader};
use crate::EventCd;
use std::io::Read;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Longest sleep between two looks at the stop flag.
const STOP_POLL: Duration = Duration::from_millis(5);

/// A RAW reader cut into clamped time slices of `batch_us`.
pub struct TimeSlices<R: Read> {
    reader: RawReader<R>,
    batch_us: i64,
    /// End of the next slice (µs); None before the first event was seen.
    end_us: Option<i64>,
    /// Newest time handed out so far.
    t_max: Option<i64>,
    clamped: u64,
    /// No slice starting after this time (µs) is handed out.
    until_us: i64,
}

impl<R: Read> TimeSlices<R> {
    pub fn new(reader: RawReader<R>, batch_us: i64) -> Result<Self> {
        if batch_us < 1 {
            return Err(Error::InvalidArgument(format!(
                "batch_us must be >= 1, got {batch_us}"
            )));
        }
        Ok(Self {
            reader,
            batch_us,
            end_us: None,
            t_max: None,
            clamped: 0,
            until_us: i64::MAX,
        })
    }

    /// End the slices with the one holding `t_us` (µs): no slice starting after it is handed out.
    pub fn until(mut self, t_us: i64) -> Self {
        self.until_us = t_us;
        self
    }

    /// Length of the slices (µs).
    pub fn batch_us(&self) -> i64 {
        self.batch_us
    }

    /// Events stamped with a newer time because they stepped back.
    pub fn clamped(&self) -> u64 {
        self.clamped
    }

    /// Replaces `out` with the next slice and returns its end time (µs); None at the end of the
    /// file. Slices inside the recording may be empty.
    pub fn next_slice(&mut self, out: &mut Vec<EventCd>) -> Result<Option<i64>> {
        out.clear();
        let end = match self.end_us {
            Some(e) => e,
            None => match self.reader.peek_t()? {
                None => return Ok(None),
                Some(first) => grid_end(first, self.batch_us),
            },
        };
        if end - self.batch_us > self.until_us || !self.reader.read_until_t(end, out)? {
            return Ok(None);
        }
        self.end_us = Some(end + self.batch_us);
        let mut t_max = self.t_max.unwrap_or(i64::MIN);
        for e in out.iter_mut() {
            if e.t < t_max {
                e.t = t_max;
                self.clamped += 1;
            } else {
                t_max = e.t;
            }
        }
        if !out.is_empty() {
            self.t_max = Some(t_max);
        }
        Ok(Some(end))
    }
}

/// How fast a replay feeds its consumer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pace {
    /// Each slice as soon as the previous one was taken.
    AsFastAsPossible,
    /// A slice ending at event time `t` is fed when `(t - t_first) / speed` of wall time has
    /// passed since the start (speed 1 = real time).
    Speed(f64),
}

/// Counters a replay keeps live (readable from another thread while it runs).
#[derive(Debug, Default)]
pub struct ReplayProgress {
    pub slices: AtomicU64,
    pub events: AtomicU64,
    pub clamped: AtomicU64,
    /// End time of the last slice fed (µs), i64::MIN before the first.
    pub end_us: std::sync::atomic::AtomicI64,
}

/// Feeds every slice of `slices` with its end time (µs) to `consume` at `pace` until the slices
/// end, `stop` is set, or `consume` or the decoder fails (that error is returned). Empty slices
/// inside the recording are fed too (a consumer that updates per slice updates on them as well).
pub fn replay<R: Read>(
    mut slices: TimeSlices<R>,
    pace: Pace,
    stop: &AtomicBool,
    progress: &ReplayProgress,
    mut consume: impl FnMut(&[EventCd], i64) -> Result<()>,
) -> Result<()> {
    if let Pace::Speed(s) = pace {
        if !(s.is_finite() && s > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "replay speed must be a finite number > 0, got {s}"
            )));
        }
    }
    let mut batch = Vec::new();
    let started = Instant::now();
    let mut t_first = None;
    while !stop.load(Ordering::Acquire) {
        let Some(end) = slices.next_slice(&mut batch)? else {
            break;
        };
        if let Pace::Speed(speed) = pace {
            let first = *t_first.get_or_insert(end - slices.batch_us);
            let due = started + Duration::from_secs_f64((end - first) as f64 * 1e-6 / speed);
            if !sleep_until(due, stop) {
                break;
            }
        }
        consume(&batch, end)?;
        progress.slices.fetch_add(1, Ordering::Relaxed);
        progress
            .events
            .fetch_add(batch.len() as u64, Ordering::Relaxed);
        progress.clamped.store(slices.clamped(), Ordering::Relaxed);
        progress.end_us.store(end, Ordering::Release);
    }
    Ok(())
}

/// Sleeps until `due`, looking at `stop` every few ms; false if stopped first.
fn sleep_until(due: Instant, stop: &AtomicBool) -> bool {
    loop {
        if stop.load(Ordering::Acquire) {
            return false;
        }
        let now = Instant::now();
        if now >= due {
            return true;
        }
        std::thread::sleep((due - now).min(STOP_POLL));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::event::EventSink;
    use crate::io::{encode_evt3, RawHeader};

    fn raw_file(events: &[EventCd]) -> Vec<u8> {
        let mut bytes = b"% evt 3.0\n% format EVT3;height=480;width=640\n% end\n".to_vec();
        let mut batch = crate::EventBatch::default();
        batch.extend_from_records(events);
        bytes.extend(encode_evt3(&batch, 640, 480).unwrap());
        assert!(RawHeader::read_from(&mut &bytes[..]).is_ok());
        bytes
    }

    #[test]
    fn slices_follow_the_grid_and_clamp_steps_back() {
        let ev = |x, t| EventCd::new(x, 1, 1, t);
        let events = [
            ev(1, 1500),
            ev(2, 1999),
            ev(3, 2000),
            ev(4, 1990),
            ev(5, 4100),
        ];
        let reader = RawReader::new(std::io::Cursor::new(raw_file(&events))).unwrap();
        let mut slices = TimeSlices::new(reader, 1000).unwrap();
        let mut out = Vec::new();
        let mut got = Vec::new();
        while let Some(end) = slices.next_slice(&mut out).unwrap() {
            got.push((end, out.iter().map(|e| (e.x, e.t)).collect::<Vec<_>>()));
        }
        assert_eq!(
            got,
            vec![
                (2000, vec![(1, 1500), (2, 1999)]),
                // 1990 steps back after 2000: clamped to 2000, kept in stream order.
                (3000, vec![(3, 2000), (4, 2000)]),
                (4000, vec![]),
                (5000, vec![(5, 4100)]),
            ]
        );
        assert_eq!(slices.clamped(), 1);
    }

    #[test]
    fn replay_feeds_every_event_and_stops_on_request() {
        let events: Vec<EventCd> = (0..5000)
            .map(|i| EventCd::new((i % 640) as u16, 3, 0, 10 * i64::from(i)))
            .collect();
        let bytes = raw_file(&events);
        let open = || {
            let r = RawReader::new(std::io::Cursor::new(bytes.clone())).unwrap();
            TimeSlices::new(r, 1000).unwrap()
        };
        let (stop, progress) = (AtomicBool::new(false), ReplayProgress::default());
        let mut fed = Vec::new();
        let mut ends = Vec::new();
        replay(
            open(),
            Pace::AsFastAsPossible,
            &stop,
            &progress,
            |b, end| {
                fed.extend_from_slice(b);
                ends.push(end);
                Ok(())
            },
        )
        .unwrap();
        assert_eq!(fed, events);
        assert_eq!(ends, (1..=50).map(|k| k * 1000).collect::<Vec<_>>());
        assert_eq!(progress.events.load(Ordering::Relaxed), 5000);
        // Cut after the slice holding 20 ms: the slices [0, 21 ms).
        let mut n = 0;
        let until = open().until(20_000);
        replay(until, Pace::AsFastAsPossible, &stop, &progress, |b, _| {
            n += b.len();
            Ok(())
        })
        .unwrap();
        assert_eq!(n, 2100);
        // A consumer error ends the replay with that error; a set stop flag feeds nothing.
        let err = replay(open(), Pace::Speed(1.0), &stop, &progress, |_, _| {
            Err(Error::Tracking("full".into()))
        });
        assert!(matches!(err, Err(Error::Tracking(_))));
        stop.store(true, Ordering::Release);
        let mut n = 0;
        replay(open(), Pace::Speed(1.0), &stop, &progress, |b, _| {
            n += b.len();
            Ok(())
        })
        .unwrap();
        assert_eq!(n, 0);
    }
}
