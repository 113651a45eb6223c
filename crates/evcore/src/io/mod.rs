//! Prophesee RAW event files: header parsing, streaming EVT 2.0 / EVT 3.0 decoders, a file reader,
//! and an EVT 3.0 encoder (for event packets written to ROS bags).
//!
//! The decoders are pure state machines over little-endian bytes. They accept any chunking of
//! the stream (a partial word is kept between calls), so they work the same on a file read in
//! blocks and on a USB packet stream.
//!
//! Conventions shared by both decoders, matching OpenEB's reference decoders:
//! - Every word before the first TIME_HIGH is skipped (counted in
//!   [`DecodeStats::skipped_before_time_high`]): without a time base those events have no time.
//! - The time base wraps (2^34 µs for EVT 2.0, 2^24 µs for EVT 3.0). A wrap is counted only when
//!   TIME_HIGH falls by almost a full period; smaller backward steps are passed through
//!   unchanged, so the output time is not guaranteed to be monotonic.
//! - A change-detection event outside the sensor geometry is a [`Error::Decode`]: corrupt data
//!   is reported, not silently clipped. The decoder is then poisoned: events decoded before the
//!   bad word stay in the output batch and every later call returns the same error.
//! - Reserved, trigger, IMU and continuation words are counted in [`DecodeStats`] and ignored.

mod evt2;
mod evt3;
mod evt3_encode;
mod header;
mod raw;
mod slices;
mod target;

pub use evt2::{Evt2Decoder, Evt2Words};
pub use evt3::{Evt3Decoder, Evt3Words};
pub use evt3_encode::{encode_evt3, Evt3Encoder, MAX_WRAPS_PER_GAP};
pub use header::{Format, RawHeader};
pub use raw::{RawReader, BLOCK_BYTES};
pub use slices::{grid_end, SliceRule, SliceRun, MAX_SLICES_PER_RUN};
pub use target::{ColumnSlots, DecodeTarget, RecordSlots, Slots};

use crate::error::{Error, Result};

/// Widest and tallest sensor the formats can address: both carry 11-bit coordinates.
pub const MAX_SENSOR_SIDE_PX: u32 = 2048;

/// What a decoder saw besides the events it produced.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct DecodeStats {
    /// Words seen, indexed by their 4-bit type code (the top nibble of the word).
    pub words_by_type: [u64; 16],
    /// Words dropped because no TIME_HIGH had been seen yet.
    pub skipped_before_time_high: u64,
    /// Time-base wraps detected so far.
    pub time_loops: u64,
}

impl DecodeStats {
    /// All words seen, of any type.
    pub fn words(&self) -> u64 {
        self.words_by_type.iter().sum()
    }
}

/// The format-specific half of a streaming decoder: decodes runs of whole words, keeping whatever
/// state the encoding carries from word to word.
pub trait WordDecoder: Default {
    /// Reject events outside `width`×`height` pixels (already checked against the format's range).
    fn set_geometry(&mut self, width: u32, height: u32);
    fn stats(&self) -> &DecodeStats;
    /// An upper bound of the time (µs) of every event decoded so far; None before the first.
    fn t_bound(&self) -> Option<i64>;
    /// Decode whole words (the length is a multiple of the word size), appending to `out`.
    fn decode_words<O: DecodeTarget>(&mut self, bytes: &[u8], out: &mut O) -> Result<()>;
}

/// A streaming decoder: a format's [`WordDecoder`] plus what every format shares, the partial
/// `N`-byte word carried between calls and the error that poisons the stream once it fails.
#[derive(Debug, Clone)]
pub struct Stream<D, const N: usize> {
    words: D,
    carry: Carry<N>,
    failed: Option<Error>,
}

impl<D: WordDecoder, const N: usize> Default for Stream<D, N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<D: WordDecoder, const N: usize> Stream<D, N> {
    /// A decoder accepting the full 11-bit address range (2048×2048 px).
    pub fn new() -> Self {
        Self {
            words: D::default(),
            carry: Carry::new(),
            failed: None,
        }
    }

    /// A decoder that rejects events outside `width`×`height` px.
    pub fn with_geometry(width: u32, height: u32) -> Result<Self> {
        let (width, height) = check_geometry(width, height)?;
        let mut s = Self::new();
        s.words.set_geometry(width, height);
        Ok(s)
    }

    pub fn stats(&self) -> &DecodeStats {
        self.words.stats()
    }

    /// Bytes of an incomplete word held back for the next call.
    pub fn pending_bytes(&self) -> usize {
        self.carry.len
    }

    /// An upper bound of the time (µs) of every event output so far (None before the time base
    /// is known): no event at or after a later time has been output.
    pub fn t_bound(&self) -> Option<i64> {
        self.words.t_bound()
    }

    /// Decodes the next chunk of the stream, appending its events to `out` (columns or records).
    pub fn decode<O: DecodeTarget>(&mut self, bytes: &[u8], out: &mut O) -> Result<()> {
        if let Some(e) = &self.failed {
            return Err(e.clone());
        }
        let (first, whole) = self.carry.split(bytes);
        let mut res = Ok(());
        if let Some(w) = first {
            res = self.words.decode_words(&w, out);
        }
        if res.is_ok() {
            res = self.words.decode_words(whole, out);
        }
        if let Err(e) = &res {
            self.failed = Some(e.clone());
        }
        res
    }
}

/// A streaming decoder of one of the supported encodings.
#[derive(Debug, Clone)]
pub enum Decoder {
    Evt2(Evt2Decoder),
    Evt3(Evt3Decoder),
}

impl Decoder {
    /// A decoder for `format` that rejects events outside `width`×`height` pixels.
    pub fn for_sensor(format: Format, width: u32, height: u32) -> Result<Self> {
        Ok(match format {
            Format::Evt2 => Self::Evt2(Evt2Decoder::with_geometry(width, height)?),
            Format::Evt3 => Self::Evt3(Evt3Decoder::with_geometry(width, height)?),
        })
    }

    pub fn decode<O: DecodeTarget>(&mut self, bytes: &[u8], out: &mut O) -> Result<()> {
        match self {
            Self::Evt2(d) => d.decode(bytes, out),
            Self::Evt3(d) => d.decode(bytes, out),
        }
    }

    /// Bytes of an incomplete word held back for the next call.
    pub fn pending_bytes(&self) -> usize {
        match self {
            Self::Evt2(d) => d.pending_bytes(),
            Self::Evt3(d) => d.pending_bytes(),
        }
    }

    pub fn stats(&self) -> &DecodeStats {
        match self {
            Self::Evt2(d) => d.stats(),
            Self::Evt3(d) => d.stats(),
        }
    }

    /// See [`Stream::t_bound`].
    pub fn t_bound(&self) -> Option<i64> {
        match self {
            Self::Evt2(d) => d.t_bound(),
            Self::Evt3(d) => d.t_bound(),
        }
    }
}

fn check_geometry(width: u32, height: u32) -> Result<(u32, u32)> {
    if width == 0 || height == 0 || width > MAX_SENSOR_SIDE_PX || height > MAX_SENSOR_SIDE_PX {
        return Err(Error::Decode(format!(
            "sensor geometry {width}x{height} px is outside 1..={MAX_SENSOR_SIDE_PX} px per side"
        )));
    }
    Ok((width, height))
}

/// The tail of a stream chunk that did not fill a whole `N`-byte word.
#[derive(Debug, Clone)]
struct Carry<const N: usize> {
    bytes: [u8; N],
    len: usize,
}

impl<const N: usize> Carry<N> {
    fn new() -> Self {
        Self {
            bytes: [0; N],
            len: 0,
        }
    }

    /// Splits a new chunk into: the word completed by its head (if a partial word was held),
    /// the run of whole words that follows, and the remainder which is held for the next call.
    fn split<'a>(&mut self, mut bytes: &'a [u8]) -> (Option<[u8; N]>, &'a [u8]) {
        let mut first = None;
        if self.len > 0 {
            let take = (N - self.len).min(bytes.len());
            self.bytes[self.len..self.len + take].copy_from_slice(&bytes[..take]);
            self.len += take;
            bytes = &bytes[take..];
            if self.len < N {
                return (None, &[]);
            }
            self.len = 0;
            first = Some(self.bytes);
        }
        let whole = bytes.len() / N * N;
        let tail = &bytes[whole..];
        self.bytes[..tail.len()].copy_from_slice(tail);
        self.len = tail.len();
        (first, &bytes[..whole])
    }
}

/// The time-base wrap rule of the reference decoders: a new TIME_HIGH base that falls below the
/// current one by at least `period - guard` is the counter wrapping, not a step back.
fn unwrap_time_base(
    current_us: i64,
    raw_base_us: i64,
    loops: &mut u64,
    period_us: i64,
    guard_us: i64,
) -> i64 {
    let offset = (*loops as i64).saturating_mul(period_us);
    let mut base = raw_base_us.saturating_add(offset);
    if current_us > base && current_us - base >= period_us - guard_us {
        base = base.saturating_add(period_us);
        *loops += 1;
    }
    base
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn carry_holds_partial_words_across_chunks() {
        let mut c = Carry::<4>::new();
        let (first, whole) = c.split(&[1, 2, 3, 4, 5, 6]);
        assert_eq!((first, whole), (None, &[1u8, 2, 3, 4][..]));
        let (first, whole) = c.split(&[7]);
        assert_eq!((first, whole.len()), (None, 0));
        let (first, whole) = c.split(&[8, 9, 10, 11, 12, 13]);
        assert_eq!(first, Some([5, 6, 7, 8]));
        assert_eq!(whole, &[9, 10, 11, 12]);
        assert_eq!(c.len, 1);
    }

    #[test]
    fn wrap_only_on_near_full_period_drop() {
        let mut loops = 0;
        // A 4096 µs step back is jitter, not a wrap.
        assert_eq!(
            unwrap_time_base(100_000, 95_904, &mut loops, 1 << 24, 10 << 12),
            95_904
        );
        assert_eq!(loops, 0);
        // From near the top of the 24-bit range back to 0: one wrap.
        let near_top = (1 << 24) - 4096;
        assert_eq!(
            unwrap_time_base(near_top, 0, &mut loops, 1 << 24, 10 << 12),
            1 << 24
        );
        assert_eq!(loops, 1);
        // Later bases carry the loop offset.
        assert_eq!(
            unwrap_time_base(1 << 24, 4096, &mut loops, 1 << 24, 10 << 12),
            (1 << 24) + 4096
        );
    }
}
