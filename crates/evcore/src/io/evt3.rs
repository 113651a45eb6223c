//! EVT 3.0: 16-bit little-endian stateful words, type in bits 15..12.
//!
//! | type | word | effect |
//! | --- | --- | --- |
//! | 0x0 | ADDR_Y | y = bits 10..0 (bit 11 = master/slave, ignored) |
//! | 0x2 | ADDR_X | one event at x = bits 10..0, polarity bit 11, current y and t |
//! | 0x3 | VECT_BASE_X | x base = bits 10..0, vector polarity = bit 11 |
//! | 0x4 | VECT_12 | bit i set → event at base + i; base += 12 |
//! | 0x5 | VECT_8 | bit i set → event at base + i; base += 8 |
//! | 0x6 | TIME_LOW | low 12 µs bits |
//! | 0x8 | TIME_HIGH | bits 23..12 of the time |
//!
//! Time is `TIME_HIGH << 12 | TIME_LOW` from the last word of each kind, as the format
//! specification states; a TIME_HIGH does not reset the last TIME_LOW. A repeated TIME_HIGH
//! followed by a smaller TIME_LOW is a step back in time, not a wrap, and is output as such.
//! EXT_TRIGGER 0xA, CONTINUED 0x7/0xF, OTHERS 0xE and the reserved types are counted and ignored.

use super::{unwrap_time_base, DecodeStats, Stream, WordDecoder, MAX_SENSOR_SIDE_PX};
use crate::error::{Error, Result};
use crate::EventBatch;

const ADDR_Y: u16 = 0x0;
const ADDR_X: u16 = 0x2;
const VECT_BASE_X: u16 = 0x3;
const VECT_12: u16 = 0x4;
const VECT_8: u16 = 0x5;
const TIME_LOW: u16 = 0x6;
const TIME_HIGH: u16 = 0x8;
/// The 24-bit time counter wraps after 2^24 µs (16.777216 s).
const PERIOD_US: i64 = 1 << 24;
/// OpenEB's tolerance: a drop within ten TIME_HIGH steps of a full period is still a wrap.
const WRAP_GUARD_US: i64 = (10 << 12) + (1 << 12);
/// Words decoded per block (2048 words): the block's scratch columns stay in L1/L2 cache.
const BLOCK_BYTES: usize = 4 * 1024;

/// Decoder state that the hot loop copies into registers.
#[derive(Debug, Clone, Copy, Default)]
struct State {
    /// TIME_HIGH base in µs, wraps applied.
    time_high_us: i64,
    time_low_us: i64,
    y: u32,
    x_base: u32,
    vect_p: i16,
}

/// Streaming EVT 3.0 decoder (see the module docs of [`crate::io`] for the shared rules).
/// Streaming EVT 3.0 decoder (see the module docs of [`crate::io`] for the shared rules).
pub type Evt3Decoder = Stream<Evt3Words, 2>;

/// The EVT 3.0 half of [`Evt3Decoder`]: sensor bounds, the stateful address/time registers and
/// statistics.
#[derive(Debug, Clone)]
pub struct Evt3Words {
    width: u32,
    height: u32,
    /// `None` until the first TIME_HIGH.
    state: Option<State>,
    /// Per-block output columns, reused across calls; their length is capacity, not content.
    scratch: EventBatch,
    stats: DecodeStats,
}

impl Default for Evt3Words {
    /// Accepts the full 11-bit address range (2048×2048 px).
    fn default() -> Self {
        Self {
            width: MAX_SENSOR_SIDE_PX,
            height: MAX_SENSOR_SIDE_PX,
            state: None,
            scratch: EventBatch::default(),
            stats: DecodeStats::default(),
        }
    }
}

impl WordDecoder for Evt3Words {
    fn set_geometry(&mut self, width: u32, height: u32) {
        (self.width, self.height) = (width, height);
    }

    fn stats(&self) -> &DecodeStats {
        &self.stats
    }

    fn decode_words(&mut self, bytes: &[u8], out: &mut EventBatch) -> Result<()> {
        let mut body = bytes;
        let mut s = match self.state {
            Some(s) => s,
            None => {
                let mut found = None;
                while let [lo, hi, rest @ ..] = body {
                    body = rest;
                    let w = u16::from_le_bytes([*lo, *hi]);
                    self.stats.words_by_type[usize::from(w >> 12)] += 1;
                    if w >> 12 == TIME_HIGH {
                        found = Some(State {
                            time_high_us: i64::from(w & 0xfff) << 12,
                            ..State::default()
                        });
                        break;
                    }
                    self.stats.skipped_before_time_high += 1;
                }
                match found {
                    Some(s) => s,
                    None => return Ok(()),
                }
            }
        };
        let mut res = Ok(());
        while !body.is_empty() && res.is_ok() {
            let (block, rest) = body.split_at(body.len().min(BLOCK_BYTES));
            res = self.decode_block(&mut s, block, out);
            body = rest;
        }
        self.state = Some(s);
        res
    }
}

impl Evt3Words {
    /// Decodes whole words into the scratch columns, which are sized by the exact number of
    /// events the block can produce so the loop writes by index, and stay in cache; the events
    /// are then appended to `out` with one copy per column.
    fn decode_block(
        &mut self,
        state: &mut State,
        block: &[u8],
        out: &mut EventBatch,
    ) -> Result<()> {
        let mut s = *state;
        // VECT words write all 12 slots and keep the set ones, hence the slack.
        let room = max_events(block) + 12;
        let scratch = &mut self.scratch;
        if scratch.len() < room {
            scratch.x.resize(room, 0);
            scratch.y.resize(room, 0);
            scratch.p.resize(room, 0);
            scratch.t_us.resize(room, 0);
        }
        let EventBatch {
            x: xs,
            y: ys,
            p: ps,
            t_us: ts,
        } = scratch;
        let (width, height) = (self.width, self.height);
        // Common types are counted in registers; the array takes the rare ones.
        let [mut n_y, mut n_x, mut n_base, mut n_v12, mut n_v8, mut n_low] = [0u64; 6];
        let mut rare = [0u64; 16];
        let mut loops = self.stats.time_loops;
        let mut t = s.time_high_us + s.time_low_us;
        let mut n = 0usize;
        let mut res = Ok(());
        for c in block.chunks_exact(2) {
            let w = u16::from_le_bytes([c[0], c[1]]);
            let ty = w >> 12;
            if ty == VECT_12 || ty == VECT_8 {
                let (mask, step) = if ty == VECT_12 {
                    n_v12 += 1;
                    (u32::from(w & 0xfff), 12)
                } else {
                    n_v8 += 1;
                    (u32::from(w & 0xff), 8)
                };
                if mask != 0 {
                    let x_last = s.x_base + 31 - mask.leading_zeros();
                    if x_last >= width || s.y >= height {
                        res = Err((x_last, s.y));
                        break;
                    }
                    // All 12 slots are written and the set bits kept: a fixed, unrolled
                    // sequence instead of a loop whose length the branch predictor cannot guess.
                    ys[n..n + 12].fill(s.y as u16);
                    ps[n..n + 12].fill(s.vect_p);
                    ts[n..n + 12].fill(t);
                    let slots = &mut xs[n..n + 12];
                    let mut k = 0;
                    for i in 0..12 {
                        slots[k] = (s.x_base + i) as u16;
                        k += ((mask >> i) & 1) as usize;
                    }
                    n += k;
                }
                // Saturating: a long run of vectors in garbage input must not wrap back
                // into the sensor.
                s.x_base = s.x_base.saturating_add(step);
            } else if ty == ADDR_X {
                n_x += 1;
                let x = u32::from(w & 0x7ff);
                if x >= width || s.y >= height {
                    res = Err((x, s.y));
                    break;
                }
                xs[n] = x as u16;
                ys[n] = s.y as u16;
                ps[n] = ((w >> 11) & 1) as i16;
                ts[n] = t;
                n += 1;
            } else if ty == ADDR_Y {
                n_y += 1;
                s.y = u32::from(w & 0x7ff);
            } else if ty == VECT_BASE_X {
                n_base += 1;
                s.x_base = u32::from(w & 0x7ff);
                s.vect_p = ((w >> 11) & 1) as i16;
            } else if ty == TIME_LOW {
                n_low += 1;
                s.time_low_us = i64::from(w & 0xfff);
                t = s.time_high_us + s.time_low_us;
            } else {
                rare[usize::from(ty)] += 1;
                if ty == TIME_HIGH {
                    let raw = i64::from(w & 0xfff) << 12;
                    s.time_high_us =
                        unwrap_time_base(s.time_high_us, raw, &mut loops, PERIOD_US, WRAP_GUARD_US);
                    t = s.time_high_us + s.time_low_us;
                }
            }
        }
        rare[usize::from(ADDR_Y)] += n_y;
        rare[usize::from(ADDR_X)] += n_x;
        rare[usize::from(VECT_BASE_X)] += n_base;
        rare[usize::from(VECT_12)] += n_v12;
        rare[usize::from(VECT_8)] += n_v8;
        rare[usize::from(TIME_LOW)] += n_low;
        for (total, k) in self.stats.words_by_type.iter_mut().zip(rare) {
            *total += k;
        }
        self.stats.time_loops = loops;
        *state = s;
        out.x.extend_from_slice(&xs[..n]);
        out.y.extend_from_slice(&ys[..n]);
        out.p.extend_from_slice(&ps[..n]);
        out.t_us.extend_from_slice(&ts[..n]);
        res.map_err(|(x, y)| {
            let word = self.stats.words() - 1;
            Error::Decode(format!(
                "EVT3 event at ({x}, {y}) lies outside the {width}x{height} sensor (word {word})"
            ))
        })
    }
}

/// Events a block of whole words can produce: one per ADDR_X, one per set vector bit.
fn max_events(block: &[u8]) -> usize {
    block
        .chunks_exact(2)
        .map(|c| {
            let w = u16::from_le_bytes([c[0], c[1]]);
            let mask = match w >> 12 {
                VECT_12 => w & 0xfff,
                VECT_8 => w & 0xff,
                _ => 0,
            };
            usize::from(w >> 12 == ADDR_X) + mask.count_ones() as usize
        })
        .sum()
}
