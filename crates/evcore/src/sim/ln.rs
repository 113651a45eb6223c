//! A natural logarithm of f32 that the compiler can vectorise: no libm call and no branch, so a
//! loop over a row segment's pixels becomes SIMD code. The sensor model takes the log of every
//! changed pixel at every step, and libm's `logf` is a call per pixel that keeps the loop scalar.
//!
//! Accuracy: within 2 ulp of the correctly rounded result for normal positive inputs (test
//! below), far finer than a contrast threshold (≥ 0.1 log units) can resolve. Scalar and
//! vectorised code give bit-identical results (Rust does not contract `a * b + c` into FMA), so
//! every path of the sensor model sees the same levels.

/// Bits of √½: mantissas are brought into [√½, √2), where the series below converges fastest.
const SQRT_HALF_BITS: u32 = 0x3f35_04f3;
/// ln 2 split in two (Cephes' split): `LN2_HI` has 9 significant bits, so `e · LN2_HI` is exact
/// for every f32 exponent, and `LN2_LO` carries the rest.
const LN2_HI: f32 = 355.0 / 512.0;
const LN2_LO: f32 = -2.121_944_4e-4;

/// ln x for a normal, finite x > 0 (zero, subnormal, negative, infinite or NaN input gives
/// an unspecified value; the sensor model adds `log_eps` > 0 to intensities ≥ 0 first).
#[inline(always)]
pub(super) fn ln(x: f32) -> f32 {
    let bits = x.to_bits();
    // x = 2^e · m with m ∈ [√½, √2): e counts how far the bits lie above √½'s.
    let e = (bits.wrapping_sub(SQRT_HALF_BITS) as i32) >> 23;
    let m = f32::from_bits(bits.wrapping_sub((e as u32) << 23));
    // ln m = 2·atanh(s), s = (m − 1)/(m + 1) ∈ [−0.172, 0.172): the odd series to s⁹ leaves
    // an error below 1e-9.
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let tail = s2 * (1.0 / 3.0 + s2 * (1.0 / 5.0 + s2 * (1.0 / 7.0 + s2 * (1.0 / 9.0))));
    let ef = e as f32;
    ef * LN2_HI + (2.0 * s + (2.0 * s * tail + ef * LN2_LO))
}

#[cfg(test)]
mod tests {
    use super::ln;

    /// Distance in ulps between two finite f32 of the same sign.
    fn ulps(a: f32, b: f32) -> u32 {
        (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs() as u32
    }

    #[test]
    fn ln_is_within_two_ulps_of_the_correctly_rounded_log() {
        // Every intensity the sensor meets (log_eps + [0, a few]) and far beyond, densely: a
        // geometric sweep over 1e-30 .. 1e30 and a linear one over the sensor's range, against
        // the log taken in f64 and rounded once.
        let geometric = (0..200_000).map(|k| 1e-30_f64 * 10f64.powf(60.0 * k as f64 / 2e5));
        let linear = (0..200_000).map(|k| 1e-3 + 4.0 * k as f64 / 2e5);
        let mut worst = 0;
        for x in geometric.chain(linear).map(|x| x as f32) {
            let exact = f64::from(x).ln() as f32;
            let got = ln(x);
            // Near x = 1 the log is near zero, where an ulp is tiny: compare absolutely there.
            if exact.abs() < 1e-3 {
                assert!(
                    (got - exact).abs() < 2e-10,
                    "ln({x}) = {got}, exact {exact}"
                );
            } else {
                worst = worst.max(ulps(got, exact));
            }
        }
        assert!(worst <= 2, "worst error {worst} ulps");
        // Powers of two and their neighbours, where the exponent split changes.
        for e in -20..20 {
            for x in [2f32.powi(e), 2f32.powi(e) * std::f32::consts::FRAC_1_SQRT_2] {
                for y in [
                    f32::from_bits(x.to_bits() - 1),
                    x,
                    f32::from_bits(x.to_bits() + 1),
                ] {
                    let exact = f64::from(y).ln() as f32;
                    assert!(
                        ulps(ln(y), exact) <= 2 || (ln(y) - exact).abs() < 2e-10,
                        "ln({y}) = {}, exact {exact}",
                        ln(y)
                    );
                }
            }
        }
    }
}
