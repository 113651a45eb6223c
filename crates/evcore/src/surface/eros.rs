//! EROS, the Exponentially Reduced Ordinal Surface (`robotology/event-driven`, used by EDOPT).
//!
//! Each event multiplies the k×k patch around it by d^(1/k) and sets its own pixel to 255, so a
//! pixel loses a factor d after about k neighbouring events: decay follows local event count, not
//! time. The decay factor lives in each instance (the C++ keeps it in a function-static shared by
//! every surface, so a second surface with another d silently used the first one's).

use super::{check_grid, fill_roi, EventSurface};
use crate::error::{ensure, Result};
use crate::image::Roi;

/// Largest accepted patch side; bigger ones would cost more per event than the surface is worth.
const MAX_KERNEL_PX: u32 = 63;

#[derive(Debug, Clone)]
pub struct Eros {
    width: u32,
    height: u32,
    /// Patch side k (odd) and half-width h = k/2.
    kernel: usize,
    half: usize,
    /// Per-event multiplier d^(1/k).
    factor: f32,
    /// Values above this are active: 255·d^((k−½)/k), i.e. decayed by fewer than k neighbouring
    /// events since last touched. Half a step below 255·d so float rounding of the repeated
    /// products cannot flip the k-th decay either way.
    threshold: f32,
    /// (width + 2h) × (height + 2h), row-major; the h-pixel pad lets patches skip bounds checks.
    surface: Box<[f32]>,
}

impl Eros {
    /// Even `kernel_px` is raised by one (as the reference does); `decay` must lie in (0, 1).
    pub fn new(width: u32, height: u32, kernel_px: u32, decay: f32) -> Result<Self> {
        check_grid(width, height)?;
        ensure((1..=MAX_KERNEL_PX).contains(&kernel_px), || {
            format!("EROS kernel {kernel_px} px must be in 1..={MAX_KERNEL_PX}")
        })?;
        ensure(decay.is_finite() && decay > 0.0 && decay < 1.0, || {
            format!("EROS decay {decay} must be in (0, 1)")
        })?;
        let kernel = (kernel_px | 1) as usize;
        let half = kernel / 2;
        let k = kernel as f64;
        let factor = f64::from(decay).powf(1.0 / k) as f32;
        let threshold = (255.0 * f64::from(decay).powf((k - 0.5) / k)) as f32;
        let padded = (width as usize + 2 * half) * (height as usize + 2 * half);
        Ok(Self {
            width,
            height,
            kernel,
            half,
            factor,
            threshold,
            surface: vec![0.0; padded].into_boxed_slice(),
        })
    }

    pub fn kernel_px(&self) -> u32 {
        self.kernel as u32
    }

    /// Activity threshold on the 0–255 surface.
    pub fn threshold(&self) -> f32 {
        self.threshold
    }

    fn padded_width(&self) -> usize {
        self.width as usize + 2 * self.half
    }

    /// Surface value at (x, y), 0–255; 0 outside the grid.
    pub fn value(&self, x: u32, y: u32) -> f32 {
        if x >= self.width || y >= self.height {
            return 0.0;
        }
        self.surface[(y as usize + self.half) * self.padded_width() + x as usize + self.half]
    }
}

impl EventSurface for Eros {
    fn ingest(&mut self, pixels: &[u32], polarity: &[i16]) {
        let w = self.width as usize;
        let n_pixels = w * self.height as usize;
        let pw = self.padded_width();
        let (k, factor) = (self.kernel, self.factor);
        for &p in &pixels[..pixels.len().min(polarity.len())] {
            let p = p as usize;
            if p >= n_pixels {
                continue;
            }
            let (x, y) = (p % w, p / w);
            // In padded coordinates the patch's top-left corner is (x, y) and its centre (x+h, y+h).
            for row in self.surface[y * pw..].chunks_mut(pw).take(k) {
                for v in &mut row[x..x + k] {
                    *v *= factor;
                }
            }
            self.surface[(y + self.half) * pw + x + self.half] = 255.0;
        }
    }

    fn fill_mask(&self, roi: Roi, out: &mut [u8]) {
        let (w, pw, h) = (self.width as usize, self.padded_width(), self.half);
        fill_roi(self.width, self.height, roi, out, |start, dst| {
            let (x, y) = (start % w, start / w);
            let src = &self.surface[(y + h) * pw + x + h..][..dst.len()];
            for (d, &v) in dst.iter_mut().zip(src) {
                *d = u8::from(v > self.threshold);
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
        "eros"
    }

    fn reset(&mut self) {
        self.surface.fill(0.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn active(s: &Eros, x: u32, y: u32) -> bool {
        let mut m = [0u8];
        s.fill_mask(
            Roi {
                x0: x,
                y0: y,
                width: 1,
                height: 1,
            },
            &mut m,
        );
        m[0] == 1
    }

    #[test]
    fn decays_with_neighbouring_event_count() {
        let (w, k, d) = (40u32, 7u32, 0.7f32);
        let mut s = Eros::new(w, 30, k, d).unwrap();
        let at = |x: u32, y: u32| y * w + x;
        s.ingest(&[at(10, 10)], &[1]);
        assert_eq!(s.value(10, 10), 255.0);
        // Events outside the 7×7 patch (|dx| > 3) leave the pixel alone however many there are.
        s.ingest(&[at(14, 10); 100], &[0; 100]);
        assert_eq!(s.value(10, 10), 255.0);
        // Each event within the patch multiplies by d^(1/7): after 6 it is still active, after 7
        // it has lost the factor d = 0.7 and drops out.
        for j in 1..=7 {
            s.ingest(&[at(13, 7)], &[1]);
            let expected = 255.0 * 0.7f64.powf(f64::from(j) / 7.0);
            assert!(
                (f64::from(s.value(10, 10)) - expected).abs() < 1e-3,
                "after {j}: {}",
                s.value(10, 10)
            );
            assert_eq!(active(&s, 10, 10), j < 7, "after {j} neighbouring events");
        }
        assert!((s.value(10, 10) - 178.5).abs() < 1e-3);
        assert!(active(&s, 13, 7));
        // A second instance with another decay keeps its own factor (the C++ static bug).
        let mut other = Eros::new(w, 30, k, 0.3).unwrap();
        other.ingest(&[at(10, 10), at(11, 10)], &[1, 1]);
        assert!((f64::from(other.value(10, 10)) - 255.0 * 0.3f64.powf(1.0 / 7.0)).abs() < 1e-3);
    }

    #[test]
    fn events_at_the_border_stay_inside_the_pad() {
        let mut s = Eros::new(16, 12, 9, 0.5).unwrap();
        let corners = [0, 15, 11 * 16, 11 * 16 + 15];
        s.ingest(&corners, &[1; 4]);
        for (x, y) in [(0, 0), (15, 0), (0, 11), (15, 11)] {
            assert_eq!(s.value(x, y), 255.0);
        }
        assert_eq!(s.kernel_px(), 9);
        assert_eq!(Eros::new(16, 12, 8, 0.5).unwrap().kernel_px(), 9);
    }
}
