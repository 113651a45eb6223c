//! Anti-flicker: drop events from pixels that fire periodically at the mains flicker frequency.
//!
//! A lamp on 50 Hz (60 Hz) mains swings its brightness at 100 Hz (120 Hz), so every pixel that sees
//! it fires an ON burst and an OFF burst each period, forever, while a moving edge crosses a pixel
//! once. Per pixel and polarity the filter keeps the start time of the last burst (events closer
//! than a quarter period belong to the same burst) and counts how many consecutive bursts came one
//! flicker period apart (±15 %). From the second such period on, the pixel's events are dropped;
//! one burst off the rhythm (an edge, or the lamp switched off) resets it.

use crate::error::{ensure, Result};

/// Consecutive on-period bursts after which a pixel counts as flickering.
const PERIODIC_AFTER: u8 = 2;
/// Accepted deviation from the period, as a fraction of it.
const TOLERANCE: f64 = 0.15;

#[derive(Debug, Clone)]
pub struct FlickerFilter {
    width: u32,
    /// Flicker periods to reject (µs), e.g. 10 000 and 8 333 for both mains frequencies.
    periods_us: Vec<i64>,
    /// Per pixel and polarity (index 2·pixel + ON): start of the last burst (µs, wrapping u32).
    burst_start: Vec<u32>,
    /// Per pixel and polarity: consecutive bursts one period apart (saturating).
    periodic: Vec<u8>,
}

impl FlickerFilter {
    /// A filter for a `width`×`height` sensor rejecting flicker at each of `frequencies_hz`
    /// (light intensity frequencies: 100 Hz on 50 Hz mains, 120 Hz on 60 Hz).
    pub fn new(width: u32, height: u32, frequencies_hz: &[f64]) -> Result<Self> {
        ensure(!frequencies_hz.is_empty(), || {
            "anti-flicker needs at least one frequency".into()
        })?;
        for &f in frequencies_hz {
            ensure(f.is_finite() && (1.0..=10_000.0).contains(&f), || {
                format!("flicker frequency {f} Hz must be within 1..=10000 Hz")
            })?;
        }
        let n = 2 * width as usize * height as usize;
        Ok(Self {
            width,
            periods_us: frequencies_hz
                .iter()
                .map(|f| (1e6 / f).round() as i64)
                .collect(),
            burst_start: vec![0; n],
            periodic: vec![0; n],
        })
    }

    /// Whether to keep the event at raw pixel (x, y) with polarity `p` at time `t_us`; events of one
    /// pixel must come in time order (validated batches do).
    #[inline]
    pub fn pass(&mut self, x: u16, y: u16, p: i16, t_us: i64) -> bool {
        let k = 2 * (usize::from(y) * self.width as usize + usize::from(x)) + usize::from(p != 0);
        let dt = i64::from((t_us as u32).wrapping_sub(self.burst_start[k]));
        let shortest = self.periods_us.iter().min().copied().unwrap_or(0);
        if dt < shortest / 4 && self.periodic[k] != 0 {
            // Still inside the current burst of a pixel already on a rhythm.
            return self.periodic[k] < PERIODIC_AFTER;
        }
        let on_period = self
            .periods_us
            .iter()
            .any(|&period| ((dt - period).abs() as f64) <= TOLERANCE * period as f64);
        self.periodic[k] = if on_period {
            self.periodic[k].saturating_add(1)
        } else {
            0
        };
        self.burst_start[k] = t_us as u32;
        self.periodic[k] < PERIODIC_AFTER
    }

    /// Forget every pixel's history.
    pub fn reset(&mut self) {
        self.burst_start.fill(0);
        self.periodic.fill(0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    /// 400 lamp pixels flickering at 100 Hz (an ON and an OFF burst of 1-3 events per period, with
    /// jitter) for 0.5 s, and an edge sweeping across other pixels once, firing 2 events per pixel.
    #[test]
    fn drops_mains_flicker_and_keeps_a_moving_edge() {
        let (w, h) = (200u32, 100u32);
        let mut rng = Rng::new(4);
        let mut events: Vec<(u16, u16, i16, i64, bool)> = Vec::new();
        for lamp in 0..400u32 {
            let (x, y) = ((lamp % 40) as u16, (lamp / 40) as u16);
            let phase = rng.below(10_000) as i64;
            for cycle in 0..50i64 {
                for (p, offset) in [(1i16, 0i64), (0, 5_000)] {
                    let t0 = phase + cycle * 10_000 + offset + rng.below(300) as i64;
                    for k in 0..1 + rng.below(3) as i64 {
                        events.push((x, y, p, t0 + 40 * k, true));
                    }
                }
            }
        }
        for col in 0..150u32 {
            for row in 0..h {
                let t = i64::from(col) * 3_000 + rng.below(500) as i64;
                events.push(((50 + col) as u16, row as u16, 1, t, false));
                events.push(((50 + col) as u16, row as u16, 1, t + 100, false));
            }
        }
        events.sort_by_key(|e| e.3);
        let mut f = FlickerFilter::new(w, h, &[100.0, 120.0]).unwrap();
        let (mut lamp_kept, mut lamp_all, mut edge_kept, mut edge_all) = (0, 0, 0, 0);
        for &(x, y, p, t, lamp) in &events {
            let kept = f.pass(x, y, p, t);
            if lamp {
                lamp_all += 1;
                lamp_kept += usize::from(kept);
            } else {
                edge_all += 1;
                edge_kept += usize::from(kept);
            }
        }
        let (lamp_frac, edge_frac) = (
            lamp_kept as f64 / lamp_all as f64,
            edge_kept as f64 / edge_all as f64,
        );
        // A lamp pixel passes its first two or three periods (≈ 5 % of 50), then nothing.
        assert!(lamp_frac < 0.08, "flicker kept {lamp_frac:.3}");
        assert_eq!(edge_kept, edge_all, "edge kept {edge_frac:.3}");
        // Without the filter's rhythm the same pixels pass again: a lamp that stops is forgotten.
        f.reset();
        assert!(f.pass(0, 0, 1, 10_000_000));
        assert!(FlickerFilter::new(w, h, &[]).is_err());
        assert!(FlickerFilter::new(w, h, &[f64::NAN]).is_err());
    }
}
