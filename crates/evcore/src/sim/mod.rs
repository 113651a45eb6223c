//! Event-camera sensor model: linear-intensity frames in, time-sorted change-detection events out.
//!
//! The model is ESIM's (per-pixel threshold crossings in log space, linearly interpolated in
//! time) with the noise sources of v2e and Prophesee's `video_to_event` simulator. Choices, and
//! where they depart from those references:
//!
//! * **Log intensity.** Frames hold linear intensity (f32 ≥ 0, 1 = full white) on the raw
//!   (distorted) `width`×`height` grid, row-major. The pixel sees L = ln(ε + I) with
//!   ε = [`SimParams::log_eps`] (default 1e-3, ESIM's value): it bounds black pixels at
//!   ln ε ≈ −6.9, i.e. a dynamic range of ~60 dB below white, and keeps sensor noise in the dark
//!   from producing unbounded contrast.
//! * **Crossings.** Between frames k and k+1 each pixel's L moves linearly from L₀ to L₁. Every
//!   level ref ± n·C passed on the way fires one event at t₀ + (level − L₀)/(L₁ − L₀)·Δt, rounded
//!   to the nearest microsecond (so within ±0.5 µs of the interpolated time, and never outside
//!   [t₀, t₁]); the reference moves to the level. Several events per pixel per interval are
//!   normal for fast edges.
//! * **Threshold mismatch.** Each pixel draws its ON and OFF thresholds once, at construction,
//!   from N(C, σ_C) clamped to ≥ 0.01: a fixed pattern, as in v2e and the Prophesee simulator
//!   and as in real sensors. ESIM instead redraws the threshold per pixel and per interval,
//!   which turns mismatch into temporal noise; we do not.
//! * **Refractory period.** After an event a pixel is silent for `refractory_us`. A crossing that
//!   falls inside that window is dropped **and its level is still consumed**: the reference
//!   advances as if it had fired (ESIM). v2e does the opposite — only emitted events move the
//!   reference, so suppressed crossings fire later; ESIM's rule loses them, which is what a
//!   saturated comparator does and keeps the event count bounded by the contrast.
//! * **Leak.** The reference drifts down by `leak_rate_hz`·r·C_on per second (v2e), so a static
//!   pixel emits ON events at `leak_rate_hz`·r. The per-pixel factor r is log-normal,
//!   10^(d·N(0,1)) with d = `leak_rate_spread_decades` (v2e), divided by its mean so that the
//!   sensor-wide mean rate equals `leak_rate_hz` (v2e does not normalise; its mean is a few
//!   percent high). v2e's temporal leak jitter is not modelled. The drift is folded into the
//!   interval's line, so leak events get interpolated timestamps like signal events.
//! * **Shot noise.** Each pixel fires spurious events as a Poisson process of rate
//!   `shot_noise_rate_hz` in the dark, half ON and half OFF (v2e). With
//!   `shot_noise_bright_factor` b ≠ 1 the rate scales by 1 + (b − 1)·clamp(I, 0, 1) of the new
//!   frame (v2e's dependence uses b = 0.25: full rate in the dark, a quarter at white). Unlike
//!   v2e, which draws a Bernoulli per frame (at most one per polarity) and stamps it with the
//!   frame time, arrivals are exact Poisson with uniform times inside the interval, so rates
//!   do not depend on the frame rate. A noise event resets the reference to the current level
//!   (v2e), which also restarts the leak build-up: with the `noisy` preset the static event rate
//!   is therefore close to the shot rate alone. Noise respects the refractory period; a
//!   suppressed noise event does nothing. v2e's scaling of shot rate by θ_nominal/θ_pixel is
//!   left out so that the configured rate is the mean rate.
//! * **Output.** Each step's events are sorted by time, ties broken by row-major pixel index
//!   and then by generation order, in [`EventBatch`] (EventCD convention: p = 1 ON, 0 OFF).
//!   All times of a step lie in [t₀, t₁], so consecutive steps concatenate into a sorted stream.
//! * **Determinism.** Thresholds and leak factors come from per-row streams of (seed, row); the
//!   shot noise of step k, row y from a stream of (seed, k, y). Rows are processed in parallel
//!   (rayon) but never share a generator, so events are bit-identical for any thread count.
//! * **Region of interest.** [`EventSimulator::step_roi`] updates only the pixels of a region,
//!   like the sensor's hardware ROI: pixels outside it emit nothing (no signal, leak or shot
//!   noise) and keep their state untouched, including the leak drift they would have
//!   accumulated. When such a pixel is next updated, the whole change since its last update is
//!   interpolated over that step's interval; keep a margin around moving content. Full
//!   [`EventSimulator::step`] calls give the full sensor's noise statistics.
//!
//! Not modelled: the photoreceptor low-pass (v2e `cutoff_hz`, intensity-dependent bandwidth),
//! read-out latency and bandwidth limits (ERC), and motion blur over the exposure.

pub mod camera;
mod ln;
mod params;
mod pixel;
mod tiles;

pub use params::{SimParams, PRESETS};
pub use pixel::SEGMENT_PX;

use crate::error::{ensure, Error, Result};
use crate::event::EventBatch;
use crate::image::Roi;
use crate::rng::Rng;
use pixel::{Interval, RawEvent, Row};
use rayon::prelude::*;

/// Tile height of [`EventSimulator::step_tiles`]; tiles are as wide as a row segment.
pub const TILE_PX: u32 = SEGMENT_PX as u32;

/// Smallest per-pixel threshold after mismatch (log units), as in v2e, ESIM and Prophesee.
pub const MIN_THRESHOLD: f64 = 0.01;

/// Refuse steps whose expected noise events per pixel exceed this: a long interval at a high
/// noise rate would otherwise allocate without bound.
const MAX_NOISE_EVENTS_PER_PIXEL_STEP: f64 = 1000.0;

/// Random streams are keyed by purpose so that, e.g., threshold draws never correlate with
/// the shot noise of some step.
const STREAM_FIXED_PATTERN: u64 = 0x5EED_F1E1D;
const STREAM_SHOT: u64 = 0x5EED_5407;
const STREAM_HOT: u64 = 0x5EED_4077;

/// Whether every value of `c` is a linear intensity: finite and ≥ 0 ([0, ∞) excludes NaN and
/// infinities). A non-short-circuiting fold, so it vectorises.
fn intensities_valid(c: &[f32]) -> bool {
    c.iter()
        .fold(true, |ok, &v| ok & (0.0..f32::INFINITY).contains(&v))
}

/// The error of a frame that [`intensities_valid`] refuses.
fn invalid_intensities() -> String {
    "frame intensities must be finite and >= 0 (linear intensity)".into()
}

/// Generator for one (seed, purpose, a, b) tuple; splitmix64's finaliser decorrelates nearby keys.
fn stream(seed: u64, purpose: u64, a: u64, b: u64) -> Rng {
    fn mix(mut x: u64) -> u64 {
        x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        x ^ (x >> 31)
    }
    Rng::new(mix(mix(mix(seed ^ mix(purpose)) ^ a) ^ b))
}

/// ESIM's adaptive sampling rule (method 1): the largest frame interval in microseconds such
/// that nothing moves more than `lambda` pixels between frames, Δt = λ / max‖flow‖, but never
/// longer than 1 / `min_rate_hz`. λ = 0.5 means at most half a pixel per sample.
/// Rounded down, at least 1 µs.
pub fn adaptive_dt_us(max_flow_px_per_s: f64, lambda: f64, min_rate_hz: f64) -> Result<i64> {
    ensure(
        max_flow_px_per_s.is_finite() && max_flow_px_per_s >= 0.0,
        || format!("max_flow_px_per_s must be finite and >= 0, got {max_flow_px_per_s}"),
    )?;
    ensure(lambda.is_finite() && lambda > 0.0, || {
        format!("lambda must be finite and > 0, got {lambda}")
    })?;
    ensure(min_rate_hz.is_finite() && min_rate_hz > 0.0, || {
        format!("min_rate_hz must be finite and > 0, got {min_rate_hz}")
    })?;
    let cap_s = 1.0 / min_rate_hz;
    let dt_s = if max_flow_px_per_s > 0.0 {
        (lambda / max_flow_px_per_s).min(cap_s)
    } else {
        cap_s
    };
    // The float-to-int cast saturates, so an absurdly low floor rate cannot overflow.
    Ok(((dt_s * 1e6).floor() as i64).max(1))
}

/// The sensor model; see the module documentation for the semantics.
#[derive(Debug, Clone)]
pub struct EventSimulator {
    width: u32,
    height: u32,
    params: SimParams,
    rows: Vec<Row>,
    /// Largest per-pixel leak rate (Hz), for the per-step noise budget check.
    max_leak_hz: f64,
    t_prev_us: Option<i64>,
    /// Frame intervals since the last reset; keys the shot-noise streams.
    step_index: u64,
    merged: Vec<RawEvent>,
    sort_keys: Vec<u128>,
}

impl EventSimulator {
    /// A `width`×`height` sensor (each 1..=65535, the range of EventCD coordinates). Draws the
    /// fixed-pattern thresholds and leak factors from `params.seed`.
    pub fn new(width: u32, height: u32, params: SimParams) -> Result<Self> {
        params.validate()?;
        ensure(
            (1..=u32::from(u16::MAX)).contains(&width)
                && (1..=u32::from(u16::MAX)).contains(&height),
            || format!("sensor size must be within 1..=65535 per side, got {width}x{height}"),
        )?;
        let spread = params.leak_rate_spread_decades * std::f64::consts::LN_10;
        // Mean of exp(spread·z) for z ~ N(0, 1); dividing by it makes the factor's mean 1.
        let factor_mean = (0.5 * spread * spread).exp();
        let mut max_leak_hz: f64 = 0.0;
        let rows: Vec<Row> = (0..height)
            .map(|y| {
                let mut rng = stream(params.seed, STREAM_FIXED_PATTERN, u64::from(y), 0);
                let mut row = Row::new(width as usize);
                for x in 0..width as usize {
                    let cp = (params.c_pos + params.sigma_c * rng.normal()).max(MIN_THRESHOLD);
                    let cn = (params.c_neg + params.sigma_c * rng.normal()).max(MIN_THRESHOLD);
                    let leak_hz = params.leak_rate_hz * (spread * rng.normal()).exp() / factor_mean;
                    max_leak_hz = max_leak_hz.max(leak_hz);
                    row.c_pos[x] = cp as f32;
                    row.c_neg[x] = cn as f32;
                    row.set_leak(x, (leak_hz * 1e-6 * f64::from(row.c_pos[x])) as f32);
                }
                if params.hot_pixel_fraction > 0.0 {
                    let mut rng = stream(params.seed, STREAM_HOT, u64::from(y), 0);
                    row.hot = (0..width)
                        .filter(|_| rng.uniform() < params.hot_pixel_fraction)
                        .collect();
                }
                row
            })
            .collect();
        Ok(Self {
            width,
            height,
            params,
            rows,
            max_leak_hz,
            t_prev_us: None,
            step_index: 0,
            merged: Vec::new(),
            sort_keys: Vec::new(),
        })
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    pub fn params(&self) -> &SimParams {
        &self.params
    }

    /// Time of the last frame taken (reset or step), if any.
    pub fn time_us(&self) -> Option<i64> {
        self.t_prev_us
    }

    /// Per-pixel (ON, OFF) thresholds in log units, row-major `width`×`height`.
    pub fn thresholds(&self) -> (Vec<f32>, Vec<f32>) {
        let on = self
            .rows
            .iter()
            .flat_map(|r| r.c_pos.iter().copied())
            .collect();
        let off = self
            .rows
            .iter()
            .flat_map(|r| r.c_neg.iter().copied())
            .collect();
        (on, off)
    }

    /// Row-major indices of the hot pixels.
    pub fn hot_pixels(&self) -> Vec<u32> {
        let w = self.width;
        self.rows
            .iter()
            .enumerate()
            .flat_map(|(y, r)| r.hot.iter().map(move |&x| y as u32 * w + x))
            .collect()
    }

    /// Per-pixel static leak-event rate in Hz, row-major.
    pub fn leak_rates_hz(&self) -> Vec<f64> {
        self.rows
            .iter()
            .flat_map(|r| {
                r.leak_per_us()
                    .iter()
                    .zip(&r.c_pos)
                    .map(|(&k, &c)| f64::from(k) / f64::from(c) * 1e6)
            })
            .collect()
    }

    /// Take `frame` at `t_us` as the new state: references at the current levels, no event
    /// history, step counter back to zero (so a reset simulator replays identically).
    /// Thresholds and leak factors are kept: they are properties of the sensor.
    pub fn reset(&mut self, frame: &[f32], t_us: i64) -> Result<()> {
        self.check_frame(frame, self.width, self.height)?;
        let eps = self.params.log_eps as f32;
        let w = self.width as usize;
        self.rows
            .par_iter_mut()
            .zip(frame.par_chunks(w))
            .for_each(|(row, f)| row.reset(f, eps, t_us));
        self.t_prev_us = Some(t_us);
        self.step_index = 0;
        Ok(())
    }

    /// Advance the whole sensor to `frame` at `t_us` (strictly after the previous frame) and
    /// put the interval's events, time-sorted, in `out` (cleared first). The first frame a
    /// simulator sees only initialises it (as [`Self::reset`]) and yields no events.
    pub fn step(&mut self, frame: &[f32], t_us: i64, out: &mut EventBatch) -> Result<()> {
        if self.t_prev_us.is_none() {
            self.reset(frame, t_us)?;
            out.clear();
            return Ok(());
        }
        self.check_frame(frame, self.width, self.height)?;
        let roi = Roi::full(self.width, self.height);
        self.advance(frame, roi, t_us, out)
    }

    /// Advance only the pixels of `roi` to `frame_roi` (row-major `roi.width`×`roi.height`) at
    /// `t_us`; the rest of the sensor emits nothing and keeps its state (module docs). Needs a
    /// prior [`Self::reset`] or [`Self::step`], since a region cannot initialise the sensor.
    pub fn step_roi(
        &mut self,
        frame_roi: &[f32],
        roi: Roi,
        t_us: i64,
        out: &mut EventBatch,
    ) -> Result<()> {
        ensure(self.t_prev_us.is_some(), || {
            "step_roi before the sensor was initialised by reset or step".into()
        })?;
        ensure(
            roi.width > 0
                && roi.height > 0
                && u64::from(roi.x0) + u64::from(roi.width) <= u64::from(self.width)
                && u64::from(roi.y0) + u64::from(roi.height) <= u64::from(self.height),
            || {
                format!(
                    "ROI {roi:?} is empty or leaves the {}x{} sensor",
                    self.width, self.height
                )
            },
        )?;
        self.check_frame(frame_roi, roi.width, roi.height)?;
        self.advance(frame_roi, roi, t_us, out)
    }

    /// Number of [`TILE_PX`]-square tiles across and down (the last ones may be partial).
    pub fn tiles(&self) -> (usize, usize) {
        (
            (self.width as usize).div_ceil(SEGMENT_PX),
            (self.height as usize).div_ceil(TILE_PX as usize),
        )
    }

    /// Advance the whole sensor to `frame` (all `width`×`height` pixels) at `t_us`, like
    /// [`Self::step`], but touching only the pixels that can fire: those of the tiles flagged in
    /// `changed` (row-major over [`Self::tiles`]), plus any row segment with a shot-noise arrival
    /// or a leak event due. The caller guarantees that every pixel of an unflagged tile has the
    /// intensity it had when last stepped (a rendered frame knows which tiles it redrew); then
    /// the events equal a full [`Self::step`]'s — bit for bit without leak, and up to f32
    /// rounding of the accumulated leak with it. Only changed tiles are validated.
    /// Mixing with [`Self::step_roi`]: the row segments a ROI step touches count as up to date.
    pub fn step_tiles(
        &mut self,
        frame: &[f32],
        changed: &[bool],
        t_us: i64,
        out: &mut EventBatch,
    ) -> Result<()> {
        ensure(self.t_prev_us.is_some(), || {
            "step_tiles before the sensor was initialised by reset or step".into()
        })?;
        let w = self.width as usize;
        ensure(frame.len() == w * self.height as usize, || {
            format!(
                "frame has {} values, expected {}x{}",
                frame.len(),
                self.width,
                self.height
            )
        })?;
        let (tx, ty) = self.tiles();
        ensure(changed.len() == tx * ty, || {
            format!("{} tile flags for {tx}x{ty} tiles", changed.len())
        })?;
        let valid = frame.par_chunks(w).enumerate().all(|(y, row)| {
            let flags = &changed[y / TILE_PX as usize * tx..][..tx];
            row.chunks(SEGMENT_PX)
                .zip(flags)
                .filter(|(_, &f)| f)
                .all(|(c, _)| intensities_valid(c))
        });
        ensure(valid, invalid_intensities)?;
        let iv = self.interval(t_us)?;
        let (seed, k) = (self.params.seed, self.step_index);
        self.rows
            .par_iter_mut()
            .zip(frame.par_chunks(w))
            .enumerate()
            .for_each(|(y, (row, f))| {
                let flags = &changed[y / TILE_PX as usize * tx..][..tx];
                let mut rng = stream(seed, STREAM_SHOT, k, y as u64);
                row.step_segments(f, flags, (y * w) as u32, &iv, &mut rng);
            });
        self.t_prev_us = Some(t_us);
        self.step_index += 1;
        self.collect(0, self.height as usize, iv.t0_us, out);
        Ok(())
    }

    fn check_frame(&self, frame: &[f32], w: u32, h: u32) -> Result<()> {
        let n = w as usize * h as usize;
        ensure(frame.len() == n, || {
            format!("frame has {} values, expected {w}x{h} = {n}", frame.len())
        })?;
        ensure(
            frame.par_chunks(1 << 14).all(intensities_valid),
            invalid_intensities,
        )
    }

    fn interval(&self, t_us: i64) -> Result<Interval> {
        let t0 = self.t_prev_us.unwrap_or(t_us);
        let dt_us = t_us.checked_sub(t0).filter(|dt| *dt > 0).ok_or_else(|| {
            Error::InvalidArgument(format!(
                "frame time {t_us} µs is not after the previous frame at {t0} µs"
            ))
        })?;
        let p = &self.params;
        let bright = p.shot_noise_bright_factor.max(1.0);
        let noise_per_step =
            (self.max_leak_hz + p.shot_noise_rate_hz * bright + p.hot_pixel_rate_hz)
                * dt_us as f64
                * 1e-6;
        ensure(noise_per_step <= MAX_NOISE_EVENTS_PER_PIXEL_STEP, || {
            format!("a {dt_us} µs interval expects {noise_per_step:.0} noise events per pixel; step more often")
        })?;
        Ok(Interval {
            t0_us: t0,
            dt_us,
            refractory_us: p.refractory_us,
            log_eps: p.log_eps as f32,
            shot_per_us: p.shot_noise_rate_hz * 1e-6,
            shot_bright_factor: p.shot_noise_bright_factor,
            hot_per_us: p.hot_pixel_rate_hz * 1e-6,
        })
    }

    /// The shared body of `step` and `step_roi`; `frame` covers exactly `roi` (validated).
    fn advance(&mut self, frame: &[f32], roi: Roi, t_us: i64, out: &mut EventBatch) -> Result<()> {
        let iv = self.interval(t_us)?;
        let (seed, k, w) = (self.params.seed, self.step_index, self.width);
        let (x0, y0, rw, rh) = (
            roi.x0 as usize,
            roi.y0 as usize,
            roi.width as usize,
            roi.height as usize,
        );
        self.rows[y0..y0 + rh]
            .par_iter_mut()
            .zip(frame.par_chunks(rw))
            .enumerate()
            .for_each(|(dy, (row, f))| {
                let y = (y0 + dy) as u32;
                let mut rng = stream(seed, STREAM_SHOT, k, u64::from(y));
                row.step(f, x0, y * w + x0 as u32, &iv, &mut rng);
            });
        self.t_prev_us = Some(t_us);
        self.step_index += 1;
        self.collect(y0, y0 + rh, iv.t0_us, out);
        Ok(())
    }

    /// Merge the events of rows `y0 .. y1` of the step that began at `t0_us` into `out`, sorted.
    fn collect(&mut self, y0: usize, y1: usize, t0_us: i64, out: &mut EventBatch) {
        let w = self.width;
        self.merged.clear();
        for row in &self.rows[y0..y1] {
            self.merged.extend_from_slice(&row.events);
        }
        // One u128 per event, (time offset, pixel, position in `merged`): unique keys make an
        // unstable sort deterministic, and a pixel's own events sit in `merged` in generation
        // order, so equal (time, pixel) keeps it. Positions fit 32 bits: 2³² events would be a
        // 64 GB step. Sorting plain integers is several times faster than a stable struct sort.
        let keys = &mut self.sort_keys;
        keys.clear();
        keys.extend(self.merged.iter().enumerate().map(|(pos, e)| {
            let off = (e.t_us - t0_us) as u64;
            (u128::from(off) << 64) | (u128::from(e.idx) << 32) | pos as u128
        }));
        keys.par_sort_unstable();
        out.clear();
        let n = keys.len();
        out.x.reserve(n);
        out.y.reserve(n);
        out.p.reserve(n);
        out.t_us.reserve(n);
        for &key in keys.iter() {
            let e = &self.merged[(key as u32) as usize];
            // Indices are < 65535² so both coordinates fit u16 (checked in `new`).
            out.push(
                (e.idx % w) as u16,
                (e.idx / w) as u16,
                i16::from(e.on),
                e.t_us,
            );
        }
    }
}

#[cfg(test)]
mod tests;
