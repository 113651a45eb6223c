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
    /// The time of the next event: the TIME_HIGH base plus the last TIME_LOW.
    t_us: i64,
    y: u32,
    /// The last VECT_BASE_X word (x in bits 0..11, polarity in bit 11) plus, in bits 16..32, how
    /// far the vectors since have advanced x (saturating).
    vbase: u32,
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
    /// The latest time any event decoded so far can carry (the largest time register value);
    /// `i64::MIN` before the first TIME_HIGH.
    t_max: i64,
    stats: DecodeStats,
}

impl Default for Evt3Words {
    /// Accepts the full 11-bit address range (2048×2048 px).
    fn default() -> Self {
        Self {
            width: MAX_SENSOR_SIDE_PX,
            height: MAX_SENSOR_SIDE_PX,
            state: None,
            t_max: i64::MIN,
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

    fn t_bound(&self) -> Option<i64> {
        (self.t_max > i64::MIN).then_some(self.t_max)
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
                        let time_high_us = i64::from(w & 0xfff) << 12;
                        found = Some(State {
                            time_high_us,
                            t_us: time_high_us,
                            ..State::default()
                        });
                        self.t_max = self.t_max.max(time_high_us);
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
    /// A first, vectorisable pass counts the ADDR_Y and ADDR_X words and checks every address
    /// they carry against the sensor; when all lie on it (always, in a sound stream) the word
    /// loop runs without bounds checks or counters on its hot path, otherwise a checked twin of
    /// the same loop finds the first bad event exactly. See [`Evt3Words::decode_words_into`].
    fn decode_block<O: DecodeTarget>(
        &mut self,
        state: &mut State,
        block: &[u8],
        out: &mut O,
    ) -> Result<()> {
        let slots = out.reserve_slots(12 * (block.len() / 2) + 12);
        let (n_y, n_x, on_sensor) = scan_addresses(block, self.width, self.height);
        // The y carried in from the previous block is checked too: that block may have ended on
        // an ADDR_Y off the sensor that no event used.
        let (n, res) = if on_sensor && state.y < self.height {
            let (n, res, words) = self.decode_words_into::<false, _>(state, block, slots);
            // A vector off the sensor stops the run early: count only the words it read.
            let (n_y, n_x, _) = match res {
                Ok(()) => (n_y, n_x, true),
                Err(_) => scan_addresses(&block[..2 * words], self.width, self.height),
            };
            self.stats.words_by_type[usize::from(ADDR_Y)] += n_y;
            self.stats.words_by_type[usize::from(ADDR_X)] += n_x;
            (n, res)
        } else {
            let (n, res, _) = self.decode_words_into::<true, _>(state, block, slots);
            (n, res)
        };
        // SAFETY: the first n slots were written.
        unsafe { out.commit(n) };
        res.map_err(|(x, y)| {
            let (width, height) = (self.width, self.height);
            let word = self.stats.words() - 1;
            Error::Decode(format!(
                "EVT3 event at ({x}, {y}) lies outside the {width}x{height} sensor (word {word})"
            ))
        })
    }

    /// The word loop: decodes `block` into `slots` and returns how many events it wrote, the
    /// error (the pixel) that stopped it, and how many words it read. `CHECKED` = false skips the bounds checks and counting
    /// of ADDR_X / ADDR_Y words, which [`scan_addresses`] did for the block.
    ///
    /// Shaped for the real streams, where ADDR_X and ADDR_Y (≈ 83 % of the words) interleave
    /// unpredictably: those two take one branch-free path that always writes an event slot (two
    /// 8-byte stores), advances the count only for ADDR_X (an ADDR_Y merely leaves a slot that
    /// the next event overwrites) and selects the new y with a conditional move; the state it
    /// carries stays in registers (y pre-shifted to its place in the record, the time as one
    /// sum). The other types take a second path. Vector words expand through a nibble table:
    /// four output slots per 4 mask bits, with the count advanced by the nibble's population.
    /// Every write stays below `n + 12`, and `n` never exceeds 12 per word, which is what the
    /// room reserved by the caller covers.
    #[inline(always)]
    fn decode_words_into<const CHECKED: bool, S: Slots>(
        &mut self,
        state: &mut State,
        block: &[u8],
        slots: S,
    ) -> (usize, std::result::Result<(), (u64, u64)>, usize) {
        let width = u64::from(self.width);
        let height_sh = u64::from(self.height) << 16;
        let mut high = state.time_high_us;
        let mut t = state.t_us;
        let mut y_sh = u64::from(state.y) << 16;
        let mut vbase = state.vbase;
        let mut counts = [0u64; 16];
        let mut loops = self.stats.time_loops;
        // Every event takes the time register's value: its largest value bounds their times.
        let mut t_max = self.t_max;
        let mut n = 0usize;
        let mut res = Ok(());
        let mut words = as_words(block).iter();
        while let Some(&c) = words.next() {
            let w = u16::from_le_bytes(c);
            if w & 0xd000 == 0 {
                // ADDR_Y (0x0) or ADDR_X (0x2): bit 13 tells them apart.
                let w = u64::from(w);
                let v = w & 0x7ff;
                let is_x = (w >> 13) & 1;
                if CHECKED {
                    counts[usize::from(ADDR_X)] += is_x;
                    counts[usize::from(ADDR_Y)] += 1 - is_x;
                    if (is_x != 0) & ((v >= width) | (y_sh >= height_sh)) {
                        res = Err((v, y_sh >> 16));
                        break;
                    }
                }
                // x | y << 16 | p << 32: polarity is bit 11 of the word.
                let xyp = v | y_sh | ((w & 0x800) << 21);
                // SAFETY (every put): slot < n + 12 <= 12 * (words so far) + 12 <= room.
                unsafe { slots.put_packed(n, xyp, t) };
                n += is_x as usize;
                y_sh = if is_x != 0 { y_sh } else { v << 16 };
                continue;
            }
            let ty = w >> 12;
            // One array indexed by type: a counter per type held in the loop took registers from
            // the ADDR path, which then reloaded its state from the stack at every word.
            counts[usize::from(ty)] += 1;
            match ty {
                VECT_12 | VECT_8 => {
                    let (bits, step) = if ty == VECT_12 {
                        (u64::from(w & 0xfff), 12)
                    } else {
                        (u64::from(w & 0xff), 8)
                    };
                    let x_base = u64::from(vbase & 0x7ff) + u64::from(vbase >> 16);
                    // A third of the masks are empty, in no predictable order: they take the
                    // same path without a branch (a mispredicted one cost ≈ 10 % of the loop)
                    // and write slots that the count does not advance over. x_end is one past
                    // the last event's x, masked to 0 for an empty mask rather than tested
                    // (the compiler turns a `bits != 0 &&` into that branch).
                    let nonempty = 0u64.wrapping_sub(u64::from(bits != 0));
                    let x_end = (x_base + 64 - u64::from(bits.leading_zeros())) & nonempty;
                    if (x_end > width) | ((y_sh & nonempty) >= height_sh) {
                        res = Err((x_end - 1, y_sh >> 16));
                        break;
                    }
                    // For a non-empty mask x_end <= width <= 2048, so adding an offset to x never
                    // carries into y; an empty one may, but writes only slots left uncounted.
                    let first = x_base | y_sh | (u64::from(vbase & 0x800) << 21);
                    // SAFETY: slot < n + 12, the room of one word.
                    n = unsafe { put_mask::<3, S>(slots, n, bits, first, t) };
                    // The advance since VECT_BASE_X counts in the high half, saturating: a long
                    // run of vectors in garbage input must not wrap back into the sensor.
                    vbase = vbase.saturating_add(step << 16);
                }
                VECT_BASE_X => {
                    vbase = u32::from(w);
                    // Real streams follow a base with VECT_12, VECT_12, VECT_8 (32 pixels):
                    // taken as one 32-bit mask, when all of it lies on the sensor, that is one
                    // dispatch instead of four. Anything else goes word by word.
                    if let [a, b, c, ..] = words.as_slice() {
                        let (a, b, c) = (
                            u16::from_le_bytes(*a),
                            u16::from_le_bytes(*b),
                            u16::from_le_bytes(*c),
                        );
                        let run = (a >> 12 == VECT_12) & (b >> 12 == VECT_12) & (c >> 12 == VECT_8);
                        let bits = u64::from(a & 0xfff)
                            | (u64::from(b & 0xfff) << 12)
                            | (u64::from(c & 0xff) << 24);
                        let x_base = u64::from(w & 0x7ff);
                        let nonempty = 0u64.wrapping_sub(u64::from(bits != 0));
                        let x_end = (x_base + 64 - u64::from(bits.leading_zeros())) & nonempty;
                        if run & (x_end <= width) & ((y_sh & nonempty) < height_sh) {
                            // x stays below width <= 2048 for the events counted (see above).
                            let first = x_base | y_sh | (u64::from(w & 0x800) << 21);
                            // SAFETY: slot < n + 32 <= 12 * (words up to the VECT_8).
                            n = unsafe { put_mask::<8, S>(slots, n, bits, first, t) };
                            vbase = vbase.saturating_add(32 << 16);
                            counts[usize::from(VECT_12)] += 2;
                            counts[usize::from(VECT_8)] += 1;
                            words.nth(2);
                        }
                    }
                }
                TIME_LOW => {
                    t = high + i64::from(w & 0xfff);
                    t_max = t_max.max(t);
                }
                TIME_HIGH => {
                    let low = t - high;
                    let raw = i64::from(w & 0xfff) << 12;
                    high = unwrap_time_base(high, raw, &mut loops, PERIOD_US, WRAP_GUARD_US);
                    t = high + low;
                    t_max = t_max.max(t);
                }
                _ => {}
            }
        }
        *state = State {
            time_high_us: high,
            t_us: t,
            y: (y_sh >> 16) as u32,
            vbase,
        };
        for (total, k) in self.stats.words_by_type.iter_mut().zip(counts) {
            *total += k;
        }
        self.stats.time_loops = loops;
        self.t_max = t_max;
        (n, res, block.len() / 2 - words.len())
    }
}

/// The whole 2-byte words of `bytes` (a trailing odd byte left out), each one load.
fn as_words(bytes: &[u8]) -> &[[u8; 2]] {
    // SAFETY: [u8; 2] has alignment 1 and no invalid values; the length stays inside `bytes`.
    unsafe { std::slice::from_raw_parts(bytes.as_ptr().cast(), bytes.len() / 2) }
}

/// (ADDR_Y words, ADDR_X words, whether every address they carry lies on the `width`×`height`
/// sensor) of a block of EVT 3.0 words. One pass without branches in 16-bit lanes, which the
/// compiler turns into full-width vector operations: 16 lanes where the CPU has AVX2 (a third of
/// the time of SSE2's 8 on the Gen4.1 sample), else 8.
fn scan_addresses(block: &[u8], width: u32, height: u32) -> (u64, u64, bool) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2.
        return unsafe { scan_addresses_avx2(block, width, height) };
    }
    scan_addresses_in_lanes::<8>(block, width, height)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn scan_addresses_avx2(block: &[u8], width: u32, height: u32) -> (u64, u64, bool) {
    scan_addresses_in_lanes::<16>(block, width, height)
}

/// One word of the address pre-scan, as 0/1 flags: an ADDR_Y word, an ADDR_X word, and an address
/// outside the sensor. Plain integer arithmetic, no branch, so the lane loop vectorises.
#[inline(always)]
fn classify_address(word: [u8; 2], width: u16, height: u16) -> (u16, u16, u16) {
    let w = u16::from_le_bytes(word);
    let (ty, v) = (w >> 12, w & 0x7ff);
    let (is_y, is_x) = (u16::from(ty == ADDR_Y), u16::from(ty == ADDR_X));
    (
        is_y,
        is_x,
        (is_x & u16::from(v >= width)) | (is_y & u16::from(v >= height)),
    )
}

/// [`scan_addresses`] over groups of `LANES` words, one 16-bit counter per lane.
#[inline(always)]
fn scan_addresses_in_lanes<const LANES: usize>(
    block: &[u8],
    width: u32,
    height: u32,
) -> (u64, u64, bool) {
    let (width, height) = (width as u16, height as u16);
    let (mut n_y, mut n_x, mut bad) = (0u64, 0u64, false);
    // A lane counts at most one word per group: 65 535 groups cannot overflow it.
    for part in as_words(block).chunks(LANES * usize::from(u16::MAX)) {
        let (mut ys, mut xs, mut bads) = ([0u16; LANES], [0u16; LANES], [0u16; LANES]);
        let groups = part.chunks_exact(LANES);
        let tail = groups.remainder();
        for group in groups {
            for k in 0..LANES {
                let (is_y, is_x, out) = classify_address(group[k], width, height);
                ys[k] += is_y;
                xs[k] += is_x;
                bads[k] |= out;
            }
        }
        for &c in tail {
            let (is_y, is_x, out) = classify_address(c, width, height);
            n_y += u64::from(is_y);
            n_x += u64::from(is_x);
            bad |= out != 0;
        }
        n_y += ys.iter().map(|&k| u64::from(k)).sum::<u64>();
        n_x += xs.iter().map(|&k| u64::from(k)).sum::<u64>();
        bad |= bads.iter().any(|&b| b != 0);
    }
    (n_y, n_x, !bad)
}

/// Writes one event per set bit of the low `NIBBLES` nibbles of a vector mask, at `first` plus
/// the bit's index (a packed x | y | polarity record), into the slots from `n`; returns the count
/// after them. Every nibble writes all four of its slots, padded, so there is no branch on the
/// bits; only the count skips the padding.
///
/// # Safety
/// Slots `n .. n + 4 * NIBBLES` must lie in the reserved room.
#[inline(always)]
unsafe fn put_mask<const NIBBLES: usize, S: Slots>(
    slots: S,
    n: usize,
    bits: u64,
    first: u64,
    t: i64,
) -> usize {
    let mut m = n;
    for j in 0..NIBBLES {
        let nibble = ((bits >> (4 * j)) & 0xf) as usize;
        let origin = first + 4 * j as u64;
        for (k, off) in NIBBLE_BITS[nibble].iter().enumerate() {
            // SAFETY: m + k < n + 4 * NIBBLES, in the room the caller vouches for.
            unsafe { slots.put_packed(m + k, origin + u64::from(*off), t) };
        }
        m += nibble.count_ones() as usize;
    }
    m
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The address pre-scan, word by word.
    fn scan_plainly(block: &[u8], width: u32, height: u32) -> (u64, u64, bool) {
        let (mut n_y, mut n_x, mut ok) = (0, 0, true);
        for c in block.chunks_exact(2) {
            let w = u16::from_le_bytes([c[0], c[1]]);
            let v = u32::from(w & 0x7ff);
            match w >> 12 {
                ADDR_Y => (n_y, ok) = (n_y + 1, ok && v < height),
                ADDR_X => (n_x, ok) = (n_x + 1, ok && v < width),
                _ => {}
            }
        }
        (n_y, n_x, ok)
    }

    #[test]
    fn address_scans_in_lanes_count_and_check_as_word_by_word() {
        let mut rng = crate::rng::Rng::new(0x2545_f491_4f6c_dd1du64);
        let mut next = move || rng.next_u64();
        for len in (0..80).chain([4095, 4096, 4097, 1 << 20]) {
            // Mostly ADDR words (the types 0x0 to 0x3), addresses over the whole 11-bit range; an
            // odd length leaves a byte that is not a word.
            let mut block: Vec<u8> = (0..len / 2)
                .flat_map(|_| {
                    let r = next();
                    let w = if r >> 60 == 0 {
                        r as u16
                    } else {
                        (r & 0x3fff) as u16
                    };
                    w.to_le_bytes()
                })
                .collect();
            block.extend((0..len % 2).map(|_| 0x20));
            for (width, height) in [(1280, 720), (2048, 2048), (1, 1), (640, 480)] {
                let want = scan_plainly(&block, width, height);
                assert_eq!(scan_addresses(&block, width, height), want);
                assert_eq!(scan_addresses_in_lanes::<8>(&block, width, height), want);
                assert_eq!(scan_addresses_in_lanes::<16>(&block, width, height), want);
            }
        }
    }
}
