//! Is the evidence behind a pose fresh? The front-ends count events rather than time, so when the
//! object's events stop (it is hidden, it left, the light went out) the active set keeps its last
//! edges indefinitely, and a pose sitting on them looks perfectly supported. What gives it away is
//! time: an object that was moving in the image must keep firing where its edges are.
//!
//! [`Recency`] keeps, per block of sensor pixels, the time of the newest event there (and, while the
//! tracker is lost, per pixel, for the global search's `explained` share: see
//! [`Recency::pixel_fired_since`]). It is written
//! by the ingest half of the tracker (the caller's thread) and read by the solver thread, so it is a
//! table of atomics: one writer stores, readers load, no lock and no read-modify-write (event times
//! only grow, so the newest store is the maximum). [`MotionMemory`] keeps the image speed of the
//! model the recent poses imply, and remembers it for a while: an estimate parked on stale edges
//! stops moving at once, but a real object cannot stop instantly, so the speed it *was* moving at is
//! what tells how fresh its edges must be.

use crate::camera::Camera;
use crate::image::Roi;
use crate::se3::Pose;
use crate::solve::cost::{Pinhole, Rigid32};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicI64, AtomicU32, Ordering};

/// log2 of the side of a recency block (sensor pixels): 8×8 blocks.
const BLOCK_SHIFT: u32 = 3;

/// Newest event time (µs) per 8×8 block of sensor pixels (and, while the solver asks, per pixel),
/// shared by ingest (writer) and solver.
#[derive(Debug)]
pub struct Recency {
    blocks_x: usize,
    blocks_y: usize,
    /// Rectified width and, for each rectified pixel, the index of the sensor block it is seen in
    /// (`u32::MAX` where it falls outside the sensor).
    rect_width: usize,
    block_of_rect: Vec<u32>,
    last_us: Vec<AtomicI64>,
    /// Sensor width, and for each rectified pixel the index of the sensor pixel it is seen at
    /// (`u32::MAX` outside the sensor).
    sensor_width: usize,
    pixel_of_rect: Vec<u32>,
    /// The low 32 bits of the newest event time (µs) per sensor pixel: the block's exact time
    /// minus these, taken modulo 2^32, is the pixel's age behind its block (see
    /// [`Recency::pixel_fired_since`]). Written only from `pixels_from_us` on.
    pixel_us: Vec<AtomicU32>,
    /// Event time (µs) from which every event has been stamped into `pixel_us` (`i64::MAX`: the
    /// per-pixel times are not being kept). The store into a sensor-sized table makes ingest
    /// 1.3–1.4× as dear (criterion `ingest_push_32mevs_*`), so it is paid only while the solver
    /// asks for it (`pixels_wanted`: searching globally).
    pixels_from_us: AtomicI64,
    pixels_wanted: AtomicBool,
}

impl Recency {
    /// For `sensor` (raw geometry) and its rectified grid `rect`.
    pub fn new(sensor: &Camera, rect: &Camera) -> Self {
        let blocks_x = sensor.width.div_ceil(1 << BLOCK_SHIFT) as usize;
        let blocks_y = sensor.height.div_ceil(1 << BLOCK_SHIFT) as usize;
        let sensor_pixel = |u: u32, v: u32| {
            let (x, y) = sensor.distort_pixel(f64::from(u), f64::from(v));
            let (x, y) = (x.round(), y.round());
            (x >= 0.0 && y >= 0.0 && x < f64::from(sensor.width) && y < f64::from(sensor.height))
                .then_some((x as u32, y as u32))
        };
        let (mut block_of_rect, mut pixel_of_rect) = (Vec::new(), Vec::new());
        for v in 0..rect.height {
            for u in 0..rect.width {
                let (b, p) = sensor_pixel(u, v).map_or((u32::MAX, u32::MAX), |(x, y)| {
                    (
                        (y >> BLOCK_SHIFT) * blocks_x as u32 + (x >> BLOCK_SHIFT),
                        y * sensor.width + x,
                    )
                });
                block_of_rect.push(b);
                pixel_of_rect.push(p);
            }
        }
        Self {
            blocks_x,
            blocks_y,
            rect_width: rect.width as usize,
            block_of_rect,
            last_us: (0..blocks_x * blocks_y)
                .map(|_| AtomicI64::new(i64::MIN))
                .collect(),
            sensor_width: sensor.width as usize,
            pixel_of_rect,
            pixel_us: (0..sensor.width as usize * sensor.height as usize)
                .map(|_| AtomicU32::new(0))
                .collect(),
            pixels_from_us: AtomicI64::new(i64::MAX),
            pixels_wanted: AtomicBool::new(false),
        }
    }

    /// Note an event at sensor pixel (x, y) (validated) at `t_us`, in its pixel's time too when
    /// `per_pixel` (see [`Recency::keep_pixel_times`]). Single writer, times non-decreasing: a
    /// plain store keeps the newest.
    #[inline]
    pub fn record(&self, x: u16, y: u16, t_us: i64, per_pixel: bool) {
        let b = (y as usize >> BLOCK_SHIFT) * self.blocks_x + (x as usize >> BLOCK_SHIFT);
        self.last_us[b].store(t_us, Ordering::Relaxed);
        if per_pixel {
            self.pixel_us[y as usize * self.sensor_width + x as usize]
                .store(t_us as u32, Ordering::Relaxed);
        }
    }

    /// The reader asks for per-pixel times to be kept, or no longer.
    pub fn want_pixel_times(&self, wanted: bool) {
        self.pixels_wanted.store(wanted, Ordering::Relaxed);
    }

    /// Whether the reader asks for per-pixel times ([`Recency::want_pixel_times`]).
    pub fn pixel_times_wanted(&self) -> bool {
        self.pixels_wanted.load(Ordering::Relaxed)
    }

    /// Whether per-pixel times are being kept. The writer's side of [`Recency::keep_pixel_times`].
    pub fn keeps_pixel_times(&self) -> bool {
        self.pixels_from_us.load(Ordering::Relaxed) != i64::MAX
    }

    /// The writer: keep per-pixel times from the event at `from_us` on (every later event is
    /// recorded with `per_pixel`), or stop keeping them (None).
    pub fn keep_pixel_times(&self, from_us: Option<i64>) {
        self.pixels_from_us
            .store(from_us.unwrap_or(i64::MAX), Ordering::Release);
    }

    /// Did the sensor pixel that rectified pixel (u, v) is seen at fire at or after `since_us`?
    /// Its block must have (the exact test), and the pixel must be no older behind its block's
    /// newest event than the block is behind `since_us`. The per-pixel times keep only 32 bits,
    /// so a pixel silent for a multiple of 2^32 µs (71.6 min) to within that slack reads fresh.
    /// Per block alone, every pixel the front-end still holds in a block that fired counts: a
    /// moving object's older edge positions and the old noise of every block it crosses. That is
    /// the answer while per-pixel times have not been kept since `since_us`.
    #[inline]
    pub fn pixel_fired_since(&self, u: u32, v: u32, since_us: i64) -> bool {
        let i = v as usize * self.rect_width + u as usize;
        let (Some(&b), Some(&p)) = (self.block_of_rect.get(i), self.pixel_of_rect.get(i)) else {
            return false;
        };
        if b == u32::MAX {
            return false;
        }
        let block_us = self.last_us[b as usize].load(Ordering::Relaxed);
        if block_us < since_us {
            return false;
        }
        if since_us < self.pixels_from_us.load(Ordering::Acquire) {
            return true;
        }
        let behind =
            (block_us as u32).wrapping_sub(self.pixel_us[p as usize].load(Ordering::Relaxed));
        i64::from(behind) <= block_us - since_us
    }

    /// Forget every time (the time line restarts).
    pub fn reset(&self) {
        for t in &self.last_us {
            t.store(i64::MIN, Ordering::Relaxed);
        }
        for t in &self.pixel_us {
            t.store(0, Ordering::Relaxed);
        }
        self.keep_pixel_times(None);
    }

    fn block_at(&self, u: f32, v: f32) -> Option<usize> {
        if !(u >= 0.0 && v >= 0.0) {
            return None;
        }
        let (x, y) = (round_non_negative(u), round_non_negative(v));
        if x >= self.rect_width {
            return None;
        }
        match *self.block_of_rect.get(y * self.rect_width + x)? {
            u32::MAX => None,
            b => Some(b as usize),
        }
    }

    /// Newest event time of the block that rectified pixel (u, v) is seen in and its 8 neighbours
    /// (a pose trailing a fast object by a few pixels still sits next to its fresh edges);
    /// `i64::MIN` if none or outside the sensor.
    #[inline]
    pub fn last_us(&self, u: f32, v: f32) -> i64 {
        let Some(b) = self.block_at(u, v) else {
            return i64::MIN;
        };
        let (bx, by) = (b % self.blocks_x, b / self.blocks_x);
        let mut newest = i64::MIN;
        for y in by.saturating_sub(1)..(by + 2).min(self.blocks_y) {
            for x in bx.saturating_sub(1)..(bx + 2).min(self.blocks_x) {
                newest = newest.max(self.last_us[y * self.blocks_x + x].load(Ordering::Relaxed));
            }
        }
        newest
    }

    /// Clear the pixels of `mask` (row-major over `roi` of the rectified grid) whose block has no
    /// event since `since_us`: what remains is where things happen now, not what the front-end
    /// remembers.
    pub fn keep_fresh(&self, mask: &mut [u8], roi: Roi, since_us: i64) {
        for (dy, row) in mask.chunks_mut(roi.width as usize).enumerate() {
            let y = roi.y0 as usize + dy;
            let blocks = &self.block_of_rect[y * self.rect_width..][..self.rect_width];
            for (dx, m) in row.iter_mut().enumerate() {
                if *m == 0 {
                    continue;
                }
                let b = blocks[roi.x0 as usize + dx];
                if b == u32::MAX || self.last_us[b as usize].load(Ordering::Relaxed) < since_us {
                    *m = 0;
                }
            }
        }
    }
}

/// `u.round() as usize` for u ≥ 0 (ties away from zero), without the libm call `f32::round` is
/// on baseline x86-64 (a few per model point and update on the confidence path). Below 2^23 the
/// fraction u − ⌊u⌋ is exact in f32; from there on every f32 is an integer; ∞ saturates as the cast
/// does.
#[inline]
fn round_non_negative(u: f32) -> usize {
    let floor = u as usize;
    floor.saturating_add(usize::from(u - floor as f32 >= 0.5))
}

/// How busy the blocks under the projected model are against the blocks around it, over the same
/// recent window (fractions in [0, 1]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Activity {
    /// Fraction of the model's blocks (the sensor blocks its visible points fall in) that fired.
    pub on_model: f32,
    /// Fraction of the other blocks of the region around the model that fired: what the
    /// background and clutter alone make a block do.
    pub around: f32,
}

impl Activity {
    /// Firing of the model's blocks in excess of the blocks around them, as a share of the
    /// headroom (0: the model's blocks are as quiet or as busy as their surroundings).
    pub fn excess(&self) -> f32 {
        if self.around >= 1.0 {
            return 0.0;
        }
        ((self.on_model - self.around) / (1.0 - self.around)).clamp(0.0, 1.0)
    }
}

impl Recency {
    fn block_fired(&self, b: usize, since_us: i64) -> bool {
        self.last_us[b].load(Ordering::Relaxed) >= since_us
    }

    /// [`Activity`] since `since_us` of the blocks under the rectified pixels `uv` (all inside
    /// `region`) against the other blocks of `region` (rectified pixels), sampled every
    /// [`ACTIVITY_STRIDE_PX`]. `near_model` is scratch.
    pub fn activity(
        &self,
        uv: &[(f32, f32)],
        region: Roi,
        since_us: i64,
        near_model: &mut Vec<bool>,
    ) -> Activity {
        let s = ACTIVITY_STRIDE_PX as f32;
        let (gw, gh) = (
            region.width.div_ceil(ACTIVITY_STRIDE_PX) as usize,
            region.height.div_ceil(ACTIVITY_STRIDE_PX) as usize,
        );
        near_model.clear();
        near_model.resize(gw * gh, false);
        let (mut on, mut fired) = (0usize, 0usize);
        for &(u, v) in uv {
            let Some(b) = self.block_at(u, v) else {
                continue;
            };
            on += 1;
            fired += usize::from(self.block_fired(b, since_us));
            let gx = ((u - region.x0 as f32) / s) as usize;
            let gy = ((v - region.y0 as f32) / s) as usize;
            if gx < gw && gy < gh {
                near_model[gy * gw + gx] = true;
            }
        }
        if on == 0 {
            return Activity::default();
        }
        let (mut others, mut others_fired) = (0usize, 0usize);
        for gy in 0..gh {
            for gx in 0..gw {
                if near_model[gy * gw + gx] {
                    continue;
                }
                let (u, v) = (
                    region.x0 as f32 + (gx as f32 + 0.5) * s,
                    region.y0 as f32 + (gy as f32 + 0.5) * s,
                );
                if let Some(b) = self.block_at(u, v) {
                    others += 1;
                    others_fired += usize::from(self.block_fired(b, since_us));
                }
            }
        }
        Activity {
            on_model: fired as f32 / on as f32,
            around: if others == 0 {
                0.0
            } else {
                others_fired as f32 / others as f32
            },
        }
    }
}

/// Grid step (rectified pixels) of the blocks sampled around the model for [`Activity::around`]:
/// a fraction of blocks needs a few hundred samples, not all of them.
pub const ACTIVITY_STRIDE_PX: u32 = 16;

/// How long the speed a model was moving at is remembered (µs): about the time a robot arm needs
/// to bring a target from a fast move to rest.
pub const SPEED_MEMORY_US: f64 = 300_000.0;
/// Poses over this span (µs) measure the speed; longer than the tracker's jitter needs.
const SPEED_WINDOW_US: i64 = 20_000;
/// Below this image speed (pixels/s) no freshness is demanded: the tracker's own jitter is
/// about this, and a still object rightly sits on old events.
pub const STILL_PX_S: f32 = 60.0;
/// An edge moving at v pixels/s fires within about 1/v s per pixel; allow this many pixels of
/// motion (plus the floor below) before its support counts as stale.
const FRESH_PX: f32 = 4.0;
const FRESH_MIN_US: f32 = 8_000.0;

/// The model's recent image speed, remembered with a linear decay over [`SPEED_MEMORY_US`].
#[derive(Debug, Clone, Default)]
pub struct MotionMemory {
    history: VecDeque<(i64, Pose)>,
    expected_px_s: f32,
    expected_at_us: i64,
}

impl MotionMemory {
    /// Add the pose published at `t_us` and return the image speed (pixels/s) the model is expected
    /// to be moving at now: the larger of what the recent poses show and what it showed before,
    /// decayed.
    pub fn update(&mut self, t_us: i64, pose: &Pose, pin: &Pinhole, points: &[[f32; 3]]) -> f32 {
        while self
            .history
            .front()
            .is_some_and(|(t, _)| t_us - t > SPEED_WINDOW_US)
        {
            self.history.pop_front();
        }
        let decayed = match t_us - self.expected_at_us {
            dt if dt > 0 => {
                self.expected_px_s * (1.0 - dt as f64 / SPEED_MEMORY_US).max(0.0) as f32
            }
            _ => self.expected_px_s,
        };
        let measured = match self.history.front() {
            Some((t0, p0)) if t_us - t0 >= SPEED_WINDOW_US / 2 => {
                image_displacement_px(pin, p0, pose, points) / ((t_us - t0) as f32 * 1e-6)
            }
            _ => 0.0,
        };
        self.history.push_back((t_us, *pose));
        if measured >= decayed {
            self.expected_px_s = measured;
            self.expected_at_us = t_us;
        }
        measured.max(decayed)
    }

    /// Forget the motion (after a re-initialisation, when the old poses no longer mean anything).
    pub fn reset(&mut self) {
        *self = Self::default();
    }
}

/// How old (µs) the newest event near a supported point may be at `expected_px_s`; None when the
/// model is taken to be still and old events are as good as new.
pub fn max_age_us(expected_px_s: f32) -> Option<i64> {
    (expected_px_s >= STILL_PX_S).then(|| (FRESH_MIN_US + FRESH_PX / expected_px_s * 1e6) as i64)
}

/// Mean image displacement (pixels) of a few model points between two poses.
fn image_displacement_px(pin: &Pinhole, a: &Pose, b: &Pose, points: &[[f32; 3]]) -> f32 {
    let (ra, rb) = (Rigid32::from_pose(a), Rigid32::from_pose(b));
    let stride = (points.len() / 32).max(1);
    let (mut sum, mut n) = (0.0f32, 0usize);
    for &x in points.iter().step_by(stride) {
        if let (Some(p), Some(q)) = (pin.project(ra.apply(x)), pin.project(rb.apply(x))) {
            sum += ((p.0 - q.0).powi(2) + (p.1 - q.1).powi(2)).sqrt();
            n += 1;
        }
    }
    if n == 0 {
        0.0
    } else {
        sum / n as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Vector3};

    #[test]
    fn rounding_without_libm_matches_f32_round() {
        let mut rng = crate::rng::Rng::new(5);
        let mut cases = vec![
            0.0f32,
            0.5,
            1.5,
            2.5,
            0.5f32.next_down(),
            0.5f32.next_up(),
            1279.5,
            719.5f32.next_down(),
            8_388_607.5,
            8_388_608.0,
            16_777_217.0,
            3.0e9,
            f32::MAX,
            f32::INFINITY,
        ];
        cases.extend((0..10_000).map(|_| rng.below(1 << 24) as f32 / 8192.0));
        for u in cases {
            assert_eq!(round_non_negative(u), u.round() as usize, "{u}");
        }
    }

    #[test]
    fn recency_keeps_the_newest_time_per_block_across_threads() {
        // Without distortion, so that rectified pixels are sensor pixels.
        let cam = Camera::imx636().rectified();
        let r = std::sync::Arc::new(Recency::new(&cam, &cam));
        let writer = {
            let r = std::sync::Arc::clone(&r);
            std::thread::spawn(move || {
                r.record(20, 10, 300, false);
                r.record(22, 12, 500, false);
            })
        };
        writer.join().unwrap();
        assert_eq!(r.last_us(17.0, 9.5), 500);
        assert_eq!(r.last_us(28.0, 9.5), 500, "a neighbouring block counts");
        assert_eq!(r.last_us(40.0, 9.5), i64::MIN);
        assert_eq!(r.last_us(-1.0, 9.5), i64::MIN);
        assert_eq!(r.last_us(2000.0, 9.5), i64::MIN);
        let roi = Roi {
            x0: 16,
            y0: 8,
            width: 24,
            height: 2,
        };
        let mut mask = vec![1u8; 48];
        r.keep_fresh(&mut mask, roi, 400);
        assert_eq!(mask[..8], [1; 8], "the block that fired at 500 µs stays");
        assert_eq!(mask[8..24], [0; 16], "blocks without events are cleared");
        r.reset();
        assert_eq!(r.last_us(17.0, 9.5), i64::MIN);
        // With distortion, a rectified pixel reads the block of the sensor pixel it is seen at.
        let raw = Camera::imx636();
        let r = Recency::new(&raw, &raw.rectified());
        let (x, y) = raw.distort_pixel(100.0, 80.0);
        r.record(x.round() as u16, y.round() as u16, 7, false);
        assert!(
            (x - 100.0).abs() > 24.0,
            "the test needs a pixel distortion moves"
        );
        assert_eq!(r.last_us(100.0, 80.0), 7);
    }

    #[test]
    fn a_pixel_is_fresh_only_if_it_fired_itself_not_just_its_block() {
        let cam = Camera::imx636().rectified();
        let r = Recency::new(&cam, &cam);
        // Two pixels of one 8×8 block: (17, 9) at 300 µs, (22, 12) at 500 µs; then, past the 32 bits
        // the per-pixel times keep (71.6 min), (20, 10) of the same block fires.
        r.record(17, 9, 100, false);
        assert!(!r.keeps_pixel_times());
        assert!(
            r.pixel_fired_since(20, 10, 50),
            "without per-pixel times: its block's"
        );
        r.keep_pixel_times(Some(300));
        assert!(r.keeps_pixel_times());
        r.record(17, 9, 300, true);
        r.record(22, 12, 500, true);
        assert!(r.pixel_fired_since(22, 12, 400));
        assert!(
            !r.pixel_fired_since(17, 9, 400),
            "its block fired since, it did not"
        );
        assert!(r.pixel_fired_since(17, 9, 300) && r.pixel_fired_since(22, 12, 300));
        assert!(
            !r.pixel_fired_since(22, 12, 501),
            "nothing in the block since"
        );
        assert!(
            !r.pixel_fired_since(30, 9, 0),
            "another block that never fired"
        );
        assert!(!r.pixel_fired_since(5000, 9, 0), "outside the image");
        let later = (1i64 << 32) + 200;
        r.record(20, 10, later, true);
        assert!(r.pixel_fired_since(20, 10, later - 10));
        assert!(!r.pixel_fired_since(22, 12, later - 10));
        assert!(
            !r.pixel_fired_since(17, 9, later - 1000),
            "2^32 − 100 µs old: the wrapped difference does not make it fresh"
        );
        assert!(
            r.pixel_fired_since(17, 9, 299),
            "since before the per-pixel times were kept: its block's"
        );
        r.reset();
        assert!(!r.keeps_pixel_times());
        assert!(!r.pixel_fired_since(20, 10, 0));
    }

    #[test]
    fn a_model_that_stops_dead_is_still_expected_to_move() {
        let pin = Pinhole::at_level(&Camera::imx636(), 0);
        let points: Vec<[f32; 3]> = (0..64).map(|i| [0.001 * i as f32, 0.05, 0.0]).collect();
        let mut m = MotionMemory::default();
        let at = |x: f64| Isometry3::new(Vector3::new(x, 0.0, 0.6), Vector3::zeros());
        // 0.2 m/s at 0.6 m: fx · 0.2 / 0.6 px/s.
        let expect = pin.fx * 0.2 / 0.6;
        let mut speed = 0.0;
        for k in 0..50 {
            speed = m.update(k * 1000, &at(0.2 * k as f64 * 1e-3), &pin, &points);
        }
        assert!(
            (speed - expect).abs() < 0.03 * expect,
            "{speed} vs {expect}"
        );
        // Parked from 49 ms on: after 30 ms the memory still expects about 90 % of that speed.
        for k in 50..80 {
            speed = m.update(k * 1000, &at(0.2 * 49e-3), &pin, &points);
        }
        assert!((speed - 0.9 * expect).abs() < 0.04 * expect, "{speed}");
        assert!(max_age_us(speed).unwrap() < 25_000);
        // And forgets it after the memory span.
        for k in 80..400 {
            speed = m.update(k * 1000, &at(0.2 * 49e-3), &pin, &points);
        }
        assert!(speed < STILL_PX_S && max_age_us(speed).is_none(), "{speed}");
    }
}
