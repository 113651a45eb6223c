//! EVT 2.0: 32-bit little-endian words, type in bits 31..28.
//! CD_OFF 0x0 / CD_ON 0x1 carry ts[27:22] (low 6 µs bits), x[21:11], y[10:0];
//! TIME_HIGH 0x8 carries bits 33..6 of the time. Everything else is counted and ignored.

use super::target::{DecodeTarget, Slots};
use super::{unwrap_time_base, DecodeStats, Stream, WordDecoder, MAX_SENSOR_SIDE_PX};
use crate::error::{Error, Result};

const CD_OFF: u32 = 0x0;
const CD_ON: u32 = 0x1;
const TIME_HIGH: u32 = 0x8;
/// The 34-bit time counter wraps after 2^34 µs (about 4 h 46 min).
const PERIOD_US: i64 = 1 << 34;
/// OpenEB's tolerance: a drop within ten TIME_HIGH steps of a full period is still a wrap.
const WRAP_GUARD_US: i64 = (10 << 6) + (1 << 6);

/// Streaming EVT 2.0 decoder (see the module docs of [`crate::io`] for the shared rules).
pub type Evt2Decoder = Stream<Evt2Words, 4>;

/// The EVT 2.0 half of [`Evt2Decoder`]: sensor bounds, time base and statistics.
#[derive(Debug, Clone)]
pub struct Evt2Words {
    width: u32,
    height: u32,
    /// Time base in µs with wraps applied; `None` until the first TIME_HIGH.
    time_high_us: Option<i64>,
    /// The largest time base so far (an event adds at most 63 µs to it); `i64::MIN` before the
    /// first TIME_HIGH.
    base_max: i64,
    stats: DecodeStats,
}

impl Default for Evt2Words {
    /// Accepts the full 11-bit address range (2048×2048 px).
    fn default() -> Self {
        Self {
            width: MAX_SENSOR_SIDE_PX,
            height: MAX_SENSOR_SIDE_PX,
            time_high_us: None,
            base_max: i64::MIN,
            stats: DecodeStats::default(),
        }
    }
}

impl WordDecoder for Evt2Words {
    fn set_geometry(&mut self, width: u32, height: u32) {
        (self.width, self.height) = (width, height);
    }

    fn stats(&self) -> &DecodeStats {
        &self.stats
    }

    fn t_bound(&self) -> Option<i64> {
        (self.base_max > i64::MIN).then(|| self.base_max.saturating_add(0x3f))
    }

    fn decode_words<O: DecodeTarget>(&mut self, bytes: &[u8], out: &mut O) -> Result<()> {
        let mut words = bytes
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]));
        let mut base = match self.time_high_us {
            Some(b) => b,
            None => {
                let mut found = None;
                for w in words.by_ref() {
                    self.stats.words_by_type[(w >> 28) as usize] += 1;
                    if w >> 28 == TIME_HIGH {
                        found = Some(i64::from(w & 0x0fff_ffff) << 6);
                        break;
                    }
                    self.stats.skipped_before_time_high += 1;
                }
                match found {
                    Some(b) => b,
                    None => return Ok(()),
                }
            }
        };
        let mut base_max = self.base_max.max(base);
        // At most one event per word.
        let slots = out.reserve_slots(words.len());
        let (width, height) = (self.width, self.height);
        // Word counts by type kept in registers: CD_OFF/CD_ON from the event count, the rest
        // (TIME_HIGH once per 64 µs, triggers, padding) in the rare branch.
        let (mut n, mut n_on) = (0usize, 0u64);
        let mut rare = [0u64; 16];
        let mut bad = None;
        for w in words {
            let ty = w >> 28;
            if ty <= CD_ON {
                let (x, y) = ((w >> 11) & 0x7ff, w & 0x7ff);
                if x >= width || y >= height {
                    rare[ty as usize] += 1;
                    bad = Some((x, y));
                    break;
                }
                // SAFETY: n < words decoded so far <= the room reserved.
                unsafe {
                    slots.put(
                        n,
                        x as u16,
                        y as u16,
                        ty as i16,
                        base + i64::from((w >> 22) & 0x3f),
                    )
                };
                n += 1;
                n_on += u64::from(ty);
            } else {
                rare[ty as usize] += 1;
                if ty == TIME_HIGH {
                    let raw = i64::from(w & 0x0fff_ffff) << 6;
                    base = unwrap_time_base(
                        base,
                        raw,
                        &mut self.stats.time_loops,
                        PERIOD_US,
                        WRAP_GUARD_US,
                    );
                    base_max = base_max.max(base);
                }
            }
        }
        // SAFETY: the first n slots were written above.
        unsafe { out.commit(n) };
        rare[CD_OFF as usize] += n as u64 - n_on;
        rare[CD_ON as usize] += n_on;
        for (total, k) in self.stats.words_by_type.iter_mut().zip(rare) {
            *total += k;
        }
        self.time_high_us = Some(base);
        self.base_max = base_max;
        match bad {
            None => Ok(()),
            Some((x, y)) => Err(Error::Decode(format!(
                "EVT2 event at ({x}, {y}) lies outside the {width}x{height} sensor (word {})",
                self.stats.words() - 1
            ))),
        }
    }
}
