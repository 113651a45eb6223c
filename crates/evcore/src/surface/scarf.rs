//! SCARF, the Set of Centre Active Receptive Fields (Glover et al.; `robotology/event-driven`).
//!
//! The grid is tiled into square blocks, shifted by half a block so that the outer half-block ring
//! has no block of its own. Each block keeps a FIFO of the last N events that fell in the 2×2-block
//! window centred on it. An entry from the block itself is a *centre* entry and marks its pixel
//! active; entries from the surrounding half-blocks only occupy slots, so motion next to a block
//! flushes its stale centre events. Nothing depends on time: a region keeps its last N events
//! however old they are, which is what makes the active set independent of the object's speed.
//!
//! Storage and order of work differ from the C++ in four ways, none visible in the result:
//! - activity is a per-pixel u8 count of centre entries (active = count > 0) instead of a float
//!   image updated by ±C, so no residue can build up; a pixel's count is at most N, so N ≤ 255
//!   keeps it from ever wrapping;
//! - a ring entry is the block-local index (row · block width + column) of a centre event, or the
//!   spare value `block area` for a surround event: one byte while the block area is at most 255
//!   (the default 14 px block: 196), two otherwise. The spare value maps to a spare cell of the
//!   block, past the count image, that absorbs the unconditional ±1 updates, so the hot loop has no
//!   "is this a centre entry" branch (a select between one shared spare cell and origin + offset
//!   compiled to one, taken at random on noise). One spare cell per block rather than one for
//!   all: most evictions are surround entries, and a single shared cell chained every event's
//!   three or so read-modify-writes into one dependency through memory. Block-local entries and u8
//!   counts keep the rings and the count image at ≈ 1.4 MB at 1280×720 with 14 px blocks (1.9 MB
//!   with two-byte entries, 3.8 MB with u32 pixel indices and u16 counts), which is what a stream
//!   spread over the whole sensor (a textured background) misses the cache on;
//! - a missing neighbour block points at a dummy block whose ring only ever holds the spare value,
//!   so every event does exactly four ring updates and the loop has no "is there a block" branch;
//! - a batch is first walked newest event first to find, per block, the entries of its newest N
//!   events; an older entry would be evicted from that block's FIFO within the same batch, so it
//!   is not applied at all. A block's FIFO and its pixels' counts depend only on the block's own
//!   entries in order (a count is the number of the pixel's centre entries in its own block's
//!   FIFO), so dropping entries that a block would evict anyway changes nothing once the batch is
//!   done. The walk reads only a byte per block (a few KiB); the update then runs, oldest first,
//!   over the events that still feed some block, with their other entries sent to a scratch
//!   block. A stream that keeps hitting the same blocks (an object's edges) thus costs the update
//!   only about N events per block and batch.
//!
//! Concurrency: one [`ScarfWriter`] owns the rings, the per-batch tallies and the connection
//! table; any number of
//! [`ScarfReader`] handles share only the count image (relaxed `AtomicU8`) and the active-pixel
//! total. Relaxed loads and stores of byte cells compile to plain moves on x86-64 and AArch64, so
//! the writer pays nothing for being observable.

use std::sync::atomic::{AtomicU8, AtomicUsize, Ordering::Relaxed};
use std::sync::Arc;

use super::{check_grid, fill_roi, EventSurface};
use crate::error::{ensure, Result};
use crate::image::Roi;

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
    /// the FIFO as long as the whole 2×2-block window); N must fit the u8 count image (≤ 255) and
    /// the block area the u16 ring entries (< 65535).
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
/// (rows pre-multiplied by the padded grid width), the coordinate's offset inside its own block
/// (rows pre-multiplied by the block width), and whether the own block is a real one.
#[derive(Debug, Clone, Copy)]
struct AxisEntry {
    own: u32,
    side: u32,
    local: u32,
    real: bool,
}

/// Axis table for coordinates 0..len; `pad` is the lowest block index any coordinate reaches (−1),
/// `scale` the stride of one step along this axis in the padded grid, `local_scale` that of one
/// step inside a block's local index.
fn axis_table(
    len: u32,
    block: u32,
    grid: u32,
    pad: i64,
    scale: u32,
    local_scale: u32,
) -> Box<[AxisEntry]> {
    (0..len)
        .map(|c| {
            let (own, side) = axis(c, block);
            let real = (0..i64::from(grid)).contains(&own);
            let local = if real {
                (i64::from(c) - i64::from(block / 2) - own * i64::from(block)) as u32 * local_scale
            } else {
                0
            };
            AxisEntry {
                own: (own - pad) as u32 * scale,
                side: (side - pad) as u32 * scale,
                local,
                real,
            }
        })
        .collect()
}

/// What readers see: the count image and the total. The cells past width·height are the writer's
/// spare cells (one per padded block), never read.
#[derive(Debug)]
struct Shared {
    width: u32,
    height: u32,
    counts: Box<[AtomicU8]>,
    active: AtomicUsize,
}

/// The single writer: ingests events. Not `Clone`, so there is exactly one per SCARF.
///
/// Blocks live on a padded grid with an extra ring of blocks wherever a pixel's neighbour would
/// fall outside the real grid. Those pad blocks have no centre pixels, so their FIFOs only ever
/// hold the spare index; writing to them is cheaper than branching around them. The block of a
/// pixel is `rows[y].own + cols[x].own` etc., so the lookup tables are per row and per column
/// (a few KiB, always in L1) instead of 16 bytes per pixel (15 MB at 1280×720, missed on every
/// noise event).
#[derive(Debug)]
pub struct ScarfWriter {
    shared: Arc<Shared>,
    geometry: ScarfGeometry,
    layout: Layout,
    /// Per padded block: where its ring is, the slot written last and its count cells.
    blocks: Box<[Block]>,
    /// Per padded block, N entries: a centre event's block-local index or the spare value.
    rings: Rings,
    /// Per padded block: how many of the current batch's newest entries it keeps (at most N);
    /// all 0 between batches.
    kept: Box<[u8]>,
    /// The batch's events that feed at least one block, oldest first: pixel | feeds << 28.
    survivors: Vec<u32>,
    /// Whether the newest-first walk ran on the last batch and paid for itself; see [`WALK_RETRY`].
    walk_pays: bool,
    /// Batches since the walk last ran.
    since_walk: u32,
    /// Writer-side copy of the active-pixel total, published after each batch.
    active: usize,
}

/// The writer's fixed lookup tables: where an event's four blocks and their count cells are.
#[derive(Debug)]
struct Layout {
    /// Pixels in the count image; spare cells follow.
    n_pixels: u32,
    /// FIFO length N.
    fifo_len: usize,
    row_of: RowOf,
    cols: Box<[AxisEntry]>,
    rows: Box<[AxisEntry]>,
    /// Pixel offset from a block's top-left pixel of each block-local index, then 0 for the spare
    /// value (whose base is the spare cell itself).
    local_offsets: Box<[u32]>,
    /// The first of four scratch blocks (after the padded grid), one per entry of an event, that
    /// take the entries a block does not keep: like pad blocks, their rings only ever hold the
    /// spare value. One per entry, so that an event's evictions from them (spare cell updates)
    /// do not chain through one cell.
    scratch: u32,
}

/// The newest-first walk costs about a third of the update it saves (thread CPU, 29k events of a
/// box's outline, every event kept: 1.30× the update alone). It runs while it drops at least a
/// third of a batch's events, and otherwise is retried every this many batches, so a stream whose
/// blocks stop filling within a batch pays for it rarely and one that starts to again is noticed.
const WALK_RETRY: u32 = 16;

/// A survivor's pixel index takes the low 28 bits (a grid within 16384² has fewer pixels than
/// 2^28); which of its four entries are kept, the high four.
const FEEDS_SHIFT: u32 = 28;

/// One padded block's ring state and count cells, together so that an update reads one 16-byte
/// record (and no ring index is multiplied out) rather than three arrays.
#[derive(Debug, Clone, Copy)]
struct Block {
    /// Ring index of the slot written last, in start..start + N.
    last: u32,
    /// Ring index of the block's first slot.
    start: u32,
    /// The count cell a ring entry's offset starts from: [the pixel index of the block's top-left
    /// pixel (0 for pad blocks, whose rings only hold the spare value), the block's spare cell],
    /// indexed by "the entry is the spare value".
    cells: [u32; 2],
}

/// A ring entry: a centre event's block-local index, or the spare value (the block area).
trait Entry: Copy + Eq {
    /// `local` ≤ block area, which the width was chosen to hold.
    fn new(local: u32) -> Self;
    fn index(self) -> usize;
}

impl Entry for u8 {
    #[inline(always)]
    fn new(local: u32) -> Self {
        local as u8
    }
    #[inline(always)]
    fn index(self) -> usize {
        usize::from(self)
    }
}

impl Entry for u16 {
    #[inline(always)]
    fn new(local: u32) -> Self {
        local as u16
    }
    #[inline(always)]
    fn index(self) -> usize {
        usize::from(self)
    }
}

/// The rings in the narrowest entry that holds the spare value: a byte per entry up to a block
/// area of 255 (the default 14 px block: 196), halving the rings' footprint.
#[derive(Debug)]
enum Rings {
    Narrow(Box<[u8]>),
    Wide(Box<[u16]>),
}

/// A cheap, cloneable read handle; safe to use from any thread while the writer runs.
///
/// Reads are not synchronised with the writer, so a reader may see a batch half applied, or one
/// pixel between the eviction and the insertion of the same event (a count one below for a
/// moment). Mid-batch, a block has stepped only through the entries that survive the batch, so a
/// count read then is one the pixel would have had without the batch's older events; when the
/// batch completes every count is exact. A mask is thus at worst one batch stale at a few pixels;
/// the tracker treats it as a noisy sample anyway.
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
        // Four more blocks than the padded grid: the scratch blocks.
        let n_padded = (padded_w * padded_h) as usize + 4;
        let ring_words = n_padded * geometry.fifo_len as usize;
        ensure(u32::try_from(ring_words).is_ok(), || {
            format!("SCARF rings of {ring_words} words exceed u32 offsets")
        })?;
        let (bw, bh) = (geometry.block_w, geometry.block_h);
        let cols = axis_table(width, bw, geometry.grid_w, -1, 1, 1);
        let rows = axis_table(height, bh, geometry.grid_h, -1, padded_w as u32, bw);
        // Spare cells follow the count image, one per padded block: n_pixels + n_padded cells, far
        // below u32::MAX for a grid within 16384².
        let n = geometry.fifo_len;
        let mut blocks: Vec<Block> = (0..n_padded)
            .map(|b| Block {
                last: b as u32 * n,
                start: b as u32 * n,
                cells: [0, (n_pixels + b) as u32],
            })
            .collect();
        for by in 0..geometry.grid_h {
            for bx in 0..geometry.grid_w {
                let b = (by + 1) as usize * padded_w as usize + (bx + 1) as usize;
                blocks[b].cells[0] = (bh / 2 + by * bh) * width + bw / 2 + bx * bw;
            }
        }
        let area = bw * bh;
        let local_offsets = (0..area)
            .map(|l| l / bw * width + l % bw)
            .chain([0])
            .collect();
        let rings = if area <= u32::from(u8::MAX) {
            Rings::Narrow(vec![0; ring_words].into_boxed_slice())
        } else {
            Rings::Wide(vec![0; ring_words].into_boxed_slice())
        };
        let counts = (0..n_pixels + n_padded).map(|_| AtomicU8::new(0)).collect();
        let shared = Arc::new(Shared {
            width,
            height,
            counts,
            active: AtomicUsize::new(0),
        });
        let mut writer = ScarfWriter {
            shared: Arc::clone(&shared),
            geometry,
            layout: Layout {
                n_pixels: n_pixels as u32,
                fifo_len: geometry.fifo_len as usize,
                scratch: n_padded as u32 - 4,
                row_of: RowOf::new(width),
                cols,
                rows,
                local_offsets,
            },
            blocks: blocks.into_boxed_slice(),
            rings,
            kept: vec![0; n_padded].into_boxed_slice(),
            survivors: Vec::new(),
            walk_pays: true,
            since_walk: 0,
            active: 0,
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

impl ScarfWriter {
    /// Ingest events at rectified pixel indices; indices ≥ width·height are skipped.
    pub fn ingest(&mut self, pixels: &[u32]) {
        let (layout, blocks, counts) = (&self.layout, &mut *self.blocks, &*self.shared.counts);
        let kept = &mut *self.kept;
        self.active = if self.walk_pays || self.since_walk >= WALK_RETRY {
            layout.select(pixels, kept, &mut self.survivors);
            self.walk_pays = 3 * self.survivors.len() <= 2 * pixels.len();
            self.since_walk = 0;
            let survivors = &*self.survivors;
            match &mut self.rings {
                Rings::Narrow(rings) => {
                    layout.ingest::<_, true>(survivors, kept, blocks, rings, counts, self.active)
                }
                Rings::Wide(rings) => {
                    layout.ingest::<_, true>(survivors, kept, blocks, rings, counts, self.active)
                }
            }
        } else {
            self.since_walk += 1;
            match &mut self.rings {
                Rings::Narrow(rings) => {
                    layout.ingest::<_, false>(pixels, kept, blocks, rings, counts, self.active)
                }
                Rings::Wide(rings) => {
                    layout.ingest::<_, false>(pixels, kept, blocks, rings, counts, self.active)
                }
            }
        };
        self.shared.active.store(self.active, Relaxed);
    }

    /// Empty every FIFO and the count image.
    pub fn reset(&mut self) {
        let spare = self.layout.local_offsets.len() as u32 - 1;
        match &mut self.rings {
            Rings::Narrow(rings) => rings.fill(Entry::new(spare)),
            Rings::Wide(rings) => rings.fill(Entry::new(spare)),
        }
        for b in self.blocks.iter_mut() {
            b.last = b.start;
        }
        for c in self.shared.counts.iter() {
            c.store(0, Relaxed);
        }
        self.active = 0;
        self.shared.active.store(0, Relaxed);
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

/// How far ahead of the event being inserted its count cell is prefetched, in events.
const PREFETCH_EVENTS: usize = 16;

/// Hint that `at` will be read soon; never faults, so any address (even past the end) is fine.
#[inline(always)]
fn prefetch<T>(at: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch has no architectural effect and does not fault on any address.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(at.cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = at;
}

impl Layout {
    /// (x, y) of pixel `p` < width·height and its two axis entries.
    #[inline(always)]
    fn axes(&self, p: u32) -> (&AxisEntry, &AxisEntry) {
        let (x, y) = self.row_of.split(p);
        // SAFETY: p < width·height, so x < width = cols.len() and y < height = rows.len().
        unsafe {
            (
                self.cols.get_unchecked(x as usize),
                self.rows.get_unchecked(y as usize),
            )
        }
    }

    /// Walk the batch newest first and keep, per block, the entries of its newest N events
    /// (`kept` counts them); collect the events with at least one kept entry, oldest first.
    fn select(&self, pixels: &[u32], kept: &mut [u8], survivors: &mut Vec<u32>) {
        survivors.clear();
        let n = self.fifo_len as u32;
        for &p in pixels.iter().rev() {
            if p >= self.n_pixels {
                continue;
            }
            let (c, r) = self.axes(p);
            let fed = [
                r.own + c.own,
                r.side + c.own,
                r.own + c.side,
                r.side + c.side,
            ];
            let mut feeds = 0;
            for (k, b) in fed.into_iter().enumerate() {
                // SAFETY: the axis tables only hold indices inside the padded grid.
                let count = unsafe { kept.get_unchecked_mut(b as usize) };
                // Stored unconditionally: a branch here is taken at random where blocks fill up.
                let keep = u32::from(*count) < n;
                *count += u8::from(keep);
                feeds |= u32::from(keep) << k;
            }
            if feeds != 0 {
                survivors.push(p | feeds << FEEDS_SHIFT);
            }
        }
        survivors.reverse();
    }

    /// The insert loop for one ring entry width, oldest first: over the survivors of `select` if
    /// SELECTED (a kept entry to its block, the others to a scratch block; clears `kept`), else
    /// over the raw pixels (every entry to its block, indices past the grid skipped). Returns the
    /// new active-pixel total.
    #[inline(always)]
    fn ingest<E: Entry, const SELECTED: bool>(
        &self,
        events: &[u32],
        kept: &mut [u8],
        blocks: &mut [Block],
        rings: &mut [E],
        counts: &[AtomicU8],
        mut active: usize,
    ) -> usize {
        let (n_pixels, n, scratch) = (self.n_pixels, self.fifo_len as u32, self.scratch);
        let spare_local = self.local_offsets.len() as u32 - 1;
        let spare_entry = E::new(spare_local);
        let offsets = &*self.local_offsets;
        let pixel_mask = (1 << FEEDS_SHIFT) - 1;
        for (i, &s) in events.iter().enumerate() {
            // A noise event's count cell is a cache miss; asking for it a few events ahead lets
            // the miss overlap the work in between.
            if let Some(&ahead) = events.get(i + PREFETCH_EVENTS) {
                prefetch(counts.as_ptr().wrapping_add((ahead & pixel_mask) as usize));
            }
            let (p, feeds) = if SELECTED {
                (s & pixel_mask, s >> FEEDS_SHIFT)
            } else if s < n_pixels {
                (s, 0b1111)
            } else {
                continue;
            };
            let (c, r) = self.axes(p);
            // `&`, not `&&`: one test of both flags instead of two branches. The own block's entry
            // counts only where that block keeps it.
            let real = c.real & r.real & (feeds & 1 != 0);
            let own = r.own + c.own;
            // A pixel outside every real block, or whose own block does not keep its entry, feeds
            // its own block's spare cell.
            let (centre, centre_entry) = if real {
                (p, E::new(r.local + c.local))
            } else {
                (n_pixels + own, spare_entry)
            };
            let fed = [own, r.side + c.own, r.own + c.side, r.side + c.side];
            for (k, b) in fed.into_iter().enumerate() {
                let b = if feeds >> k & 1 != 0 {
                    b
                } else {
                    scratch + k as u32
                };
                if SELECTED {
                    // SAFETY: b is a padded block or a scratch block, all inside `kept`.
                    unsafe { *kept.get_unchecked_mut(b as usize) = 0 };
                }
                // SAFETY: the axis tables only hold indices inside the padded grid, which with
                // the scratch blocks has blocks.len() blocks of n ring entries each; `last` stays
                // in start..start + n.
                let block = unsafe { blocks.get_unchecked_mut(b as usize) };
                let next = block.last + 1;
                block.last = if next == block.start + n {
                    block.start
                } else {
                    next
                };
                let entry = unsafe { rings.get_unchecked_mut(block.last as usize) };
                let old = std::mem::replace(entry, if k == 0 { centre_entry } else { spare_entry });
                let surround = old == spare_entry;
                // SAFETY: a ring entry is a local index < block area (only ever written into a
                // real block's ring, whose origin plus offset is a pixel of that block) or the
                // spare value, whose base is the block's spare cell and offset 0; counts holds
                // n_pixels + one spare cell per padded block.
                let cell = block.cells[usize::from(surround)]
                    + unsafe { offsets.get_unchecked(old.index()) };
                let cell = unsafe { counts.get_unchecked(cell as usize) };
                let v = cell.load(Relaxed).wrapping_sub(1);
                cell.store(v, Relaxed);
                active -= usize::from(v == 0 && !surround);
            }
            // SAFETY: centre is a pixel index or the own block's spare cell.
            let cell = unsafe { counts.get_unchecked(centre as usize) };
            let v = cell.load(Relaxed);
            cell.store(v.wrapping_add(1), Relaxed);
            active += usize::from(v == 0 && real);
        }
        active
    }
}

impl ScarfReader {
    pub fn width(&self) -> u32 {
        self.shared.width
    }

    pub fn height(&self) -> u32 {
        self.shared.height
    }

    /// Number of centre entries for pixel (x, y) in its block's FIFO; 0 outside the grid.
    pub fn count(&self, x: u32, y: u32) -> u16 {
        if x >= self.shared.width || y >= self.shared.height {
            return 0;
        }
        u16::from(
            self.shared.counts[y as usize * self.shared.width as usize + x as usize].load(Relaxed),
        )
    }

    /// Number of active pixels as of the writer's last completed batch.
    pub fn active_count(&self) -> usize {
        self.shared.active.load(Relaxed)
    }

    /// See [`EventSurface::fill_mask`].
    pub fn fill_mask(&self, roi: Roi, out: &mut [u8]) {
        let counts = &self.shared.counts;
        fill_roi(
            self.shared.width,
            self.shared.height,
            roi,
            out,
            |start, dst| {
                let src = &counts[start..start + dst.len()];
                for (d, c) in dst.iter_mut().zip(src) {
                    *d = u8::from(c.load(Relaxed) != 0);
                }
            },
        );
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
        // The u8 count image holds N ≤ 255: block 22 at alpha 1 gives 242, block 24 gives 288.
        assert_eq!(ScarfGeometry::new(640, 480, 22, 1.0).unwrap().fifo_len, 242);
        assert!(ScarfGeometry::new(640, 480, 24, 1.0).is_err(), "N = 288");
        assert_eq!(
            Scarf::new(346, 260, 14, 1.0).unwrap().geometry(),
            ScarfGeometry::new(346, 260, 14, 1.0).unwrap()
        );
    }

    /// Straightforward port of the C++ update (a deque per block, skipped missing neighbours,
    /// explicit centre flags): the branch-free writer must agree with it count for count.
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

    /// Every pixel's count and the active total of `s` equal the reference's.
    fn assert_same_counts(s: &Scarf, r: &Reference) {
        let reader = s.reader();
        let w = r.width;
        let got: Vec<u16> = (0..r.counts.len() as u32)
            .map(|p| reader.count(p % w, p / w))
            .collect();
        assert_eq!(got, r.counts);
        assert_eq!(
            reader.active_count(),
            r.counts.iter().filter(|&&c| c > 0).count()
        );
    }

    #[test]
    fn agrees_with_a_plain_port_of_the_reference() {
        let (w, h) = (120u32, 90u32);
        let mut rng = Rng::new(3);
        // Half uniform (border pixels included), half clustered so FIFOs wrap many times.
        let pixels: Vec<u32> = (0..60_000)
            .map(|i| {
                if i % 2 == 0 {
                    rng.below(u64::from(w * h)) as u32
                } else {
                    (40 + rng.below(20) as u32) * w + 30 + rng.below(25) as u32
                }
            })
            .collect();
        let mut s = Scarf::new(w, h, 11, 0.7).unwrap();
        let mut r = Reference::new(w, h, 11, 0.7);
        s.writer().ingest(&pixels[..12_345]);
        s.writer().ingest(&pixels[12_345..]);
        pixels.iter().for_each(|&p| r.update(p));
        assert_same_counts(&s, &r);
        assert!(
            s.reader().active_count() > 450,
            "the test must exercise a well-filled set"
        );
    }

    /// The largest FIFO the u8 counts allow (block 22, N = 242), on a grid that is not a multiple
    /// of the block, with a few pixels firing over and over so single counts reach N.
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
        assert!(matches!(s.writer.rings, Rings::Wide(_)));
        let mut r = Reference::new(w, h, 22, 1.0);
        s.writer().ingest(&pixels[..40_000]);
        pixels[..40_000].iter().for_each(|&p| r.update(p));
        // A run of one pixel fills its block's FIFO: its count is N.
        let hot = vec![60 * w + 70; 300];
        s.writer().ingest(&hot);
        hot.iter().for_each(|&p| r.update(p));
        assert_eq!(s.reader().count(70, 60), 242);
        s.writer().ingest(&pixels[40_000..]);
        pixels[40_000..].iter().for_each(|&p| r.update(p));
        assert_same_counts(&s, &r);
    }

    /// One-byte ring entries at their limits: the default 14 px block (area 196) with the longest
    /// FIFO a u8 count allows (N = 255), one pixel fired until its count is 255 = u8::MAX (a count
    /// is at most N, so it cannot wrap), then noise and clusters that evict it again; on a grid
    /// with border pixels outside every block (their events feed only pad blocks).
    #[test]
    fn one_byte_entries_agree_with_the_reference_at_the_largest_fifo() {
        let (w, h) = (150u32, 110u32);
        let mut s = Scarf::new(w, h, 14, 2.603).unwrap();
        assert_eq!(s.geometry().fifo_len, 255);
        assert!(matches!(s.writer.rings, Rings::Narrow(_)));
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
        assert_eq!(s.reader().count(50, 40), 255);
        assert_same_counts(&s, &r);
        for chunk in pixels[400..].chunks(7_777) {
            s.writer().ingest(chunk);
            chunk.iter().for_each(|&p| r.update(p));
            assert_same_counts(&s, &r);
        }
        // A 16 px block (area 256) does not leave room for the spare value in a byte.
        let wide = Scarf::new(w, h, 16, 1.0).unwrap();
        assert!(matches!(wide.writer.rings, Rings::Wide(_)));
    }

    /// A batch keeps at most the newest N entries per block, so the sizes around N matter:
    /// one quadrant of a block (whose events all feed the same four blocks) in batches of N − 1,
    /// N and N + 1 events, then a mixed stream (uniform, two clusters, indices past the grid) in
    /// batches from one event to thousands, compared with the event-by-event reference after
    /// every batch, with and without the newest-first walk.
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
        // Every batch walked, no batch walked, and the writer's own choice.
        for walk in [Some(true), Some(false), None] {
            let mut s = Scarf::new(w, h, 14, 1.0).unwrap();
            let mut r = Reference::new(w, h, 14, 1.0);
            for (stream, sizes) in [(&quadrant, &sizes_quadrant[..]), (&mixed, &sizes_mixed[..])] {
                let (mut at, mut k) = (0, 0);
                while at < stream.len() {
                    let batch = &stream[at..(at + sizes[k % sizes.len()]).min(stream.len())];
                    if let Some(walk) = walk {
                        s.writer.walk_pays = walk;
                        s.writer.since_walk = 0;
                    }
                    s.writer().ingest(batch);
                    batch
                        .iter()
                        .filter(|&&p| p < w * h)
                        .for_each(|&p| r.update(p));
                    assert_same_counts(&s, &r);
                    at += batch.len();
                    k += 1;
                }
            }
            assert!(s.reader().active_count() > 300, "a well-filled set");
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
        assert_eq!(inner_active, s.reader().active_count());
        // Uniform input: each FIFO holds about a quarter centre entries, so ≈ N/4 of 196 pixels.
        assert!(inner_active > g.n_blocks() * 15, "{inner_active}");
        // Centre entries per block never exceed N; events only inside one block fill it exactly.
        let block_sum = |s: &Scarf, bx: u32, by: u32| -> u32 {
            let r = s.reader();
            let mut sum = 0;
            for y in y0 + by * g.block_h..y0 + (by + 1) * g.block_h {
                for x in x0 + bx * g.block_w..x0 + (bx + 1) * g.block_w {
                    sum += u32::from(r.count(x, y));
                }
            }
            sum
        };
        for by in 0..g.grid_h {
            for bx in 0..g.grid_w {
                assert!(block_sum(&s, bx, by) <= g.fifo_len);
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
        assert_eq!(block_sum(&s, bx, by), g.fifo_len);
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
        assert!((0..w * h).all(|p| reader.count(p % w, p / w) == expected.count(p % w, p / w)));
    }
}
