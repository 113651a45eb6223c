//! Event front-ends: turn a stream of rectified events into a binary "active" pixel set.
//!
//! All three work on the rectified grid (pixel index = y·width + x) and count events rather than
//! time, so none of them needs a clock:
//! - [`Scarf`]: per-block FIFOs of the last N events with a centre/surround split (velocity invariant);
//! - [`FixedCount`]: the last N events of the whole sensor;
//! - [`Eros`]: an exponentially reduced ordinal surface whose pixels decay with nearby events.

mod eros;
mod fixed_count;
mod flicker;
mod scarf;

pub use eros::Eros;
pub use fixed_count::FixedCount;
pub use flicker::FlickerFilter;
pub use scarf::{Scarf, ScarfGeometry, ScarfReader, ScarfWriter};

use crate::error::{ensure, Error, Result};
use crate::image::Roi;
use std::sync::{Arc, Mutex, PoisonError};

/// A front-end that ingests rectified events and reports which pixels are active.
pub trait EventSurface: Send + Sync {
    /// Ingest events at rectified pixel indices (y·width + x) with polarities (0 OFF, nonzero ON).
    /// Indices ≥ width·height are skipped; if the slices differ in length the extra tail of the
    /// longer one is ignored (SCARF, fixed-count and EROS all ignore polarity).
    fn ingest(&mut self, pixels: &[u32], polarity: &[i16]);
    /// Write 1 for active pixels and 0 otherwise for `roi` (row-major, roi.width·roi.height bytes).
    /// Parts of `roi` outside the grid read as 0; only the first `out.len()` bytes are written.
    fn fill_mask(&self, roi: Roi, out: &mut [u8]);
    fn width(&self) -> u32;
    fn height(&self) -> u32;
    fn name(&self) -> &'static str;
    /// Forget everything (as after construction).
    fn reset(&mut self);
}

/// Which front-end to build, with its parameters.
#[derive(Debug, Clone, PartialEq)]
pub enum FrontEnd {
    /// `block_px`: receptive-field side in pixels (odd values are raised by one);
    /// `alpha`: FIFO length factor, N = ⌊block area · alpha / 2⌋.
    Scarf { block_px: u32, alpha: f32 },
    /// `n_events`: how many of the most recent events are active.
    FixedCount { n_events: usize },
    /// `kernel_px`: decay patch side (even values are raised by one); `decay`: factor a pixel loses
    /// after about `kernel_px` neighbouring events, in (0, 1).
    Eros { kernel_px: u32, decay: f32 },
}

impl FrontEnd {
    /// SCARF as used for servoing in EDOPT+SCARF: 14-pixel blocks, alpha 1.
    pub fn scarf_default() -> Self {
        Self::Scarf {
            block_px: 14,
            alpha: 1.0,
        }
    }

    /// The accepted names, the only spellings [`FrontEnd::parse`] takes (the bindings hand this
    /// list to Python for its command-line choices).
    pub const NAMES: [&'static str; 3] = ["scarf", "fixed-count", "eros"];

    /// "scarf" (block 14, alpha 1), "fixed-count" (8000 events) or "eros" (k 7, d 0.7 as EDOPT's main.cpp).
    pub fn parse(name: &str) -> Result<Self> {
        match name {
            "scarf" => Ok(Self::scarf_default()),
            "fixed-count" => Ok(Self::FixedCount { n_events: 8000 }),
            "eros" => Ok(Self::Eros {
                kernel_px: 7,
                decay: 0.7,
            }),
            _ => Err(Error::InvalidArgument(format!(
                "unknown front-end {name:?}; choose one of {}",
                Self::NAMES.join(", ")
            ))),
        }
    }
}

/// Build the front-end `kind` for a `width`×`height` rectified grid, validating every parameter.
pub fn make_surface(kind: &FrontEnd, width: u32, height: u32) -> Result<Box<dyn EventSurface>> {
    Ok(match *kind {
        FrontEnd::Scarf { block_px, alpha } => {
            Box::new(Scarf::new(width, height, block_px, alpha)?)
        }
        FrontEnd::FixedCount { n_events } => Box::new(FixedCount::new(width, height, n_events)?),
        FrontEnd::Eros { kernel_px, decay } => {
            Box::new(Eros::new(width, height, kernel_px, decay)?)
        }
    })
}

/// The ingest half of a front-end split for two threads: exactly one, owned by whoever pushes events.
pub trait SurfaceWriter: Send {
    /// Ingest events at rectified pixel indices (y·width + x); indices ≥ width·height are skipped.
    fn ingest(&mut self, pixels: &[u32]);
    /// Forget every event.
    fn reset(&mut self);
    /// Another read handle onto the same active set.
    fn reader(&self) -> Arc<dyn SurfaceReader>;
}

/// The read half: any number of them, on any thread, while the writer ingests.
pub trait SurfaceReader: Send + Sync {
    /// As [`EventSurface::fill_mask`].
    fn fill_mask(&self, roi: Roi, out: &mut [u8]);
}

impl SurfaceWriter for ScarfWriter {
    fn ingest(&mut self, pixels: &[u32]) {
        ScarfWriter::ingest(self, pixels);
    }
    fn reset(&mut self) {
        ScarfWriter::reset(self);
    }
    fn reader(&self) -> Arc<dyn SurfaceReader> {
        Arc::new(ScarfWriter::reader(self))
    }
}

impl SurfaceReader for ScarfReader {
    fn fill_mask(&self, roi: Roi, out: &mut [u8]) {
        ScarfReader::fill_mask(self, roi, out);
    }
}

/// A front-end without a lock-free split (fixed-count, EROS) shared behind a mutex: ingest holds
/// it for one batch, a reader for one region's mask.
struct Locked(Arc<Mutex<Box<dyn EventSurface>>>);

impl Locked {
    fn with<T>(&self, f: impl FnOnce(&mut dyn EventSurface) -> T) -> T {
        // A panic while holding the lock cannot leave a surface half-built in a way that matters
        // more than a stale mask, so a poisoned lock is used as it is.
        f(self
            .0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .as_mut())
    }
}

/// Polarity is ignored by every front-end; the writer interface carries pixels only.
const NO_POLARITY: [i16; 4096] = [1; 4096];

impl SurfaceWriter for Locked {
    fn ingest(&mut self, pixels: &[u32]) {
        self.with(|s| {
            for chunk in pixels.chunks(NO_POLARITY.len()) {
                s.ingest(chunk, &NO_POLARITY[..chunk.len()]);
            }
        });
    }
    fn reset(&mut self) {
        self.with(|s| s.reset());
    }
    fn reader(&self) -> Arc<dyn SurfaceReader> {
        Arc::new(Locked(Arc::clone(&self.0)))
    }
}

impl SurfaceReader for Locked {
    fn fill_mask(&self, roi: Roi, out: &mut [u8]) {
        self.with(|s| s.fill_mask(roi, out));
    }
}

/// Build the front-end `kind` split into its writer and a reader: SCARF shares only its count
/// image (lock-free); the others share one instance behind a mutex.
pub fn split_surface(
    kind: &FrontEnd,
    width: u32,
    height: u32,
) -> Result<(Box<dyn SurfaceWriter>, Arc<dyn SurfaceReader>)> {
    if let FrontEnd::Scarf { block_px, alpha } = *kind {
        let (writer, reader) = Scarf::new(width, height, block_px, alpha)?.split();
        return Ok((Box::new(writer), Arc::new(reader)));
    }
    let shared = Arc::new(Mutex::new(make_surface(kind, width, height)?));
    Ok((
        Box::new(Locked(Arc::clone(&shared))),
        Arc::new(Locked(shared)),
    ))
}

/// Same bound as [`crate::Camera::new`]; keeps width·height below 2^28 so pixel indices, plus one
/// spare "nowhere" index, fit in a u32.
fn check_grid(width: u32, height: u32) -> Result<()> {
    ensure(
        (1..=16384).contains(&width) && (1..=16384).contains(&height),
        || format!("grid size {width}x{height} must be within 1..=16384 pixels"),
    )
}

/// Zero `out`, then call `row(first_pixel_index, dst)` for each in-grid run of `roi` so the
/// front-end only writes its activity test; clipping and short buffers are handled once here.
fn fill_roi(
    width: u32,
    height: u32,
    roi: Roi,
    out: &mut [u8],
    mut row: impl FnMut(usize, &mut [u8]),
) {
    out.fill(0);
    if roi.width == 0 {
        return;
    }
    let x_end = roi.x0.saturating_add(roi.width).min(width);
    let y_end = roi.y0.saturating_add(roi.height).min(height);
    if roi.x0 >= x_end {
        return;
    }
    let run = (x_end - roi.x0) as usize;
    for (dy, dst) in out.chunks_mut(roi.width as usize).enumerate() {
        let y = roi.y0 as usize + dy;
        if y >= y_end as usize {
            break;
        }
        let n = run.min(dst.len());
        row(y * width as usize + roi.x0 as usize, &mut dst[..n]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_names_and_reject_unknown() {
        assert_eq!(
            FrontEnd::parse("scarf").unwrap(),
            FrontEnd::Scarf {
                block_px: 14,
                alpha: 1.0
            }
        );
        assert_eq!(
            FrontEnd::parse("fixed-count").unwrap(),
            FrontEnd::FixedCount { n_events: 8000 }
        );
        // One spelling per front-end: no case or separator variants.
        for other in [" Fixed-Count ", "fixed_count", "SCARF"] {
            assert!(FrontEnd::parse(other).is_err(), "{other}");
        }
        for name in FrontEnd::NAMES {
            assert!(FrontEnd::parse(name).is_ok(), "{name}");
        }
        assert_eq!(
            FrontEnd::parse("eros").unwrap(),
            FrontEnd::Eros {
                kernel_px: 7,
                decay: 0.7
            }
        );
        assert!(matches!(
            FrontEnd::parse("sae"),
            Err(Error::InvalidArgument(_))
        ));
    }

    #[test]
    fn make_surface_validates() {
        assert!(make_surface(&FrontEnd::scarf_default(), 0, 480).is_err());
        assert!(make_surface(
            &FrontEnd::Scarf {
                block_px: 14,
                alpha: f32::NAN
            },
            640,
            480
        )
        .is_err());
        assert!(make_surface(
            &FrontEnd::Scarf {
                block_px: 400,
                alpha: 1.0
            },
            640,
            480
        )
        .is_err());
        assert!(make_surface(&FrontEnd::FixedCount { n_events: 0 }, 640, 480).is_err());
        assert!(make_surface(
            &FrontEnd::Eros {
                kernel_px: 7,
                decay: 1.0
            },
            640,
            480
        )
        .is_err());
        assert!(make_surface(
            &FrontEnd::Eros {
                kernel_px: 0,
                decay: 0.5
            },
            640,
            480
        )
        .is_err());
        for kind in ["scarf", "fixed-count", "eros"] {
            let s = make_surface(&FrontEnd::parse(kind).unwrap(), 640, 480).unwrap();
            assert_eq!((s.width(), s.height()), (640, 480));
            assert_eq!(s.name(), kind);
        }
    }

    /// Every front-end must shrug off out-of-range pixels, mismatched slices and ROIs that leave
    /// the grid or do not match the buffer, and still report the valid events.
    #[test]
    fn bad_input_is_skipped_not_fatal() {
        for kind in ["scarf", "fixed-count", "eros"] {
            let mut s = make_surface(&FrontEnd::parse(kind).unwrap(), 64, 48).unwrap();
            let inside = 20 * 64 + 20;
            s.ingest(&[u32::MAX, 64 * 48, inside, 5], &[1, 0, 1]);
            let mut full = vec![7u8; 64 * 48];
            s.fill_mask(Roi::full(64, 48), &mut full);
            assert_eq!(
                full.iter().map(|&v| usize::from(v)).sum::<usize>(),
                1,
                "{kind}"
            );
            assert_eq!(full[inside as usize], 1, "{kind}");
            // ROI hanging off the bottom-right corner: the in-grid part is copied, the rest is 0.
            let roi = Roi {
                x0: 18,
                y0: 18,
                width: 100,
                height: 100,
            };
            let mut out = vec![9u8; 100 * 100];
            s.fill_mask(roi, &mut out);
            assert_eq!(out[2 * 100 + 2], 1, "{kind}");
            assert_eq!(
                out.iter().map(|&v| usize::from(v)).sum::<usize>(),
                1,
                "{kind}"
            );
            let mut short = vec![9u8; 10];
            s.fill_mask(roi, &mut short);
            assert!(short.iter().all(|&v| v == 0), "{kind}");
            s.fill_mask(
                Roi {
                    x0: 1000,
                    y0: 0,
                    width: 4,
                    height: 4,
                },
                &mut short,
            );
            assert!(short.iter().all(|&v| v == 0), "{kind}");
            s.reset();
            s.fill_mask(Roi::full(64, 48), &mut full);
            assert!(full.iter().all(|&v| v == 0), "{kind}");
        }
    }
}
