//! How much the events support a pose: the evidence behind `Estimate::confidence`.
//!
//! The inlier fraction alone (points within `inlier_px` of an active pixel) cannot tell a locked
//! pose from a pose sitting in dense clutter or pure noise: with enough active pixels every point
//! is "near an event". What separates them is how much *more* support the model gets at the pose
//! than a random placement would get from the same events. The chance level is measured, not
//! modelled: it is the fraction of the region around the projected model whose field value passes
//! the same inlier test, i.e. the probability that a point dropped anywhere there is an inlier.
//!
//! confidence = the mean over two inlier distances (2 px and 1 px) of (support − chance) /
//! (1 − chance), clamped to [0, 1], where support is the supported fraction of the model points
//! in the image; with less than half the model in the image the object counts as gone. Support may also be required to be fresh (see [`crate::freshness`]). Candidates of a
//! global search also have to explain the event mass around them
//! ([`Evidence::acquisition_confidence`]).

use crate::field::FieldLevel;
use crate::freshness::Recency;
use crate::image::Roi;
use crate::solve::cost::{Pinhole, Rigid32};

/// What the events say at one pose (all fractions in [0, 1]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Evidence {
    /// Fraction of the model points in the image that lie within the inlier distance of an active
    /// pixel (and, when freshness is demanded, of a recent event).
    pub support: f32,
    /// The same without the freshness requirement.
    pub support_any: f32,
    /// Fraction of the pixels of the region around the model within the inlier distance of an
    /// active pixel: the support a random placement would get.
    pub chance: f32,
    /// `support` and `chance` at the tight distance [`TIGHT_PX`].
    pub support_tight: f32,
    pub chance_tight: f32,
    /// Fraction of the model points that project inside the image.
    pub visible: f32,
    /// Fraction of the active pixels of the region that lie near the projected model (within
    /// about [`EXPLAIN_CELL_PX`] to 2× that): how much of what fires there the pose accounts for.
    /// A pose fitted to part of the object's edges (a smaller, farther copy sitting on one
    /// corner) has high support but leaves most of the events around it unexplained. Only
    /// measured when the query asks for it (global search), else 0.
    pub explained: f32,
    /// Fraction of the model's sensor blocks that fired within the tracker's activity window, and
    /// of the other blocks around the model (see [`crate::freshness::Activity`]); 0 unless the
    /// tracker measured them.
    pub active: f32,
    pub active_around: f32,
}

/// Above this chance level a support test carries no evidence: nearly every placement passes it,
/// and the share of the little headroom left would turn sampling noise into certainty.
pub const MAX_CHANCE: f32 = 0.9;

/// Support `s` in excess of chance `c` as a share of the headroom 1 − c, in [0, 1].
fn excess(s: f32, c: f32) -> f32 {
    if c >= MAX_CHANCE {
        return 0.0;
    }
    ((s - c) / (1.0 - c)).clamp(0.0, 1.0)
}

/// Field value (full-resolution pixels) of the tight inlier test: f(1 px) = ½.
pub const TIGHT_PX: f32 = 0.5;

/// Below this visible fraction the object counts as having left the view: too little of it is
/// left to pin six degrees of freedom, whatever the support.
pub const MIN_VISIBLE: f32 = 0.5;

impl Evidence {
    /// Support in excess of chance, as a share of what chance leaves to gain, averaged over the
    /// two inlier distances (0: no better than random, 1: every point supported); 0 once less than
    /// [`MIN_VISIBLE`] of the model is in the image. The share, not the plain difference: with the
    /// camera moving, background clutter raises the chance level around a locked model to 0.5–0.6
    /// and the difference of a right pose falls to where wrong ones lie. Two distances: the wide
    /// one tolerates the pixel or two a tracked pose trails the events by, the tight one is what
    /// clutter and noise rarely pass by chance.
    pub fn confidence(&self) -> f32 {
        if self.visible < MIN_VISIBLE {
            return 0.0;
        }
        0.5 * (excess(self.support, self.chance) + excess(self.support_tight, self.chance_tight))
    }

    /// The stricter test for a pose found by a global search: support in excess of chance (the
    /// plain difference, which a sparse full-image field makes hard to earn), scaled down when the
    /// pose accounts for less than [`EXPLAINED_ENOUGH`] of the event mass around it. A sweep over
    /// thousands of templates finds partial fits (a smaller, farther view sitting on one corner of
    /// the object's edges) that a continuously tracked pose never jumps to. Not used while
    /// tracking: with the camera moving, background clutter rightly stays unexplained.
    pub fn acquisition_confidence(&self) -> f32 {
        if self.visible < MIN_VISIBLE {
            return 0.0;
        }
        (self.support - self.chance).clamp(0.0, 1.0) * (self.explained / EXPLAINED_ENOUGH).min(1.0)
    }
}

/// Where and how to look for evidence.
#[derive(Debug, Clone, Copy)]
pub struct Query<'a> {
    /// A point within this field value of an active pixel is supported (full-resolution pixels).
    pub inlier_px: f32,
    /// The region the chance level is measured over (full-resolution pixels; clipped to the
    /// level's region).
    pub region: Roi,
    /// The image size (pixels).
    pub image: (u32, u32),
    /// When set, a supported point also needs an event in its block at or after this time (µs).
    pub fresh_since: Option<(&'a Recency, i64)>,
    /// Also measure [`Evidence::explained`] (a pass over the region; for global-search candidates).
    pub explain: bool,
}

/// Grid stride (pixels) of the chance estimate: the fraction of a region's pixels near an event
/// needs a few thousand samples, not all of them.
const CHANCE_STRIDE: usize = 2;

/// The evidence for `pose` (points of S* in the object frame) on the full-resolution `level`.
pub fn evidence(
    level: &FieldLevel,
    pin: &Pinhole,
    pose: &Rigid32,
    points: &[[f32; 3]],
    q: &Query<'_>,
) -> Evidence {
    let Tally {
        visible,
        supported_any,
        supported,
        tight,
    } = tally(level, pin, pose, points, q);
    let n = visible.max(1) as f32;
    let (chance, chance_tight) = chance_level(level, q.region, q.inlier_px);
    Evidence {
        support: supported as f32 / n,
        support_any: supported_any as f32 / n,
        chance,
        support_tight: tight as f32 / n,
        chance_tight,
        visible: visible as f32 / points.len().max(1) as f32,
        explained: if q.explain {
            explained_fraction(level, pin, pose, points, q.region, None)
        } else {
            0.0
        },
        ..Evidence::default()
    }
}

/// Counts of model points: in the image, supported (without and with the freshness requirement),
/// and supported at the tight distance.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Tally {
    visible: usize,
    supported_any: usize,
    supported: usize,
    tight: usize,
}

impl Tally {
    /// Counts one point projected to (u, v) (pixels) where the field reads `f`.
    #[inline(always)]
    fn add(&mut self, q: &Query<'_>, u: f32, v: f32, f: f32) {
        let (w, h) = (q.image.0 as f32, q.image.1 as f32);
        if u < -0.5 || v < -0.5 || u > w - 0.5 || v > h - 0.5 {
            return;
        }
        self.visible += 1;
        if f > q.inlier_px {
            return;
        }
        self.supported_any += 1;
        let fresh = q
            .fresh_since
            .is_none_or(|(recency, since)| recency.last_us(u, v) >= since);
        self.supported += usize::from(fresh);
        self.tight += usize::from(fresh && f <= TIGHT_PX);
    }

    /// Counts `points` one at a time.
    fn add_points(
        &mut self,
        level: &FieldLevel,
        pin: &Pinhole,
        pose: &Rigid32,
        points: &[[f32; 3]],
        q: &Query<'_>,
    ) {
        for &x in points {
            if let Some((u, v)) = pin.project(pose.apply(x)) {
                self.add(q, u, v, level.sample(u, v));
            }
        }
    }
}

/// The [`Tally`] of `points` at `pose` on `level`.
fn tally(
    level: &FieldLevel,
    pin: &Pinhole,
    pose: &Rigid32,
    points: &[[f32; 3]],
    q: &Query<'_>,
) -> Tally {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2.
        return unsafe { tally_avx2(level, pin, pose, points, q) };
    }
    let mut t = Tally::default();
    t.add_points(level, pin, pose, points, q);
    t
}

/// [`tally`] eight points at a time: their warp and projection
/// ([`crate::solve::cost::warp_project8_avx2`]) and, when all eight cells lie inside the level,
/// their bilinear values ([`FieldLevel::sample_slope8_avx2`]) in vectors, each lane formed by the
/// same operations as [`Pinhole::project`] and [`FieldLevel::sample`], so the same counts. A
/// chunk with a point the projection refuses takes the one-point path, as does the remainder.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn tally_avx2(
    level: &FieldLevel,
    pin: &Pinhole,
    pose: &Rigid32,
    points: &[[f32; 3]],
    q: &Query<'_>,
) -> Tally {
    use std::arch::x86_64::*;
    let mut t = Tally::default();
    let mut chunks = points.chunks_exact(8);
    for chunk in &mut chunks {
        // SAFETY: the CPU has AVX2 and the chunk holds eight points.
        let Some(p) = (unsafe { crate::solve::cost::warp_project8_avx2(pin, pose, chunk) }) else {
            t.add_points(level, pin, pose, chunk, q);
            continue;
        };
        let (mut u, mut v, mut f) = ([0.0f32; 8], [0.0f32; 8], [0.0f32; 8]);
        // SAFETY: 8-lane stores into 8-lane arrays.
        unsafe {
            _mm256_storeu_ps(u.as_mut_ptr(), p.u);
            _mm256_storeu_ps(v.as_mut_ptr(), p.v);
        }
        match level.sample_slope8_avx2(p.u, p.v) {
            // SAFETY: as above.
            Some([value, _, _]) => unsafe { _mm256_storeu_ps(f.as_mut_ptr(), value) },
            None => {
                for i in 0..8 {
                    f[i] = level.sample(u[i], v[i]);
                }
            }
        }
        for i in 0..8 {
            t.add(q, u[i], v[i], f[i]);
        }
    }
    t.add_points(level, pin, pose, chunks.remainder(), q);
    t
}

/// A pose that accounts for this much of the event mass around it is not penalised: noise and
/// clutter rightly leave the rest unexplained.
pub const EXPLAINED_ENOUGH: f32 = 0.5;

/// Cell side (pixels) of the occupancy grid the projected model is drawn into for `explained`.
pub const EXPLAIN_CELL_PX: u32 = 4;

/// The share of the active pixels of `region` that lie near the model projected at `pose` (see
/// [`Evidence::explained`]). `fresh`: only pixels that themselves fired at or after that time (µs)
/// count as events to explain ([`Recency::pixel_fired_since`]), not every pixel the front-end
/// still holds in a block that fired: a moving object's older edge positions and the blocks' old
/// noise are nothing a pose should account for (leave-return, the truth while the box moves back:
/// 0.61 of the pixels of fresh blocks, 0.94–0.96 of the fresh pixels).
pub(crate) fn explained_fraction(
    level: &FieldLevel,
    pin: &Pinhole,
    pose: &Rigid32,
    points: &[[f32; 3]],
    region: Roi,
    fresh: Option<(&Recency, i64)>,
) -> f32 {
    let c = EXPLAIN_CELL_PX;
    let (gw, gh) = (
        region.width.div_ceil(c) as usize,
        region.height.div_ceil(c) as usize,
    );
    if gw == 0 || gh == 0 {
        return 0.0;
    }
    let mut near = vec![false; gw * gh];
    for &x in points {
        let Some((u, v)) = pin.project(pose.apply(x)) else {
            continue;
        };
        let (gx, gy) = (
            ((u - region.x0 as f32) / c as f32).floor(),
            ((v - region.y0 as f32) / c as f32).floor(),
        );
        if gx < 0.0 || gy < 0.0 || gx >= gw as f32 || gy >= gh as f32 {
            continue;
        }
        // The cell and its 8 neighbours: motion smear and a pixel or two of misalignment.
        let (gx, gy) = (gx as usize, gy as usize);
        for ny in gy.saturating_sub(1)..(gy + 2).min(gh) {
            for nx in gx.saturating_sub(1)..(gx + 2).min(gw) {
                near[ny * gw + nx] = true;
            }
        }
    }
    let lr = level.roi;
    let x0 = region.x0.max(lr.x0);
    let y0 = region.y0.max(lr.y0);
    let x1 = (region.x0 + region.width).min(lr.x0 + lr.width);
    let y1 = (region.y0 + region.height).min(lr.y0 + lr.height);
    let (mut active, mut explained) = (0usize, 0usize);
    let w = lr.width as usize;
    for y in y0..y1 {
        let row = &level.value[(y - lr.y0) as usize * w..][..w];
        let grow = ((y - region.y0) / c) as usize * gw;
        for x in x0..x1 {
            if row[(x - lr.x0) as usize] == 0.0
                && fresh.is_none_or(|(recency, since)| recency.pixel_fired_since(x, y, since))
            {
                active += 1;
                explained += usize::from(near[grow + ((x - region.x0) / c) as usize]);
            }
        }
    }
    if active == 0 {
        0.0
    } else {
        explained as f32 / active as f32
    }
}

/// Fractions of the pixels of `region` ∩ the level's region whose field value is ≤ `inlier_px`
/// and ≤ [`TIGHT_PX`]; pixels of `region` outside the built level count as far (no event there is
/// known).
fn chance_level(level: &FieldLevel, region: Roi, inlier_px: f32) -> (f32, f32) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f") {
        // SAFETY: the CPU has AVX-512F.
        return unsafe { chance_level_avx512(level, region, inlier_px) };
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2.
        return unsafe { chance_level_avx2(level, region, inlier_px) };
    }
    chance_level_in::<1>(level, region, inlier_px)
}

/// [`chance_level`] compiled for AVX2, counting eight values to a comparison (integer counts:
/// the same result).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn chance_level_avx2(level: &FieldLevel, region: Roi, inlier_px: f32) -> (f32, f32) {
    chance_level_in::<8>(level, region, inlier_px)
}

/// [`chance_level`] compiled for AVX-512F, sixteen values to a comparison straight into a mask
/// register, the odd lanes masked out by the comparison itself (the same counts).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn chance_level_avx512(level: &FieldLevel, region: Roi, inlier_px: f32) -> (f32, f32) {
    chance_level_in::<16>(level, region, inlier_px)
}

/// `LANES`: 1 (portable), 8 (only from [`chance_level_avx2`]) or 16 (only from
/// [`chance_level_avx512`]).
#[inline(always)]
fn chance_level_in<const LANES: usize>(
    level: &FieldLevel,
    region: Roi,
    inlier_px: f32,
) -> (f32, f32) {
    let lr = level.roi;
    let x0 = region.x0.max(lr.x0);
    let y0 = region.y0.max(lr.y0);
    let x1 = (region.x0 + region.width).min(lr.x0 + lr.width);
    let y1 = (region.y0 + region.height).min(lr.y0 + lr.height);
    let total = (region.width as usize).div_ceil(CHANCE_STRIDE)
        * (region.height as usize).div_ceil(CHANCE_STRIDE);
    if total == 0 || x0 >= x1 || y0 >= y1 {
        return (0.0, 0.0);
    }
    let w = lr.width as usize;
    let (mut near, mut tight) = (0usize, 0usize);
    for y in (y0..y1).step_by(CHANCE_STRIDE) {
        let row = &level.value[(y - lr.y0) as usize * w..][..w];
        let (n, t) = count_strided::<LANES>(
            &row[(x0 - lr.x0) as usize..(x1 - lr.x0) as usize],
            inlier_px,
        );
        near += n;
        tight += t;
    }
    let frac = |k: usize| (k as f32 / total as f32).min(1.0);
    (frac(near), frac(tight))
}

/// How many of `row[0]`, `row[CHANCE_STRIDE]`, … are ≤ `inlier_px` and ≤ [`TIGHT_PX`]. `LANES` as
/// in [`chance_level_in`].
#[inline(always)]
fn count_strided<const LANES: usize>(row: &[f32], inlier_px: f32) -> (usize, usize) {
    let (mut near, mut tight) = (0usize, 0usize);
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if LANES == 16 && CHANCE_STRIDE == 2 {
        use std::arch::x86_64::*;
        // The even lanes of each group of sixteen (a group starts at an even offset).
        const EVEN: __mmask16 = 0x5555;
        done = row.len() / 16 * 16;
        // SAFETY: LANES = 16 only in `chance_level_avx512` (AVX-512F present); the loads read
        // the first `done` ≤ row.len() values.
        unsafe {
            let (a, b) = (_mm512_set1_ps(inlier_px), _mm512_set1_ps(TIGHT_PX));
            for i in (0..done).step_by(16) {
                let v = _mm512_loadu_ps(row.as_ptr().add(i));
                near += _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(EVEN, v, a).count_ones() as usize;
                tight += _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(EVEN, v, b).count_ones() as usize;
            }
        }
    } else if LANES == 8 && CHANCE_STRIDE == 2 {
        use std::arch::x86_64::*;
        // The even lanes of each group of eight (a group starts at an even offset).
        const EVEN: i32 = 0b0101_0101;
        done = row.len() / 8 * 8;
        // SAFETY: LANES = 8 only in `chance_level_avx2` (AVX2 present); the loads read the
        // first `done` ≤ row.len() values.
        unsafe {
            let (a, b) = (_mm256_set1_ps(inlier_px), _mm256_set1_ps(TIGHT_PX));
            for i in (0..done).step_by(8) {
                let v = _mm256_loadu_ps(row.as_ptr().add(i));
                let n = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(v, a)) & EVEN;
                let t = _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_LE_OQ>(v, b)) & EVEN;
                near += n.count_ones() as usize;
                tight += t.count_ones() as usize;
            }
        }
    }
    for &f in row[done..].iter().step_by(CHANCE_STRIDE) {
        near += usize::from(f <= inlier_px);
        tight += usize::from(f <= TIGHT_PX);
    }
    (near, tight)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::field::{DistanceField, FieldParams};
    use crate::rng::Rng;
    use crate::solve::cost::testing;
    use nalgebra::{Isometry3, Vector3};

    /// The AVX2 and AVX-512 counts of the chance level agree with the scalar one, at odd and even
    /// offsets and widths, with regions reaching past the level's.
    #[test]
    fn chance_level_counts_the_same_in_every_width() {
        let mut rng = Rng::new(11);
        let roi = Roi {
            x0: 101,
            y0: 40,
            width: 203,
            height: 57,
        };
        let value: Vec<f32> = (0..roi.area())
            .map(|_| [0.0, 0.4, 1.5, 2.5, 9.5][rng.below(5) as usize])
            .collect();
        let level = FieldLevel {
            level: 0,
            roi,
            tau_px: 10.0,
            value,
        };
        for _ in 0..200 {
            let region = Roi {
                x0: 90 + rng.below(40) as u32,
                y0: 30 + rng.below(30) as u32,
                width: 1 + rng.below(230) as u32,
                height: 1 + rng.below(60) as u32,
            };
            let inlier = [0.5, 1.5, 2.0, 3.0][rng.below(4) as usize];
            let plain = chance_level_in::<1>(&level, region, inlier);
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the CPU has AVX2.
                let wide = unsafe { chance_level_avx2(&level, region, inlier) };
                assert_eq!(plain, wide, "{region:?} {inlier}");
            }
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx512f") {
                // SAFETY: the CPU has AVX-512F.
                let wide = unsafe { chance_level_avx512(&level, region, inlier) };
                assert_eq!(plain, wide, "{region:?} {inlier}");
            }
        }
    }

    /// The eight-at-a-time counts equal the one-at-a-time counts: poses across the image border,
    /// points behind the camera, a field roi that cuts the model (chunks straddling it), with and
    /// without the freshness requirement.
    #[test]
    fn eight_points_at_a_time_count_as_one_at_a_time() {
        let cam = Camera::imx636();
        let pin = Pinhole::at_level(&cam, 0);
        let recency = Recency::new(&cam, &cam.rectified());
        let mut rng = Rng::new(21);
        for _ in 0..3000 {
            recency.record(
                rng.below(1280) as u16,
                rng.below(720) as u16,
                rng.below(100) as i64,
                false,
            );
        }
        let rot = Vector3::new(0.3, 0.4, 0.1);
        let truth = Isometry3::new(Vector3::new(0.0, 0.0, 0.6), rot);
        let (points, _) = testing::visible_box_model(&truth);
        let roi = Roi {
            x0: 500,
            y0: 200,
            width: 300,
            height: 250,
        };
        let full = mask_of(&pin, &truth, &points, 20_000);
        let mask: Vec<u8> = (0..roi.height as usize)
            .flat_map(|y| {
                let row = (roi.y0 as usize + y) * 1280 + roi.x0 as usize;
                full[row..row + roi.width as usize].to_vec()
            })
            .collect();
        let mut field = DistanceField::new(FieldParams::default()).unwrap();
        field.build(&mask, roi, 1).unwrap();
        let (mut supported, mut unsupported) = (0, 0);
        for k in 0..120 {
            let dx = rng.uniform() * 1.4 - 0.7;
            let dy = rng.uniform() * 0.8 - 0.4;
            // Every tenth pose puts part of the box behind the camera.
            let z = if k % 10 == 0 {
                0.05
            } else {
                0.3 + rng.uniform()
            };
            let pose = Isometry3::new(Vector3::new(dx * z, dy * z, z), rot);
            let rig = Rigid32::from_pose(&pose);
            for fresh_since in [None, Some((&recency, 50))] {
                let q = Query {
                    inlier_px: 2.0,
                    region: roi,
                    image: (1280, 720),
                    fresh_since,
                    explain: false,
                };
                let mut one = Tally::default();
                one.add_points(field.level(0), &pin, &rig, &points, &q);
                assert_eq!(
                    tally(field.level(0), &pin, &rig, &points, &q),
                    one,
                    "{pose:?}"
                );
                if one.supported > 0 {
                    supported += 1;
                } else {
                    unsupported += 1;
                }
            }
        }
        assert!(
            supported > 40 && unsupported > 10,
            "{supported} {unsupported}"
        );
    }

    /// Rasterise the projected points of `pose` into a full-image mask, plus `noise` random pixels.
    fn mask_of(pin: &Pinhole, pose: &Isometry3<f64>, points: &[[f32; 3]], noise: usize) -> Vec<u8> {
        let (w, h) = (1280usize, 720usize);
        let mut m = vec![0u8; w * h];
        let rig = Rigid32::from_pose(pose);
        for &x in points {
            if let Some((u, v)) = pin.project(rig.apply(x)) {
                let (u, v) = (u.round() as i64, v.round() as i64);
                if (0..w as i64).contains(&u) && (0..h as i64).contains(&v) {
                    m[v as usize * w + u as usize] = 1;
                }
            }
        }
        let mut rng = Rng::new(3);
        for _ in 0..noise {
            m[rng.below((w * h) as u64) as usize] = 1;
        }
        m
    }

    fn score(mask: &[u8], pin: &Pinhole, pose: &Isometry3<f64>, points: &[[f32; 3]]) -> Evidence {
        let full = Roi::full(1280, 720);
        let mut field = DistanceField::new(FieldParams::default()).unwrap();
        field.build(mask, full, 1).unwrap();
        let rig = Rigid32::from_pose(pose);
        let uv = points
            .iter()
            .filter_map(|&x| pin.project(rig.apply(x)))
            .map(|(u, v)| (f64::from(u), f64::from(v)));
        let region = Roi::around(uv, 16.0, 1280, 720).unwrap_or(full);
        let q = Query {
            inlier_px: 2.0,
            region,
            image: (1280, 720),
            fresh_since: None,
            explain: false,
        };
        evidence(field.level(0), pin, &rig, points, &q)
    }

    #[test]
    fn separates_a_locked_pose_from_a_wrong_one_and_from_pure_noise() {
        let pin = Pinhole::at_level(&Camera::imx636(), 0);
        let truth = Isometry3::new(Vector3::new(0.0, 0.0, 0.6), Vector3::new(0.3, 0.4, 0.1));
        let (points, _) = testing::visible_box_model(&truth);
        // Locked on the edges with 2000 noise pixels sprinkled over the image.
        let locked = score(&mask_of(&pin, &truth, &points, 2000), &pin, &truth, &points);
        assert!(
            locked.support > 0.95 && locked.confidence() > 0.8,
            "{locked:?}"
        );
        // 40 mm sideways: off the edges.
        let off = Isometry3::new(Vector3::new(0.04, 0.0, 0.6), Vector3::new(0.3, 0.4, 0.1));
        let wrong = score(&mask_of(&pin, &truth, &points, 2000), &pin, &off, &points);
        assert!(wrong.confidence() < 0.3, "{wrong:?}");
        // Dense noise and no object: most points are "inliers", yet no better than chance.
        let noise = score(&mask_of(&pin, &truth, &[], 300_000), &pin, &truth, &points);
        assert!(
            noise.support > 0.8,
            "the inlier fraction is fooled: {noise:?}"
        );
        assert!(noise.confidence() < 0.15, "{noise:?}");
    }

    #[test]
    fn a_model_half_out_of_the_image_is_half_visible_and_no_longer_trusted() {
        let pin = Pinhole::at_level(&Camera::imx636(), 0);
        let rot = Vector3::new(0.3, 0.4, 0.1);
        let truth = Isometry3::new(Vector3::new(0.0, 0.0, 0.6), rot);
        let (points, _) = testing::visible_box_model(&truth);
        // Shift so the pivot sits on the right image border (u = 1280 at x = (1280 − cx)·z/fx).
        let x_edge = f64::from(1280.0 - pin.cx) * 0.6 / f64::from(pin.fx);
        let at_edge = Isometry3::new(Vector3::new(x_edge, 0.0, 0.6), rot);
        let e = score(
            &mask_of(&pin, &at_edge, &points, 0),
            &pin,
            &at_edge,
            &points,
        );
        assert!((e.visible - 0.5).abs() < 0.15, "{e:?}");
        assert!(e.support > 0.95, "what is in view is supported: {e:?}");
        let x_out = x_edge + 0.03;
        let beyond = Isometry3::new(Vector3::new(x_out, 0.0, 0.6), rot);
        let e = score(&mask_of(&pin, &beyond, &points, 0), &pin, &beyond, &points);
        assert!(e.visible < MIN_VISIBLE && e.confidence() == 0.0, "{e:?}");
    }
}
