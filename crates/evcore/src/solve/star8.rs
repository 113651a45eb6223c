//! The search stars of eight model points at once on the distance field (AVX2): the 13 candidates
//! of [`super::search`] are the vectors, the eight points their lanes.
//!
//! One star per call of [`crate::field::FieldLevel::add_star_avx2`] fills 13 of 16 lanes and
//! needs the point's projection and Jacobian first, one point at a time; here the eight points'
//! warp, projection and Jacobian run in vectors too, and every lane of every gather is used.

use crate::field::FieldLevel;
use std::arch::x86_64::*;

/// The 13 values of the stars of eight points, candidate-major (vector 0 the centres, 2k+1 and
/// 2k+2 the ± offsets of axis k), each the value [`FieldLevel::add_star`] adds for that point and
/// candidate: the coordinate, cell, weights and bilinear blend are formed by the same operations in
/// the same order, so the bits agree. None unless every sample's cell lies wholly inside the roi
/// (the caller then takes the stars one by one).
///
/// # Safety
/// The CPU must have AVX2.
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) unsafe fn field_stars8_avx2(
    field: &FieldLevel,
    u: __m256,
    v: __m256,
    du: &[__m256; 6],
    dv: &[__m256; 6],
) -> Option<[__m256; 13]> {
    let roi = field.roi;
    let (x0, y0) = (_mm256_set1_ps(roi.x0 as f32), _mm256_set1_ps(roi.y0 as f32));
    // Level pixels relative to the roi, as `add_star` forms them: (u ± δ) − x0.
    let mut xs = [_mm256_sub_ps(u, x0); 13];
    let mut ys = [_mm256_sub_ps(v, y0); 13];
    for k in 0..6 {
        xs[2 * k + 1] = _mm256_sub_ps(_mm256_add_ps(u, du[k]), x0);
        ys[2 * k + 1] = _mm256_sub_ps(_mm256_add_ps(v, dv[k]), y0);
        xs[2 * k + 2] = _mm256_sub_ps(_mm256_sub_ps(u, du[k]), x0);
        ys[2 * k + 2] = _mm256_sub_ps(_mm256_sub_ps(v, dv[k]), y0);
    }
    let (w, h) = (roi.width as f32 - 1.0, roi.height as f32 - 1.0);
    // NaN fails and takes the general path.
    let mut ok = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
    for (&x, &y) in xs.iter().zip(&ys) {
        ok = _mm256_and_ps(ok, crate::field::lanes_in_box_avx2(x, y, w, h));
    }
    if _mm256_movemask_ps(ok) != 0xFF {
        return None;
    }
    let val = field.value.as_ptr();
    let stride = roi.width as usize;
    let s = _mm256_set1_epi32(stride as i32);
    // A lane's two horizontal taps are adjacent: one 64-bit gather lane per point and row. The
    // gathers take the points in the order 0 1 4 5 and 2 3 6 7, so that splitting the pairs into
    // left and right taps (per 128-bit half) puts the points back in order 0..8.
    let halves = _mm256_setr_epi32(0, 1, 4, 5, 2, 3, 6, 7);
    let taps = |row: *const f32, idx: __m256i| {
        let (p, q) = (
            _mm256_castsi256_si128(idx),
            _mm256_extracti128_si256::<1>(idx),
        );
        // SAFETY: every lane's cell lies wholly inside the roi, so its two taps in `row` (the
        // cell's row or the one below) lie within `value`.
        let (p, q) = unsafe {
            (
                _mm256_castsi256_ps(_mm256_i32gather_epi64::<4>(row.cast(), p)),
                _mm256_castsi256_ps(_mm256_i32gather_epi64::<4>(row.cast(), q)),
            )
        };
        (
            _mm256_shuffle_ps::<0b10_00_10_00>(p, q),
            _mm256_shuffle_ps::<0b11_01_11_01>(p, q),
        )
    };
    Some(std::array::from_fn(|i| {
        // Non-negative and in range inside the roi: truncation is the floor.
        let ix = _mm256_cvttps_epi32(xs[i]);
        let iy = _mm256_cvttps_epi32(ys[i]);
        let ax = _mm256_sub_ps(xs[i], _mm256_cvtepi32_ps(ix));
        let ay = _mm256_sub_ps(ys[i], _mm256_cvtepi32_ps(iy));
        let idx = _mm256_add_epi32(_mm256_mullo_epi32(iy, s), ix);
        let idx = _mm256_permutevar8x32_epi32(idx, halves);
        let (v00, v10) = taps(val, idx);
        // SAFETY: the row below every cell lies inside the roi as well.
        let (v01, v11) = taps(unsafe { val.add(stride) }, idx);
        let top = _mm256_add_ps(v00, _mm256_mul_ps(ax, _mm256_sub_ps(v10, v00)));
        let bottom = _mm256_add_ps(v01, _mm256_mul_ps(ax, _mm256_sub_ps(v11, v01)));
        _mm256_add_ps(top, _mm256_mul_ps(ay, _mm256_sub_ps(bottom, top)))
    }))
}
