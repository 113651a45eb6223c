//! The shared cost of Eq. (1): the distance field sampled at the model points S* warped by a pose
//! and projected to the rectified image, plus the image Jacobian both solvers need.
//!
//! Increments are applied about a pivot c (the model's centroid in the camera frame), with axes
//! parallel to the camera's: P' = c + exp(ξ)·(P − c). Rotating about the object instead of the camera
//! centre keeps the six axes nearly independent in the image (a camera-centred rotation is mostly a
//! translation of a distant object), which is what the one-pixel candidates of the search assume
//! and what keeps the LM normal equations well conditioned.

use crate::camera::Camera;
use crate::se3::{self, Pose};
use nalgebra::{Translation3, Vector3, Vector6};

/// A 2D cost surface in one pyramid level's pixel grid (pixel centres at integer coordinates).
pub trait CostMap {
    /// Bilinear value at (u, v); the truncation value outside the surface.
    fn sample(&self, u: f32, v: f32) -> f32;
    /// (value, ∂/∂u, ∂/∂v); zero gradient outside.
    fn sample_grad(&self, u: f32, v: f32) -> [f32; 3];
    /// The truncation value: what a point far from every event (or off the map) costs.
    fn max_value(&self) -> f32;
    /// Adds to `sums` the 13 values of a search star: `sums[0]` at (u, v), `sums[2k+1]` at
    /// (u + du[k], v + dv[k]) and `sums[2k+2]` at (u − du[k], v − dv[k]). A map may override this
    /// with a faster path for stars that lie wholly inside it.
    #[inline]
    fn add_star(&self, u: f32, v: f32, du: &[f32; 6], dv: &[f32; 6], sums: &mut [f32; 13]) {
        sums[0] += self.sample(u, v);
        for k in 0..6 {
            sums[2 * k + 1] += self.sample(u + du[k], v + dv[k]);
            sums[2 * k + 2] += self.sample(u - du[k], v - dv[k]);
        }
    }
    /// [`Self::add_star`] for callers compiled for AVX2; a map may override it with a version
    /// that uses AVX2 and returns the same sums.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[inline(always)]
    unsafe fn add_star_avx2(
        &self,
        u: f32,
        v: f32,
        du: &[f32; 6],
        dv: &[f32; 6],
        sums: &mut [f32; 13],
    ) {
        self.add_star(u, v, du, dv, sums)
    }
    /// [`Self::sample_grad`] at the eight points in the lanes of `u` and `v`, for callers compiled
    /// for AVX2: a map may return the same values from a vector path; None (the default, and
    /// whenever a map has no vector path for these points) sends the caller to `sample_grad`.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn sample_grad8_avx2(
        &self,
        _u: std::arch::x86_64::__m256,
        _v: std::arch::x86_64::__m256,
    ) -> Option<[std::arch::x86_64::__m256; 3]> {
        None
    }
    /// The search stars of eight points (lanes of `u`, `v`; their offsets `du[k]`, `dv[k]`), for
    /// callers compiled for AVX2: candidate i's eight values in vector i, each the value
    /// [`Self::add_star`] would add for that point and candidate. None (the default, and whenever
    /// a map has no vector path for these stars) sends the caller to the stars one by one.
    ///
    /// # Safety
    /// The CPU must have AVX2.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn stars8_avx2(
        &self,
        _u: std::arch::x86_64::__m256,
        _v: std::arch::x86_64::__m256,
        _du: &[std::arch::x86_64::__m256; 6],
        _dv: &[std::arch::x86_64::__m256; 6],
    ) -> Option<[std::arch::x86_64::__m256; 13]> {
        None
    }
}

/// Points closer to the camera plane than this are treated as unprojectable (metres).
pub const MIN_DEPTH_M: f32 = 1e-3;

/// Pinhole intrinsics of one pyramid level, in f32 for the hot loops.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pinhole {
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
}

impl Pinhole {
    /// The rectified pinhole of `camera` at pyramid level `level` (0 = full resolution).
    pub fn at_level(camera: &Camera, level: u32) -> Self {
        let c = camera.at_level(level);
        Self {
            fx: c.fx as f32,
            fy: c.fy as f32,
            cx: c.cx as f32,
            cy: c.cy as f32,
        }
    }

    #[inline]
    pub fn project(&self, p: [f32; 3]) -> Option<(f32, f32)> {
        if p[2] < MIN_DEPTH_M {
            return None;
        }
        let iz = 1.0 / p[2];
        Some((self.fx * p[0] * iz + self.cx, self.fy * p[1] * iz + self.cy))
    }
}

/// A rigid transform in f32 (row-major rotation, translation) for warping many points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rigid32 {
    pub r: [f32; 9],
    pub t: [f32; 3],
}

impl Rigid32 {
    pub fn from_pose(pose: &Pose) -> Self {
        let m = pose.rotation.to_rotation_matrix();
        let m = m.matrix();
        let t = pose.translation.vector;
        Self {
            r: std::array::from_fn(|i| m[(i / 3, i % 3)] as f32),
            t: [t.x as f32, t.y as f32, t.z as f32],
        }
    }

    #[inline]
    pub fn apply(&self, p: [f32; 3]) -> [f32; 3] {
        let r = &self.r;
        [
            r[0] * p[0] + r[1] * p[1] + r[2] * p[2] + self.t[0],
            r[3] * p[0] + r[4] * p[1] + r[5] * p[2] + self.t[1],
            r[6] * p[0] + r[7] * p[1] + r[8] * p[2] + self.t[2],
        ]
    }
}

/// Apply increment ξ = (v, ω) about `pivot_c` (camera frame): T' = Tr(c)·exp(ξ)·Tr(−c)·T.
pub fn apply_increment(pose: &Pose, xi: &Vector6<f64>, pivot_c: &Vector3<f64>) -> Pose {
    let pivot = Translation3::from(*pivot_c);
    pivot * se3::exp(xi) * pivot.inverse() * pose
}

/// Centroid of a point set (object frame).
pub fn centroid(points: &[[f32; 3]]) -> Vector3<f64> {
    let n = points.len().max(1) as f64;
    points.iter().fold(Vector3::zeros(), |acc, p| {
        acc + Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
    }) / n
}

/// ∂u/∂ξ (2×6, rows u and v) for camera-frame point `p` under an increment about `pivot`.
/// With a = ∂u/∂P, the translation columns are a and the rotation columns are (p − c) × a.
#[inline]
pub fn image_jacobian(pin: &Pinhole, p: [f32; 3], pivot: [f32; 3]) -> [[f32; 6]; 2] {
    let iz = 1.0 / p[2];
    let au = [pin.fx * iz, 0.0, -pin.fx * p[0] * iz * iz];
    let av = [0.0, pin.fy * iz, -pin.fy * p[1] * iz * iz];
    let q = [p[0] - pivot[0], p[1] - pivot[1], p[2] - pivot[2]];
    let row = |a: [f32; 3]| {
        [
            a[0],
            a[1],
            a[2],
            q[1] * a[2] - q[2] * a[1],
            q[2] * a[0] - q[0] * a[2],
            q[0] * a[1] - q[1] * a[0],
        ]
    };
    [row(au), row(av)]
}

/// Eight points warped by `rig` and projected, lane by lane the same operations in the same
/// order as [`Rigid32::apply`] and [`Pinhole::project`] (so the same bits): the camera-frame
/// coordinates and (u, v). None when a point lies in front of the minimum depth, which `project`
/// refuses.
///
/// # Safety
/// The CPU must have AVX2, and `chunk` must hold eight points.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) unsafe fn warp_project8_avx2(
    pin: &Pinhole,
    rig: &Rigid32,
    chunk: &[[f32; 3]],
) -> Option<Projected8> {
    use std::arch::x86_64::*;
    debug_assert_eq!(chunk.len(), 8);
    let base = chunk.as_ptr().cast::<f32>();
    let lanes = _mm256_setr_epi32(0, 3, 6, 9, 12, 15, 18, 21);
    // SAFETY: the gathers read coordinate c of the eight points, within `chunk`.
    let coord = |c: usize| unsafe { _mm256_i32gather_ps::<4>(base.add(c), lanes) };
    let (x, y, z) = (coord(0), coord(1), coord(2));
    let s = _mm256_set1_ps;
    // r[3i]·x + r[3i+1]·y + r[3i+2]·z + t[i], added left to right as in `Rigid32::apply`.
    let row = |i: usize| {
        let r = &rig.r[3 * i..3 * i + 3];
        let xy = _mm256_add_ps(_mm256_mul_ps(s(r[0]), x), _mm256_mul_ps(s(r[1]), y));
        _mm256_add_ps(_mm256_add_ps(xy, _mm256_mul_ps(s(r[2]), z)), s(rig.t[i]))
    };
    let p = [row(0), row(1), row(2)];
    // `Pinhole::project` refuses a depth below the minimum (and takes NaN, which a map refuses).
    if _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(p[2], s(MIN_DEPTH_M))) != 0 {
        return None;
    }
    let iz = _mm256_div_ps(s(1.0), p[2]);
    let u = _mm256_add_ps(_mm256_mul_ps(_mm256_mul_ps(s(pin.fx), p[0]), iz), s(pin.cx));
    let v = _mm256_add_ps(_mm256_mul_ps(_mm256_mul_ps(s(pin.fy), p[1]), iz), s(pin.cy));
    Some(Projected8 { p, u, v })
}

/// What [`warp_project8_avx2`] gives for eight points: camera-frame coordinates (metres) and image
/// positions (level pixels), one lane per point.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(crate) struct Projected8 {
    pub p: [std::arch::x86_64::__m256; 3],
    pub u: std::arch::x86_64::__m256,
    pub v: std::arch::x86_64::__m256,
}

/// [`image_jacobian`] of eight camera-frame points (lanes of `p`), the same operations in the same
/// order per lane (the zero entries of ∂u/∂P included, since 0·q is not always +0), so the same
/// bits.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) unsafe fn image_jacobian8_avx2(
    pin: &Pinhole,
    p: &[std::arch::x86_64::__m256; 3],
    pivot: [f32; 3],
) -> [[std::arch::x86_64::__m256; 6]; 2] {
    use std::arch::x86_64::*;
    let s = _mm256_set1_ps;
    let (mul, sub) = (_mm256_mul_ps, _mm256_sub_ps);
    let iz = _mm256_div_ps(s(1.0), p[2]);
    let zero = _mm256_setzero_ps();
    let au = [
        mul(s(pin.fx), iz),
        zero,
        mul(mul(mul(s(-pin.fx), p[0]), iz), iz),
    ];
    let av = [
        zero,
        mul(s(pin.fy), iz),
        mul(mul(mul(s(-pin.fy), p[1]), iz), iz),
    ];
    let q = [
        sub(p[0], s(pivot[0])),
        sub(p[1], s(pivot[1])),
        sub(p[2], s(pivot[2])),
    ];
    let row = |a: [__m256; 3]| {
        [
            a[0],
            a[1],
            a[2],
            sub(mul(q[1], a[2]), mul(q[2], a[1])),
            sub(mul(q[2], a[0]), mul(q[0], a[2])),
            sub(mul(q[0], a[1]), mul(q[1], a[0])),
        ]
    };
    [row(au), row(av)]
}

/// One model point's term of Eq. (1) at `pose`: the map at its projection. An unprojectable point
/// costs the truncation value, so the cost never rewards pushing points out of view.
#[inline]
pub fn point_cost(map: &impl CostMap, pin: &Pinhole, pose: &Rigid32, x: [f32; 3]) -> f32 {
    pin.project(pose.apply(x))
        .map_or_else(|| map.max_value(), |(u, v)| map.sample(u, v))
}

/// Eq. (1) at `pose`: the sum of [`point_cost`] over the points.
pub fn total_cost(map: &impl CostMap, pin: &Pinhole, pose: &Rigid32, points: &[[f32; 3]]) -> f32 {
    points.iter().map(|&x| point_cost(map, pin, pose, x)).sum()
}

/// Where in the rectified image events can appear: the pixels whose raw position (after
/// distortion) lies on the sensor, shrunk by a margin. Model points that project elsewhere can never
/// meet an event, so they drop out of the cost instead of counting as misses: a part of the object
/// that left the image must not pull the pose towards keeping it in view.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewMask {
    width: u32,
    height: u32,
    valid: Vec<bool>,
}

impl ViewMask {
    /// The mask of raw sensor `camera` (distortion included) in its rectified grid, with every pixel
    /// within `margin_px` of the invalid area or the border removed.
    pub fn new(camera: &Camera, margin_px: f64) -> Self {
        let (w, h) = (camera.width, camera.height);
        let (lo, hi_u, hi_v) = (
            margin_px - 0.5,
            f64::from(w) - 0.5 - margin_px,
            f64::from(h) - 0.5 - margin_px,
        );
        let inside = |u: f64, v: f64| u >= lo && v >= lo && u <= hi_u && v <= hi_v;
        let valid = (0..camera.n_pixels())
            .map(|i| {
                let (u, v) = ((i % w as usize) as f64, (i / w as usize) as f64);
                // Where a lens maps outside the sensor the rectified pixel sees nothing; the
                // border margin applies on both sides of the warp.
                let (ud, vd) = camera.distort_pixel(u, v);
                inside(u, v) && inside(ud, vd)
            })
            .collect();
        Self {
            width: w,
            height: h,
            valid,
        }
    }

    /// True when rectified full-resolution pixel position (u, v) can see events.
    #[inline(always)]
    pub fn contains(&self, u: f32, v: f32) -> bool {
        let (x, y) = (u.round(), v.round());
        x >= 0.0
            && y >= 0.0
            && x < self.width as f32
            && y < self.height as f32
            && self.valid[y as usize * self.width as usize + x as usize]
    }

    /// The points of `points` that project into the mask at `pose` (full-resolution pinhole `pin`),
    /// written to `out` (cleared first).
    pub fn visible_points(
        &self,
        pin: &Pinhole,
        pose: &Rigid32,
        points: &[[f32; 3]],
        out: &mut Vec<[f32; 3]>,
    ) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2.
            unsafe { self.visible_points_avx2(pin, pose, points, out) };
            return;
        }
        self.visible_points_in(pin, pose, points, out);
    }

    /// [`Self::visible_points`] compiled for AVX2, eight points at a time wherever all eight
    /// project: their warp, projection and rounding in vectors ([`warp_project8_avx2`]; the
    /// rounding half away from zero as `f32::round`, up to the sign of a zero, which no test
    /// below tells apart), then the mask read for the lanes inside the image. The same points in
    /// the same order.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn visible_points_avx2(
        &self,
        pin: &Pinhole,
        pose: &Rigid32,
        points: &[[f32; 3]],
        out: &mut Vec<[f32; 3]>,
    ) {
        use std::arch::x86_64::*;
        out.clear();
        let chunks = points.chunks_exact(8);
        let rest = chunks.remainder();
        let (w, h) = (self.width as f32, self.height as f32);
        // `f32::round`: the truncation, moved one away from zero when the dropped part is ≥ ½.
        let round = |x: __m256| {
            let t = _mm256_round_ps::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(x);
            let dropped = _mm256_andnot_ps(_mm256_set1_ps(-0.0), _mm256_sub_ps(x, t));
            let away = _mm256_or_ps(_mm256_set1_ps(1.0), _mm256_and_ps(x, _mm256_set1_ps(-0.0)));
            let up = _mm256_cmp_ps::<_CMP_GE_OQ>(dropped, _mm256_set1_ps(0.5));
            _mm256_blendv_ps(t, _mm256_add_ps(t, away), up)
        };
        for chunk in chunks {
            // SAFETY: the CPU has AVX2 and the chunk holds eight points.
            let Some(Projected8 { u, v, .. }) = (unsafe { warp_project8_avx2(pin, pose, chunk) })
            else {
                self.visible_points_of(pin, pose, chunk, out);
                continue;
            };
            let (x, y) = (round(u), round(v));
            // NaN is outside, as in `contains`.
            let inside = crate::field::lanes_in_box_avx2(x, y, w, h);
            let mut lanes = _mm256_movemask_ps(inside) as u32;
            if lanes == 0 {
                continue;
            }
            let (mut xs, mut ys) = ([0i32; 8], [0i32; 8]);
            // SAFETY: eight lanes into eight integers. Inside the image the coordinates are
            // integers in 0..width and 0..height, so the conversion is exact.
            unsafe {
                _mm256_storeu_si256(xs.as_mut_ptr().cast(), _mm256_cvttps_epi32(x));
                _mm256_storeu_si256(ys.as_mut_ptr().cast(), _mm256_cvttps_epi32(y));
            }
            while lanes != 0 {
                let i = lanes.trailing_zeros() as usize;
                lanes &= lanes - 1;
                if self.valid[ys[i] as usize * self.width as usize + xs[i] as usize] {
                    out.push(chunk[i]);
                }
            }
        }
        self.visible_points_of(pin, pose, rest, out);
    }

    fn visible_points_in(
        &self,
        pin: &Pinhole,
        pose: &Rigid32,
        points: &[[f32; 3]],
        out: &mut Vec<[f32; 3]>,
    ) {
        out.clear();
        self.visible_points_of(pin, pose, points, out);
    }

    /// The points of `points` that project into the mask, appended to `out`.
    #[inline(always)]
    fn visible_points_of(
        &self,
        pin: &Pinhole,
        pose: &Rigid32,
        points: &[[f32; 3]],
        out: &mut Vec<[f32; 3]>,
    ) {
        out.extend(points.iter().copied().filter(|&x| {
            pin.project(pose.apply(x))
                .is_some_and(|(u, v)| self.contains(u, v))
        }));
    }
}

/// Quality of an alignment: mean cost per point (pixels) and the fraction of points within
/// `inlier_px` of an event.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CostStats {
    pub mean: f32,
    pub inlier_fraction: f32,
}

pub fn cost_stats(
    map: &impl CostMap,
    pin: &Pinhole,
    pose: &Rigid32,
    points: &[[f32; 3]],
    inlier_px: f32,
) -> CostStats {
    if points.is_empty() {
        return CostStats {
            mean: map.max_value(),
            inlier_fraction: 0.0,
        };
    }
    let (mut sum, mut inliers) = (0.0f32, 0usize);
    for &x in points {
        let c = point_cost(map, pin, pose, x);
        sum += c;
        inliers += usize::from(c <= inlier_px);
    }
    let n = points.len() as f32;
    CostStats {
        mean: sum / n,
        inlier_fraction: inliers as f32 / n,
    }
}

/// The event distance field is the cost surface; LM reads the slope of its bilinear interpolant
/// (see [`crate::field::FieldLevel::sample_slope`]).
impl CostMap for crate::field::FieldLevel {
    #[inline]
    fn sample(&self, u: f32, v: f32) -> f32 {
        crate::field::FieldLevel::sample(self, u, v)
    }
    #[inline]
    fn sample_grad(&self, u: f32, v: f32) -> [f32; 3] {
        self.sample_slope(u, v)
    }
    fn max_value(&self) -> f32 {
        crate::field::FieldLevel::max_value(self)
    }
    #[inline(always)]
    fn add_star(&self, u: f32, v: f32, du: &[f32; 6], dv: &[f32; 6], sums: &mut [f32; 13]) {
        crate::field::FieldLevel::add_star(self, u, v, du, dv, sums)
    }
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn add_star_avx2(
        &self,
        u: f32,
        v: f32,
        du: &[f32; 6],
        dv: &[f32; 6],
        sums: &mut [f32; 13],
    ) {
        // SAFETY: the caller guarantees AVX2.
        unsafe { crate::field::FieldLevel::add_star_avx2(self, u, v, du, dv, sums) }
    }
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn sample_grad8_avx2(
        &self,
        u: std::arch::x86_64::__m256,
        v: std::arch::x86_64::__m256,
    ) -> Option<[std::arch::x86_64::__m256; 3]> {
        // SAFETY: the caller guarantees AVX2.
        unsafe { crate::field::FieldLevel::sample_slope8_avx2(self, u, v) }
    }
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn stars8_avx2(
        &self,
        u: std::arch::x86_64::__m256,
        v: std::arch::x86_64::__m256,
        du: &[std::arch::x86_64::__m256; 6],
        dv: &[std::arch::x86_64::__m256; 6],
    ) -> Option<[std::arch::x86_64::__m256; 13]> {
        // SAFETY: the caller guarantees AVX2.
        unsafe { super::star8::field_stars8_avx2(self, u, v, du, dv) }
    }
}

#[cfg(test)]
pub(crate) mod testing {
    //! An analytic cost map for solver tests: the truncated distance to a set of 2D segments.
    use super::*;

    /// A 3D segment (two endpoints in the object frame, metres).
    pub type Edge = ([f32; 3], [f32; 3]);

    pub struct SegmentMap {
        pub segments: Vec<[(f32, f32); 2]>,
        pub tau: f32,
    }

    impl SegmentMap {
        fn dist(&self, u: f32, v: f32) -> f32 {
            let mut best = f32::INFINITY;
            for &[(ax, ay), (bx, by)] in &self.segments {
                let (dx, dy) = (bx - ax, by - ay);
                let len2 = (dx * dx + dy * dy).max(1e-12);
                let s = (((u - ax) * dx + (v - ay) * dy) / len2).clamp(0.0, 1.0);
                let (px, py) = (ax + s * dx - u, ay + s * dy - v);
                best = best.min((px * px + py * py).sqrt());
            }
            best.min(self.tau)
        }
    }

    impl CostMap for SegmentMap {
        fn sample(&self, u: f32, v: f32) -> f32 {
            self.dist(u, v)
        }
        fn sample_grad(&self, u: f32, v: f32) -> [f32; 3] {
            let h = 0.05;
            [
                self.dist(u, v),
                (self.dist(u + h, v) - self.dist(u - h, v)) / (2.0 * h),
                (self.dist(u, v + h) - self.dist(u, v - h)) / (2.0 * h),
            ]
        }
        fn max_value(&self) -> f32 {
            self.tau
        }
    }

    /// Corners and edges of a 0.16 × 0.21 × 0.06 m box, its edges sampled into points.
    pub fn box_model() -> (Vec<[f32; 3]>, Vec<Edge>) {
        let (hx, hy, hz) = (0.08f32, 0.105f32, 0.03f32);
        let corner = |i: usize| {
            [
                if i & 1 == 0 { -hx } else { hx },
                if i & 2 == 0 { -hy } else { hy },
                if i & 4 == 0 { -hz } else { hz },
            ]
        };
        let mut edges = Vec::new();
        for i in 0..8 {
            for bit in [1, 2, 4] {
                if i & bit == 0 {
                    edges.push((corner(i), corner(i | bit)));
                }
            }
        }
        let mut points = Vec::new();
        for &(a, b) in &edges {
            for k in 0..40 {
                let s = (k as f32 + 0.5) / 40.0;
                points.push([
                    a[0] + s * (b[0] - a[0]),
                    a[1] + s * (b[1] - a[1]),
                    a[2] + s * (b[2] - a[2]),
                ]);
            }
        }
        (points, edges)
    }

    /// The box's edges that are visible at `pose` (an edge shows when one of its faces faces the
    /// camera), sampled into points, and the edges themselves. An opaque box, unlike a wireframe,
    /// has no Necker-reversed second minimum.
    pub fn visible_box_model(pose: &Pose) -> (Vec<[f32; 3]>, Vec<Edge>) {
        let (_, edges) = box_model();
        let half = [0.08f32, 0.105, 0.03];
        let faces_camera = |axis: usize, sign: f32| {
            let mut n = Vector3::zeros();
            n[axis] = f64::from(sign);
            let mut c = nalgebra::Point3::origin();
            c[axis] = f64::from(sign * half[axis]);
            (pose.rotation * n).dot(&(pose * c).coords) < 0.0
        };
        let visible: Vec<_> = edges
            .into_iter()
            .filter(|(a, b)| {
                // The edge lies on the two faces where both endpoints share a coordinate at ±half.
                (0..3).any(|axis| a[axis] == b[axis] && faces_camera(axis, a[axis].signum()))
            })
            .collect();
        let mut points = Vec::new();
        for &(a, b) in &visible {
            for k in 0..60 {
                let s = (k as f32 + 0.5) / 60.0;
                points.push([
                    a[0] + s * (b[0] - a[0]),
                    a[1] + s * (b[1] - a[1]),
                    a[2] + s * (b[2] - a[2]),
                ]);
            }
        }
        (points, visible)
    }

    /// The fixture of the eight-at-a-time equivalence tests: the box's visible points at a pose
    /// near 0.6 m, truncated to whole chunks of eight plus a tail of five, and a distance field
    /// over a roi covering only the left part of the projected box, built from a random mask
    /// (one pixel in `one_in` set, seeded by `seed`) so that chunks fall inside, across and off it.
    pub fn partial_field(
        seed: u64,
        one_in: u64,
    ) -> (Pose, Vec<[f32; 3]>, crate::field::DistanceField) {
        let truth = Pose::new(Vector3::new(0.01, 0.02, 0.6), Vector3::new(0.3, 0.4, 0.1));
        let (mut points, _) = visible_box_model(&truth);
        points.truncate(points.len() / 8 * 8 + 5);
        let roi = crate::image::Roi {
            x0: 420,
            y0: 150,
            width: 260,
            height: 420,
        };
        let mut rng = crate::rng::Rng::new(seed);
        let mask: Vec<u8> = (0..roi.area())
            .map(|_| u8::from(rng.below(one_in) == 0))
            .collect();
        let mut field =
            crate::field::DistanceField::new(crate::field::FieldParams::default()).expect("field");
        field.build(&mask, roi, 1).expect("build");
        (truth, points, field)
    }

    /// The segment map of the box's visible edges seen at `pose` through `pin`.
    pub fn box_map(pin: &Pinhole, pose: &Pose, tau: f32) -> SegmentMap {
        let (_, edges) = visible_box_model(pose);
        let rig = Rigid32::from_pose(pose);
        let segments = edges
            .iter()
            .filter_map(|&(a, b)| Some([pin.project(rig.apply(a))?, pin.project(rig.apply(b))?]))
            .collect();
        SegmentMap { segments, tau }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Point3};

    /// A 1280 × 720 camera with strong pincushion distortion (k1 = 0.3): the rectified image's
    /// corners fall off the sensor, so its view mask has holes.
    fn pincushion() -> Camera {
        Camera::new(
            1280,
            720,
            1100.0,
            1100.0,
            640.0,
            360.0,
            [0.3, 0.0, 0.0, 0.0, 0.0],
        )
        .unwrap()
    }

    #[test]
    fn analytic_jacobian_matches_finite_differences() {
        let pin = Pinhole::at_level(&Camera::imx636(), 0);
        let pose = Isometry3::new(Vector3::new(0.05, -0.02, 0.6), Vector3::new(0.3, -0.2, 0.1));
        let pivot = Vector3::new(0.04, -0.01, 0.62);
        for x in [[0.08f32, 0.1, -0.03], [-0.05, 0.02, 0.03]] {
            let p = pose * Point3::new(f64::from(x[0]), f64::from(x[1]), f64::from(x[2]));
            let pc = [p.x as f32, p.y as f32, p.z as f32];
            let j = image_jacobian(&pin, pc, [pivot.x as f32, pivot.y as f32, pivot.z as f32]);
            for k in 0..6 {
                let h = 1e-6;
                let proj = |s: f64| {
                    let moved = apply_increment(&pose, &(se3::unit_twist(k) * s), &pivot);
                    let q = moved * Point3::new(f64::from(x[0]), f64::from(x[1]), f64::from(x[2]));
                    Camera::imx636().project_pinhole(&q.coords).unwrap()
                };
                let (a, b) = (proj(h), proj(-h));
                let (du, dv) = ((a.0 - b.0) / (2.0 * h), (a.1 - b.1) / (2.0 * h));
                let tol = 1e-3 * (du.abs() + dv.abs()).max(1.0);
                assert!(
                    (f64::from(j[0][k]) - du).abs() < tol,
                    "axis {k}: du {} vs {du}",
                    j[0][k]
                );
                assert!(
                    (f64::from(j[1][k]) - dv).abs() < tol,
                    "axis {k}: dv {} vs {dv}",
                    j[1][k]
                );
            }
        }
    }

    #[test]
    fn view_mask_drops_the_border_and_what_the_lens_cannot_see() {
        let cam = Camera::imx636();
        let mask = ViewMask::new(&cam, 2.0);
        assert!(mask.contains(640.0, 360.0));
        assert!(!mask.contains(1.0, 360.0) && !mask.contains(640.0, 718.6));
        assert!(!mask.contains(-5.0, 360.0) && !mask.contains(640.0, 1e6));
        // Pincushion distortion (k1 > 0) pushes the rectified corners off the sensor: they see
        // nothing, while the undistorted sensor sees them.
        let pincushion = pincushion();
        assert!(!ViewMask::new(&pincushion, 2.0).contains(10.0, 10.0));
        assert!(ViewMask::new(&pincushion, 2.0).contains(640.0, 30.0));
        assert!(ViewMask::new(&pincushion.rectified(), 2.0).contains(10.0, 10.0));
        // Every pixel marked valid maps to a raw pixel on the sensor.
        let mask_p = ViewMask::new(&pincushion, 2.0);
        for (u, v) in [
            (3.0f32, 360.0f32),
            (640.0, 3.0),
            (200.0, 100.0),
            (100.0, 60.0),
        ] {
            if mask_p.contains(u, v) {
                let (ud, vd) = pincushion.distort_pixel(f64::from(u), f64::from(v));
                assert!(ud >= 0.0 && vd >= 0.0 && ud < 1280.0 && vd < 720.0);
            }
        }
        let pin = Pinhole::at_level(&cam, 0);
        // A row of points at 0.6 m whose right half (x ≥ 0) lies past the right border: those drop out.
        let points: Vec<[f32; 3]> = (0..100)
            .map(|i| [-0.5 + 0.01 * i as f32, 0.0, 0.0])
            .collect();
        let shifted = Isometry3::translation(f64::from((1280.0 - pin.cx) / pin.fx * 0.6), 0.0, 0.6);
        let mut out = Vec::new();
        mask.visible_points(&pin, &Rigid32::from_pose(&shifted), &points, &mut out);
        assert!(
            out.len() > 45 && out.len() < 55,
            "{} of 100 visible",
            out.len()
        );
        assert!(out.iter().all(|p| p[0] < 0.0));
    }

    /// The AVX2 path keeps the same points in the same order as the one-point path: ties of the
    /// rounding (u, v on half pixels, below zero and at the far border), a lens whose mask has
    /// holes, points behind the camera, and the tail after the last chunk of eight.
    #[test]
    fn visible_points_eight_at_a_time_match_one_at_a_time() {
        let pincushion = pincushion();
        let mask = ViewMask::new(&pincushion, 2.0);
        let check = |pin: &Pinhole, pose: &Rigid32, points: &[[f32; 3]]| {
            let (mut one, mut wide) = (Vec::new(), Vec::new());
            mask.visible_points_in(pin, pose, points, &mut one);
            mask.visible_points(pin, pose, points, &mut wide);
            assert_eq!(one, wide);
            one.len()
        };
        // A unit pinhole at depth 1 puts (u, v) exactly at (x, y): every quarter pixel along the
        // rows and columns through the corners and the centre.
        let unit = Pinhole {
            fx: 1.0,
            fy: 1.0,
            cx: 0.0,
            cy: 0.0,
        };
        let identity = Rigid32::from_pose(&Isometry3::identity());
        let quarters = |n: usize| (0..4 * n + 17).map(|i| -2.0 + 0.25 * i as f32);
        let mut grid: Vec<[f32; 3]> = Vec::new();
        for y in [-0.5, 0.5, 1.5, 2.5, 360.0, 716.5, 717.5, 719.5, 720.5] {
            grid.extend(quarters(1280).map(|x| [x, y, 1.0]));
        }
        for x in [-0.5, 1.5, 2.5, 640.0, 1276.5, 1277.5, 1279.5] {
            grid.extend(quarters(720).map(|y| [x, y, 1.0]));
        }
        grid.push([5.0, 5.0, 1.0]);
        let n = check(&unit, &identity, &grid);
        assert!(n > 1000 && n < grid.len() / 2, "{n} of {}", grid.len());
        // The box model at poses across the image, partly out of it, and half behind the camera.
        let pin = Pinhole::at_level(&pincushion, 0);
        let truth = Isometry3::new(Vector3::new(0.01, 0.02, 0.6), Vector3::new(0.3, 0.4, 0.1));
        let (mut points, _) = testing::visible_box_model(&truth);
        points.truncate(points.len() / 8 * 8 + 3);
        for (dx, dz) in [(0.0, 0.0), (0.25, 0.0), (-0.3, 0.1), (0.0, -0.6)] {
            let pose = Isometry3::translation(dx, 0.0, dz) * truth;
            check(&pin, &Rigid32::from_pose(&pose), &points);
        }
    }

    #[test]
    fn cost_is_zero_at_truth_and_counts_unprojectable_points_as_far() {
        let pin = Pinhole::at_level(&Camera::imx636(), 0);
        let pose = Isometry3::new(Vector3::new(0.0, 0.0, 0.6), Vector3::new(0.2, 0.3, 0.0));
        let map = testing::box_map(&pin, &pose, 10.0);
        let (points, _) = testing::visible_box_model(&pose);
        let at_truth = total_cost(&map, &pin, &Rigid32::from_pose(&pose), &points);
        assert!(at_truth / (points.len() as f32) < 0.01, "{at_truth}");
        let behind = Isometry3::translation(0.0, 0.0, -1.0);
        let c = total_cost(&map, &pin, &Rigid32::from_pose(&behind), &points);
        assert_eq!(c, 10.0 * points.len() as f32);
    }
}
