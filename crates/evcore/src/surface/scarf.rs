//! SCARF, the Set of Centre Active Receptive Fields (Glover et al.; `robotology/event-driven`).
//!
//! The grid is tiled into square blocks, shifted by half a block so that the outer half-block ring
//! has no block of its own. Each block keeps a FIFO of the last N events that fell in the 2×2-block
//! window centred on it. An entry from the block itself is a *centre* entry and marks its pixel
//! active; entries from the surrounding half-blocks only occupy slots, so motion next to a block
//! flushes its stale centre events. Nothing depends on time: a region keeps its last N events
//! however old they are, which is what makes the active set independent of the object's speed.
//!
//! Storage differs from the C++ in three ways, none visible in the active set:
//! - a pixel is active exactly while its newest centre entry is among the newest N entries of its
//!   block's FIFO, so the FIFO itself is never stored. Each block keeps its *sequence*, the number
//!   of entries it has received, and each pixel the sequence its block had at the pixel's newest
//!   centre entry: the pixel is active iff the block's sequence minus the pixel's is below N. An
//!   event thus costs four counter increments (a few KiB of counters, in L1) and one store into
//!   the pixel image, and nothing is evicted. The C++'s float image updated by ±C, and this
//!   crate's earlier per-block rings with per-pixel counts, read back every evicted entry and
//!   updated its pixel: four dependent loads per event, the cache misses that bounded ingest.
//! - sequences are u16 and a difference is taken modulo 2^16. A pixel left inactive for 2^16 of
//!   its block's entries would alias back into the window, so whenever a block's sequence passes
//!   a multiple of [`SWEEP_PERIOD`] its inactive pixels are set exactly N behind; between two such
//!   sweeps no difference can grow past N + SWEEP_PERIOD < 2^16, so every difference is exact
//!   where it matters (below N or not);
//! - a missing neighbour block is a pad block that counts entries like any other but has no
//!   pixels, so every event does exactly four increments and the loop has no "is there a block"
//!   branch.
//!
//! Concurrency: one [`ScarfWriter`] updates the sequences; any number of [`ScarfReader`] handles
//! read them (relaxed atomics, which compile to plain moves on x86-64 and AArch64, so the writer
//! pays nothing for being observable).

use std::sync::atomic::{AtomicU16, AtomicU64, Ordering::Relaxed};
use std::sync::Arc;

use super::{check_grid, fill_roi, EventSurface};
use crate::error::{ensure, Result};
use crate::image::Roi;
use crate::prefetch::prefetch;

/// Block layout derived from the grid size, the requested block size and alpha (C++ `getScarfParams`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScarfGeometry {
    /// Number of blocks across and down.
    pub grid_w: u32,
    pub grid_h: u32,
    /// Block width and height in pixels (even); the first block starts at (block_w/2, block_h/2).
    pub block_w: u32,
    pub block_h: u32,
    /// FIFO length N per block, in events.
    pub fifo_len: u32,
}

impl ScarfGeometry {
    /// Odd `block_px` is raised by one; the grid drops one block's worth of border; block dims are
    /// rounded down to even; N = ⌊block_w·block_h·alpha/2⌋. `alpha` must lie in (0, 8] (8 makes
    /// the FIFO as long as the whole 2×2-block window); N ≤ 255 and a block area below 65535.
    /// The sequences below need only N + 2^15 < 2^16; the tighter bounds are those of the earlier
    /// u8 counts and u16 ring entries, kept so that the accepted parameters do not change.
    pub fn new(width: u32, height: u32, block_px: u32, alpha: f32) -> Result<Self> {
        check_grid(width, height)?;
        ensure(alpha.is_finite() && alpha > 0.0 && alpha <= 8.0, || {
            format!("SCARF alpha {alpha} must be in (0, 8]")
        })?;
        ensure(block_px >= 2, || {
            format!("SCARF block size {block_px} px must be at least 2")
        })?;
        let b = block_px + block_px % 2;
        let (grid_w, grid_h) = (
            (width / b).saturating_sub(1),
            (height / b).saturating_sub(1),
        );
        ensure(grid_w >= 1 && grid_h >= 1, || {
            format!("SCARF block {b} px leaves no block inside a {width}x{height} grid (need at least 2 blocks per side)")
        })?;
        let block_w = width / (grid_w + 1) / 2 * 2;
        let block_h = height / (grid_h + 1) / 2 * 2;
        let n = (f64::from(block_w) * f64::from(block_h) * f64::from(alpha) * 0.5).floor();
        ensure((1.0..=f64::from(u8::MAX)).contains(&n), || {
            format!("SCARF FIFO length {n} (block {block_w}x{block_h}, alpha {alpha}) must be in 1..=255")
        })?;
        ensure(block_w * block_h < u32::from(u16::MAX), || {
            format!("SCARF block {block_w}x{block_h} px is too large (area must be below 65535)")
        })?;
        Ok(Self {
            grid_w,
            grid_h,
            block_w,
            block_h,
            fifo_len: n as u32,
        })
    }

    pub fn n_blocks(&self) -> usize {
        self.grid_w as usize * self.grid_h as usize
    }

    /// The block whose centre area holds pixel (x, y), if any: (column, row).
    pub fn block_of(&self, x: u32, y: u32) -> Option<(u32, u32)> {
        self.connections(x, y)[0]
    }

    /// The four blocks pixel (x, y) feeds: its own, the vertical, horizontal and diagonal neighbours
    /// on the side of its quadrant, in that order; `None` where that block is outside the grid.
    pub fn connections(&self, x: u32, y: u32) -> [Option<(u32, u32)>; 4] {
        let (bx, sx) = axis(x, self.block_w);
        let (by, sy) = axis(y, self.block_h);
        let at = |cx: i64, cy: i64| {
            let inside = (0..i64::from(self.grid_w)).contains(&cx)
                && (0..i64::from(self.grid_h)).contains(&cy);
            inside.then_some((cx as u32, cy as u32))
        };
        [at(bx, by), at(bx, sy), at(sx, by), at(sx, sy)]
    }
}

/// Along one axis: the block index owning coordinate `c` after the half-block shift (floor
/// division, so −1 left of the first block), and the neighbour on the side of its half.
fn axis(c: u32, block: u32) -> (i64, i64) {
    let b = i64::from(block);
    let m = i64::from(c) - b / 2;
    let own = m.div_euclid(b);
    let side = if m.rem_euclid(b) < b / 2 {
        own - 1
    } else {
        own + 1
    };
    (own, side)
}

/// Row of a pixel index by multiply and shift instead of a division (a 32-bit `div` alone costs
/// more than the rest of the table lookup). With m = ⌈2^42/w⌉ the product's error stays below
/// p/2^42 < w·2^14/2^42 ≤ 1/w for w < 2^14 (and is zero for w = 2^14), too small to cross an
/// integer, and p·m < 2^57 cannot overflow; valid for every index of a grid that passed `check_grid`.
#[derive(Debug, Clone, Copy)]
struct RowOf {
    width: u32,
    m: u64,
}

impl RowOf {
    fn new(width: u32) -> Self {
        Self {
            width,
            m: (1u64 << 42).div_ceil(u64::from(width)),
        }
    }

    /// (x, y) of pixel index `p`.
    #[inline(always)]
    fn split(self, p: u32) -> (u32, u32) {
        let y = ((u64::from(p) * self.m) >> 42) as u32;
        (p - y * self.width, y)
    }
}

/// Per row or column: the padded-grid offsets of the own and the side block along that axis
/// (rows pre-multiplied by the padded grid width), and whether the own block is a real one.
#[derive(Debug, Clone, Copy)]
struct AxisEntry {
    own: u32,
    side: u32,
    real: bool,
}

/// Axis table for coordinates 0..len; `pad` is the lowest block index any coordinate reaches (−1),
/// `scale` the stride of one step along this axis in the padded grid.
fn axis_table(len: u32, block: u32, grid: u32, pad: i64, scale: u32) -> Box<[AxisEntry]> {
    (0..len)
        .map(|c| {
            let (own, side) = axis(c, block);
            AxisEntry {
                own: (own - pad) as u32 * scale,
                side: (side - pad) as u32 * scale,
                real: (0..i64::from(grid)).contains(&own),
            }
        })
        .collect()
}

/// A block's sequence passing a multiple of this sets its inactive pixels exactly N behind (see
/// the module notes). With N ≤ 255, N + SWEEP_PERIOD < 2^16; a sweep touches one block's pixels
/// once per 32768 of its entries, too rarely to show in the cost per event.
const SWEEP_PERIOD: u16 = 1 << 15;

/// What the writer and the readers share. Blocks live on a padded grid with an extra ring of pad
/// blocks wherever a pixel's neighbour would fall outside the real grid; the block of a pixel is
/// `rows[y].own + cols[x].own` etc., so the lookup tables are per row and per column (a few KiB,
/// always in L1) instead of per pixel.
#[derive(Debug)]
struct Shared {
    width: u32,
    height: u32,
    /// FIFO length N.
    fifo_len: u16,
    row_of: RowOf,
    cols: Box<[AxisEntry]>,
    rows: Box<[AxisEntry]>,
    /// Per padded block: how many entries it has received, modulo 2^16.
    seqs: Box<[AtomicU16]>,
    /// Per pixel: its block's sequence at the pixel's newest centre entry; four pixels per word
    /// (pixel 4i + k in bits 16k..16k + 16) so that a reader copies a row a word at a time.
    /// The lanes of pixels outside every real block hold their pad block's sequence, never read.
    last: Box<[AtomicU64]>,
}

impl Shared {
    /// Pixel `p`'s stored sequence.
    fn last_of(&self, p: usize) -> u16 {
        (self.last[p / 4].load(Relaxed) >> (16 * (p % 4))) as u16
    }
}

/// Store `seq` as pixel `p`'s sequence in `last` (see [`Shared::last`]). Only the writer stores,
/// so a relaxed load and store of the word cannot lose another pixel's update.
#[inline(always)]
fn set_last(last: &[AtomicU64], p: usize, seq: u16) {
    let word = &last[p / 4];
    let shift = 16 * (p % 4);
    let old = word.load(Relaxed);
    word.store(old & !(0xffff << shift) | u64::from(seq) << shift, Relaxed);
}

impl Shared {
    /// Whether pixel `p` = (x, y) is active: its block's sequence is less than N past its own.
    fn is_active(&self, p: usize, x: u32, y: u32) -> bool {
        let (c, r) = (&self.cols[x as usize], &self.rows[y as usize]);
        let seq = self.seqs[(r.own + c.own) as usize].load(Relaxed);
        c.real && r.real && seq.wrapping_sub(self.last_of(p)) < self.fifo_len
    }
}

/// The single writer: ingests events. Not `Clone`, so there is exactly one per SCARF.
#[derive(Debug)]
pub struct ScarfWriter {
    shared: Arc<Shared>,
    geometry: ScarfGeometry,
    /// Blocks across the padded grid (the real grid plus one pad block on each side).
    padded_w: u32,
}

/// A cheap, cloneable read handle; safe to use from any thread while the writer runs.
///
/// Reads are not synchronised with the writer. A mask taken while a batch is being applied reads
/// a band of rows' block sequences before their pixels, so it mixes the two moments: a pixel whose
/// centre entry lands in between reads inactive, one whose block moved on in between reads as of
/// the earlier moment. When the batch completes every pixel is exact. A mask is thus at worst one
/// batch stale at a few pixels; the tracker treats it as a noisy sample anyway.
#[derive(Debug, Clone)]
pub struct ScarfReader {
    shared: Arc<Shared>,
}

/// A SCARF that owns its writer and one reader; [`Scarf::split`] hands them out separately.
#[derive(Debug)]
pub struct Scarf {
    writer: ScarfWriter,
    reader: ScarfReader,
}

impl Scarf {
    pub fn new(width: u32, height: u32, block_px: u32, alpha: f32) -> Result<Self> {
        let geometry = ScarfGeometry::new(width, height, block_px, alpha)?;
        let n_pixels = width as usize * height as usize;
        // Block indices reached along an axis run from −1 to the side block of the last pixel.
        let span = |len: u32, block: u32| axis(len - 1, block).1.max(axis(len - 1, block).0) + 2;
        let (padded_w, padded_h) = (
            span(width, geometry.block_w),
            span(height, geometry.block_h),
        );
        let n_padded = (padded_w * padded_h) as usize;
        let shared = Arc::new(Shared {
            width,
            height,
            fifo_len: geometry.fifo_len as u16,
            row_of: RowOf::new(width),
            cols: axis_table(width, geometry.block_w, geometry.grid_w, -1, 1),
            rows: axis_table(
                height,
                geometry.block_h,
                geometry.grid_h,
                -1,
                padded_w as u32,
            ),
            seqs: (0..n_padded).map(|_| AtomicU16::new(0)).collect(),
            last: (0..n_pixels.div_ceil(4))
                .map(|_| AtomicU64::new(0))
                .collect(),
        });
        let mut writer = ScarfWriter {
            shared: Arc::clone(&shared),
            geometry,
            padded_w: padded_w as u32,
        };
        writer.reset();
        Ok(Self {
            writer,
            reader: ScarfReader { shared },
        })
    }

    pub fn geometry(&self) -> ScarfGeometry {
        self.writer.geometry
    }

    /// Another read handle onto this SCARF.
    pub fn reader(&self) -> ScarfReader {
        self.reader.clone()
    }

    /// Separate the writer (for the ingest thread) from a reader (for the tracker thread).
    pub fn split(self) -> (ScarfWriter, ScarfReader) {
        (self.writer, self.reader)
    }

    pub fn writer(&mut self) -> &mut ScarfWriter {
        &mut self.writer
    }
}

/// How far ahead of the event being inserted its pixel's word is prefetched, in events.
const PREFETCH_EVENTS: usize = 16;

impl ScarfWriter {
    /// Ingest events at rectified pixel indices; indices ≥ width·height are skipped.
    pub fn ingest(&mut self, pixels: &[u32]) {
        let s = &*self.shared;
        // Slices and fields in locals: behind `s`, the compiler reloads them after every atomic
        // store, as it cannot tell the store does not change them.
        let (cols, rows, seqs, row_of) = (&*s.cols, &*s.rows, &*s.seqs, s.row_of);
        let last = &*s.last;
        let n_pixels = s.width * s.height;
        for (i, &p) in pixels.iter().enumerate() {
            // A noise event's pixel word is a cache miss; asking for it a few events ahead lets
            // the miss overlap the work in between.
            if let Some(&ahead) = pixels.get(i + PREFETCH_EVENTS) {
                prefetch(last.as_ptr().wrapping_add(ahead as usize / 4));
            }
            if p >= n_pixels {
                continue;
            }
            let (x, y) = row_of.split(p);
            // SAFETY: p < width·height, so x < width = cols.len() and y < height = rows.len().
            let (c, r) = unsafe {
                (
                    cols.get_unchecked(x as usize),
                    rows.get_unchecked(y as usize),
                )
            };
            let fed = [
                r.own + c.own,
                r.side + c.own,
                r.own + c.side,
                r.side + c.side,
            ];
            let mut own_seq = 0;
            for (k, b) in fed.into_iter().enumerate() {
                // SAFETY: the axis tables only hold indices inside the padded grid.
                let seq = unsafe { seqs.get_unchecked(b as usize) };
                let v = seq.load(Relaxed).wrapping_add(1);
                seq.store(v, Relaxed);
                if v % SWEEP_PERIOD == 0 {
                    self.sweep(b, v);
                }
                if k == 0 {
                    own_seq = v;
                }
            }
            // Stored for a pixel outside every real block too (its own block is a pad block):
            // readers never look at those lanes, and the loop saves the test.
            set_last(last, p as usize, own_seq);
        }
    }

    /// Set every inactive pixel of padded block `b` (none for a pad block) exactly N behind its
    /// sequence `seq`, so that its difference cannot wrap before the next sweep.
    #[cold]
    #[inline(never)]
    fn sweep(&self, b: u32, seq: u16) {
        let (s, g) = (&*self.shared, &self.geometry);
        let (bx, by) = (b % self.padded_w, b / self.padded_w);
        if !(1..=g.grid_w).contains(&bx) || !(1..=g.grid_h).contains(&by) {
            return;
        }
        let (x0, y0) = (
            g.block_w / 2 + (bx - 1) * g.block_w,
            g.block_h / 2 + (by - 1) * g.block_h,
        );
        for y in y0..y0 + g.block_h {
            for x in x0..x0 + g.block_w {
                let p = (y * s.width + x) as usize;
                if seq.wrapping_sub(s.last_of(p)) >= s.fifo_len {
                    set_last(&s.last, p, seq.wrapping_sub(s.fifo_len));
                }
            }
        }
    }

    /// Empty every FIFO: all sequences 0, every pixel N behind.
    pub fn reset(&mut self) {
        let s = &*self.shared;
        for seq in s.seqs.iter() {
            seq.store(0, Relaxed);
        }
        let behind = u64::from(0u16.wrapping_sub(s.fifo_len));
        let word = behind * 0x0001_0001_0001_0001;
        for w in s.last.iter() {
            w.store(word, Relaxed);
        }
    }

    pub fn geometry(&self) -> ScarfGeometry {
        self.geometry
    }

    pub fn reader(&self) -> ScarfReader {
        ScarfReader {
            shared: Arc::clone(&self.shared),
        }
    }
}

impl ScarfReader {
    pub fn width(&self) -> u32 {
        self.shared.width
    }

    pub fn height(&self) -> u32 {
        self.shared.height
    }

    /// Whether pixel (x, y) is active; false outside the grid.
    pub fn is_active(&self, x: u32, y: u32) -> bool {
        let s = &*self.shared;
        x < s.width && y < s.height && s.is_active((y * s.width + x) as usize, x, y)
    }

    /// Number of active pixels, by a scan of the whole grid (for tests and diagnostics).
    pub fn active_count(&self) -> usize {
        let full = Roi::full(self.shared.width, self.shared.height);
        let mut mask = vec![0u8; full.area()];
        self.fill_mask(full, &mut mask);
        mask.iter().map(|&v| usize::from(v)).sum()
    }

    /// See [`EventSurface::fill_mask`].
    pub fn fill_mask(&self, roi: Roi, out: &mut [u8]) {
        let s = &*self.shared;
        // Every row of a band of blocks compares against the same block sequences: `seq_row`
        // holds them per column of the roi for the band `band`, and `fifo_row` N per column (0
        // outside every real block, so that no difference is below it).
        let mut band = None;
        let (mut seq_row, mut lasts) = (Vec::new(), Vec::new());
        let fifo_row: Vec<u16> = s.cols[(roi.x0.min(s.width)) as usize..]
            .iter()
            .take(roi.width as usize)
            .map(|c| if c.real { s.fifo_len } else { 0 })
            .collect();
        fill_roi(s.width, s.height, roi, out, |start, dst| {
            let (x0, y) = s.row_of.split(start as u32);
            let r = &s.rows[y as usize];
            if !r.real {
                return;
            }
            if band != Some(r.own) {
                band = Some(r.own);
                seq_row.clear();
                seq_row.extend(
                    s.cols[x0 as usize..][..dst.len()]
                        .iter()
                        .map(|c| s.seqs[(r.own + c.own) as usize].load(Relaxed)),
                );
            }
            // The row's words copied out (the compiler never merges atomic loads, so comparing
            // straight from them would go lane by lane), then compared in bulk.
            let words = &s.last[start / 4..(start + dst.len()).div_ceil(4)];
            lasts.resize(4 * words.len(), 0);
            for (lanes, w) in lasts.chunks_exact_mut(4).zip(words) {
                let v = w.load(Relaxed);
                lanes.copy_from_slice(&[
                    v as u16,
                    (v >> 16) as u16,
                    (v >> 32) as u16,
                    (v >> 48) as u16,
                ]);
            }
            compare_row(&seq_row, &lasts[start % 4..], &fifo_row, dst);
        });
    }
}

/// One row of a mask: `dst[i]` is 1 iff the block sequence `seqs[i]` is less than `fifo[i]` past
/// the pixel's `lasts[i]` (all three at least as long as `dst`).
fn compare_row(seqs: &[u16], lasts: &[u16], fifo: &[u16], dst: &mut [u8]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2.
        return unsafe { compare_row_avx2(seqs, lasts, fifo, dst) };
    }
    compare_row_lanes(seqs, lasts, fifo, dst);
}

/// [`compare_row`] compiled for AVX2: sixteen pixels per vector instead of SSE2's eight.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn compare_row_avx2(seqs: &[u16], lasts: &[u16], fifo: &[u16], dst: &mut [u8]) {
    compare_row_lanes(seqs, lasts, fifo, dst);
}

#[inline(always)]
fn compare_row_lanes(seqs: &[u16], lasts: &[u16], fifo: &[u16], dst: &mut [u8]) {
    let n = dst.len();
    // Equal-length slices, so the loop below has no bounds checks and vectorises.
    let (seqs, lasts, fifo) = (&seqs[..n], &lasts[..n], &fifo[..n]);
    for i in 0..n {
        dst[i] = u8::from(seqs[i].wrapping_sub(lasts[i]) < fifo[i]);
    }
}

impl EventSurface for Scarf {
    fn ingest(&mut self, pixels: &[u32], polarity: &[i16]) {
        // Polarity is stored but never drawn in the reference, so only the pixel matters here.
        self.writer
            .ingest(&pixels[..pixels.len().min(polarity.len())]);
    }

    fn fill_mask(&self, roi: Roi, out: &mut [u8]) {
        self.reader.fill_mask(roi, out);
    }

    fn width(&self) -> u32 {
        self.reader.width()
    }

    fn height(&self) -> u32 {
        self.reader.height()
    }

    fn name(&self) -> &'static str {
        "scarf"
    }

    fn reset(&mut self) {
        self.writer.reset();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;
    use crate::surface::FixedCount;
    use std::collections::VecDeque;

    fn mask(s: &dyn EventSurface, roi: Roi) -> Vec<u8> {
        let mut m = vec![0u8; roi.area()];
        s.fill_mask(roi, &mut m);
        m
    }

    fn ones(m: &[u8]) -> usize {
        m.iter().filter(|&&v| v == 1).count()
    }

    fn iou(a: &[u8], b: &[u8]) -> f64 {
        let inter = a.iter().zip(b).filter(|(&x, &y)| x == 1 && y == 1).count();
        let union = a.iter().zip(b).filter(|(&x, &y)| x == 1 || y == 1).count();
        inter as f64 / union as f64
    }

    fn shuffle(v: &mut [u32], rng: &mut Rng) {
        for i in (1..v.len()).rev() {
            v.swap(i, rng.below(i as u64 + 1) as usize);
        }
    }

    /// `len` pixels of a `w`×`h` grid: each uniform over the whole grid (border pixels included)
    /// with probability 1/`one_in_uniform`, else uniform in `rect`, a cluster whose blocks' FIFOs
    /// turn over many times.
    fn mixed_stream(
        w: u32,
        h: u32,
        seed: u64,
        len: usize,
        one_in_uniform: u64,
        rect: Roi,
    ) -> Vec<u32> {
        let mut rng = Rng::new(seed);
        (0..len)
            .map(|_| {
                if rng.below(one_in_uniform) == 0 {
                    rng.below(u64::from(w * h)) as u32
                } else {
                    let y = rect.y0 + rng.below(u64::from(rect.height)) as u32;
                    y * w + rect.x0 + rng.below(u64::from(rect.width)) as u32
                }
            })
            .collect()
    }

    /// A random merge of two streams that keeps each stream's own order.
    fn interleave(a: &[u32], b: &[u32], rng: &mut Rng) -> Vec<u32> {
        let (mut i, mut j) = (0, 0);
        let mut out = Vec::with_capacity(a.len() + b.len());
        while i < a.len() || j < b.len() {
            let left = (a.len() - i) as u64;
            if rng.below(left + (b.len() - j) as u64) < left {
                out.push(a[i]);
                i += 1;
            } else {
                out.push(b[j]);
                j += 1;
            }
        }
        out
    }

    #[test]
    fn row_of_matches_division_at_every_row_boundary() {
        for w in [1u32, 2, 3, 7, 346, 640, 1280, 4095, 9999, 16383, 16384] {
            let d = RowOf::new(w);
            for y in (0..16384u32).step_by(7).chain([16382, 16383]) {
                for p in [y * w, y * w + w - 1, y * w + w / 2] {
                    assert_eq!(d.split(p), (p % w, p / w), "w {w} p {p}");
                }
            }
        }
    }

    #[test]
    fn geometry_matches_the_worked_numbers() {
        let g = |w, h, b| {
            let g = ScarfGeometry::new(w, h, b, 1.0).unwrap();
            (g.grid_w, g.grid_h, g.block_w, g.block_h, g.fifo_len)
        };
        assert_eq!(g(640, 480, 14), (44, 33, 14, 14, 98));
        assert_eq!(g(640, 480, 10), (63, 47, 10, 10, 50));
        assert_eq!(g(640, 480, 11), (52, 39, 12, 12, 72));
        assert_eq!(g(1280, 720, 14), (90, 50, 14, 14, 98));
        assert_eq!(g(346, 260, 14), (23, 17, 14, 14, 98));
        assert_eq!(ScarfGeometry::new(640, 480, 14, 0.5).unwrap().fifo_len, 49);
        assert!(ScarfGeometry::new(27, 480, 14, 1.0).is_err());
        assert!(ScarfGeometry::new(640, 480, 14, 0.0).is_err());
        assert!(
            ScarfGeometry::new(640, 480, 2, 0.1).is_err(),
            "N = 0 must be refused"
        );
        // N ≤ 255: block 22 at alpha 1 gives 242, block 24 gives 288.
        assert_eq!(ScarfGeometry::new(640, 480, 22, 1.0).unwrap().fifo_len, 242);
        assert!(ScarfGeometry::new(640, 480, 24, 1.0).is_err(), "N = 288");
        assert_eq!(
            Scarf::new(346, 260, 14, 1.0).unwrap().geometry(),
            ScarfGeometry::new(346, 260, 14, 1.0).unwrap()
        );
    }

    /// Straightforward port of the C++ update (a deque per block, skipped missing neighbours,
    /// explicit centre flags): the writer must agree with it on every pixel's activity, and on how
    /// many entries its block has taken since an active pixel's newest centre entry.
    struct Reference {
        geometry: ScarfGeometry,
        width: u32,
        fifos: Vec<VecDeque<Option<u32>>>,
        counts: Vec<u16>,
    }

    impl Reference {
        fn new(width: u32, height: u32, block_px: u32, alpha: f32) -> Self {
            let geometry = ScarfGeometry::new(width, height, block_px, alpha).unwrap();
            let n = geometry.fifo_len as usize;
            let fifos = vec![VecDeque::from(vec![None; n]); geometry.n_blocks()];
            Self {
                geometry,
                width,
                fifos,
                counts: vec![0; (width * height) as usize],
            }
        }

        fn update(&mut self, p: u32) {
            let conns = self.geometry.connections(p % self.width, p / self.width);
            for (k, conn) in conns.into_iter().enumerate() {
                let Some((bx, by)) = conn else { continue };
                let fifo = &mut self.fifos[(by * self.geometry.grid_w + bx) as usize];
                if let Some(Some(old)) = fifo.pop_front() {
                    self.counts[old as usize] -= 1;
                }
                fifo.push_back((k == 0).then_some(p));
                if k == 0 {
                    self.counts[p as usize] += 1;
                }
            }
        }
    }

    impl Reference {
        /// Per pixel: how many entries its block took after the pixel's newest centre entry, if
        /// that entry is still in the FIFO (i.e. the pixel is active).
        fn ages(&self) -> Vec<Option<u16>> {
            let mut ages = vec![None; self.counts.len()];
            for fifo in &self.fifos {
                for (age, entry) in fifo.iter().rev().enumerate() {
                    if let Some(p) = *entry {
                        ages[p as usize].get_or_insert(age as u16);
                    }
                }
            }
            ages
        }
    }

    /// The writer's counterpart of [`Reference::ages`]: its block's sequence minus the pixel's,
    /// where that is below N.
    fn ages(s: &Scarf) -> Vec<Option<u16>> {
        let sh = &*s.reader.shared;
        (0..sh.width * sh.height)
            .map(|p| {
                let (x, y) = sh.row_of.split(p);
                let (c, r) = (&sh.cols[x as usize], &sh.rows[y as usize]);
                let seq = sh.seqs[(r.own + c.own) as usize].load(Relaxed);
                let age = seq.wrapping_sub(sh.last_of(p as usize));
                (c.real && r.real && age < sh.fifo_len).then_some(age)
            })
            .collect()
    }

    /// Every pixel's age, its activity (by `is_active` and by a full mask) and the active total
    /// of `s` equal the reference's.
    fn assert_same_state(s: &Scarf, r: &Reference) {
        assert_eq!(ages(s), r.ages());
        let reader = s.reader();
        let w = r.width;
        let want: Vec<u8> = r.counts.iter().map(|&c| u8::from(c > 0)).collect();
        let got: Vec<u8> = (0..r.counts.len() as u32)
            .map(|p| u8::from(reader.is_active(p % w, p / w)))
            .collect();
        assert_eq!(got, want);
        assert_eq!(mask(s, Roi::full(w, want.len() as u32 / w)), want);
        assert_eq!(
            reader.active_count(),
            want.iter().map(|&v| usize::from(v)).sum::<usize>()
        );
    }

    #[test]
    fn agrees_with_a_plain_port_of_the_reference() {
        let (w, h) = (120u32, 90u32);
        let cluster = Roi {
            x0: 30,
            y0: 40,
            width: 25,
            height: 20,
        };
        let pixels = mixed_stream(w, h, 3, 60_000, 2, cluster);
        let mut s = Scarf::new(w, h, 11, 0.7).unwrap();
        let mut r = Reference::new(w, h, 11, 0.7);
        s.writer().ingest(&pixels[..12_345]);
        s.writer().ingest(&pixels[12_345..]);
        pixels.iter().for_each(|&p| r.update(p));
        assert_same_state(&s, &r);
        assert!(
            s.reader().active_count() > 450,
            "the test must exercise a well-filled set"
        );
    }

    /// The largest FIFO at alpha 1 (block 22, N = 242), on a grid that is not a multiple of the
    /// block, with a few pixels firing over and over so single counts reach N.
    #[test]
    fn agrees_with_the_reference_up_to_the_largest_fifo() {
        let (w, h) = (203u32, 140u32);
        let mut rng = Rng::new(8);
        let pixels: Vec<u32> = (0..80_000)
            .map(|i| match i % 3 {
                0 => rng.below(u64::from(w * h)) as u32,
                1 => 60 * w + 70 + rng.below(2) as u32,
                _ => (20 + rng.below(90) as u32) * w + 150 + rng.below(40) as u32,
            })
            .collect();
        let mut s = Scarf::new(w, h, 22, 1.0).unwrap();
        assert_eq!(s.geometry().fifo_len, 242);
        let mut r = Reference::new(w, h, 22, 1.0);
        s.writer().ingest(&pixels[..40_000]);
        pixels[..40_000].iter().for_each(|&p| r.update(p));
        // A run of one pixel fills its block's FIFO: its count is N, its age 0.
        let hot = vec![60 * w + 70; 300];
        s.writer().ingest(&hot);
        hot.iter().for_each(|&p| r.update(p));
        assert_eq!(r.counts[(60 * w + 70) as usize], 242);
        assert_same_state(&s, &r);
        s.writer().ingest(&pixels[40_000..]);
        pixels[40_000..].iter().for_each(|&p| r.update(p));
        assert_same_state(&s, &r);
    }

    /// The default 14 px block with the longest FIFO allowed (N = 255), one pixel fired until
    /// its count is 255, then noise and clusters that evict it again; on a grid with border
    /// pixels outside every block (their events feed only pad blocks).
    #[test]
    fn agrees_with_the_reference_at_the_largest_fifo_of_the_default_block() {
        let (w, h) = (150u32, 110u32);
        let mut s = Scarf::new(w, h, 14, 2.603).unwrap();
        assert_eq!(s.geometry().fifo_len, 255);
        let mut r = Reference::new(w, h, 14, 2.603);
        let mut rng = Rng::new(17);
        let hot = 40 * w + 50;
        let mut pixels = vec![hot; 400];
        pixels.extend((0..90_000).map(|i| match i % 4 {
            0 => rng.below(u64::from(w * h)) as u32,
            1 => 40 * w + 45 + rng.below(12) as u32,
            2 => hot,
            _ => (30 + rng.below(40) as u32) * w + 20 + rng.below(60) as u32,
        }));
        s.writer().ingest(&pixels[..400]);
        pixels[..400].iter().for_each(|&p| r.update(p));
        assert_eq!(r.counts[hot as usize], 255);
        assert_same_state(&s, &r);
        for chunk in pixels[400..].chunks(7_777) {
            s.writer().ingest(chunk);
            chunk.iter().for_each(|&p| r.update(p));
            assert_same_state(&s, &r);
        }
    }

    /// Batch sizes around N: one quadrant of a block (whose events all feed the same four blocks)
    /// in batches of N − 1, N and N + 1 events, then a mixed stream (uniform, two clusters,
    /// indices past the grid) in batches from one event to thousands, compared with the
    /// event-by-event reference after every batch.
    #[test]
    fn batches_of_every_size_agree_with_the_reference() {
        let (w, h) = (130u32, 100u32);
        let n = ScarfGeometry::new(w, h, 14, 1.0).unwrap().fifo_len as usize;
        assert_eq!(n, 98);
        let mut rng = Rng::new(29);
        // Block (2, 2) starts at pixel (35, 35); its top-left quadrant is 35..42 on both axes.
        let quadrant: Vec<u32> = (0..3000)
            .map(|_| (35 + rng.below(7) as u32) * w + 35 + rng.below(7) as u32)
            .collect();
        let mixed: Vec<u32> = (0..40_000)
            .map(|i| match i % 4 {
                0 => rng.below(u64::from(w * h)) as u32,
                1 => (30 + rng.below(20) as u32) * w + 60 + rng.below(9) as u32,
                2 => (60 + rng.below(5) as u32) * w + 20 + rng.below(30) as u32,
                _ if i % 40 == 3 => w * h + rng.below(1000) as u32,
                _ => (10 + rng.below(80) as u32) * w + 100 + rng.below(20) as u32,
            })
            .collect();
        let sizes_quadrant = [n - 1, n, n + 1, 1, 2 * n, n];
        let sizes_mixed = [1, 2, n - 1, n, n + 1, 4 * n - 1, 4 * n, 4 * n + 1, 5000, 17];
        let mut s = Scarf::new(w, h, 14, 1.0).unwrap();
        let mut r = Reference::new(w, h, 14, 1.0);
        for (stream, sizes) in [(&quadrant, &sizes_quadrant[..]), (&mixed, &sizes_mixed[..])] {
            let (mut at, mut k) = (0, 0);
            while at < stream.len() {
                let batch = &stream[at..(at + sizes[k % sizes.len()]).min(stream.len())];
                s.writer().ingest(batch);
                batch
                    .iter()
                    .filter(|&&p| p < w * h)
                    .for_each(|&p| r.update(p));
                assert_same_state(&s, &r);
                at += batch.len();
                k += 1;
            }
        }
        assert!(s.reader().active_count() > 300, "a well-filled set");
    }

    /// Sequences are u16: a block's passes 2^16 every 65536 entries, and a pixel left behind
    /// would alias back into the window there without the sweeps. Most events hit one quadrant
    /// of one block (so its sequence wraps four times, with pixels that fired once and never
    /// again), the rest land anywhere; batches of fewer than N events, so that every window of N
    /// entries has a comparison with the reference in it.
    #[test]
    fn sequences_wrap_exactly() {
        let (w, h) = (70u32, 56u32);
        let n = ScarfGeometry::new(w, h, 14, 1.0).unwrap().fifo_len as usize;
        // Block (1, 1) starts at pixel (21, 21); its top-left quadrant is 21..28 on both axes.
        let quadrant = Roi {
            x0: 21,
            y0: 21,
            width: 7,
            height: 7,
        };
        let pixels = mixed_stream(w, h, 41, 280_000, 20, quadrant);
        let mut s = Scarf::new(w, h, 14, 1.0).unwrap();
        let mut r = Reference::new(w, h, 14, 1.0);
        for batch in pixels.chunks(n - 37) {
            s.writer().ingest(batch);
            batch.iter().for_each(|&p| r.update(p));
            assert_same_state(&s, &r);
        }
        let g = s.geometry();
        let entries = pixels
            .iter()
            .filter(|&&p| g.connections(p % w, p / w).contains(&Some((1, 1))))
            .count();
        assert!(entries > 4 << 16, "block (1, 1) took {entries} entries");
    }

    /// The mask copies a row's words and compares them in bulk: rois that start and end at every
    /// offset within a word, cross the grid's edges or lie partly outside it must agree pixel for
    /// pixel with `is_active`.
    #[test]
    fn masks_of_any_roi_agree_with_is_active() {
        let (w, h) = (203u32, 140u32);
        let cluster = Roi {
            x0: 40,
            y0: 20,
            width: 120,
            height: 90,
        };
        let pixels = mixed_stream(w, h, 53, 60_000, 3, cluster);
        let mut rng = Rng::new(54);
        let mut s = Scarf::new(w, h, 14, 1.0).unwrap();
        s.writer().ingest(&pixels);
        let reader = s.reader();
        for _ in 0..300 {
            let roi = Roi {
                x0: rng.below(u64::from(w + 4)) as u32,
                y0: rng.below(u64::from(h + 4)) as u32,
                width: 1 + rng.below(120) as u32,
                height: 1 + rng.below(60) as u32,
            };
            let got = mask(&s, roi);
            for (i, &v) in got.iter().enumerate() {
                let (x, y) = (roi.x0 + i as u32 % roi.width, roi.y0 + i as u32 / roi.width);
                assert_eq!(v, u8::from(reader.is_active(x, y)), "{roi:?} ({x}, {y})");
            }
        }
        assert!(
            reader.active_count() > 2000,
            "a well-filled set: {}",
            reader.active_count()
        );
    }

    /// The row comparison at every length around the vector widths, with differences at the
    /// edges that matter (N − 1, N, wrapped below zero, the largest) and N = 0 columns: the
    /// dispatched build (AVX2 here) against the portable loop and the definition.
    #[test]
    fn row_comparison_matches_its_definition() {
        let mut rng = Rng::new(61);
        for len in 0..150 {
            let fifo: Vec<u16> = (0..len)
                .map(|_| [0, 1, 98, 255][rng.below(4) as usize])
                .collect();
            let seqs: Vec<u16> = (0..len).map(|_| rng.below(1 << 16) as u16).collect();
            let lasts: Vec<u16> = seqs
                .iter()
                .zip(&fifo)
                .map(|(&s, &n)| {
                    let age =
                        [0, n.wrapping_sub(1), n, n + 1, u16::MAX, 40_000][rng.below(6) as usize];
                    s.wrapping_sub(age)
                })
                .collect();
            let want: Vec<u8> = (0..len)
                .map(|i| u8::from(u32::from(seqs[i].wrapping_sub(lasts[i])) < u32::from(fifo[i])))
                .collect();
            let (mut got, mut plain) = (vec![7u8; len], vec![7u8; len]);
            compare_row(&seqs, &lasts, &fifo, &mut got);
            compare_row_lanes(&seqs, &lasts, &fifo, &mut plain);
            assert_eq!(got, want, "len {len}");
            assert_eq!(plain, want, "len {len}");
        }
    }

    #[test]
    fn border_is_never_drawn_and_fifos_are_bounded() {
        let (w, h) = (346u32, 260u32);
        let mut s = Scarf::new(w, h, 14, 1.0).unwrap();
        let g = s.geometry();
        let mut rng = Rng::new(11);
        let pixels: Vec<u32> = (0..400_000)
            .map(|_| rng.below(u64::from(w * h)) as u32)
            .collect();
        s.ingest(&pixels, &vec![1; pixels.len()]);
        let m = mask(&s, Roi::full(w, h));
        let (x0, y0) = (g.block_w / 2, g.block_h / 2);
        let (x1, y1) = (x0 + g.grid_w * g.block_w, y0 + g.grid_h * g.block_h);
        let inner = Roi {
            x0,
            y0,
            width: x1 - x0,
            height: y1 - y0,
        };
        let mut inner_active = 0;
        for (i, &v) in m.iter().enumerate() {
            let (x, y) = (i as u32 % w, i as u32 / w);
            if inner.contains(x, y) {
                inner_active += usize::from(v);
            } else {
                assert_eq!(v, 0, "border pixel ({x}, {y}) drawn");
            }
        }
        // Uniform input: each FIFO holds about a quarter centre entries, so ≈ N/4 of 196 pixels.
        assert!(inner_active > g.n_blocks() * 15, "{inner_active}");
        // A block's active pixels are distinct centre entries of its FIFO, so at most N; once
        // only its own pixels fire, they are exactly the distinct pixels of the last N events.
        let block_active = |s: &Scarf, bx: u32, by: u32| -> Vec<u32> {
            let r = s.reader();
            let mut on = Vec::new();
            for y in y0 + by * g.block_h..y0 + (by + 1) * g.block_h {
                for x in x0 + bx * g.block_w..x0 + (bx + 1) * g.block_w {
                    if r.is_active(x, y) {
                        on.push(y * w + x);
                    }
                }
            }
            on
        };
        for by in 0..g.grid_h {
            for bx in 0..g.grid_w {
                assert!(block_active(&s, bx, by).len() <= g.fifo_len as usize);
            }
        }
        let (bx, by) = (5, 4);
        let own: Vec<u32> = (0..1000)
            .map(|_| {
                let x = x0 + bx * g.block_w + rng.below(u64::from(g.block_w)) as u32;
                let y = y0 + by * g.block_h + rng.below(u64::from(g.block_h)) as u32;
                y * w + x
            })
            .collect();
        s.writer().ingest(&own);
        let mut newest = own[own.len() - g.fifo_len as usize..].to_vec();
        newest.sort_unstable();
        newest.dedup();
        assert_eq!(block_active(&s, bx, by), newest);
    }

    /// A vertical edge (rows 40..220, one event per pixel per position) sweeps x = 30..190.
    /// Background activity arrives at a constant rate *per unit time*: a flickering patch at
    /// x 250..330 (1500 events per step) and sparse sensor-wide noise (2 per step). At 1× the
    /// edge advances 1 px per step, at 10× it advances 10 px per step, so at 10× there are 10×
    /// fewer background events per edge position. Returns (SCARF, fixed-count 8000) masks of the
    /// final edge's neighbourhood x 150..220 (a tracker's ROI), clear of the flicker's blocks.
    fn sweep(speed: u32, seed: u64) -> (Vec<u8>, Vec<u8>) {
        let (w, h) = (346u32, 260u32);
        let mut rng = Rng::new(seed);
        let mut scarf = Scarf::new(w, h, 14, 1.0).unwrap();
        let mut fixed = FixedCount::new(w, h, 8000).unwrap();
        let mut x = 30;
        while x < 190 {
            // Edge positions stay in time order; rows fire in random order within a position.
            let mut edge = Vec::new();
            for xe in x..(x + speed).min(190) {
                let mut column: Vec<u32> = (40..220).map(|y| y * w + xe).collect();
                shuffle(&mut column, &mut rng);
                edge.extend(column);
            }
            let mut background: Vec<u32> = (0..1500)
                .map(|_| (30 + rng.below(200) as u32) * w + 250 + rng.below(80) as u32)
                .collect();
            background.extend((0..2).map(|_| rng.below(u64::from(w * h)) as u32));
            let step = interleave(&edge, &background, &mut rng);
            let pol = vec![1i16; step.len()];
            scarf.ingest(&step, &pol);
            fixed.ingest(&step, &pol);
            x += speed;
        }
        let roi = Roi {
            x0: 150,
            y0: 0,
            width: 70,
            height: h,
        };
        (mask(&scarf, roi), mask(&fixed, roi))
    }

    #[test]
    fn active_set_is_velocity_invariant_unlike_fixed_count() {
        let (scarf_slow, fixed_slow) = sweep(1, 21);
        let (scarf_fast, fixed_fast) = sweep(10, 22);
        let (ns, nf) = (ones(&scarf_slow), ones(&scarf_fast));
        let scarf_iou = iou(&scarf_slow, &scarf_fast);
        let (fs, ff) = (ones(&fixed_slow), ones(&fixed_fast));
        let fixed_iou = iou(&fixed_slow, &fixed_fast);
        eprintln!("SCARF 1x {ns} 10x {nf} IoU {scarf_iou:.3}; fixed-count 1x {fs} 10x {ff} IoU {fixed_iou:.3}");
        // Measured: SCARF 721 vs 703 active, IoU 0.86 (the oldest, half-evicted column differs
        // with the random row order, and 1× holds 10× more noise); fixed-count 860 vs 4368
        // active, IoU 0.20 (a 5-column trail against a 24-column one).
        assert!(ns > 500, "the edge must be drawn: {ns}");
        assert!(scarf_iou > 0.8, "SCARF IoU {scarf_iou}");
        assert!(
            (ns as f64 / nf as f64 - 1.0).abs() < 0.08,
            "SCARF {ns} vs {nf}"
        );
        assert!(fixed_iou < 0.3, "fixed-count IoU {fixed_iou}");
        assert!(ff as f64 > 4.0 * fs as f64, "fixed-count {fs} vs {ff}");
    }

    #[test]
    fn active_set_holds_when_events_stop_or_fall_elsewhere() {
        let (w, h) = (346u32, 260u32);
        let mut s = Scarf::new(w, h, 14, 1.0).unwrap();
        let edge: Vec<u32> = (60..70)
            .flat_map(|x| (50..150).map(move |y| y * w + x))
            .collect();
        s.ingest(&edge, &vec![0; edge.len()]);
        let roi = Roi {
            x0: 30,
            y0: 20,
            width: 70,
            height: 160,
        };
        let before = mask(&s, roi);
        assert!(ones(&before) > 300, "{}", ones(&before));
        s.ingest(&[], &[]);
        assert_eq!(mask(&s, roi), before);
        // Plenty of activity more than a block away from the ROI does not touch it.
        let mut rng = Rng::new(5);
        let far: Vec<u32> = (0..200_000)
            .map(|_| rng.below(u64::from(h)) as u32 * w + 150 + rng.below(196) as u32)
            .collect();
        s.ingest(&far, &vec![1; far.len()]);
        assert_eq!(mask(&s, roi), before);
    }

    #[test]
    fn concurrent_reader_sees_a_consistent_final_state() {
        let (w, h) = (640u32, 480u32);
        let mut rng = Rng::new(99);
        let pixels: Vec<u32> = (0..3_000_000)
            .map(|i| {
                let t = (i / 20_000) as u32;
                if i % 5 == 0 {
                    rng.below(u64::from(w * h)) as u32
                } else {
                    (100 + rng.below(200) as u32) * w + 50 + 3 * t + rng.below(3) as u32
                }
            })
            .collect();
        let mut single = Scarf::new(w, h, 14, 1.0).unwrap();
        single.writer().ingest(&pixels);
        let (mut writer, reader) = Scarf::new(w, h, 14, 1.0).unwrap().split();
        let done = std::sync::atomic::AtomicBool::new(false);
        let reading = std::sync::atomic::AtomicBool::new(false);
        let roi = Roi {
            x0: 20,
            y0: 40,
            width: 400,
            height: 400,
        };
        let reads = std::thread::scope(|scope| {
            let r = reader.clone();
            let (done, reading) = (&done, &reading);
            let watcher = scope.spawn(move || {
                let mut buf = vec![0u8; roi.area()];
                let mut reads = 0usize;
                while !done.load(std::sync::atomic::Ordering::Acquire) {
                    r.fill_mask(roi, &mut buf);
                    assert!(ones(&buf) <= roi.area());
                    reads += 1;
                    reading.store(true, std::sync::atomic::Ordering::Release);
                }
                reads
            });
            // On a loaded machine the watcher may not run before the writer is done: the reads must
            // overlap the writes for the test to mean anything, so the writer waits for the first.
            while !reading.load(std::sync::atomic::Ordering::Acquire) {
                std::thread::yield_now();
            }
            for chunk in pixels.chunks(4096) {
                writer.ingest(chunk);
            }
            done.store(true, std::sync::atomic::Ordering::Release);
            watcher.join().unwrap()
        });
        assert!(reads > 0);
        let expected = single.reader();
        let full = Roi::full(w, h);
        let (mut a, mut b) = (vec![0u8; full.area()], vec![0u8; full.area()]);
        reader.fill_mask(full, &mut a);
        expected.fill_mask(full, &mut b);
        assert_eq!(a, b);
        assert_eq!(reader.active_count(), expected.active_count());
        assert_eq!(ages(&Scarf { writer, reader }), ages(&single));
    }
}
