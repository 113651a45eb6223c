//! Truncated event distance field on a ¼ / ½ / 1 pyramid.
//!
//! The field at a pixel is f(D), D the exact Euclidean distance (in that level's pixels) to the
//! nearest active pixel of that level, with
//!
//! * f(D) = D²/2 for D < 1 and D − ½ beyond (a Huber-shaped "rounded" distance). A plain D has a
//!   V-shaped kink on the edge itself, so Gauss–Newton sees a gradient of constant magnitude that
//!   flips sign across the edge and never settles; the quadratic bottom gives it a minimum with a
//!   vanishing gradient. The two pieces meet with equal value and slope at D = 1.
//! * truncation at τ (`tau_px`): f is capped at f(τ), so events farther than τ from a model point
//!   cannot pull the solution (they are outliers, not evidence), and pixels of a region without any
//!   active pixel carry f(τ) too.
//!
//! τ is in level pixels and is the same at every level. A level-ℓ pixel spans 2^ℓ full-resolution
//! pixels, so the ½ and ¼ levels see a basin 2× and 4× wider in full-resolution pixels: the coarse
//! levels absorb large inter-frame motions, the full-resolution level keeps outliers out and
//! refines. Level ℓ's mask is the OR-pool of 2^ℓ×2^ℓ full-resolution pixels aligned to the
//! absolute image grid (the grid of [`Roi::at_level`]), so that a pixel at level ℓ is active
//! whenever any pixel it covers is.
//!
//! The build is two separable passes. Distances beyond τ are never needed, so the column pass
//! counts in `u8` up to a cap just above τ, and the row pass only looks at candidates within τ,
//! on small integer squared distances: `u8` lanes (16 per SSE2 vector) while the squared cap fits
//! a byte, as it does for the default τ, else `i16`. A block of pixels stops early once every
//! pixel of it already has a candidate closer than the next offset. For τ too large for those
//! integers, the build falls back to the exact Felzenszwalb–Huttenlocher transform, which also
//! backs [`euclidean_distance`].

use crate::error::{ensure, Error, Result};
use crate::image::Roi;

/// Default truncation radius τ, in level pixels.
pub const DEFAULT_TAU_PX: f32 = 10.0;

/// Most pyramid levels a field can have (full, ½, ¼).
pub const MAX_LEVELS: u32 = 3;

/// Largest window (⌊τ⌋) whose squared cap fits `u8` lanes: (window + 1)² ≤ 255.
const MAX_BYTE_WINDOW_PX: usize = 14;

/// Largest window (⌊τ⌋) whose squared cap fits `i16` lanes: (window + 1)² ≤ 32767.
const MAX_WINDOW_PX: usize = 180;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldParams {
    /// Truncation radius τ in level pixels (finite, > 0).
    pub tau_px: f32,
    /// Number of pyramid levels, 1..=3 (1 = full resolution only).
    pub levels: u32,
}

impl Default for FieldParams {
    fn default() -> Self {
        Self {
            tau_px: DEFAULT_TAU_PX,
            levels: MAX_LEVELS,
        }
    }
}

impl FieldParams {
    pub fn validate(&self) -> Result<()> {
        ensure(self.tau_px.is_finite() && self.tau_px > 0.0, || {
            format!("tau_px must be finite and positive, got {}", self.tau_px)
        })?;
        ensure((1..=MAX_LEVELS).contains(&self.levels), || {
            format!(
                "levels must be within 1..={MAX_LEVELS}, got {}",
                self.levels
            )
        })
    }
}

/// The rounded, truncated distance f(min(D, τ)): D²/2 below 1 px, D − ½ from 1 px on.
#[inline]
pub fn rounded_distance(d_px: f32, tau_px: f32) -> f32 {
    let d = d_px.min(tau_px);
    if d < 1.0 {
        0.5 * d * d
    } else {
        d - 0.5
    }
}

/// One pyramid level of the field.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldLevel {
    /// Pyramid level (0 = full resolution); one pixel here spans 2^level full-resolution pixels.
    pub level: u32,
    /// The region covered, in this level's grid.
    pub roi: Roi,
    /// Truncation radius τ in this level's pixels.
    pub tau_px: f32,
    /// f(D) per pixel, row-major over `roi` (level pixels).
    pub value: Vec<f32>,
}

impl FieldLevel {
    fn empty(level: u32, tau_px: f32) -> Self {
        Self {
            level,
            roi: Roi {
                x0: 0,
                y0: 0,
                width: 0,
                height: 0,
            },
            tau_px,
            value: Vec::new(),
        }
    }

    /// f(τ), the value of every pixel farther than τ from any active pixel.
    pub fn max_value(&self) -> f32 {
        rounded_distance(self.tau_px, self.tau_px)
    }

    /// Bilinear sample at level-grid pixel coordinates (absolute, pixel centres at integers).
    /// Taps outside the roi read f(τ), so the field stays continuous across the roi border;
    /// non-finite coordinates give f(τ).
    #[inline]
    pub fn sample(&self, u: f32, v: f32) -> f32 {
        match self.cell(u, v) {
            Cell::Interior { i, ax, ay } => {
                let w = self.roi.width as usize;
                let val = &self.value;
                let top = val[i] + ax * (val[i + 1] - val[i]);
                let bottom = val[i + w] + ax * (val[i + w + 1] - val[i + w]);
                top + ay * (bottom - top)
            }
            Cell::Border { x, y, ax, ay } => {
                let tap = |dx: i64, dy: i64| self.tap(x + dx, y + dy);
                bilinear(tap(0, 0), tap(1, 0), tap(0, 1), tap(1, 1), ax, ay)
            }
            Cell::Outside => self.max_value(),
        }
    }

    /// (value, d/du, d/dv) of the bilinear interpolant itself: its slope is constant across each
    /// cell, so on the V of an unsigned distance a Gauss–Newton step lands on the edge exactly,
    /// where a smoothed central-difference gradient would vanish at the edge and make the step
    /// overshoot.
    #[inline]
    pub fn sample_slope(&self, u: f32, v: f32) -> [f32; 3] {
        let (v00, v10, v01, v11, ax, ay) = match self.cell(u, v) {
            Cell::Interior { i, ax, ay } => {
                let w = self.roi.width as usize;
                let val = &self.value;
                (val[i], val[i + 1], val[i + w], val[i + w + 1], ax, ay)
            }
            Cell::Border { x, y, ax, ay } => {
                let tap = |dx: i64, dy: i64| self.tap(x + dx, y + dy);
                (tap(0, 0), tap(1, 0), tap(0, 1), tap(1, 1), ax, ay)
            }
            Cell::Outside => return [self.max_value(), 0.0, 0.0],
        };
        [
            bilinear(v00, v10, v01, v11, ax, ay),
            (v10 - v00) + ay * ((v11 - v01) - (v10 - v00)),
            (v01 - v00) + ax * ((v11 - v10) - (v01 - v00)),
        ]
    }

    /// Adds the 13 samples of a search star (see [`crate::solve::cost::CostMap::add_star`]) to
    /// `sums`. When every sample's cell lies inside the roi (the common case), the samples skip the
    /// per-sample cell tests and run as fixed-length array passes (coordinates, one test for all,
    /// indices and weights, then taps and blends) that the compiler turns into vector code around
    /// the 52 scalar loads; otherwise each sample takes [`Self::sample`]. Both give the same values.
    #[inline(always)]
    pub fn add_star(&self, u: f32, v: f32, du: &[f32; 6], dv: &[f32; 6], sums: &mut [f32; 13]) {
        // Lane 0 is the centre, lanes 2k+1 / 2k+2 the ± pair of axis k; lanes 13..16 repeat the
        // centre. Coordinates are formed exactly as `sample` forms them, so the values agree.
        let (x0, y0) = (self.roi.x0 as f32, self.roi.y0 as f32);
        let mut xs = [u - x0; 16];
        let mut ys = [v - y0; 16];
        for k in 0..6 {
            xs[2 * k + 1] = (u + du[k]) - x0;
            ys[2 * k + 1] = (v + dv[k]) - y0;
            xs[2 * k + 2] = (u - du[k]) - x0;
            ys[2 * k + 2] = (v - dv[k]) - y0;
        }
        let (w, h) = (self.roi.width as f32 - 1.0, self.roi.height as f32 - 1.0);
        // NaN fails every comparison and takes the general path.
        let inside = xs.iter().zip(&ys).fold(true, |ok, (&x, &y)| {
            ok & (x >= 0.0) & (y >= 0.0) & (x < w) & (y < h)
        });
        if !inside {
            sums[0] += self.sample(u, v);
            for k in 0..6 {
                sums[2 * k + 1] += self.sample(u + du[k], v + dv[k]);
                sums[2 * k + 2] += self.sample(u - du[k], v - dv[k]);
            }
            return;
        }
        let stride = self.roi.width as usize;
        // Non-negative inside the roi, so truncation is the floor. Plain i32 truncation (one
        // vector instruction for four lanes) instead of `as usize`, whose saturating semantics
        // cost a scalar conversion and fix-ups per lane.
        // SAFETY: every lane passed the inside test, so it is finite and in 0..roi size < 2^31.
        let ix: [i32; 16] = std::array::from_fn(|i| unsafe { xs[i].to_int_unchecked() });
        let iy: [i32; 16] = std::array::from_fn(|i| unsafe { ys[i].to_int_unchecked() });
        let ax: [f32; 16] = std::array::from_fn(|i| xs[i] - ix[i] as f32);
        let ay: [f32; 16] = std::array::from_fn(|i| ys[i] - iy[i] as f32);
        let val = &self.value;
        for i in 0..13 {
            let idx = iy[i] as usize * stride + ix[i] as usize;
            // Inside, every tap lies in the roi: idx + stride + 1 < value.len().
            let t = &val[idx..idx + stride + 2];
            sums[i] += bilinear(t[0], t[1], t[stride], t[stride + 1], ax[i], ay[i]);
        }
    }

    /// [`Self::add_star`] with AVX2 gathers: the 16 lanes of coordinates, cells and weights in two
    /// vectors each and the four taps of every lane in four gathers per vector, in place of 52
    /// scalar loads. Each lane's coordinate, cell, weights and bilinear value are formed by the
    /// same operations in the same order as in [`Self::add_star`] (u − δ as u + (−δ), which IEEE
    /// defines it to be), so the sums come out bit for bit the same; a star not wholly inside the
    /// roi takes [`Self::add_star`] itself.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    pub(crate) fn add_star_avx2(
        &self,
        u: f32,
        v: f32,
        du: &[f32; 6],
        dv: &[f32; 6],
        sums: &mut [f32; 13],
    ) {
        use std::arch::x86_64::*;
        // Lane 0 is the centre, lanes 2k+1 / 2k+2 the ± pair of axis k, lanes 13..16 the centre
        // again (blended in, so a centre lane is u itself, not u + 0).
        let mut ox = [0.0f32; 16];
        let mut oy = [0.0f32; 16];
        for k in 0..6 {
            ox[2 * k + 1] = du[k];
            ox[2 * k + 2] = -du[k];
            oy[2 * k + 1] = dv[k];
            oy[2 * k + 2] = -dv[k];
        }
        let stride = self.roi.width as usize;
        let inside;
        let (mut vals_lo, mut vals_hi) = (_mm256_setzero_ps(), _mm256_setzero_ps());
        // SAFETY: the loads read `ox`/`oy`/`sums` within bounds (16, 16 and 8 + 4 + 1 lanes); the
        // gathers run only when every lane's cell lies wholly inside the roi, i.e. idx + stride + 1
        // < value.len() for every lane.
        unsafe {
            let (uu, vv) = (_mm256_set1_ps(u), _mm256_set1_ps(v));
            let (x0, y0) = (
                _mm256_set1_ps(self.roi.x0 as f32),
                _mm256_set1_ps(self.roi.y0 as f32),
            );
            let lane = |o: &[f32; 16], base: __m256, c: __m256, half: usize| {
                let moved = _mm256_add_ps(base, _mm256_loadu_ps(o.as_ptr().add(8 * half)));
                let centred = if half == 0 {
                    _mm256_blend_ps::<0b0000_0001>(moved, base)
                } else {
                    _mm256_blend_ps::<0b1110_0000>(moved, base)
                };
                _mm256_sub_ps(centred, c)
            };
            let xs = [lane(&ox, uu, x0, 0), lane(&ox, uu, x0, 1)];
            let ys = [lane(&oy, vv, y0, 0), lane(&oy, vv, y0, 1)];
            let (w, h) = (
                _mm256_set1_ps(self.roi.width as f32 - 1.0),
                _mm256_set1_ps(self.roi.height as f32 - 1.0),
            );
            let zero = _mm256_setzero_ps();
            // Ordered comparisons: NaN fails every one and takes the general path.
            let ok = |x: __m256, y: __m256| {
                let a = _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_GE_OQ>(x, zero),
                    _mm256_cmp_ps::<_CMP_GE_OQ>(y, zero),
                );
                let b = _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_LT_OQ>(x, w),
                    _mm256_cmp_ps::<_CMP_LT_OQ>(y, h),
                );
                _mm256_movemask_ps(_mm256_and_ps(a, b))
            };
            inside = ok(xs[0], ys[0]) == 0xFF && ok(xs[1], ys[1]) == 0xFF;
            if inside {
                let val = self.value.as_ptr();
                let s = _mm256_set1_epi32(stride as i32);
                let one_row = val.add(stride);
                let star = |x: __m256, y: __m256| {
                    // Non-negative and in range inside the roi: truncation is the floor.
                    let ix = _mm256_cvttps_epi32(x);
                    let iy = _mm256_cvttps_epi32(y);
                    let ax = _mm256_sub_ps(x, _mm256_cvtepi32_ps(ix));
                    let ay = _mm256_sub_ps(y, _mm256_cvtepi32_ps(iy));
                    let idx = _mm256_add_epi32(_mm256_mullo_epi32(iy, s), ix);
                    let mut at = [0i32; 8];
                    _mm256_storeu_si256(at.as_mut_ptr().cast(), idx);
                    // The two horizontal taps of a lane are adjacent: one 8-byte load per lane and
                    // row, two lanes to a 128-bit half, then split into left and right taps.
                    let pairs = |row: *const f32, j: usize| {
                        let lo = _mm_load_sd(row.add(at[j] as usize).cast());
                        _mm_castpd_ps(_mm_loadh_pd(lo, row.add(at[j + 1] as usize).cast()))
                    };
                    let taps = |row: *const f32| {
                        let p = _mm256_set_m128(pairs(row, 4), pairs(row, 0));
                        let q = _mm256_set_m128(pairs(row, 6), pairs(row, 2));
                        (
                            _mm256_shuffle_ps::<0b10_00_10_00>(p, q),
                            _mm256_shuffle_ps::<0b11_01_11_01>(p, q),
                        )
                    };
                    let (v00, v10) = taps(val);
                    let (v01, v11) = taps(one_row);
                    let top = _mm256_add_ps(v00, _mm256_mul_ps(ax, _mm256_sub_ps(v10, v00)));
                    let bottom = _mm256_add_ps(v01, _mm256_mul_ps(ax, _mm256_sub_ps(v11, v01)));
                    _mm256_add_ps(top, _mm256_mul_ps(ay, _mm256_sub_ps(bottom, top)))
                };
                vals_lo = star(xs[0], ys[0]);
                vals_hi = star(xs[1], ys[1]);
            }
        }
        if !inside {
            self.add_star(u, v, du, dv, sums);
            return;
        }
        // SAFETY: lanes 0..8 and 8..12 of `sums` are in bounds.
        unsafe {
            let p = sums.as_mut_ptr();
            _mm256_storeu_ps(p, _mm256_add_ps(_mm256_loadu_ps(p), vals_lo));
            let hi4 = _mm256_castps256_ps128(vals_hi);
            _mm_storeu_ps(p.add(8), _mm_add_ps(_mm_loadu_ps(p.add(8)), hi4));
            sums[12] += _mm_cvtss_f32(_mm256_extractf128_ps::<1>(vals_hi));
        }
    }

    /// [`Self::sample_slope`] at the eight points in the lanes of `u` and `v` when every one of
    /// their cells lies wholly inside the roi (None otherwise: the caller samples them one by one).
    /// Each lane's cell, weights, value and slope are formed by the same operations in the same
    /// order as in `sample_slope`, so the results are the same bit for bit; the four taps take one
    /// gather each.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(crate) fn sample_slope8_avx2(
        &self,
        u: std::arch::x86_64::__m256,
        v: std::arch::x86_64::__m256,
    ) -> Option<[std::arch::x86_64::__m256; 3]> {
        use std::arch::x86_64::*;
        let x = _mm256_sub_ps(u, _mm256_set1_ps(self.roi.x0 as f32));
        let y = _mm256_sub_ps(v, _mm256_set1_ps(self.roi.y0 as f32));
        let (w, h) = (self.roi.width as f32, self.roi.height as f32);
        // NaN fails, as in `cell`.
        let inside = lanes_in_box_avx2(x, y, w - 1.0, h - 1.0);
        if _mm256_movemask_ps(inside) != 0xFF {
            return None;
        }
        // Non-negative and in range inside the roi: truncation is the floor.
        let (ix, iy) = (_mm256_cvttps_epi32(x), _mm256_cvttps_epi32(y));
        let ax = _mm256_sub_ps(x, _mm256_cvtepi32_ps(ix));
        let ay = _mm256_sub_ps(y, _mm256_cvtepi32_ps(iy));
        let stride = self.roi.width as usize;
        let idx = _mm256_add_epi32(_mm256_mullo_epi32(iy, _mm256_set1_epi32(stride as i32)), ix);
        let val = self.value.as_ptr();
        // SAFETY: every lane's cell lies inside the roi, so idx + stride + 1 < value.len().
        let (v00, v10, v01, v11) = unsafe {
            (
                _mm256_i32gather_ps::<4>(val, idx),
                _mm256_i32gather_ps::<4>(val.add(1), idx),
                _mm256_i32gather_ps::<4>(val.add(stride), idx),
                _mm256_i32gather_ps::<4>(val.add(stride + 1), idx),
            )
        };
        let top = _mm256_add_ps(v00, _mm256_mul_ps(ax, _mm256_sub_ps(v10, v00)));
        let bottom = _mm256_add_ps(v01, _mm256_mul_ps(ax, _mm256_sub_ps(v11, v01)));
        let value = _mm256_add_ps(top, _mm256_mul_ps(ay, _mm256_sub_ps(bottom, top)));
        let (d10, d01) = (_mm256_sub_ps(v10, v00), _mm256_sub_ps(v01, v00));
        let gu = _mm256_add_ps(
            d10,
            _mm256_mul_ps(ay, _mm256_sub_ps(_mm256_sub_ps(v11, v01), d10)),
        );
        let gv = _mm256_add_ps(
            d01,
            _mm256_mul_ps(ax, _mm256_sub_ps(_mm256_sub_ps(v11, v10), d01)),
        );
        Some([value, gu, gv])
    }

    /// Locates the bilinear cell of (u, v): fully inside (fast path), straddling the roi border,
    /// or out of reach of every pixel.
    #[inline]
    fn cell(&self, u: f32, v: f32) -> Cell {
        let x = u - self.roi.x0 as f32;
        let y = v - self.roi.y0 as f32;
        let (w, h) = (self.roi.width as f32, self.roi.height as f32);
        // Written so that NaN fails every comparison and lands in `Outside`. On the fast path the
        // coordinates are non-negative, so truncation is the floor; `f32::floor` is a libm call on
        // baseline x86-64 and dominated the cost of a sample.
        if x >= 0.0 && y >= 0.0 && x < w - 1.0 && y < h - 1.0 {
            let (ix, iy) = (x as usize, y as usize);
            Cell::Interior {
                i: iy * self.roi.width as usize + ix,
                ax: x - ix as f32,
                ay: y - iy as f32,
            }
        } else if x >= -1.0 && y >= -1.0 && x < w && y < h {
            let (fx, fy) = (x.floor(), y.floor());
            Cell::Border {
                x: fx as i64,
                y: fy as i64,
                ax: x - fx,
                ay: y - fy,
            }
        } else {
            Cell::Outside
        }
    }

    /// Value of roi-local pixel (x, y); f(τ) outside the roi.
    fn tap(&self, x: i64, y: i64) -> f32 {
        let (w, h) = (i64::from(self.roi.width), i64::from(self.roi.height));
        if x < 0 || y < 0 || x >= w || y >= h {
            return self.max_value();
        }
        self.value[(y * w + x) as usize]
    }
}

enum Cell {
    Interior { i: usize, ax: f32, ay: f32 },
    Border { x: i64, y: i64, ax: f32, ay: f32 },
    Outside,
}

#[inline]
fn bilinear(v00: f32, v10: f32, v01: f32, v11: f32, ax: f32, ay: f32) -> f32 {
    let top = v00 + ax * (v10 - v00);
    let bottom = v01 + ax * (v11 - v01);
    top + ay * (bottom - top)
}

/// The field pyramid, rebuilt in place on every tracker update.
#[derive(Debug, Clone)]
pub struct DistanceField {
    pub params: FieldParams,
    /// One entry per configured level (`params.levels`); levels not built by the last
    /// [`Self::build`] have an empty roi and sample as f(τ) everywhere.
    pub levels: Vec<FieldLevel>,
    built: u32,
    /// Returned by [`Self::level`] when `levels` is empty.
    absent: FieldLevel,
    /// The value buffers of the levels the last build skipped, kept at their length so that the
    /// next build of that level reuses them without zeroing them first (a search step builds
    /// level 0 only, the LM step after it all three: a memset of the coarse levels each time).
    parked: Vec<Vec<f32>>,
    /// Pooled masks of levels 1 and 2, and one row of pooling work.
    pooled: [Vec<u8>; 2],
    pair_row: Vec<u8>,
    scratch: Scratch,
}

/// Buffers reused across builds.
#[derive(Debug, Clone, Default)]
struct Scratch {
    /// Capped vertical distances (column pass).
    col: Vec<u8>,
    /// One padded row of squared vertical distances, in the lane type of the window.
    row8: Vec<u8>,
    row16: Vec<i16>,
    /// f as a function of the integer squared distance.
    lut: Vec<f32>,
    /// Squared vertical distances (exact fallback path).
    d2: Vec<f64>,
    fh: FhScratch,
}

impl DistanceField {
    pub fn new(params: FieldParams) -> Result<Self> {
        params.validate()?;
        let levels = (0..params.levels)
            .map(|l| FieldLevel::empty(l, params.tau_px))
            .collect();
        let absent = FieldLevel::empty(0, params.tau_px);
        Ok(Self {
            params,
            levels,
            built: 0,
            absent,
            parked: Vec::new(),
            pooled: Default::default(),
            pair_row: Vec::new(),
            scratch: Scratch::default(),
        })
    }

    /// Number of levels the last build produced (0 before the first build).
    pub fn n_built(&self) -> u32 {
        self.built
    }

    /// Level `l`; an `l` beyond the configured levels gives the coarsest one. Levels the last
    /// build skipped are empty and sample as f(τ).
    pub fn level(&self, l: u32) -> &FieldLevel {
        // `levels` is public, so it may have been emptied by hand; then everything samples f(τ).
        self.levels
            .get(l as usize)
            .or(self.levels.last())
            .unwrap_or(&self.absent)
    }

    /// Rebuild from a full-resolution mask of `roi` (row-major, `roi.width * roi.height`, nonzero
    /// = active). Builds the first `n_levels` (1..=params.levels) levels; 1 gives full resolution
    /// only, for the cheap search step.
    pub fn build(&mut self, mask: &[u8], roi: Roi, n_levels: u32) -> Result<()> {
        ensure((1..=self.params.levels).contains(&n_levels), || {
            format!(
                "n_levels must be within 1..={}, got {n_levels}",
                self.params.levels
            )
        })?;
        ensure(
            roi.x0.checked_add(roi.width).is_some() && roi.y0.checked_add(roi.height).is_some(),
            || format!("roi {roi:?} overflows the pixel grid"),
        )?;
        ensure(mask.len() == roi.area(), || {
            format!(
                "mask has {} pixels, roi {}x{} needs {}",
                mask.len(),
                roi.width,
                roi.height,
                roi.area()
            )
        })?;
        self.params.validate()?;
        let (tau, configured) = (self.params.tau_px, self.params.levels as usize);
        self.absent.tau_px = tau;
        let Self {
            levels,
            parked,
            pooled,
            pair_row,
            scratch,
            ..
        } = self;
        levels.resize_with(configured, || FieldLevel::empty(0, tau));
        parked.resize_with(configured, Vec::new);
        let [m1, m2] = pooled;
        for l in 0..n_levels {
            let lvl = &mut levels[l as usize];
            lvl.level = l;
            lvl.tau_px = tau;
            lvl.roi = roi.at_level(l);
            let level_mask: &[u8] = match l {
                0 => mask,
                1 => {
                    or_pool(mask, roi, m1, pair_row);
                    m1
                }
                _ => {
                    or_pool(m1, roi.at_level(1), m2, pair_row);
                    m2
                }
            };
            let (w, h) = (lvl.roi.width as usize, lvl.roi.height as usize);
            if lvl.value.is_empty() {
                std::mem::swap(&mut lvl.value, &mut parked[l as usize]);
            }
            // Every entry is overwritten, so only new ones need initialising.
            lvl.value.resize(w * h, 0.0);
            truncated_field(level_mask, w, h, tau, &mut lvl.value, scratch);
        }
        for (l, lvl) in levels.iter_mut().enumerate().skip(n_levels as usize) {
            lvl.level = l as u32;
            lvl.tau_px = tau;
            lvl.roi = Roi {
                x0: 0,
                y0: 0,
                width: 0,
                height: 0,
            };
            if !lvl.value.is_empty() {
                std::mem::swap(&mut lvl.value, &mut parked[l]);
            }
            lvl.value.clear();
        }
        self.built = n_levels;
        Ok(())
    }
}

/// OR-pools 2×2 blocks of `src` (a mask over `roi`) into the mask of `roi.at_level(1)`, with
/// blocks aligned to the absolute grid so the pyramid nests.
fn or_pool(src: &[u8], roi: Roi, dst: &mut Vec<u8>, pair_row: &mut Vec<u8>) {
    let half = roi.at_level(1);
    let (sw, sh) = (roi.width as usize, roi.height as usize);
    let (dw, dh) = (half.width as usize, half.height as usize);
    // Every entry is overwritten below, so only new ones need initialising.
    dst.resize(dw * dh, 0);
    if dw == 0 {
        return;
    }
    // Offset of the roi inside its first 2×2 block (0 or 1) in each axis.
    let (ox, oy) = ((roi.x0 & 1) as usize, (roi.y0 & 1) as usize);
    // The OR of two source rows, placed so that destination pixel X pools entries 2X and 2X+1;
    // the (at most two) slots outside the roi stay 0.
    pair_row.clear();
    pair_row.resize(2 * dw, 0);
    let source_row = |r: Option<usize>| r.filter(|&r| r < sh).map(|r| &src[r * sw..(r + 1) * sw]);
    for (dy, drow) in dst.chunks_exact_mut(dw).enumerate() {
        let pair = &mut pair_row[ox..ox + sw];
        match (
            source_row((2 * dy).checked_sub(oy)),
            source_row(Some(2 * dy + 1 - oy)),
        ) {
            (Some(a), Some(b)) => {
                for ((p, &a), &b) in pair.iter_mut().zip(a).zip(b) {
                    *p = a | b;
                }
            }
            (Some(a), None) | (None, Some(a)) => pair.copy_from_slice(a),
            (None, None) => pair.fill(0),
        }
        for (d, two) in drow.iter_mut().zip(pair_row.chunks_exact(2)) {
            *d = two[0] | two[1];
        }
    }
}

/// Truncated field values of a `w`×`h` mask into `out`.
fn truncated_field(
    mask: &[u8],
    w: usize,
    h: usize,
    tau: f32,
    out: &mut [f32],
    scratch: &mut Scratch,
) {
    if w == 0 || h == 0 {
        return;
    }
    let Scratch {
        col,
        row8,
        row16,
        lut,
        d2,
        fh,
    } = scratch;
    let window = tau.floor() as usize;
    if window > MAX_WINDOW_PX {
        exact_squared_edt(mask, w, h, out, d2, fh);
        for v in out.iter_mut() {
            *v = rounded_distance(v.sqrt(), tau);
        }
        return;
    }
    let bufs = WindowBufs {
        col,
        row8,
        row16,
        lut,
    };
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        if has_vbmi() {
            // SAFETY: the CPU has AVX2, AVX-512F, BW and VBMI.
            unsafe { windowed_field_vbmi(mask, w, h, tau, window, out, bufs) };
        } else {
            // SAFETY: the CPU has AVX2.
            unsafe { windowed_field_avx2(mask, w, h, tau, window, out, bufs) };
        }
        return;
    }
    // Blocks of two SSE2 vectors: 32 bytes or 16 halfwords.
    windowed_field::<32, 16, false, false>(mask, w, h, tau, window, out, bufs);
}

/// Whether the CPU has what [`windowed_field_vbmi`] needs besides AVX2.
#[cfg(target_arch = "x86_64")]
fn has_vbmi() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512bw")
        && std::arch::is_x86_feature_detected!("avx512vbmi")
}

/// The scratch buffers of [`windowed_field`].
struct WindowBufs<'a> {
    col: &'a mut Vec<u8>,
    row8: &'a mut Vec<u8>,
    row16: &'a mut Vec<i16>,
    lut: &'a mut Vec<f32>,
}

/// [`windowed_field`] compiled for AVX2: the same integer passes and table, so the same values,
/// in vectors twice as wide (blocks of two 32-byte vectors).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn windowed_field_avx2(
    mask: &[u8],
    w: usize,
    h: usize,
    tau: f32,
    window: usize,
    out: &mut [f32],
    bufs: WindowBufs,
) {
    windowed_field::<64, 32, true, false>(mask, w, h, tau, window, out, bufs);
}

/// [`windowed_field_avx2`] with the table looked up by AVX-512 VBMI byte permutations
/// ([`look_up_bytes_vbmi`]) instead of AVX2 gathers: the same entries, so the same values.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vbmi")]
fn windowed_field_vbmi(
    mask: &[u8],
    w: usize,
    h: usize,
    tau: f32,
    window: usize,
    out: &mut [f32],
    bufs: WindowBufs,
) {
    windowed_field::<64, 32, true, true>(mask, w, h, tau, window, out, bufs);
}

/// The windowed build (⌊τ⌋ ≤ [`MAX_WINDOW_PX`]) in blocks of `B8` byte lanes or `B16` halfword
/// lanes; `WIDE` and `VBMI` as in [`Lane::look_up`] and [`byte_planes`].
#[inline(always)]
fn windowed_field<const B8: usize, const B16: usize, const WIDE: bool, const VBMI: bool>(
    mask: &[u8],
    w: usize,
    h: usize,
    tau: f32,
    window: usize,
    out: &mut [f32],
    bufs: WindowBufs,
) {
    let WindowBufs {
        col,
        row8,
        row16,
        lut,
    } = bufs;
    // Any cap above τ is exact after truncation: a capped candidate is still farther than τ.
    let cap = (window + 1) as u8;
    column_pass(mask, w, h, cap, col);
    // Squared distances are small integers (at most cap²), so f comes from a table.
    let top = usize::from(cap) * usize::from(cap);
    lut.clear();
    lut.extend((0..=top).map(|d2| rounded_distance((d2 as f32).sqrt(), tau)));
    let planes = byte_planes::<VBMI>(lut);
    let table = Lut {
        f: lut,
        planes: planes.as_ref(),
    };
    if window <= MAX_BYTE_WINDOW_PX {
        row_pass::<u8, B8, WIDE>(col, w, window, cap, out, row8, &table);
    } else {
        row_pass::<i16, B16, WIDE>(col, w, window, cap, out, row16, &table);
    }
}

/// f as a function of the integer squared distance, and where the CPU can look it up in
/// registers the same table as byte planes.
struct Lut<'a> {
    f: &'a [f32],
    planes: Option<&'a BytePlanes>,
}

/// Byte k of every entry of a table of at most 128 `f32`, plane k at `[k]`: the table as four
/// AVX-512 VBMI byte permutations of two registers each.
type BytePlanes = [[u8; 128]; 4];

/// The byte planes of `lut` when `VBMI` (only from [`windowed_field_vbmi`]) and the table has at
/// most 128 entries (τ < 11 px); else None.
#[inline(always)]
fn byte_planes<const VBMI: bool>(lut: &[f32]) -> Option<BytePlanes> {
    if VBMI && lut.len() <= 128 {
        let mut planes = [[0u8; 128]; 4];
        for (i, f) in lut.iter().enumerate() {
            for (plane, byte) in planes.iter_mut().zip(f.to_le_bytes()) {
                plane[i] = byte;
            }
        }
        return Some(planes);
    }
    None
}

/// Integer lanes of the windowed row pass. Sums saturate, which is exact here: any saturated
/// candidate is beyond the cap and so beyond τ.
trait Lane: Copy + Ord + Default {
    fn from_small(v: usize) -> Self;
    fn sat_add(self, other: Self) -> Self;
    fn index(self) -> usize;
    /// The squared distances of the `N` pixels whose row window `seg` holds (see [`window_min`]),
    /// or None when every candidate in `seg` is capped (≥ `capsq`): then each pixel's minimum is
    /// `capsq`. `WIDE` as in [`Lane::look_up`].
    #[inline(always)]
    fn block_min<const N: usize, const WIDE: bool>(
        seg: &[Self],
        window: usize,
        capsq: Self,
    ) -> Option<[Self; N]> {
        if seg.iter().fold(capsq, |m, &v| m.min(v)) == capsq {
            return None;
        }
        Some(window_min::<Self, N>(seg, window))
    }
    /// `out[i] = lut[d2[i]]` (indices clamped to the table); `WIDE` only from
    /// [`windowed_field_avx2`] and [`windowed_field_vbmi`], where a lane type may look up in AVX2
    /// vectors, or in AVX-512 byte permutations where the table has planes (only in the latter).
    #[inline(always)]
    fn look_up<const WIDE: bool>(d2: &[Self], lut: &Lut, out: &mut [f32]) {
        let lut = lut.f;
        let top = lut.len() - 1;
        for (o, &d) in out.iter_mut().zip(d2) {
            *o = lut[d.index().min(top)];
        }
    }
}

impl Lane for u8 {
    #[inline(always)]
    fn block_min<const N: usize, const WIDE: bool>(
        seg: &[Self],
        window: usize,
        capsq: Self,
    ) -> Option<[Self; N]> {
        #[cfg(target_arch = "x86_64")]
        if WIDE && N == 64 {
            // SAFETY: WIDE is only set by `windowed_field_avx2` and `windowed_field_vbmi`, which
            // run on CPUs with AVX2.
            let wide = unsafe { block_min_bytes_avx2(seg, window, capsq) }?;
            let mut d2 = [0; N];
            d2.copy_from_slice(&wide);
            return Some(d2);
        }
        if seg.iter().fold(capsq, |m, &v| m.min(v)) == capsq {
            return None;
        }
        Some(window_min::<Self, N>(seg, window))
    }
    #[inline(always)]
    fn look_up<const WIDE: bool>(d2: &[Self], lut: &Lut, out: &mut [f32]) {
        #[cfg(target_arch = "x86_64")]
        if let Some(planes) = lut.planes {
            // SAFETY: planes exist only in `windowed_field_vbmi`, which runs on CPUs with
            // AVX-512F, BW and VBMI.
            unsafe { look_up_bytes_vbmi(d2, planes, lut.f.len() - 1, out) };
            return;
        }
        let lut = lut.f;
        #[cfg(target_arch = "x86_64")]
        if WIDE {
            // SAFETY: WIDE is only set by `windowed_field_avx2` and `windowed_field_vbmi`, which
            // run on CPUs with AVX2.
            unsafe { look_up_bytes_avx2(d2, lut, out) };
            return;
        }
        let top = lut.len() - 1;
        for (o, &d) in out.iter_mut().zip(d2) {
            *o = lut[usize::from(d).min(top)];
        }
    }
    #[inline]
    fn from_small(v: usize) -> Self {
        v as u8
    }
    #[inline]
    fn sat_add(self, other: Self) -> Self {
        self.saturating_add(other)
    }
    #[inline]
    fn index(self) -> usize {
        usize::from(self)
    }
}

impl Lane for i16 {
    #[inline]
    fn from_small(v: usize) -> Self {
        v as i16
    }
    #[inline]
    fn sat_add(self, other: Self) -> Self {
        self.saturating_add(other)
    }
    #[inline]
    fn index(self) -> usize {
        self.max(0) as usize
    }
}

/// [`Lane::block_min`] for 64 byte lanes, the block held in two AVX2 registers. Before, the
/// compiler kept the block on the stack and tested for the early stop with a horizontal maximum.
/// The same minima (`adds_epu8` is `saturating_add`); the stop is tested at every offset, as "k²
/// subtracted from every lane with saturation leaves zero", i.e. every pixel already has a
/// candidate no farther than k²: the offsets from k on cannot lower any pixel, so stopping at
/// any such k gives the same values as [`window_min`].
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn block_min_bytes_avx2(seg: &[u8], window: usize, capsq: u8) -> Option<[u8; 64]> {
    use std::arch::x86_64::*;
    let n = seg.len();
    // Offsets up to ⌊τ⌋ ≤ MAX_BYTE_WINDOW_PX keep k² within a byte.
    assert!(n >= 2 * window + 64 && window <= MAX_BYTE_WINDOW_PX);
    let load = |i: usize| {
        debug_assert!(i + 32 <= n);
        // SAFETY: every caller's i + 32 ≤ n (the assertion above).
        unsafe { _mm256_loadu_si256(seg.as_ptr().add(i).cast()) }
    };
    // Capped everywhere: every byte ≥ capsq (the last load overlaps the ones before, which the
    // minimum does not mind).
    let mut low = load(n - 32);
    for i in (0..n - 32).step_by(32) {
        low = _mm256_min_epu8(low, load(i));
    }
    let cap = _mm256_set1_epi8(capsq as i8);
    let below_cap = _mm256_subs_epu8(cap, low);
    if _mm256_testz_si256(below_cap, below_cap) == 1 {
        return None;
    }
    let (mut a0, mut a1) = (load(window), load(window + 32));
    for k in 1..=window {
        let kk = _mm256_set1_epi8((k * k) as u8 as i8);
        let above = _mm256_or_si256(_mm256_subs_epu8(a0, kk), _mm256_subs_epu8(a1, kk));
        if _mm256_testz_si256(above, above) == 1 {
            break;
        }
        let (l, r) = (window - k, window + k);
        a0 = _mm256_min_epu8(a0, _mm256_adds_epu8(_mm256_min_epu8(load(l), load(r)), kk));
        a1 = _mm256_min_epu8(
            a1,
            _mm256_adds_epu8(_mm256_min_epu8(load(l + 32), load(r + 32)), kk),
        );
    }
    let mut d2 = [0u8; 64];
    // SAFETY: two 32-byte stores into the 64-byte array.
    unsafe {
        _mm256_storeu_si256(d2.as_mut_ptr().cast(), a0);
        _mm256_storeu_si256(d2.as_mut_ptr().add(32).cast(), a1);
    }
    Some(d2)
}

/// `out[i] = lut[min(d2[i], lut.len() − 1)]`, eight lanes to a gather from the (L1-resident)
/// table; the same entries as the scalar lookup.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn look_up_bytes_avx2(d2: &[u8], lut: &[f32], out: &mut [f32]) {
    use std::arch::x86_64::*;
    let top = lut.len() - 1;
    let n = out.len().min(d2.len());
    let whole = if top <= usize::from(u8::MAX) {
        n / 8 * 8
    } else {
        0
    };
    // SAFETY: loads and stores stay within the first `whole` ≤ n lanes of `d2` and `out`, and
    // every index is clamped to `top`, inside `lut`.
    unsafe {
        let clamp = _mm_set1_epi8(top as u8 as i8);
        for i in (0..whole).step_by(8) {
            let bytes = _mm_min_epu8(_mm_loadl_epi64(d2.as_ptr().add(i).cast()), clamp);
            let v = _mm256_i32gather_ps::<4>(lut.as_ptr(), _mm256_cvtepu8_epi32(bytes));
            _mm256_storeu_ps(out.as_mut_ptr().add(i), v);
        }
    }
    for i in whole..n {
        out[i] = lut[usize::from(d2[i]).min(top)];
    }
}

/// The interleave in [`look_up_bytes_vbmi`] puts output dword m of register q, 128-bit lane l,
/// at input byte 16l + 4q + m; so that register q holds outputs 16q..16q + 16 in order, byte
/// 16l + 4q + m must hold input 16q + 4l + m.
#[cfg(target_arch = "x86_64")]
const VBMI_ORDER: [u8; 64] = {
    let mut order = [0u8; 64];
    let mut i = 0;
    while i < 64 {
        order[i] = ((i / 4 % 4) * 16 + (i / 16) * 4 + i % 4) as u8;
        i += 1;
    }
    order
};

/// `out[i] = lut[min(d2[i], top)]` from the byte planes of `lut` (`top` < 128), 64 lanes at a time:
/// each plane's bytes by one two-register byte permutation, then the four planes interleaved
/// into the entries' bytes, little-endian. The same entries as the scalar lookup (a copy of their
/// bits). The interleave works within 128-bit lanes; the lanes are put in an order beforehand
/// that the interleave undoes.
///
/// # Safety
/// The CPU must have AVX-512F, BW and VBMI.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512vbmi")]
#[inline]
fn look_up_bytes_vbmi(d2: &[u8], planes: &BytePlanes, top: usize, out: &mut [f32]) {
    use std::arch::x86_64::*;
    debug_assert!(top < 128);
    let n = out.len().min(d2.len());
    // SAFETY: the loads read the 64-byte `order` and the two halves of each 128-byte plane; the
    // masked loads and stores touch only the first `n` lanes of `d2` and `out`.
    unsafe {
        let order = _mm512_loadu_si512(VBMI_ORDER.as_ptr().cast());
        let clamp = _mm512_set1_epi8(top as i8);
        let half = |k: usize, h: usize| _mm512_loadu_si512(planes[k].as_ptr().add(64 * h).cast());
        let tables: [[__m512i; 2]; 4] = std::array::from_fn(|k| [half(k, 0), half(k, 1)]);
        for i in (0..n).step_by(64) {
            let len = (n - i).min(64);
            let at = d2.as_ptr().add(i);
            // A whole block as two 32-byte loads: the caller's block was just stored as two
            // 32-byte halves, and one 64-byte load across both stores would stall until they
            // retire (store forwarding fails; 19 % of the row pass in perf).
            let idx = if len == 64 {
                let low = _mm512_castsi256_si512(_mm256_loadu_si256(at.cast()));
                _mm512_inserti64x4::<1>(low, _mm256_loadu_si256(at.add(32).cast()))
            } else {
                _mm512_maskz_loadu_epi8(u64::MAX >> (64 - len), at.cast())
            };
            let idx = _mm512_permutexvar_epi8(order, _mm512_min_epu8(idx, clamp));
            let b: [__m512i; 4] =
                std::array::from_fn(|k| _mm512_permutex2var_epi8(tables[k][0], idx, tables[k][1]));
            let (lo01, hi01) = (
                _mm512_unpacklo_epi8(b[0], b[1]),
                _mm512_unpackhi_epi8(b[0], b[1]),
            );
            let (lo23, hi23) = (
                _mm512_unpacklo_epi8(b[2], b[3]),
                _mm512_unpackhi_epi8(b[2], b[3]),
            );
            let quarters = [
                _mm512_unpacklo_epi16(lo01, lo23),
                _mm512_unpackhi_epi16(lo01, lo23),
                _mm512_unpacklo_epi16(hi01, hi23),
                _mm512_unpackhi_epi16(hi01, hi23),
            ];
            for (q, &v) in quarters.iter().enumerate() {
                let rem = len.saturating_sub(16 * q).min(16);
                if rem == 0 {
                    break;
                }
                let keep = (u32::MAX >> (32 - rem)) as u16;
                let at = out.as_mut_ptr().add(i + 16 * q);
                _mm512_mask_storeu_ps(at, keep, _mm512_castsi512_ps(v));
            }
        }
    }
}

/// Row pass over the capped column distances `col`: f of the squared distance, via `lut`.
#[inline(always)]
fn row_pass<T: Lane, const N: usize, const WIDE: bool>(
    col: &[u8],
    w: usize,
    window: usize,
    cap: u8,
    out: &mut [f32],
    row: &mut Vec<T>,
    table: &Lut,
) {
    let lut = table.f;
    let top = lut.len() - 1;
    // Pads of cap² keep the row window free of bounds tests; the right pad also rounds the
    // row up to whole blocks.
    let capsq = T::from_small(usize::from(cap) * usize::from(cap));
    let far = lut[capsq.index().min(top)];
    row.clear();
    row.resize(window + w.div_ceil(N) * N + window, capsq);
    for (g, orow) in col.chunks_exact(w).zip(out.chunks_exact_mut(w)) {
        for (p, &gv) in row[window..window + w].iter_mut().zip(g) {
            *p = T::from_small(usize::from(gv) * usize::from(gv));
        }
        for (x0, oblock) in (0..w).step_by(N).zip(orow.chunks_mut(N)) {
            let seg = &row[x0..x0 + 2 * window + N];
            // Every candidate of the block capped (no active pixel within the cap of any of its
            // pixels, most of a roi): each pixel's minimum is cap², whose f is `far`. The same
            // value the window and the table give, without the window's full ⌊τ⌋ offsets.
            match T::block_min::<N, WIDE>(seg, window, capsq) {
                None => oblock.fill(far),
                Some(d2) => T::look_up::<WIDE>(&d2[..oblock.len()], table, oblock),
            }
        }
    }
}

/// Vertical distance to the nearest active pixel of the same column, capped at `cap`.
#[inline(always)]
fn column_pass(mask: &[u8], w: usize, h: usize, cap: u8, col: &mut Vec<u8>) {
    // Every entry is overwritten below, so only new ones need initialising.
    col.resize(w * h, 0);
    // Row-wise sweeps so each step is a vectorisable operation over a whole row; the first row
    // sees a virtual row of `cap` above it.
    for (g, &m) in col[..w].iter_mut().zip(&mask[..w]) {
        *g = cap & inactive(m);
    }
    for y in 1..h {
        let (done, rest) = col.split_at_mut(y * w);
        sweep_down(
            &mut rest[..w],
            &done[(y - 1) * w..],
            &mask[y * w..(y + 1) * w],
            cap,
        );
    }
    for y in (0..h.saturating_sub(1)).rev() {
        let (upper, lower) = col.split_at_mut((y + 1) * w);
        sweep_up(&mut upper[y * w..], &lower[..w]);
    }
}

/// One row of the downward sweep: 0 on active pixels, else one more than above, capped.
#[inline(always)]
fn sweep_down(row: &mut [u8], above: &[u8], mask: &[u8], cap: u8) {
    for ((g, &a), &m) in row.iter_mut().zip(above).zip(mask) {
        *g = a.saturating_add(1).min(cap) & inactive(m);
    }
}

/// 0xFF for an inactive mask pixel, 0 for an active one: a select written as a bit mask so that
/// the sweeps vectorise.
#[inline(always)]
fn inactive(m: u8) -> u8 {
    u8::from(m != 0).wrapping_sub(1)
}

/// One row of the upward sweep: the nearer of the downward distance and one more than below.
#[inline(always)]
fn sweep_up(row: &mut [u8], below: &[u8]) {
    for (g, &b) in row.iter_mut().zip(below) {
        *g = (*g).min(b.saturating_add(1));
    }
}

/// Squared distances of N pixels: min over offsets k in −window..=window of row[x + k] + k²,
/// where `seg` starts `window` pixels before the block. Stops once k² reaches the block's
/// current maximum, since no farther candidate can then improve any pixel.
#[inline(always)]
fn window_min<T: Lane, const N: usize>(seg: &[T], window: usize) -> [T; N] {
    let mut acc = [T::default(); N];
    acc.copy_from_slice(&seg[window..window + N]);
    for k in 1..=window {
        let kk = T::from_small(k * k);
        // The test costs about as much as an offset, so it runs at every other one: the offsets
        // it would have skipped leave every pixel as it is (their candidates are at least k²,
        // already no better than any pixel's current value).
        if k % 2 == 0 && acc.iter().fold(T::default(), |m, &a| m.max(a)) <= kk {
            break;
        }
        let left = &seg[window - k..window - k + N];
        let right = &seg[window + k..window + k + N];
        for ((a, &l), &r) in acc.iter_mut().zip(left).zip(right) {
            *a = (*a).min(l.min(r).sat_add(kk));
        }
    }
    acc
}

/// Exact Euclidean distance (px) from each pixel of a `w`×`h` mask to its nearest nonzero pixel;
/// +∞ everywhere when there is none. Felzenszwalb–Huttenlocher, untruncated: the oracle the
/// truncated build is checked against, and its fallback for very large τ.
pub fn euclidean_distance(mask: &[u8], w: usize, h: usize, out: &mut [f32]) -> Result<()> {
    let n = w
        .checked_mul(h)
        .ok_or_else(|| Error::InvalidArgument(format!("mask {w}x{h} is too large")))?;
    ensure(mask.len() == n && out.len() == n, || {
        format!(
            "mask ({}) and output ({}) must both hold {w}x{h} = {n} pixels",
            mask.len(),
            out.len()
        )
    })?;
    if n == 0 {
        return Ok(());
    }
    exact_squared_edt(mask, w, h, out, &mut Vec::new(), &mut FhScratch::default());
    for v in out.iter_mut() {
        *v = v.sqrt();
    }
    Ok(())
}

#[derive(Debug, Clone, Default)]
struct FhScratch {
    /// Parabola vertices, their heights and left boundaries of the lower envelope.
    v: Vec<usize>,
    f: Vec<f64>,
    z: Vec<f64>,
}

/// Squared EDT into `out`: vertical squared distances, then the 1-D lower envelope per row.
/// f64 inside, since squared distances of large images exceed f32's exact integers.
fn exact_squared_edt(
    mask: &[u8],
    w: usize,
    h: usize,
    out: &mut [f32],
    d2: &mut Vec<f64>,
    fh: &mut FhScratch,
) {
    d2.clear();
    d2.resize(w * h, f64::INFINITY);
    for x in 0..w {
        let mut last: Option<usize> = None;
        for y in 0..h {
            if mask[y * w + x] != 0 {
                last = Some(y);
            }
            if let Some(l) = last {
                d2[y * w + x] = ((y - l) as f64).powi(2);
            }
        }
        let mut next: Option<usize> = None;
        for y in (0..h).rev() {
            if mask[y * w + x] != 0 {
                next = Some(y);
            }
            if let Some(nx) = next {
                let o = &mut d2[y * w + x];
                *o = o.min(((nx - y) as f64).powi(2));
            }
        }
    }
    for (frow, orow) in d2.chunks_exact(w).zip(out.chunks_exact_mut(w)) {
        lower_envelope(frow, orow, fh);
    }
}

/// 1-D squared distance transform: out[q] = min_p (q − p)² + f[p] (Felzenszwalb–Huttenlocher).
fn lower_envelope(f: &[f64], out: &mut [f32], s: &mut FhScratch) {
    s.v.clear();
    s.f.clear();
    s.z.clear();
    for (p, &fp) in f.iter().enumerate() {
        if !fp.is_finite() {
            continue;
        }
        let pf = p as f64;
        while let (Some(&q), Some(&fq), Some(&zq)) = (s.v.last(), s.f.last(), s.z.last()) {
            let qf = q as f64;
            // Where the parabola of p starts to lie below the one of q.
            let cross = ((fp + pf * pf) - (fq + qf * qf)) / (2.0 * (pf - qf));
            if cross > zq {
                s.z.push(cross);
                break;
            }
            s.v.pop();
            s.f.pop();
            s.z.pop();
        }
        if s.v.is_empty() {
            s.z.push(f64::NEG_INFINITY);
        }
        s.v.push(p);
        s.f.push(fp);
    }
    if s.v.is_empty() {
        out.fill(f32::INFINITY);
        return;
    }
    let mut k = 0;
    for (q, o) in out.iter_mut().enumerate() {
        let qf = q as f64;
        while k + 1 < s.v.len() && s.z[k + 1] < qf {
            k += 1;
        }
        let d = qf - s.v[k] as f64;
        *o = (d * d + s.f[k]) as f32;
    }
}

/// All-ones in the lanes where 0 ≤ x < w and 0 ≤ y < h, zero elsewhere. The comparisons are
/// ordered, so a NaN coordinate is outside.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) fn lanes_in_box_avx2(
    x: std::arch::x86_64::__m256,
    y: std::arch::x86_64::__m256,
    w: f32,
    h: f32,
) -> std::arch::x86_64::__m256 {
    use std::arch::x86_64::*;
    let zero = _mm256_setzero_ps();
    _mm256_and_ps(
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GE_OQ>(x, zero),
            _mm256_cmp_ps::<_CMP_GE_OQ>(y, zero),
        ),
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_LT_OQ>(x, _mm256_set1_ps(w)),
            _mm256_cmp_ps::<_CMP_LT_OQ>(y, _mm256_set1_ps(h)),
        ),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    fn random_mask(w: usize, h: usize, density: f64, seed: u64) -> Vec<u8> {
        let mut rng = Rng::new(seed);
        (0..w * h)
            .map(|_| u8::from(rng.uniform() < density))
            .collect()
    }

    /// O(n²) reference distance to the nearest active pixel.
    fn brute_distance(mask: &[u8], w: usize, h: usize) -> Vec<f32> {
        let active: Vec<(f64, f64)> = (0..w * h)
            .filter(|&i| mask[i] != 0)
            .map(|i| ((i % w) as f64, (i / w) as f64))
            .collect();
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                active
                    .iter()
                    .map(|&(ax, ay)| (ax - x).hypot(ay - y))
                    .fold(f64::INFINITY, f64::min) as f32
            })
            .collect()
    }

    fn field(tau: f32, levels: u32) -> DistanceField {
        DistanceField::new(FieldParams {
            tau_px: tau,
            levels,
        })
        .unwrap()
    }

    /// The star fast path must return the general path's values bit for bit, inside the roi, across
    /// its border (where the general path takes over) and off it.
    #[test]
    fn search_star_matches_single_samples_everywhere() {
        let (w, h) = (61usize, 47usize);
        let mut rng = crate::rng::Rng::new(4);
        let mask: Vec<u8> = (0..w * h).map(|_| u8::from(rng.below(9) == 0)).collect();
        let roi = Roi {
            x0: 17,
            y0: 5,
            width: w as u32,
            height: h as u32,
        };
        let mut f = field(10.0, 1);
        f.build(&mask, roi, 1).unwrap();
        let lvl = f.level(0);
        let (mut inside, mut border) = (0, 0);
        for i in 0..4000 {
            let u = 17.0 - 4.0 + (w as f32 + 8.0) * rng.below(1 << 20) as f32 / (1 << 20) as f32;
            let v = 5.0 - 4.0 + (h as f32 + 8.0) * rng.below(1 << 20) as f32 / (1 << 20) as f32;
            let s = 0.3 + (i % 7) as f32 * 0.4;
            let du: [f32; 6] = std::array::from_fn(|k| s * (k as f32 - 2.5) / 2.5);
            let dv: [f32; 6] = std::array::from_fn(|k| s * (1.5 - k as f32) / 2.5);
            let mut fast = [0.0f32; 13];
            lvl.add_star(u, v, &du, &dv, &mut fast);
            let mut slow = [lvl.sample(u, v); 13];
            for k in 0..6 {
                slow[2 * k + 1] = lvl.sample(u + du[k], v + dv[k]);
                slow[2 * k + 2] = lvl.sample(u - du[k], v - dv[k]);
            }
            assert_eq!(fast, slow, "star at ({u}, {v}) step {s}");
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") {
                let mut wide = [0.0f32; 13];
                // SAFETY: the CPU has AVX2.
                unsafe { lvl.add_star_avx2(u, v, &du, &dv, &mut wide) };
                let bits = |a: &[f32; 13]| a.map(f32::to_bits);
                assert_eq!(bits(&wide), bits(&slow), "AVX2 star at ({u}, {v}) step {s}");
            }
            let x = u - 17.0;
            if x > s + 0.5
                && x < w as f32 - s - 2.0
                && v - 5.0 > s + 0.5
                && v - 5.0 < h as f32 - s - 2.0
            {
                inside += 1;
            } else {
                border += 1;
            }
        }
        assert!(inside > 2000 && border > 500, "{inside} {border}");
    }

    #[test]
    fn rounded_distance_is_huber_shaped_and_capped() {
        assert_eq!(rounded_distance(0.0, 10.0), 0.0);
        assert_eq!(rounded_distance(0.5, 10.0), 0.125);
        assert_eq!(rounded_distance(1.0, 10.0), 0.5);
        assert_eq!(rounded_distance(3.0, 10.0), 2.5);
        assert_eq!(rounded_distance(25.0, 10.0), 9.5);
        assert_eq!(rounded_distance(0.8, 0.5), 0.125);
        // Value and slope continuous where the pieces meet.
        let e = 1e-3;
        assert!((rounded_distance(1.0 - e, 10.0) - rounded_distance(1.0 + e, 10.0)).abs() < 2.1e-3);
        let slope_below =
            (rounded_distance(1.0 - e, 10.0) - rounded_distance(1.0 - 2.0 * e, 10.0)) / e;
        assert!((slope_below - 1.0).abs() < 3e-3, "{slope_below}");
    }

    #[test]
    fn exact_distance_of_a_single_pixel() {
        let (w, h) = (7, 5);
        let mut mask = vec![0u8; w * h];
        mask[2 * w + 4] = 1;
        let mut d = vec![0.0; w * h];
        euclidean_distance(&mask, w, h, &mut d).unwrap();
        assert_eq!(d[2 * w + 4], 0.0);
        assert_eq!(d[2 * w], 4.0);
        assert!((d[6] - 8f32.sqrt()).abs() < 1e-6);
        assert!((d[4 * w] - 20f32.sqrt()).abs() < 1e-6);

        let mut f = field(2.5, 1);
        f.build(&mask, Roi::full(7, 5), 1).unwrap();
        let v = &f.level(0).value;
        assert_eq!(v[2 * w + 4], 0.0);
        assert_eq!(v[2 * w + 5], 0.5);
        assert!((v[w + 5] - (2f32.sqrt() - 0.5)).abs() < 1e-6);
        assert_eq!(v[2 * w + 6], 1.5);
        assert_eq!(v[2 * w], 2.0, "4 px away is capped at f(2.5)");
        assert_eq!(f.level(0).max_value(), 2.0);
    }

    #[test]
    fn exact_distance_matches_brute_force() {
        for (i, &(w, h, density)) in [
            (1, 1, 1.0),
            (1, 9, 0.2),
            (13, 1, 0.2),
            (31, 17, 0.01),
            (40, 33, 0.3),
            (64, 5, 0.05),
        ]
        .iter()
        .enumerate()
        {
            let mask = random_mask(w, h, density, i as u64);
            let mut d = vec![0.0; w * h];
            euclidean_distance(&mask, w, h, &mut d).unwrap();
            for (a, b) in d.iter().zip(brute_distance(&mask, w, h)) {
                assert!(a == &b || (a - b).abs() < 1e-4, "{w}x{h}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn truncated_build_equals_rounded_exact_distance() {
        let cases = [
            (97, 61, 0.02, 10.0),
            (50, 40, 0.001, 10.0),
            (33, 29, 0.1, 3.7),
            (17, 70, 0.05, 1.0),
            (20, 20, 0.05, 0.4),
            (45, 38, 0.003, 40.0),
            (45, 38, 0.003, 250.0),
            (1, 30, 0.1, 10.0),
            (30, 1, 0.1, 10.0),
        ];
        for (i, &(w, h, density, tau)) in cases.iter().enumerate() {
            let mask = random_mask(w, h, density, 100 + i as u64);
            let mut d = vec![0.0; w * h];
            euclidean_distance(&mask, w, h, &mut d).unwrap();
            let mut f = field(tau, 1);
            f.build(&mask, Roi::full(w as u32, h as u32), 1).unwrap();
            for (k, (&v, &dk)) in f.level(0).value.iter().zip(&d).enumerate() {
                let want = rounded_distance(dk, tau);
                assert!(
                    (v - want).abs() < 1e-5,
                    "{w}x{h} tau {tau} at {k}: {v} vs {want} (D {dk})"
                );
            }
        }
    }

    /// The AVX2 build, the AVX-512 VBMI build (where the CPU has it) and the SSE2 build give the
    /// same values bit for bit, in byte lanes (τ ≤ 14; the VBMI lookup for τ < 11) and halfword
    /// lanes, on sparse masks (mostly capped blocks) and dense ones, with rows of whole blocks and
    /// with a partial last block.
    #[test]
    fn vector_widths_build_the_same_field() {
        for (i, &(w, h, density, tau)) in [
            (434usize, 141usize, 0.002, 10.0f32),
            (97, 61, 0.05, 10.0),
            (130, 77, 0.0005, 14.5),
            (101, 83, 0.01, 3.2),
            (90, 70, 0.003, 22.0),
            (65, 9, 0.3, 10.0),
            (128, 40, 0.02, 7.5),
        ]
        .iter()
        .enumerate()
        {
            let mask = random_mask(w, h, density, 300 + i as u64);
            let window = tau.floor() as usize;
            // 0: SSE2, 1: AVX2, 2: AVX-512 VBMI; None where the CPU lacks the path.
            let run = |path: u8| {
                let mut s = Scratch::default();
                let mut out = vec![0.0f32; w * h];
                let bufs = WindowBufs {
                    col: &mut s.col,
                    row8: &mut s.row8,
                    row16: &mut s.row16,
                    lut: &mut s.lut,
                };
                if path == 0 {
                    windowed_field::<32, 16, false, false>(
                        &mask, w, h, tau, window, &mut out, bufs,
                    );
                    return Some(out);
                }
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("avx2") {
                    if path == 1 {
                        // SAFETY: the CPU has AVX2.
                        unsafe { windowed_field_avx2(&mask, w, h, tau, window, &mut out, bufs) };
                        return Some(out);
                    }
                    if has_vbmi() {
                        // SAFETY: the CPU has AVX2, AVX-512F, BW and VBMI.
                        unsafe { windowed_field_vbmi(&mask, w, h, tau, window, &mut out, bufs) };
                        return Some(out);
                    }
                }
                None
            };
            let narrow = run(0).unwrap();
            let mut d = vec![0.0; w * h];
            euclidean_distance(&mask, w, h, &mut d).unwrap();
            for (&v, &dk) in narrow.iter().zip(&d) {
                assert!((v - rounded_distance(dk, tau)).abs() < 1e-5);
            }
            for path in [1, 2] {
                if let Some(wide) = run(path) {
                    let same = narrow
                        .iter()
                        .zip(&wide)
                        .all(|(a, b)| a.to_bits() == b.to_bits());
                    assert!(same, "case {i}, path {path}");
                }
            }
        }
    }

    /// The VBMI lookup gives the table's entries bit for bit for every byte index (clamped to the
    /// table) and every length up to two blocks.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn vbmi_lookup_copies_the_table() {
        if !has_vbmi() {
            return;
        }
        for len in [1usize, 2, 11, 100, 121, 122, 128] {
            // Entries with every byte distinct, and NaN payloads, so a swapped plane shows.
            let lut: Vec<f32> = (0..len as u32)
                .map(|i| f32::from_bits(0x7FC0_0000 ^ (i * 0x0103_0507)))
                .collect();
            let planes = byte_planes::<true>(&lut).unwrap();
            for n in 0..=130usize {
                let d2: Vec<u8> = (0..n).map(|i| (i * 37 + len) as u8).collect();
                let mut out = vec![0.0f32; n + 3];
                // SAFETY: the CPU has AVX-512F, BW and VBMI.
                unsafe { look_up_bytes_vbmi(&d2, &planes, len - 1, &mut out[..n]) };
                for (i, &d) in d2.iter().enumerate() {
                    assert_eq!(
                        out[i].to_bits(),
                        lut[usize::from(d).min(len - 1)].to_bits(),
                        "len {len}, n {n}, lane {i}"
                    );
                }
                assert!(out[n..].iter().all(|&v| v == 0.0), "wrote past {n}");
            }
        }
    }

    #[test]
    fn empty_mask_is_flat_at_the_cap() {
        let mut d = vec![0.0; 12];
        euclidean_distance(&[0; 12], 4, 3, &mut d).unwrap();
        assert!(d.iter().all(|v| v.is_infinite()));
        let mut f = field(6.0, 3);
        f.build(
            &[0; 12 * 9],
            Roi {
                x0: 5,
                y0: 3,
                width: 12,
                height: 9,
            },
            3,
        )
        .unwrap();
        for lvl in &f.levels {
            assert!(lvl.value.iter().all(|&v| v == 5.5));
        }
    }

    #[test]
    fn pyramid_or_pools_on_the_absolute_grid() {
        let roi = Roi {
            x0: 3,
            y0: 1,
            width: 21,
            height: 14,
        };
        let (w, h) = (roi.width as usize, roi.height as usize);
        let mask = random_mask(w, h, 0.01, 7);
        let mut f = field(4.0, 3);
        f.build(&mask, roi, 3).unwrap();
        assert_eq!(f.n_built(), 3);
        for l in 0..3u32 {
            let lvl = f.level(l);
            let lr = roi.at_level(l);
            assert_eq!((lvl.level, lvl.roi), (l, lr));
            let (lw, lh) = (lr.width as usize, lr.height as usize);
            let mut pooled = vec![0u8; lw * lh];
            for (i, _) in mask.iter().enumerate().filter(|(_, &m)| m != 0) {
                let (gx, gy) = (roi.x0 as usize + i % w, roi.y0 as usize + i / w);
                pooled[((gy >> l) - lr.y0 as usize) * lw + (gx >> l) - lr.x0 as usize] = 1;
            }
            let want = brute_distance(&pooled, lw, lh);
            for (&v, &d) in lvl.value.iter().zip(&want) {
                assert!((v - rounded_distance(d, 4.0)).abs() < 1e-5, "level {l}");
            }
        }
        // One active pixel at absolute (8, 5) is level-1 pixel (4, 2) and level-2 pixel (2, 1).
        let mut one = vec![0u8; w * h];
        one[(5 - 1) * w + (8 - 3)] = 1;
        f.build(&one, roi, 3).unwrap();
        assert_eq!(f.level(1).sample(4.0, 2.0), 0.0);
        assert_eq!(f.level(1).sample(5.0, 2.0), 0.5);
        assert_eq!(f.level(2).sample(2.0, 1.0), 0.0);
        assert_eq!(f.level(2).sample(1.0, 1.0), 0.5);
    }

    #[test]
    fn sample_interpolates_and_caps_outside() {
        let roi = Roi {
            x0: 10,
            y0: 20,
            width: 30,
            height: 25,
        };
        let mut mask = vec![0u8; roi.area()];
        for y in 0..25 {
            mask[y * 30 + 12] = 1; // vertical line at absolute u = 22
        }
        let mut f = field(10.0, 1);
        f.build(&mask, roi, 1).unwrap();
        let l = f.level(0);
        assert_eq!(l.sample(22.0, 30.0), 0.0);
        assert_eq!(l.sample(25.0, 30.0), 2.5);
        assert!((l.sample(25.25, 30.7) - 2.75).abs() < 1e-6);
        assert!((l.sample(22.5, 31.0) - 0.25).abs() < 1e-6);
        // On the linear flank of the line the slope is exactly the finite-difference slope.
        let [val, gu, gv] = l.sample_slope(25.25, 30.7);
        let fd = (l.sample(25.3, 30.7) - l.sample(25.2, 30.7)) / 0.1;
        assert!(
            (val - 2.75).abs() < 1e-6
                && (gu - 1.0).abs() < 1e-6
                && gv == 0.0
                && (fd - 1.0).abs() < 1e-4
        );
        let [_, gu, _] = l.sample_slope(19.5, 30.0);
        assert!(
            (gu + 1.0).abs() < 1e-6,
            "left flank slopes down towards the line: {gu}"
        );
        assert_eq!(l.sample(0.0, 30.0), 9.5);
        assert_eq!(l.sample(f32::NAN, 30.0), 9.5);
        assert_eq!(l.sample(25.0, f32::INFINITY), 9.5);
        // Half a pixel past the last row blends the edge row with the cap.
        assert!((l.sample(25.0, 44.5) - 0.5 * (2.5 + 9.5)).abs() < 1e-6);
        assert_eq!(l.sample_slope(f32::NAN, 0.0), [9.5, 0.0, 0.0]);
    }

    #[test]
    fn partial_builds_reuse_buffers() {
        let roi = Roi::full(40, 30);
        let mask = random_mask(40, 30, 0.05, 11);
        let mut f = field(5.0, 3);
        f.build(&mask, roi, 3).unwrap();
        assert_eq!(f.n_built(), 3);
        f.build(&mask, roi, 1).unwrap();
        assert_eq!(f.n_built(), 1);
        assert_eq!(f.level(1).roi.area(), 0);
        assert_eq!(f.level(2).sample(3.0, 3.0), 4.5);
        assert_eq!(f.level(9).level, 2);

        // Rebuilding into reused buffers gives what a fresh field gives.
        let small = Roi {
            x0: 1,
            y0: 2,
            width: 9,
            height: 7,
        };
        let small_mask = random_mask(9, 7, 0.1, 12);
        f.build(&small_mask, small, 3).unwrap();
        let mut fresh = field(5.0, 3);
        fresh.build(&small_mask, small, 3).unwrap();
        assert_eq!(f.levels, fresh.levels);
    }

    #[test]
    fn bad_parameters_are_errors() {
        for tau in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            assert!(
                DistanceField::new(FieldParams {
                    tau_px: tau,
                    levels: 3
                })
                .is_err(),
                "tau {tau}"
            );
        }
        for levels in [0, 4] {
            assert!(DistanceField::new(FieldParams {
                tau_px: 10.0,
                levels
            })
            .is_err());
        }
        let mut f = DistanceField::new(FieldParams::default()).unwrap();
        let roi = Roi::full(4, 4);
        assert!(f.build(&[0; 15], roi, 1).is_err());
        assert!(f.build(&[0; 16], roi, 0).is_err());
        assert!(f.build(&[0; 16], roi, 4).is_err());
        assert!(f
            .build(
                &[0; 16],
                Roi {
                    x0: u32::MAX,
                    y0: 0,
                    width: 4,
                    height: 4
                },
                1,
            )
            .is_err());
        f.params.tau_px = f32::NAN;
        assert!(f.build(&[0; 16], roi, 1).is_err());
        assert!(euclidean_distance(&[0; 15], 4, 4, &mut [0.0; 16]).is_err());
        assert!(euclidean_distance(&[0; 16], 4, 4, &mut [0.0; 15]).is_err());
        assert!(euclidean_distance(&[], usize::MAX, 2, &mut []).is_err());
        // A hand-emptied level list still answers, with the cap.
        f.params.tau_px = 10.0;
        f.levels.clear();
        assert_eq!(f.level(0).sample(1.0, 1.0), 9.5);
        f.build(&[1; 16], roi, 3).unwrap();
        assert_eq!(f.levels.len(), 3);
    }
}
