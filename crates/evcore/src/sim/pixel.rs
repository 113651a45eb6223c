//! The per-row pixel kernel: threshold crossings, refractory gating, leak drift and shot noise
//! for one row of pixels over one frame interval. Rows are independent, so the caller runs
//! them in parallel, each with its own random stream.

use super::ln::ln;
use crate::rng::Rng;

/// `last_t_us` of a pixel that has never fired.
pub(super) const NEVER: i64 = i64::MIN;

/// Pixels per row segment: the unit in which [`Row::step_segments`] skips unchanged pixels.
pub const SEGMENT_PX: usize = 16;

/// `seg_due_us` of a segment that leak alone can never make fire.
const NEVER_DUE: i64 = i64::MAX;

/// Log-intensity slack subtracted before predicting a leak crossing: the state is f32, so the
/// crossing time is uncertain by a few ulps of the level; waking a segment early costs a quiet
/// pass, waking it late would misplace an event.
const DUE_SLACK_LOG: f64 = 1e-5;

/// One emitted event before the frame-wide sort; `idx` is the row-major pixel index.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct RawEvent {
    pub t_us: i64,
    pub idx: u32,
    pub on: bool,
}

/// A shot-noise arrival: column inside the processed span, fraction `s` ∈ [0, 1) of the interval.
#[derive(Debug, Clone, Copy)]
pub(super) struct Shot {
    col: u32,
    s: f64,
    on: bool,
}

/// What one frame interval looks like to every pixel.
#[derive(Debug, Clone, Copy)]
pub(super) struct Interval {
    pub t0_us: i64,
    pub dt_us: i64,
    pub refractory_us: i64,
    pub log_eps: f32,
    /// Shot-noise rate in the dark, per pixel and microsecond.
    pub shot_per_us: f64,
    /// Shot-rate multiplier at intensity 1.
    pub shot_bright_factor: f64,
    /// Extra noise rate of a hot pixel, per microsecond.
    pub hot_per_us: f64,
}

/// State and fixed-pattern constants of one sensor row, struct of arrays so the static-pixel
/// fast path touches as little memory as possible.
#[derive(Debug, Clone)]
pub(super) struct Row {
    pub prev_i: Vec<f32>,
    pub prev_l: Vec<f32>,
    pub ref_l: Vec<f32>,
    pub last_t_us: Vec<i64>,
    pub c_pos: Vec<f32>,
    pub c_neg: Vec<f32>,
    /// Leak drift of the reference, log units per microsecond ([`Self::set_leak`]).
    leak_per_us: Vec<f32>,
    /// Its reciprocal, microseconds per log unit (0 without leak): predicting a leak crossing
    /// for every pixel of every visited segment then multiplies instead of dividing, whose
    /// latency was a quarter of the sensor step's time.
    us_per_log_leak: Vec<f64>,
    /// Per [`SEGMENT_PX`] segment: the time its pixels were last brought up to date (µs), and
    /// the earliest time leak alone can make one of them fire (µs, [`NEVER_DUE`] if never).
    pub seg_t_us: Vec<i64>,
    pub seg_due_us: Vec<i64>,
    /// Columns of the row's hot pixels, ascending.
    pub hot: Vec<u32>,
    /// Scratch reused between steps to avoid per-step allocation.
    pub events: Vec<RawEvent>,
    shots: Vec<Shot>,
    busy: Vec<usize>,
}

/// Log intensity as the sensor model sees it; f32 because the frames are f32 and the state is
/// stored in f32. Every path of the model takes it through [`ln`], which vectorises, so a pixel
/// stepped in a segment's SIMD pass and one stepped alone see the same level.
#[inline(always)]
pub(super) fn log_intensity(i: f32, log_eps: f32) -> f32 {
    ln(log_eps + i)
}

impl Row {
    /// Set pixel `x`'s leak drift (log units per microsecond, >= 0).
    pub fn set_leak(&mut self, x: usize, leak_per_us: f32) {
        self.leak_per_us[x] = leak_per_us;
        self.us_per_log_leak[x] = if leak_per_us > 0.0 {
            1.0 / f64::from(leak_per_us)
        } else {
            0.0
        };
    }

    pub fn leak_per_us(&self) -> &[f32] {
        &self.leak_per_us
    }

    pub fn new(width: usize) -> Self {
        Self {
            prev_i: vec![0.0; width],
            prev_l: vec![0.0; width],
            ref_l: vec![0.0; width],
            last_t_us: vec![NEVER; width],
            c_pos: vec![0.0; width],
            c_neg: vec![0.0; width],
            leak_per_us: vec![0.0; width],
            us_per_log_leak: vec![0.0; width],
            seg_t_us: vec![0; width.div_ceil(SEGMENT_PX)],
            seg_due_us: vec![NEVER_DUE; width.div_ceil(SEGMENT_PX)],
            hot: Vec::new(),
            events: Vec::new(),
            shots: Vec::new(),
            busy: Vec::new(),
        }
    }

    /// Set every pixel to the intensities `frame` (the whole row) with its reference at the
    /// current level and no event history.
    pub fn reset(&mut self, frame: &[f32], log_eps: f32, t_us: i64) {
        for (x, &i) in frame.iter().enumerate() {
            let l = log_intensity(i, log_eps);
            self.prev_i[x] = i;
            self.prev_l[x] = l;
            self.ref_l[x] = l;
            self.last_t_us[x] = NEVER;
        }
        self.mark_segments(0, frame.len(), t_us);
        self.events.clear();
    }

    /// Record that columns `x0 .. x1` are up to date at `t_us`. Their leak due time is set to
    /// `t_us`, so the next [`Self::step_segments`] visits them and predicts it afresh.
    fn mark_segments(&mut self, x0: usize, x1: usize, t_us: i64) {
        if x1 > x0 {
            let segs = x0 / SEGMENT_PX..(x1 - 1) / SEGMENT_PX + 1;
            self.seg_t_us[segs.clone()].fill(t_us);
            self.seg_due_us[segs].fill(t_us);
        }
    }

    /// Draw shot-noise arrivals for columns `x0 .. x0 + frame.len()` over the interval into
    /// `self.shots`, sorted by column then time.
    ///
    /// The row's pixel-time plane is laid end to end as one line of length n·Δt and a Poisson
    /// process at the highest per-pixel rate is run along it (exponential gaps), then thinned by
    /// each pixel's intensity-dependent rate: exact Poisson statistics at a cost proportional to
    /// the number of arrivals, not of pixels.
    fn sample_shots(&mut self, frame: &[f32], iv: &Interval, rng: &mut Rng) {
        self.shots.clear();
        self.sample_dark_shots(frame, iv, rng);
        self.sample_hot_shots(frame.len(), iv, rng);
    }

    /// Every pixel's shot noise (see [`Self::sample_shots`]).
    fn sample_dark_shots(&mut self, frame: &[f32], iv: &Interval, rng: &mut Rng) {
        if iv.shot_per_us <= 0.0 {
            return;
        }
        let dt = iv.dt_us as f64;
        let max_factor = iv.shot_bright_factor.max(1.0);
        let rate = iv.shot_per_us * max_factor;
        let length = frame.len() as f64 * dt;
        let mut pos = 0.0;
        loop {
            // 1 − u lies in (0, 1], so the log is finite.
            pos += -(1.0 - rng.uniform()).ln() / rate;
            if pos >= length {
                return;
            }
            let col = ((pos / dt) as usize).min(frame.len() - 1);
            let s = ((pos - col as f64 * dt) / dt).clamp(0.0, 1.0);
            let bright = f64::from(frame[col]).clamp(0.0, 1.0);
            let factor = 1.0 + (iv.shot_bright_factor - 1.0) * bright;
            let keep = rng.uniform() * max_factor < factor;
            let on = rng.uniform() < 0.5;
            if keep {
                self.shots.push(Shot {
                    col: col as u32,
                    s,
                    on,
                });
            }
        }
    }

    /// The hot pixels' extra arrivals among columns `0 .. n` (a Poisson process per pixel),
    /// merged into `self.shots` keeping the column-then-time order.
    fn sample_hot_shots(&mut self, n: usize, iv: &Interval, rng: &mut Rng) {
        if iv.hot_per_us <= 0.0 || self.hot.is_empty() {
            return;
        }
        let rate = iv.hot_per_us * iv.dt_us as f64; // arrivals per interval
        let before = self.shots.len();
        for &col in self.hot.iter().filter(|&&c| (c as usize) < n) {
            let mut s = 0.0;
            loop {
                s += -(1.0 - rng.uniform()).ln() / rate;
                if s >= 1.0 {
                    break;
                }
                let on = rng.uniform() < 0.5;
                self.shots.push(Shot { col, s, on });
            }
        }
        if self.shots.len() > before {
            self.shots
                .sort_by(|a, b| a.col.cmp(&b.col).then(a.s.total_cmp(&b.s)));
        }
    }

    /// Advance columns `x0 .. x0 + frame.len()` to the new intensities `frame` and append
    /// their events to `self.events` (time order within a pixel; pixels in no particular
    /// order, the caller sorts). `idx0` is the row-major index of column `x0`.
    pub fn step(&mut self, frame: &[f32], x0: usize, idx0: u32, iv: &Interval, rng: &mut Rng) {
        self.events.clear();
        self.sample_shots(frame, iv, rng);
        let shots = std::mem::take(&mut self.shots);
        let mut busy = std::mem::take(&mut self.busy);
        busy.clear();
        // Columns with noise always take the full path; the spans between them go through the
        // quiet-pixel pass, which defers the few pixels that cross a threshold.
        let mut from = 0;
        let mut k = 0;
        while k < shots.len() {
            let col = shots[k].col as usize;
            let end = shots[k..]
                .iter()
                .position(|s| s.col as usize != col)
                .map_or(shots.len(), |n| k + n);
            self.quiet_span(&frame[from..col], x0 + from, iv, &mut busy);
            self.step_pixel(x0 + col, idx0 + col as u32, frame[col], &shots[k..end], iv);
            from = col + 1;
            k = end;
        }
        self.quiet_span(&frame[from..], x0 + from, iv, &mut busy);
        for &x in &busy {
            let c = x - x0;
            self.step_pixel(x, idx0 + c as u32, frame[c], &[], iv);
        }
        self.shots = shots;
        self.busy = busy;
        self.mark_segments(x0, x0 + frame.len(), iv.t0_us + iv.dt_us);
    }

    /// Advance the whole row (`frame` covers it) over `iv`, visiting only the segments that can
    /// have events: those flagged in `changed` (one flag per segment; the caller guarantees that
    /// every pixel of an unflagged segment has the same intensity as at its last update), those
    /// with a shot-noise arrival, and those whose leak is due by the interval's end. A visited
    /// segment first catches up with its pixels' constant intensity since its last update, then
    /// takes the interval like [`Self::step`]; the result equals stepping every pixel every
    /// interval, up to f32 rounding of the accumulated leak.
    pub fn step_segments(
        &mut self,
        frame: &[f32],
        changed: &[bool],
        idx0: u32,
        iv: &Interval,
        rng: &mut Rng,
    ) {
        self.events.clear();
        self.sample_shots(frame, iv, rng);
        let shots = std::mem::take(&mut self.shots);
        let t1 = iv.t0_us + iv.dt_us;
        let mut k = 0;
        for (seg, &flag) in changed.iter().enumerate() {
            let (xs, xe) = (seg * SEGMENT_PX, ((seg + 1) * SEGMENT_PX).min(frame.len()));
            let first = k;
            while k < shots.len() && (shots[k].col as usize) < xe {
                k += 1;
            }
            if !(flag || k > first || self.seg_due_us[seg] <= t1) {
                continue;
            }
            let t_from = self.seg_t_us[seg];
            let mut noisy = [false; SEGMENT_PX];
            for s in &shots[first..k] {
                noisy[s.col as usize - xs] = true;
            }
            let mut quiet = [false; SEGMENT_PX];
            self.quiet_segment(&frame[xs..xe], xs, &noisy, t_from, iv, &mut quiet);
            let mut j = first;
            for x in (xs..xe).filter(|x| !quiet[x - xs]) {
                let idx = idx0 + x as u32;
                while j < k && (shots[j].col as usize) < x {
                    j += 1;
                }
                let end = shots[j..k]
                    .iter()
                    .position(|s| s.col as usize != x)
                    .map_or(k, |n| j + n);
                if t_from < iv.t0_us {
                    self.catch_up(x, idx, t_from, iv);
                }
                self.step_pixel(x, idx, frame[x], &shots[j..end], iv);
                j = end;
            }
            self.seg_t_us[seg] = t1;
            self.seg_due_us[seg] = self.leak_due_us(xs..xe, t1);
        }
        self.shots = shots;
    }

    /// Bring pixel `x`, last updated at `t_from` < `iv.t0_us`, to `iv.t0_us`: its intensity was
    /// constant since, so only the leak moved it.
    fn catch_up(&mut self, x: usize, idx: u32, t_from: i64, iv: &Interval) {
        let gap = Interval {
            t0_us: t_from,
            dt_us: iv.t0_us - t_from,
            ..*iv
        };
        let n_ev = self.events.len();
        self.step_pixel(x, idx, self.prev_i[x], &[], &gap);
        // A leak crossing is due no earlier than t0 (the segment would have been visited in an
        // earlier interval); rounding of the f32 state may still put one a microsecond early, and
        // the output must stay sorted across steps.
        for e in &mut self.events[n_ev..] {
            e.t_us = e.t_us.max(iv.t0_us);
        }
    }

    /// The quiet-pixel test of [`Self::quiet_span`] for the pixels of one segment, columns
    /// `xs .. xs + frame.len()`, last updated at `t_from`: a pixel's path is flat (plus leak)
    /// until `iv.t0_us`, then a straight line to its new intensity, so it stays inside the band
    /// iff both corners do. Updates each pixel that fires nothing and has no shot-noise arrival
    /// (`noisy`), and sets its `quiet` flag; the others are left untouched for the full model.
    /// Branch-free over the segment, so the compiler vectorises it (logarithm included): this
    /// is the sensor's cost per changed pixel and tick.
    fn quiet_segment(
        &mut self,
        frame: &[f32],
        xs: usize,
        noisy: &[bool; SEGMENT_PX],
        t_from: i64,
        iv: &Interval,
        quiet: &mut [bool; SEGMENT_PX],
    ) {
        // A whole segment (all but a row's last if the width is not a multiple of SEGMENT_PX)
        // has a constant trip count, which the compiler unrolls into straight SIMD code.
        if frame.len() == SEGMENT_PX {
            self.quiet_lanes(&frame[..SEGMENT_PX], xs, noisy, t_from, iv, quiet);
        } else {
            self.quiet_lanes(frame, xs, noisy, t_from, iv, quiet);
        }
    }

    /// [`Self::quiet_segment`]'s body, inlined at each length.
    #[inline(always)]
    fn quiet_lanes(
        &mut self,
        frame: &[f32],
        xs: usize,
        noisy: &[bool; SEGMENT_PX],
        t_from: i64,
        iv: &Interval,
        quiet: &mut [bool; SEGMENT_PX],
    ) {
        let n = frame.len();
        let mid_us = (iv.t0_us - t_from) as f64;
        let end_us = (iv.t0_us + iv.dt_us - t_from) as f64;
        // Up to date at t0, the start is inside the band by construction (as in `quiet_span`).
        let fresh = t_from == iv.t0_us;
        let prev_i = &mut self.prev_i[xs..xs + n];
        let prev_l = &mut self.prev_l[xs..xs + n];
        let ref_l = &mut self.ref_l[xs..xs + n];
        let (c_pos, c_neg) = (&self.c_pos[xs..xs + n], &self.c_neg[xs..xs + n]);
        let leak_per_us = &self.leak_per_us[xs..xs + n];
        let (noisy, quiet) = (&noisy[..n], &mut quiet[..n]);
        // The new levels first, in f32 lanes (an unchanged intensity keeps its level bit for bit).
        let mut l1 = [0.0f32; SEGMENT_PX];
        let l1 = &mut l1[..n];
        for ((l, &i1), (&pi, &pl)) in l1
            .iter_mut()
            .zip(frame)
            .zip(prev_i.iter().zip(prev_l.iter()))
        {
            let fresh_log = log_intensity(i1, iv.log_eps);
            *l = if i1.to_bits() == pi.to_bits() {
                pl
            } else {
                fresh_log
            };
        }
        // The band test in f64 (as the full model's), the new reference with it.
        let mut ref1 = [0.0f32; SEGMENT_PX];
        let ref1 = &mut ref1[..n];
        for c in 0..n {
            let leak = f64::from(leak_per_us[c]);
            let r = f64::from(ref_l[c]);
            let (cp, cn) = (f64::from(c_pos[c]), f64::from(c_neg[c]));
            let drift = leak * end_us;
            let d_mid = f64::from(prev_l[c]) + leak * mid_us - r;
            let d_end = f64::from(l1[c]) + drift - r;
            quiet[c] = (d_end < cp) & (-d_end < cn) & (fresh | ((d_mid < cp) & (-d_mid < cn)));
            ref1[c] = (r - drift) as f32;
        }
        // Selects, not a branch: stores of every lane keep the loop one SIMD block.
        for c in 0..n {
            let q = quiet[c] & !noisy[c];
            quiet[c] = q;
            prev_i[c] = if q { frame[c] } else { prev_i[c] };
            prev_l[c] = if q { l1[c] } else { prev_l[c] };
            ref_l[c] = if q { ref1[c] } else { ref_l[c] };
        }
    }

    /// Earliest time (µs) at which leak alone can make one of the pixels `cols`, up to date at
    /// `t_us`, fire ([`NEVER_DUE`] if leak cannot).
    fn leak_due_us(&self, cols: std::ops::Range<usize>, t_us: i64) -> i64 {
        let us_per_log = &self.us_per_log_leak[cols.clone()];
        let (c_pos, prev_l, ref_l) = (
            &self.c_pos[cols.clone()],
            &self.prev_l[cols.clone()],
            &self.ref_l[cols],
        );
        // The earliest wait first, one conversion after: truncating to µs and adding are
        // monotone, so this is the minimum of the pixels' due times.
        let mut soonest = f64::INFINITY;
        for c in 0..us_per_log.len() {
            let gap = f64::from(c_pos[c]) - (f64::from(prev_l[c]) - f64::from(ref_l[c]));
            // Within a few ulps of the quotient: nothing beside the slack, worth
            // DUE_SLACK_LOG / leak µs. Negative waits (and NaN) are lifted to 0.
            let wait = ((gap - DUE_SLACK_LOG) * us_per_log[c]).max(0.0);
            soonest = soonest.min(if us_per_log[c] > 0.0 {
                wait
            } else {
                f64::INFINITY
            });
        }
        if soonest == f64::INFINITY {
            return NEVER_DUE;
        }
        // The cast truncates, which is ⌊wait⌋ for a wait ≥ 0, and saturates: a far-off
        // crossing becomes "never" in practice.
        t_us.saturating_add(soonest as i64)
    }

    /// Update the pixels of columns `x .. x + frame.len()` whose level stays strictly inside
    /// (ref − C_off, ref + C_on) over the interval — almost all of them — and push the others'
    /// columns to `busy`, untouched. A straight line that starts and ends inside that band never
    /// leaves it, so checking the end is enough. Kept branch-light and free of bounds checks:
    /// this loop is the simulator's cost for a static background.
    fn quiet_span(&mut self, frame: &[f32], x: usize, iv: &Interval, busy: &mut Vec<usize>) {
        let n = frame.len();
        let dt = iv.dt_us as f64;
        let state = self.prev_i[x..x + n]
            .iter_mut()
            .zip(&mut self.prev_l[x..x + n])
            .zip(&mut self.ref_l[x..x + n])
            .zip(&self.c_pos[x..x + n])
            .zip(&self.c_neg[x..x + n])
            .zip(&self.leak_per_us[x..x + n]);
        for (c, (&i1, (((((pi, pl), rl), &cp), &cn), &leak))) in frame.iter().zip(state).enumerate()
        {
            // Unchanged intensity skips the logarithm, the dominant cost for a static background.
            let l1 = if i1.to_bits() == pi.to_bits() {
                *pl
            } else {
                log_intensity(i1, iv.log_eps)
            };
            // Leak lowers the reference steadily; equivalently the signal rises by `drift`
            // relative to a fixed reference, which keeps the whole interval one straight line.
            let drift = f64::from(leak) * dt;
            let r = f64::from(*rl);
            let d = f64::from(l1) + drift - r;
            if d < f64::from(cp) && -d < f64::from(cn) {
                *pi = i1;
                *pl = l1;
                *rl = (r - drift) as f32;
            } else {
                busy.push(x + c);
            }
        }
    }

    /// The full model for one pixel: crossings, refractory gating and the noise arrivals
    /// `shots` (sorted by time).
    fn step_pixel(&mut self, x: usize, idx: u32, i1: f32, shots: &[Shot], iv: &Interval) {
        let i0 = self.prev_i[x];
        let l0 = f64::from(self.prev_l[x]);
        let l1_f32 = if i1.to_bits() == i0.to_bits() {
            self.prev_l[x]
        } else {
            log_intensity(i1, iv.log_eps)
        };
        let l1 = f64::from(l1_f32);
        let drift = f64::from(self.leak_per_us[x]) * iv.dt_us as f64;
        let g1 = l1 + drift;
        let mut r = f64::from(self.ref_l[x]);
        let (cp, cn) = (f64::from(self.c_pos[x]), f64::from(self.c_neg[x]));
        self.prev_i[x] = i1;
        self.prev_l[x] = l1_f32;
        let line = Line { l0, slope: g1 - l0 };
        let mut last_t = self.last_t_us[x];
        let mut s_a = 0.0;
        for shot in shots {
            r = self.crossings(&line, r, (cp, cn), (s_a, shot.s), idx, &mut last_t, iv);
            let t = iv.t_at(shot.s);
            // A pixel inside its refractory period is blind: the noise neither fires nor resets.
            if refractory_allows(last_t, t, iv.refractory_us) {
                self.events.push(RawEvent {
                    t_us: t,
                    idx,
                    on: shot.on,
                });
                last_t = t;
                r = line.at(shot.s);
            }
            s_a = shot.s;
        }
        r = self.crossings(&line, r, (cp, cn), (s_a, 1.0), idx, &mut last_t, iv);
        self.last_t_us[x] = last_t;
        self.ref_l[x] = (r - drift) as f32;
    }

    /// Emit every level r ± k·c crossed by the line on [s_a, s_b]; returns the new reference.
    /// Levels suppressed by the refractory period still move the reference (ESIM semantics).
    #[allow(clippy::too_many_arguments)]
    fn crossings(
        &mut self,
        line: &Line,
        r: f64,
        (cp, cn): (f64, f64),
        (s_a, s_b): (f64, f64),
        idx: u32,
        last_t: &mut i64,
        iv: &Interval,
    ) -> f64 {
        let gb = line.at(s_b);
        let (step, n, on) = if gb - r >= cp {
            (cp, (gb - r) / cp, true)
        } else if r - gb >= cn {
            (-cn, (r - gb) / cn, false)
        } else {
            return r;
        };
        // n ≥ 1 here, where the truncating cast is ⌊n⌋ (without a libm call).
        let n = n as u64;
        for k in 1..=n {
            // Levels from r directly rather than by accumulation, so rounding does not build up.
            let level = r + k as f64 * step;
            let s = line.time_of(level, s_b).max(s_a).min(s_b);
            let t = iv.t_at(s);
            if refractory_allows(*last_t, t, iv.refractory_us) {
                self.events.push(RawEvent { t_us: t, idx, on });
                *last_t = t;
            }
        }
        r + n as f64 * step
    }
}

/// g(s) = l0 + slope·s over the interval, s ∈ [0, 1].
struct Line {
    l0: f64,
    slope: f64,
}

impl Line {
    fn at(&self, s: f64) -> f64 {
        self.l0 + self.slope * s
    }

    /// Where the line reaches `level`; a flat line (reachable only through f32 rounding of the
    /// stored reference) is taken to cross at `fallback`.
    fn time_of(&self, level: f64, fallback: f64) -> f64 {
        let s = (level - self.l0) / self.slope;
        if s.is_finite() {
            s
        } else {
            fallback
        }
    }
}

impl Interval {
    /// Microsecond timestamp of fraction `s` of the interval, rounded to nearest and kept
    /// inside [t0, t0 + Δt] even when Δt exceeds f64's exact-integer range.
    fn t_at(&self, s: f64) -> i64 {
        let off = (s * self.dt_us as f64).round() as i64;
        self.t0_us + off.clamp(0, self.dt_us)
    }
}

fn refractory_allows(last_t: i64, t: i64, refractory_us: i64) -> bool {
    last_t == NEVER || t.saturating_sub(last_t) >= refractory_us
}
