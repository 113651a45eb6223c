//! Reading a RAW file (header + EVT 2.0/3.0 words) in slices of n events or of time.

use super::slices::{SliceRule, SliceRun, MAX_SLICES_PER_RUN};
use super::{DecodeStats, Decoder, Format, RawHeader};
use crate::error::{Error, Result};
use crate::event::EventSink;
use crate::EventCd;
use std::fs::File;
use std::io::{BufReader, Read};
use std::path::Path;

/// Bytes read at a time by default, and so the input behind one run of slices: big enough that
/// the reads and the partial slice carried from run to run cost little, small enough that a
/// decoded run (≈ 4–6 MB) stays far below the memory a recording takes whole.
pub const BLOCK_BYTES: usize = 1 << 20;

/// Bytes decoded at a time: the events they give (≈ 0.4 MB) are still in cache when the cut
/// search reads their times.
const DECODE_BYTES: usize = 64 * 1024;

/// A RAW event file reader over any byte source.
///
/// Timestamps are the decoder's plus the header's `% t0` offset ([`RawHeader::t0_us`], 0 when
/// absent), so files written with times relative to their start read back in absolute time.
///
/// Events come out in stream order. Errors are sticky: after a decode error or a stream that
/// ends inside a word, every later read returns that error.
#[derive(Debug)]
pub struct RawReader<R: Read = File> {
    input: BufReader<R>,
    header: RawHeader,
    decoder: Decoder,
    /// Input bytes read at a time, the room they are read into (reused), and the part of it
    /// read but not decoded yet.
    block_bytes: usize,
    bytes: Vec<u8>,
    undecoded: std::ops::Range<usize>,
    /// The input has reported its end (what it gave may still wait in `undecoded`).
    input_done: bool,
    /// Decoded events not yet handed out start at `pos`.
    buf: Vec<EventCd>,
    pos: usize,
    eof: bool,
    failed: Option<Error>,
}

impl RawReader<File> {
    /// Opens a RAW file and parses its header.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let file = File::open(path)
            .map_err(|e| Error::Decode(format!("cannot open {}: {e}", path.display())))?;
        Self::new(file)
    }
}

impl<R: Read> RawReader<R> {
    /// Parses the header from the start of `input`.
    pub fn new(input: R) -> Result<Self> {
        // The buffer serves the header's lines; the data is read past it in whole blocks.
        let mut input = BufReader::new(input);
        let header = RawHeader::read_from(&mut input)?;
        let decoder = Decoder::for_sensor(header.format, header.width, header.height)?;
        Ok(Self {
            input,
            header,
            decoder,
            block_bytes: BLOCK_BYTES,
            bytes: Vec::new(),
            undecoded: 0..0,
            input_done: false,
            buf: Vec::new(),
            pos: 0,
            eof: false,
            failed: None,
        })
    }

    pub fn header(&self) -> &RawHeader {
        &self.header
    }

    /// Sensor width in pixels.
    pub fn width(&self) -> u32 {
        self.header.width
    }

    /// Sensor height in pixels.
    pub fn height(&self) -> u32 {
        self.header.height
    }

    pub fn format(&self) -> Format {
        self.header.format
    }

    /// Reads `bytes` (≥ 1) of input at a time from now on instead of [`BLOCK_BYTES`].
    pub fn set_block_bytes(&mut self, bytes: usize) {
        self.block_bytes = bytes.max(1);
    }

    /// Counters of the words decoded so far.
    pub fn stats(&self) -> &DecodeStats {
        self.decoder.stats()
    }

    /// Appends the next `n` events to `out` (fewer at the end of the stream). Returns false,
    /// appending nothing, once the stream is exhausted.
    pub fn read_n_events(&mut self, n: usize, out: &mut impl EventSink) -> Result<bool> {
        let end = self.end_after_n(n)?;
        Ok(self.hand_out(end, out))
    }

    /// Appends the events before the first one at or after `t_us` to `out`, so consecutive calls
    /// with growing `t_us` slice the stream by time. Events that step back in time after that
    /// cut belong to the next slice: stream order is never changed. Returns false, appending
    /// nothing, once the stream is exhausted; an empty slice inside the stream returns true.
    pub fn read_until_t(&mut self, t_us: i64, out: &mut impl EventSink) -> Result<bool> {
        let end = self.end_before_t(t_us)?;
        Ok(self.hand_out(end, out))
    }

    /// The slice of [`RawReader::read_n_events`] as a vector of its own; None once the stream is
    /// exhausted. Where the slice is all the reader holds, its buffer is handed over uncopied.
    pub fn next_n_events(&mut self, n: usize) -> Result<Option<Vec<EventCd>>> {
        let end = self.end_after_n(n)?;
        Ok(self.take(end))
    }

    /// The slice of [`RawReader::read_until_t`] as a vector of its own; None once the stream is
    /// exhausted. Where the slice is all the reader holds, its buffer is handed over uncopied.
    pub fn next_until_t(&mut self, t_us: i64) -> Result<Option<Vec<EventCd>>> {
        let end = self.end_before_t(t_us)?;
        Ok(self.take(end))
    }

    /// The next run of slices under `rule` (see [`SliceRule`]): every slice completed by the next
    /// block of input (more blocks while none completes), back to back in one vector, and at the
    /// end of the stream the last slice; None once the stream is exhausted. Only the partial slice
    /// at the run's end is copied (into the buffer the next block is decoded after).
    pub fn next_slices(&mut self, rule: &mut SliceRule) -> Result<Option<SliceRun>> {
        self.check()?;
        let (mut scanned, mut ends) = (0, Vec::new());
        loop {
            // Indices are relative to `pos`, which `fill` may move with the events after it.
            // Times were offset by t0 after decoding, saturating: the bound moves with them.
            let bound = self
                .decoder
                .t_bound()
                .map(|b| b.saturating_add(self.header.t0_us));
            rule.find_ends(&self.buf[self.pos..], bound, &mut scanned, &mut ends);
            let held = self.buf.len() - self.pos;
            if self.eof {
                if held > ends.last().copied().unwrap_or(0) {
                    ends.push(held);
                }
                break;
            }
            if ends.len() >= MAX_SLICES_PER_RUN || (!ends.is_empty() && self.undecoded.is_empty()) {
                break;
            }
            self.fill()?;
        }
        let Some(&last) = ends.last() else {
            return Ok(None);
        };
        let events = self.take(self.pos + last).unwrap_or_default();
        Ok(Some(SliceRun { events, ends }))
    }

    /// Buffer index just past the next `n` events, decoding as needed.
    fn end_after_n(&mut self, n: usize) -> Result<usize> {
        self.check()?;
        while self.buf.len() - self.pos < n && self.fill()? {}
        Ok(self.pos + n.min(self.buf.len() - self.pos))
    }

    /// Buffer index of the first event at or after `t_us` (the buffer's end if none, once the
    /// stream is exhausted), decoding as needed.
    fn end_before_t(&mut self, t_us: i64) -> Result<usize> {
        self.check()?;
        let mut scanned = 0;
        loop {
            let from = self.pos + scanned;
            if let Some(k) = self.buf[from..].iter().position(|e| e.t >= t_us) {
                return Ok(from + k);
            }
            scanned = self.buf.len() - self.pos;
            if !self.fill()? {
                return Ok(self.buf.len());
            }
        }
    }

    /// Appends every remaining event to `out`; returns how many.
    pub fn read_all(&mut self, out: &mut impl EventSink) -> Result<usize> {
        let rest = self.read_rest()?;
        out.extend_from_records(&rest);
        Ok(rest.len())
    }

    /// Every remaining event as one vector of records: the rest of the input is read in one go
    /// and decoded straight into the vector that is returned (no intermediate buffers). On an
    /// error nothing is returned and the reader stays failed.
    pub fn read_rest(&mut self) -> Result<Vec<EventCd>> {
        self.check()?;
        let res = self.decode_rest();
        if let Err(e) = &res {
            self.failed = Some(e.clone());
        }
        res
    }

    fn decode_rest(&mut self) -> Result<Vec<EventCd>> {
        let mut bytes = self.bytes[self.undecoded.clone()].to_vec();
        self.undecoded = 0..0;
        if !self.input_done {
            self.input
                .read_to_end(&mut bytes)
                .map_err(|e| Error::Decode(format!("reading RAW data: {e}")))?;
            self.input_done = true;
        }
        self.eof = true;
        let buffered = self.buf.len() - self.pos;
        let mut out = Vec::with_capacity(buffered + self.header.format.events_hint(bytes.len()));
        out.extend_from_slice(&self.buf[self.pos..]);
        self.buf.clear();
        self.pos = 0;
        self.decoder.decode(&bytes, &mut out)?;
        self.check_no_stray_bytes()?;
        offset_times(&mut out[buffered..], self.header.t0_us);
        Ok(out)
    }

    /// Time of the next event without consuming it; None once the stream is exhausted.
    pub fn peek_t(&mut self) -> Result<Option<i64>> {
        self.check()?;
        while self.pos == self.buf.len() {
            if !self.fill()? {
                return Ok(None);
            }
        }
        Ok(Some(self.buf[self.pos].t))
    }

    fn check(&self) -> Result<()> {
        match &self.failed {
            Some(e) => Err(e.clone()),
            None => Ok(()),
        }
    }

    /// Moves buffered events `pos..end` to `out`; false when nothing moved and nothing is left.
    fn hand_out(&mut self, end: usize, out: &mut impl EventSink) -> bool {
        let (a, b) = (self.pos, end);
        out.extend_from_records(&self.buf[a..b]);
        self.pos = end;
        end > a || !(self.eof && self.pos == self.buf.len())
    }

    /// Buffered events `pos..end` as a vector; None when nothing is left. Copies the smaller of
    /// the slice and what stays buffered: a slice reaching the buffer's end is the buffer itself,
    /// and a slice starting at its head keeps the buffer when the rest is the smaller part (moved
    /// to a buffer with room for the next block, so that decoding it does not move the rest again).
    fn take(&mut self, end: usize) -> Option<Vec<EventCd>> {
        let (a, len) = (self.pos, self.buf.len());
        if end == a && self.eof && a == len {
            return None;
        }
        if a == 0 && end == len {
            return Some(std::mem::take(&mut self.buf));
        }
        if a == 0 && len - end < end {
            let room = if self.eof { 0 } else { self.block_hint() };
            let mut rest = Vec::with_capacity(len - end + room);
            rest.extend_from_slice(&self.buf[end..]);
            self.buf.truncate(end);
            return Some(std::mem::replace(&mut self.buf, rest));
        }
        self.pos = end;
        Some(self.buf[a..end].to_vec())
    }

    /// Decodes the next piece of input into the buffer; false at the end of the stream.
    fn fill(&mut self) -> Result<bool> {
        if self.eof {
            return Ok(false);
        }
        if self.pos > 0 {
            self.buf.drain(..self.pos);
            self.pos = 0;
        }
        let res = self.decode_step();
        if let Err(e) = &res {
            self.failed = Some(e.clone());
        }
        res
    }

    /// Decodes up to [`DECODE_BYTES`] of the block read last, reading the next block first when
    /// it is all decoded; marks the end of the stream once the input's end is decoded.
    fn decode_step(&mut self) -> Result<bool> {
        if self.undecoded.is_empty() && !self.input_done {
            let n = self.read_block()?;
            self.undecoded = 0..n;
            self.input_done = n < self.block_bytes;
        }
        // Room for the rest of the block at once, rather than growing by doubling as it decodes
        // (nothing to do but for a block's first step or after the buffer was handed out whole).
        self.buf
            .reserve(self.header.format.events_hint(self.undecoded.len()));
        let step =
            self.undecoded.start..self.undecoded.end.min(self.undecoded.start + DECODE_BYTES);
        self.undecoded.start = step.end;
        let first_new = self.buf.len();
        let res = self
            .decoder
            .decode(&self.bytes[step.clone()], &mut self.buf);
        // Events decoded before an error are kept, so they get the offset too.
        offset_times(&mut self.buf[first_new..], self.header.t0_us);
        res?;
        if self.input_done && self.undecoded.is_empty() {
            self.eof = true;
            self.check_no_stray_bytes()?;
        }
        Ok(!step.is_empty())
    }

    /// Reads up to a block of input into `bytes`; returns how many bytes (fewer than a block
    /// only at the end of the input).
    fn read_block(&mut self) -> Result<usize> {
        self.bytes.clear();
        // Read into reserved, uninitialised room: no pass zeroing it first.
        self.bytes.reserve(self.block_bytes);
        (&mut self.input)
            .take(self.block_bytes as u64)
            .read_to_end(&mut self.bytes)
            .map_err(|e| Error::Decode(format!("reading RAW data: {e}")))
    }

    /// Events a full block of input decodes to, as reserved ahead.
    fn block_hint(&self) -> usize {
        self.header.format.events_hint(self.block_bytes)
    }

    /// The error for a stream that ended inside a word.
    fn check_no_stray_bytes(&self) -> Result<()> {
        match self.decoder.pending_bytes() {
            0 => Ok(()),
            stray => Err(Error::Decode(format!(
                "{} stream ends inside a word ({stray} stray bytes): the file is truncated",
                self.header.format
            ))),
        }
    }
}

/// Adds the header's `% t0` (µs) to decoded times.
fn offset_times(events: &mut [EventCd], t0_us: i64) {
    if t0_us != 0 {
        for e in events {
            e.t = e.t.saturating_add(t0_us);
        }
    }
}
