//! EVT 3.0 encoder: the inverse of [`super::Evt3Decoder`], word for word.
//!
//! Every event batch fed to [`Evt3Encoder::encode`] continues one stream, so the bytes of
//! successive calls concatenate to the stream of all their events, and the decoder, given those
//! bytes cut anywhere, yields the events back exactly (same order, same fields).
//!
//! Words written (see the table in [`super::evt3`]): TIME_HIGH and TIME_LOW whenever the time
//! changes, ADDR_Y whenever the row changes, and for each event either an ADDR_X or, for a run of
//! three or more events at the same time, row and polarity with strictly increasing x inside a
//! 12-pixel window, a VECT_BASE_X (left out when the decoder's vector base is already there)
//! followed by one VECT_12.
//!
//! What the decoder can represent bounds what is accepted (anything else is an
//! [`Error::InvalidEvent`] or [`Error::InvalidArgument`], with the output and state left as they
//! were before the call):
//! - times are ≥ 0 µs; the 24-bit counter's wraps are written as TIME_HIGH 0xfff → 0x000 pairs,
//!   so forward gaps of any length up to [`MAX_WRAPS_PER_GAP`] periods encode;
//! - a step back in time must stay inside the current 2^24 µs period and be shorter than the
//!   decoder's wrap guard allows (otherwise the decoder would read it as a wrap);
//! - polarity is 0 or 1 and x, y lie on the sensor.

use super::check_geometry;
use super::evt3::{PERIOD_US, WRAP_GUARD_US};
use crate::error::{Error, Result};
use crate::EventBatch;

const ADDR_Y: u16 = 0x0;
const ADDR_X: u16 = 0x2;
const VECT_BASE_X: u16 = 0x3;
const VECT_12: u16 = 0x4;
const TIME_LOW: u16 = 0x6;
const TIME_HIGH: u16 = 0x8;
/// One TIME_HIGH step, in µs.
const HIGH_STEP_US: i64 = 1 << 12;
/// Most 2^24 µs periods one forward gap may cross (two words each): about 13 days. A larger
/// gap is almost certainly an absolute (epoch) time that should have been made relative.
pub const MAX_WRAPS_PER_GAP: i64 = 1 << 16;
/// Shortest run of events worth a vector (two words) instead of one ADDR_X each.
const MIN_VECTOR_RUN: usize = 3;

/// What the decoder holds after the words written so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct Registers {
    /// TIME_HIGH base with wraps applied (µs, a multiple of 4096).
    high_us: i64,
    /// Last TIME_LOW value (µs, < 4096).
    low_us: i64,
    y: Option<u16>,
    /// VECT_BASE_X base and polarity.
    vect: Option<(u32, i16)>,
}

/// Streaming EVT 3.0 encoder for a `width`×`height` sensor.
#[derive(Debug, Clone)]
pub struct Evt3Encoder {
    width: u32,
    height: u32,
    /// `None` until the first TIME_HIGH is written.
    regs: Option<Registers>,
}

impl Evt3Encoder {
    /// An encoder for events on a `width`×`height` px sensor (each side 1..=2048 px).
    pub fn with_geometry(width: u32, height: u32) -> Result<Self> {
        let (width, height) = check_geometry(width, height)?;
        Ok(Self {
            width,
            height,
            regs: None,
        })
    }

    /// Appends the words of `events` (a continuation of every batch encoded before) to `out`.
    /// On error `out` and the encoder are unchanged.
    pub fn encode(&mut self, events: &EventBatch, out: &mut Vec<u8>) -> Result<()> {
        let n = events.t_us.len();
        if [events.x.len(), events.y.len(), events.p.len()] != [n; 3] {
            return Err(Error::InvalidArgument(
                "event columns x, y, p, t must have the same length".into(),
            ));
        }
        let start_len = out.len();
        let saved = self.regs;
        let res = self.encode_all(events, out);
        if res.is_err() {
            out.truncate(start_len);
            self.regs = saved;
        }
        res
    }

    fn encode_all(&mut self, ev: &EventBatch, out: &mut Vec<u8>) -> Result<()> {
        out.reserve(4 * ev.len());
        let mut i = 0;
        while i < ev.len() {
            let (x, y, p, t) = (ev.x[i], ev.y[i], ev.p[i], ev.t_us[i]);
            if u32::from(x) >= self.width || u32::from(y) >= self.height {
                return Err(Error::InvalidEvent {
                    index: i,
                    reason: format!(
                        "({x}, {y}) lies outside the {}x{} sensor",
                        self.width, self.height
                    ),
                });
            }
            if p != 0 && p != 1 {
                return Err(Error::InvalidEvent {
                    index: i,
                    reason: format!("polarity {p} is neither 0 nor 1"),
                });
            }
            let mut regs = self
                .set_time(t, out)
                .map_err(|reason| Error::InvalidEvent { index: i, reason })?;
            if regs.y != Some(y) {
                push(out, ADDR_Y, y);
                regs.y = Some(y);
            }
            let run = vector_run(ev, i);
            if run.len() >= MIN_VECTOR_RUN {
                let base = u32::from(x);
                if regs.vect != Some((base, p)) {
                    push(out, VECT_BASE_X, x | (p as u16) << 11);
                }
                let mask = run.fold(0u16, |m, j| m | 1 << (ev.x[j] - x));
                push(out, VECT_12, mask);
                regs.vect = Some((base + 12, p));
                i += mask.count_ones() as usize;
            } else {
                push(out, ADDR_X, x | (p as u16) << 11);
                i += 1;
            }
            self.regs = Some(regs);
        }
        Ok(())
    }

    /// Writes the TIME_HIGH / TIME_LOW words that bring the decoder to `t_us` and returns its
    /// registers after them; an unrepresentable time is an error message (nothing written that
    /// the caller keeps: [`Self::encode`] rolls back).
    fn set_time(&mut self, t_us: i64, out: &mut Vec<u8>) -> std::result::Result<Registers, String> {
        if t_us < 0 {
            return Err(format!("time {t_us} µs is negative"));
        }
        let target_high = t_us & !(HIGH_STEP_US - 1);
        let low = t_us & (HIGH_STEP_US - 1);
        let mut regs = match self.regs {
            Some(r) => r,
            None => {
                // The decoder's first TIME_HIGH starts the stream in period 0.
                let first = target_high.min(PERIOD_US - HIGH_STEP_US);
                push(out, TIME_HIGH, high_word(first));
                Registers {
                    high_us: first,
                    ..Registers::default()
                }
            }
        };
        if target_high != regs.high_us {
            let (period_now, period_target) = (regs.high_us / PERIOD_US, target_high / PERIOD_US);
            if period_target < period_now {
                return Err(format!(
                    "time {t_us} µs steps back into an earlier 2^24 µs period (stream is at {} µs)",
                    regs.high_us + regs.low_us
                ));
            }
            if period_target == period_now
                && regs.high_us - target_high >= PERIOD_US - WRAP_GUARD_US
            {
                return Err(format!(
                    "time {t_us} µs steps back too far (from {} µs): EVT 3.0 reads it as a wrap",
                    regs.high_us + regs.low_us
                ));
            }
            if period_target - period_now > MAX_WRAPS_PER_GAP {
                return Err(format!(
                    "time {t_us} µs lies more than {MAX_WRAPS_PER_GAP} counter periods after {} µs \
                     (absolute times? make them relative to the recording start)",
                    regs.high_us + regs.low_us
                ));
            }
            // Each period crossed: the last TIME_HIGH of the period, then 0, which the decoder's
            // wrap rule reads as one wrap (a drop of 2^24 - 4096 µs).
            for period in period_now..period_target {
                let last = period * PERIOD_US + PERIOD_US - HIGH_STEP_US;
                if regs.high_us != last {
                    push(out, TIME_HIGH, high_word(last));
                }
                push(out, TIME_HIGH, 0);
                regs.high_us = (period + 1) * PERIOD_US;
            }
            if regs.high_us != target_high {
                push(out, TIME_HIGH, high_word(target_high));
                regs.high_us = target_high;
            }
        }
        if regs.low_us != low {
            push(out, TIME_LOW, low as u16);
            regs.low_us = low;
        }
        Ok(regs)
    }
}

/// The 12-bit TIME_HIGH payload of a base in µs.
fn high_word(high_us: i64) -> u16 {
    ((high_us >> 12) & 0xfff) as u16
}

fn push(out: &mut Vec<u8>, ty: u16, payload: u16) {
    out.extend_from_slice(&(ty << 12 | payload).to_le_bytes());
}

/// Indices of the events from `i` on that one VECT_12 based at `x[i]` can carry: same time,
/// row and polarity, x strictly increasing and below `x[i] + 12`.
fn vector_run(ev: &EventBatch, i: usize) -> impl ExactSizeIterator<Item = usize> {
    let (x0, y0, p0, t0) = (ev.x[i], ev.y[i], ev.p[i], ev.t_us[i]);
    let mut end = i + 1;
    while end < ev.len()
        && end - i < 12
        && ev.t_us[end] == t0
        && ev.y[end] == y0
        && ev.p[end] == p0
        && ev.x[end] > ev.x[end - 1]
        && ev.x[end] < x0 + 12
    {
        end += 1;
    }
    i..end
}

/// The EVT 3.0 stream of `events` on a `width`×`height` sensor, in one call.
pub fn encode_evt3(events: &EventBatch, width: u32, height: u32) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    Evt3Encoder::with_geometry(width, height)?.encode(events, &mut out)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::Evt3Decoder;

    fn batch(ev: &[(u16, u16, i16, i64)]) -> EventBatch {
        let mut b = EventBatch::default();
        for &(x, y, p, t) in ev {
            b.x.push(x);
            b.y.push(y);
            b.p.push(p);
            b.t_us.push(t);
        }
        b
    }

    fn decode(bytes: &[u8]) -> EventBatch {
        let mut d = Evt3Decoder::with_geometry(640, 480).unwrap();
        let mut out = EventBatch::default();
        d.decode(bytes, &mut out).unwrap();
        out
    }

    #[test]
    fn vector_run_is_two_words() {
        let ev = batch(&[
            (10, 5, 1, 100),
            (11, 5, 1, 100),
            (15, 5, 1, 100),
            (21, 5, 1, 100),
        ]);
        let bytes = encode_evt3(&ev, 640, 480).unwrap();
        // TIME_HIGH, TIME_LOW, ADDR_Y, VECT_BASE_X, VECT_12.
        assert_eq!(bytes.len(), 2 * 5);
        assert_eq!(
            u16::from_le_bytes([bytes[8], bytes[9]]),
            0x4000 | 0b1000_0010_0011
        );
        assert_eq!(decode(&bytes), ev);
    }

    #[test]
    fn wraps_and_long_gaps_round_trip() {
        let p = PERIOD_US;
        let ev = batch(&[
            (1, 1, 0, 5),
            (2, 1, 1, p - 1),
            (3, 2, 0, p + 7),
            (4, 2, 0, 5 * p + 12_345),
        ]);
        assert_eq!(decode(&encode_evt3(&ev, 640, 480).unwrap()), ev);
    }

    #[test]
    fn unrepresentable_times_are_errors_and_leave_no_trace() {
        let mut enc = Evt3Encoder::with_geometry(640, 480).unwrap();
        let mut out = Vec::new();
        enc.encode(&batch(&[(1, 1, 0, PERIOD_US + 10)]), &mut out)
            .unwrap();
        let kept = out.clone();
        for t in [-1, 10, (MAX_WRAPS_PER_GAP + 2) * PERIOD_US] {
            let e = enc.encode(&batch(&[(1, 1, 0, PERIOD_US + 20), (1, 1, 0, t)]), &mut out);
            assert!(
                matches!(e, Err(Error::InvalidEvent { index: 1, .. })),
                "{t}: {e:?}"
            );
            assert_eq!(out, kept);
        }
        assert!(enc
            .encode(&batch(&[(640, 1, 0, PERIOD_US + 20)]), &mut out)
            .is_err());
        assert!(enc
            .encode(&batch(&[(1, 1, 2, PERIOD_US + 20)]), &mut out)
            .is_err());
        assert_eq!(out, kept);
        // The stream goes on where it was.
        enc.encode(&batch(&[(2, 2, 1, PERIOD_US + 30)]), &mut out)
            .unwrap();
        assert_eq!(
            decode(&out),
            batch(&[(1, 1, 0, PERIOD_US + 10), (2, 2, 1, PERIOD_US + 30)])
        );
    }
}
