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

use super::target::{DecodeTarget, Slots};
use super::{unwrap_time_base, DecodeStats, Stream, WordDecoder, MAX_SENSOR_SIDE_PX};
use crate::error::{Error, Result};

const ADDR_Y: u16 = 0x0;
const ADDR_X: u16 = 0x2;
const VECT_BASE_X: u16 = 0x3;
const VECT_12: u16 = 0x4;
const VECT_8: u16 = 0x5;
const TIME_LOW: u16 = 0x6;
const TIME_HIGH: u16 = 0x8;
/// The 24-bit time counter wraps after 2^24 µs (16.777216 s).
pub(super) const PERIOD_US: i64 = 1 << 24;
/// OpenEB's tolerance: a drop within ten TIME_HIGH steps of a full period is still a wrap.
pub(super) const WRAP_GUARD_US: i64 = (10 << 12) + (1 << 12);
/// Words decoded per block (2048 words): bounds the capacity reserved ahead of each block.
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
pub type Evt3Decoder = Stream<Evt3Words, 2>;

/// The EVT 3.0 half of [`Evt3Decoder`]: sensor bounds, the stateful address/time registers and
/// statistics.
#[derive(Debug, Clone)]
pub struct Evt3Words {
    width: u32,
    height: u32,
    /// `None` until the first TIME_HIGH.
    state: Option<State>,
    stats: DecodeStats,
}

impl Default for Evt3Words {
    /// Accepts the full 11-bit address range (2048×2048 px).
    fn default() -> Self {
        Self {
            width: MAX_SENSOR_SIDE_PX,
            height: MAX_SENSOR_SIDE_PX,
            state: None,
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

    fn decode_words<O: DecodeTarget>(&mut self, bytes: &[u8], out: &mut O) -> Result<()> {
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
    /// Decodes a block of whole words straight into the slots past the end of `out`.
    ///
    /// The hot loop is shaped for the real streams, where ADDR_X and ADDR_Y (≈ 80 % of the
    /// words) interleave unpredictably: those two take one branch-free path that always writes an
    /// event slot and only advances the count for ADDR_X (so ADDR_Y merely leaves a slot that the
    /// next event overwrites); the rarer types share a second path. Vector words expand through
    /// a nibble table: four output slots per 4 mask bits, with the count advanced by the nibble's
    /// population. Every write stays below `n + 12`, and `n` never exceeds 12 per word, which
    /// is what the room reserved up front covers.
    fn decode_block<O: DecodeTarget>(
        &mut self,
        state: &mut State,
        block: &[u8],
        out: &mut O,
    ) -> Result<()> {
        let mut s = *state;
        let slots = out.reserve_slots(12 * (block.len() / 2) + 12);
        let (width, height) = (self.width, self.height);
        let [mut n_y, mut n_x] = [0u64; 2];
        let mut rare = [0u64; 16];
        let mut loops = self.stats.time_loops;
        let mut t = s.time_high_us + s.time_low_us;
        let mut y = s.y;
        let mut n = 0usize;
        let mut res = Ok(());
        for c in block.chunks_exact(2) {
            let w = u16::from_le_bytes([c[0], c[1]]);
            if w & 0xd000 == 0 {
                // ADDR_Y (0x0) or ADDR_X (0x2).
                let is_x = usize::from((w >> 13) & 1);
                let v = u32::from(w & 0x7ff);
                n_x += is_x as u64;
                n_y += 1 - is_x as u64;
                if (is_x != 0) & ((v >= width) | (y >= height)) {
                    res = Err((v, y));
                    break;
                }
                // SAFETY (every put): slot < n + 12 <= 12 * (words so far) + 12 <= room.
                unsafe { slots.put(n, v as u16, y as u16, ((w >> 11) & 1) as i16, t) };
                n += is_x;
                y = if is_x != 0 { y } else { v };
                continue;
            }
            let ty = w >> 12;
            rare[usize::from(ty)] += 1;
            match ty {
                VECT_12 | VECT_8 => {
                    let (mask, step) = if ty == VECT_12 {
                        (u32::from(w & 0xfff), 12)
                    } else {
                        (u32::from(w & 0xff), 8)
                    };
                    if mask != 0 {
                        let x_last = s.x_base + 31 - mask.leading_zeros();
                        if x_last >= width || y >= height {
                            res = Err((x_last, y));
                            break;
                        }
                        // x_last < width <= 2048, so every slot value below fits in u16.
                        let base = s.x_base as u16;
                        let mut m = n;
                        for j in 0..3 {
                            let nibble = ((mask >> (4 * j)) & 0xf) as usize;
                            let offsets = NIBBLE_BITS[nibble];
                            let origin = base.wrapping_add(4 * j as u16);
                            for (k, off) in offsets.iter().enumerate() {
                                unsafe {
                                    slots.put(
                                        m + k,
                                        origin.wrapping_add(*off),
                                        y as u16,
                                        s.vect_p,
                                        t,
                                    )
                                };
                            }
                            m += nibble.count_ones() as usize;
                        }
                        n = m;
                    }
                    // Saturating: a long run of vectors in garbage input must not wrap
                    // back into the sensor.
                    s.x_base = s.x_base.saturating_add(step);
                }
                VECT_BASE_X => {
                    s.x_base = u32::from(w & 0x7ff);
                    s.vect_p = ((w >> 11) & 1) as i16;
                }
                TIME_LOW => {
                    s.time_low_us = i64::from(w & 0xfff);
                    t = s.time_high_us + s.time_low_us;
                }
                TIME_HIGH => {
                    let raw = i64::from(w & 0xfff) << 12;
                    s.time_high_us =
                        unwrap_time_base(s.time_high_us, raw, &mut loops, PERIOD_US, WRAP_GUARD_US);
                    t = s.time_high_us + s.time_low_us;
                }
                _ => {}
            }
        }
        // SAFETY: the first n slots were written above.
        unsafe { out.commit(n) };
        s.y = y;
        rare[usize::from(ADDR_Y)] += n_y;
        rare[usize::from(ADDR_X)] += n_x;
        for (total, k) in self.stats.words_by_type.iter_mut().zip(rare) {
            *total += k;
        }
        self.stats.time_loops = loops;
        *state = s;
        res.map_err(|(x, y)| {
            let word = self.stats.words() - 1;
            Error::Decode(format!(
                "EVT3 event at ({x}, {y}) lies outside the {width}x{height} sensor (word {word})"
            ))
        })
    }
}

/// For each 4-bit vector mask, the offsets of its set bits in order, padded with zeros.
const NIBBLE_BITS: [[u16; 4]; 16] = {
    let mut table = [[0u16; 4]; 16];
    let mut v = 0;
    while v < 16 {
        let (mut bit, mut k) = (0, 0);
        while bit < 4 {
            if v & (1 << bit) != 0 {
                table[v][k] = bit as u16;
                k += 1;
            }
            bit += 1;
        }
        v += 1;
    }
    table
};
