//! Reading a RAW file (header + EVT 2.0/3.0 words) in slices of n events or of time.

use super::{DecodeStats, Decoder, Format, RawHeader};
use crate::error::{Error, Result};
use crate::event::EventSink;
use crate::EventCd;
use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

/// Bytes read and decoded at a time: big enough that per-call overhead vanishes, small enough
/// that decoded events stay in cache-sized batches.
const BLOCK_BYTES: usize = 256 * 1024;

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
        let mut input = BufReader::with_capacity(BLOCK_BYTES, input);
        let header = RawHeader::read_from(&mut input)?;
        let decoder = Decoder::for_sensor(header.format, header.width, header.height)?;
        Ok(Self {
            input,
            header,
            decoder,
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

    /// Counters of the words decoded so far.
    pub fn stats(&self) -> &DecodeStats {
        self.decoder.stats()
    }

    /// Appends the next `n` events to `out` (fewer at the end of the stream). Returns false,
    /// appending nothing, once the stream is exhausted.
    pub fn read_n_events(&mut self, n: usize, out: &mut impl EventSink) -> Result<bool> {
        self.check()?;
        while self.buf.len() - self.pos < n && self.fill()? {}
        let end = self.pos + n.min(self.buf.len() - self.pos);
        Ok(self.hand_out(end, out))
    }

    /// Appends the events before the first one at or after `t_us` to `out`, so consecutive calls
    /// with growing `t_us` slice the stream by time. Events that step back in time after that
    /// cut belong to the next slice: stream order is never changed. Returns false, appending
    /// nothing, once the stream is exhausted; an empty slice inside the stream returns true.
    pub fn read_until_t(&mut self, t_us: i64, out: &mut impl EventSink) -> Result<bool> {
        self.check()?;
        let mut scanned = 0;
        let end = loop {
            let from = self.pos + scanned;
            if let Some(k) = self.buf[from..].iter().position(|e| e.t >= t_us) {
                break from + k;
            }
            scanned = self.buf.len() - self.pos;
            if !self.fill()? {
                break self.buf.len();
            }
        };
        Ok(self.hand_out(end, out))
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
        let mut bytes = Vec::new();
        if !self.eof {
            self.input
                .read_to_end(&mut bytes)
                .map_err(|e| Error::Decode(format!("reading RAW data: {e}")))?;
            self.eof = true;
        }
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

    /// Decodes the next block of input into the buffer; false at the end of the stream.
    fn fill(&mut self) -> Result<bool> {
        if self.eof {
            return Ok(false);
        }
        if self.pos > 0 {
            self.buf.drain(..self.pos);
            self.pos = 0;
        }
        let res = self.fill_block();
        if let Err(e) = &res {
            self.failed = Some(e.clone());
        }
        res
    }

    fn fill_block(&mut self) -> Result<bool> {
        let chunk = self
            .input
            .fill_buf()
            .map_err(|e| Error::Decode(format!("reading RAW data: {e}")))?;
        if chunk.is_empty() {
            self.eof = true;
            self.check_no_stray_bytes()?;
            return Ok(false);
        }
        let n = chunk.len();
        let first_new = self.buf.len();
        let res = self.decoder.decode(chunk, &mut self.buf);
        // Events decoded before an error are kept, so they get the offset too.
        offset_times(&mut self.buf[first_new..], self.header.t0_us);
        res?;
        self.input.consume(n);
        Ok(true)
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
