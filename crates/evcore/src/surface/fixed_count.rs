//! Fixed-count front-end: the last N events of the whole sensor are active.
//!
//! The baseline SCARF is compared against. Because the window is global, how far back it reaches
//! on one object depends on how many events the rest of the scene (or noise) produces meanwhile,
//! so an object's trail grows and shrinks with its speed relative to everything else.

use super::{check_grid, fill_roi, EventSurface};
use crate::error::{ensure, Result};
use crate::image::Roi;

/// Largest accepted window (2^26 events, a 256 MiB ring); beyond that no grid stays sparse.
const MAX_EVENTS: usize = 1 << 26;

#[derive(Debug, Clone)]
pub struct FixedCount {
    width: u32,
    height: u32,
    /// The last N pixel indices, oldest at `head`; starts full of the spare index width·height.
    ring: Box<[u32]>,
    head: usize,
    /// Per pixel, how many ring entries hold it; the spare cell at the end starts at N so that the
    /// initial filler entries leave it exactly like real ones, without a "ring full yet" branch.
    counts: Box<[u32]>,
}

impl FixedCount {
    pub fn new(width: u32, height: u32, n_events: usize) -> Result<Self> {
        check_grid(width, height)?;
        ensure((1..=MAX_EVENTS).contains(&n_events), || {
            format!("fixed-count window {n_events} events must be in 1..={MAX_EVENTS}")
        })?;
        let n_pixels = width as usize * height as usize;
        let mut s = Self {
            width,
            height,
            ring: vec![0; n_events].into_boxed_slice(),
            head: 0,
            counts: vec![0; n_pixels + 1].into_boxed_slice(),
        };
        s.reset();
        Ok(s)
    }

    pub fn n_events(&self) -> usize {
        self.ring.len()
    }

    /// Number of window entries at pixel (x, y); 0 outside the grid.
    pub fn count(&self, x: u32, y: u32) -> u32 {
        if x >= self.width || y >= self.height {
            return 0;
        }
        self.counts[y as usize * self.width as usize + x as usize]
    }
}

impl EventSurface for FixedCount {
    fn ingest(&mut self, pixels: &[u32], polarity: &[i16]) {
        let spare = self.counts.len() - 1;
        for &p in &pixels[..pixels.len().min(polarity.len())] {
            if p as usize >= spare {
                continue;
            }
            let old = std::mem::replace(&mut self.ring[self.head], p);
            self.counts[old as usize] -= 1;
            self.counts[p as usize] += 1;
            self.head += 1;
            if self.head == self.ring.len() {
                self.head = 0;
            }
        }
    }

    fn fill_mask(&self, roi: Roi, out: &mut [u8]) {
        fill_roi(self.width, self.height, roi, out, |start, dst| {
            let src = &self.counts[start..start + dst.len()];
            for (d, &c) in dst.iter_mut().zip(src) {
                *d = u8::from(c != 0);
            }
        });
    }

    fn width(&self) -> u32 {
        self.width
    }

    fn height(&self) -> u32 {
        self.height
    }

    fn name(&self) -> &'static str {
        "fixed-count"
    }

    fn reset(&mut self) {
        let spare = self.counts.len() - 1;
        self.ring.fill(spare as u32);
        self.counts.fill(0);
        self.counts[spare] = self.ring.len() as u32;
        self.head = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exactly_the_last_n_events_are_active() {
        let (w, h, n) = (32u32, 24u32, 50usize);
        let mut s = FixedCount::new(w, h, n).unwrap();
        // 50 + 37 events at distinct pixels 0, 7, 14, ... (7 is coprime with 768, no repeats).
        let pixels: Vec<u32> = (0..(n + 37) as u32).map(|i| i * 7 % (w * h)).collect();
        let pol = vec![1i16; pixels.len()];
        s.ingest(&pixels[..20], &pol[..20]);
        s.ingest(&pixels[20..], &pol[20..]);
        let mut mask = vec![0u8; (w * h) as usize];
        s.fill_mask(Roi::full(w, h), &mut mask);
        let active: Vec<u32> = (0..w * h).filter(|&p| mask[p as usize] == 1).collect();
        let mut expected = pixels[37..].to_vec();
        expected.sort_unstable();
        assert_eq!(active, expected);
        // A repeated pixel stays active until its last occurrence leaves the window.
        s.ingest(&[5; 49], &[0; 49]);
        assert_eq!(s.count(5, 0), 49);
        s.fill_mask(Roi::full(w, h), &mut mask);
        assert_eq!(mask.iter().filter(|&&v| v == 1).count(), 2);
        assert_eq!(mask[pixels[n + 36] as usize], 1);
    }
}
