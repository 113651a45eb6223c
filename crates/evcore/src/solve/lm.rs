//! Pyramidal Levenberg–Marquardt registration (Eq. 2): coarse-to-fine over the field's pyramid,
//! each level a robust Gauss–Newton problem damped LM-style.
//!
//! Residual of point i: r_i = field value at its projection (an unsigned distance in that level's
//! pixels), Jacobian ∇field · ∂u/∂ξ. Weights are Tukey's (default) or Huber's at `robust_px` (IRLS):
//! Tukey's give points far from every event (occluded, or on an edge that made no events) no pull,
//! where Huber's let them drag the pose (benches/RESULTS.md, objects suite). The whole pyramidal step
//! is kept only if it lowers that robust cost at full resolution (see [`lm_pyramid`]).
//!
//! Every iteration looks at the normal equations in their eigenbasis, with the translation scaled
//! by the model's radius so that a unit of every axis moves the points by about the same amount.
//! Directions whose curvature is below `weak_ratio` of the strongest are *held*: the points do not
//! constrain them (a plain cylinder's spin, a sphere's attitude), so any step along them would be
//! noise, and the pose keeps its prior value there. Damping is Levenberg's μ·λ_max·I in the scaled
//! coordinates, so weakly constrained directions are damped as hard as strong ones are, instead of
//! Marquardt's μ·diag(H), which damps them least. μ follows ViSP's rule: ÷ 10 after an accepted
//! step, × 10 and retry after a rejected one, give up above `mu_max`.

use super::cost::{point_cost, CostMap, Pinhole, Rigid32};
use crate::se3::Pose;
use nalgebra::{Matrix6, SymmetricEigen, Vector3, Vector6};
use std::borrow::Cow;

/// The robust loss on point residuals.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Robust {
    /// Quadratic up to the threshold, linear beyond: every point keeps some pull.
    Huber,
    /// Tukey's biweight: points beyond the threshold have no pull at all (redescending).
    Tukey,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmParams {
    /// Iterations (accepted or rejected steps) per pyramid level.
    pub max_iterations: u32,
    pub robust: Robust,
    /// Threshold of the robust loss in level pixels (Huber's k, Tukey's c).
    pub robust_px: f32,
    /// Initial damping, relative to the largest eigenvalue of the scaled normal equations.
    pub mu_initial: f64,
    pub mu_max: f64,
    /// Stop a level once the step is below this (metres and radians, ∞-norm).
    pub min_step: f64,
    /// Stop a level once an accepted step lowers the cost by less than this fraction.
    pub min_relative_decrease: f64,
    /// Directions with curvature below this fraction of the largest are held at the prior.
    pub weak_ratio: f64,
}

impl Default for LmParams {
    fn default() -> Self {
        Self {
            max_iterations: 6,
            robust: Robust::Tukey,
            robust_px: 4.0,
            mu_initial: 1e-3,
            mu_max: 1e4,
            min_step: 1e-5,
            min_relative_decrease: 1e-3,
            weak_ratio: 1e-3,
        }
    }
}

/// What one pyramidal LM step did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmReport {
    pub pose: Pose,
    /// Iterations summed over levels.
    pub iterations: u32,
    /// Robust cost per point at the finest level after the step.
    pub cost: f32,
    /// Directions held at the finest level's last iteration, as unit twists in the camera frame
    /// about the pivot (translation in metres scaled by the model radius, then rotation);
    /// `n_held` of the six columns are valid.
    pub held: [Vector6<f64>; 6],
    pub n_held: usize,
    /// The translation scale of `held` (metres): the model's radius about the pivot.
    pub radius_m: f64,
}

impl LmReport {
    /// `xi` (an increment about the pivot in the camera frame, metres and radians) without its
    /// components along the held directions: what the search steps between two LM steps may still
    /// move. A search candidate is a one-pixel move along one axis; where the points do not
    /// constrain a direction, which candidate wins along it is decided by noise, and four such wins
    /// per cycle random-walk the pose there (the can at 1.2 m spins by degrees in the first
    /// milliseconds, before its label fires).
    pub fn without_held(&self, xi: &Vector6<f64>) -> Vector6<f64> {
        let s = scale(self.radius_m);
        let mut scaled = s.try_inverse().unwrap_or_else(Matrix6::identity) * xi;
        for h in &self.held[..self.n_held] {
            scaled -= h * h.dot(&scaled);
        }
        s * scaled
    }
}

/// (ρ(r), weight ρ'(r)/r) of the robust loss with threshold k.
#[inline]
pub(crate) fn robust_loss(kind: Robust, r: f32, k: f32) -> (f32, f32) {
    match kind {
        Robust::Huber if r <= k => (0.5 * r * r, 1.0),
        Robust::Huber => (k * (r - 0.5 * k), k / r),
        Robust::Tukey if r < k => {
            let a = 1.0 - (r / k) * (r / k);
            (k * k / 6.0 * (1.0 - a * a * a), a * a)
        }
        Robust::Tukey => (k * k / 6.0, 0.0),
    }
}

fn robust_cost(
    map: &impl CostMap,
    pin: &Pinhole,
    pose: &Pose,
    points: &[[f32; 3]],
    p: &LmParams,
) -> f64 {
    let rig = Rigid32::from_pose(pose);
    points
        .iter()
        .map(|&x| f64::from(robust_loss(p.robust, point_cost(map, pin, &rig, x), p.robust_px).0))
        .sum()
}

/// A model point at some pose: its camera-frame position and the map's (value, ∂/∂u, ∂/∂v) at its
/// projection, or None when it does not project.
#[derive(Debug, Clone, Copy)]
struct Sampled {
    p: [f32; 3],
    at: Option<[f32; 3]>,
}

/// Projects `points` at `pose` and samples the map with its slope at each, into `out` (cleared
/// first); returns their robust cost, the same sum as [`robust_cost`] bit for bit (the value of
/// `sample_grad` is `sample`'s, and the terms are added in the same order).
fn sample_points<M: CostMap>(
    map: &M,
    pin: &Pinhole,
    pose: &Pose,
    points: &[[f32; 3]],
    params: &LmParams,
    out: &mut Vec<Sampled>,
) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2.
        return unsafe { sample_points_avx2(map, pin, pose, points, params, out) };
    }
    sample_points_in::<M, false>(map, pin, pose, points, params, out)
}

/// [`sample_points`] compiled for AVX2, eight points at a time where the map has a vector path.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn sample_points_avx2<M: CostMap>(
    map: &M,
    pin: &Pinhole,
    pose: &Pose,
    points: &[[f32; 3]],
    params: &LmParams,
    out: &mut Vec<Sampled>,
) -> f64 {
    sample_points_in::<M, true>(map, pin, pose, points, params, out)
}

/// The body of [`sample_points`]; `AVX2` (only in [`sample_points_avx2`]) takes eight points at a
/// time through [`sampled8_avx2`] wherever it can.
#[inline(always)]
fn sample_points_in<M: CostMap, const AVX2: bool>(
    map: &M,
    pin: &Pinhole,
    pose: &Pose,
    points: &[[f32; 3]],
    params: &LmParams,
    out: &mut Vec<Sampled>,
) -> f64 {
    let rig = Rigid32::from_pose(pose);
    let far = map.max_value();
    let (kind, k) = (params.robust, params.robust_px);
    out.clear();
    let loss = |at: Option<[f32; 3]>| f64::from(robust_loss(kind, at.map_or(far, |a| a[0]), k).0);
    let one = |x: [f32; 3], out: &mut Vec<Sampled>| {
        let p = rig.apply(x);
        let at = pin.project(p).map(|(u, v)| map.sample_grad(u, v));
        out.push(Sampled { p, at });
        loss(at)
    };
    let mut cost = 0.0f64;
    let mut rest = points;
    #[cfg(target_arch = "x86_64")]
    if AVX2 {
        let chunks = points.chunks_exact(8);
        rest = chunks.remainder();
        for chunk in chunks {
            // SAFETY: `AVX2` is only set by `sample_points_avx2`, which runs on CPUs with AVX2.
            match unsafe { sampled8_avx2(map, pin, &rig, chunk) } {
                Some(eight) => {
                    for s in eight {
                        cost += loss(s.at);
                        out.push(s);
                    }
                }
                None => {
                    for &x in chunk {
                        cost += one(x, out);
                    }
                }
            }
        }
    }
    for &x in rest {
        cost += one(x, out);
    }
    cost
}

/// The eight points of `chunk` warped by `rig`, projected and sampled as [`sample_points`] does one
/// by one (the same operations in the same order per lane, so the same bits), when all eight
/// project and the map samples them in a vector; None otherwise.
///
/// # Safety
/// The CPU must have AVX2, and `chunk` must hold eight points.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn sampled8_avx2<M: CostMap>(
    map: &M,
    pin: &Pinhole,
    rig: &Rigid32,
    chunk: &[[f32; 3]],
) -> Option<[Sampled; 8]> {
    use std::arch::x86_64::*;
    // SAFETY: the CPU has AVX2 and `chunk` holds eight points.
    let super::cost::Projected8 { p, u, v } =
        unsafe { super::cost::warp_project8_avx2(pin, rig, chunk) }?;
    // SAFETY: the CPU has AVX2.
    let at = unsafe { map.sample_grad8_avx2(u, v) }?;
    let mut lanes_out = [[0.0f32; 8]; 6];
    for (dst, src) in lanes_out
        .iter_mut()
        .zip([p[0], p[1], p[2], at[0], at[1], at[2]])
    {
        // SAFETY: eight lanes into eight floats.
        unsafe { _mm256_storeu_ps(dst.as_mut_ptr(), src) };
    }
    let [px, py, pz, r, gu, gv] = lanes_out;
    Some(std::array::from_fn(|i| Sampled {
        p: [px[i], py[i], pz[i]],
        at: Some([r[i], gu[i], gv[i]]),
    }))
}

/// Normal equations (H, g) of the points `sampled` (see [`sample_points`]) for increments about
/// `pivot`. Sampling and solving are separate passes so that an accepted LM step, whose candidate
/// pose was already sampled to judge it, forms its normal equations without sampling again.
fn normal_equations(
    pin: &Pinhole,
    sampled: &[Sampled],
    pivot: [f32; 3],
    params: &LmParams,
) -> (Matrix6<f64>, Vector6<f64>) {
    let (kind, k) = (params.robust, params.robust_px);
    // Accumulate in f32 per point, f64 across points: the sum over ~1000 points is where precision goes.
    let mut h = [0.0f64; 21];
    let mut g = [0.0f64; 6];
    for s in sampled {
        let Some([r, gu, gv]) = s.at else {
            continue;
        };
        let (_, w) = robust_loss(kind, r, k);
        if (gu == 0.0 && gv == 0.0) || w == 0.0 {
            continue;
        }
        let ju = super::cost::image_jacobian(pin, s.p, pivot);
        let j: [f32; 6] = std::array::from_fn(|c| gu * ju[0][c] + gv * ju[1][c]);
        let mut idx = 0;
        for a in 0..6 {
            let wa = f64::from(w * j[a]);
            g[a] += wa * f64::from(r);
            for &jb in &j[a..] {
                h[idx] += wa * f64::from(jb);
                idx += 1;
            }
        }
    }
    let mut hm = Matrix6::zeros();
    let mut idx = 0;
    for a in 0..6 {
        for b in a..6 {
            hm[(a, b)] = h[idx];
            hm[(b, a)] = h[idx];
            idx += 1;
        }
    }
    (hm, Vector6::from_column_slice(&g))
}

/// The normal equations seen in scaled coordinates (translation ÷ `radius_m`): eigenvalues
/// ascending with their eigenvectors, and how many of the smallest are weak.
#[derive(Debug, Clone)]
pub struct Observability {
    pub eigenvalues: Vector6<f64>,
    /// Columns are the eigenvectors, in the order of `eigenvalues`.
    pub eigenvectors: Matrix6<f64>,
    pub n_weak: usize,
    radius_m: f64,
}

impl Observability {
    /// Decompose H (unscaled, from [`normal_equations`]) with translations scaled by `radius_m`.
    pub fn new(h: &Matrix6<f64>, radius_m: f64, weak_ratio: f64) -> Self {
        let s = scale(radius_m);
        let eig = SymmetricEigen::new(s * h * s);
        let mut order: Vec<usize> = (0..6).collect();
        order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
        let eigenvalues = Vector6::from_fn(|i, _| eig.eigenvalues[order[i]].max(0.0));
        let eigenvectors = Matrix6::from_fn(|r, c| eig.eigenvectors[(r, order[c])]);
        let top = eigenvalues[5];
        // A non-finite or empty H constrains nothing: every direction is weak.
        let n_weak = if top.is_finite() && top > 0.0 {
            eigenvalues
                .iter()
                .take_while(|&&l| !l.is_finite() || l <= weak_ratio * top)
                .count()
        } else {
            6
        };
        Self {
            eigenvalues,
            eigenvectors,
            n_weak,
            radius_m,
        }
    }

    /// The damped step −(H + μ·λ_max·I)⁻¹g restricted to the strong directions (unscaled
    /// metres and radians).
    fn step(&self, g: &Vector6<f64>, mu: f64) -> Vector6<f64> {
        let s = scale(self.radius_m);
        let gs = s * g;
        let top = self.eigenvalues[5];
        let mut step = Vector6::zeros();
        for k in self.n_weak..6 {
            let v = self.eigenvectors.column(k);
            step -= v * (v.dot(&gs) / (self.eigenvalues[k] + mu * top));
        }
        s * step
    }
}

fn scale(radius_m: f64) -> Matrix6<f64> {
    Matrix6::from_diagonal(&Vector6::new(radius_m, radius_m, radius_m, 1.0, 1.0, 1.0))
}

/// RMS distance of the points from the pivot (metres): the lever arm that makes a rotation of one
/// radian and a translation of this many metres move the points comparably.
pub fn model_radius(points: &[[f32; 3]], pivot_o: &Vector3<f64>) -> f64 {
    let n = points.len().max(1) as f64;
    let sq: f64 = points
        .iter()
        .map(|p| {
            (Vector3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2])) - pivot_o)
                .norm_squared()
        })
        .sum();
    (sq / n).sqrt().max(1e-6)
}

/// LM at one level from `pose`; returns the refined pose, the iterations used and the observability
/// of the last normal equations formed.
pub fn lm_level(
    map: &impl CostMap,
    pin: &Pinhole,
    pose: Pose,
    points: &[[f32; 3]],
    pivot_o: &Vector3<f64>,
    radius_m: f64,
    params: &LmParams,
) -> (Pose, u32, Option<Observability>) {
    let run = lm_level_costed(map, pin, pose, points, pivot_o, radius_m, params);
    (run.pose, run.iterations, run.obs)
}

/// What [`lm_level_costed`] returns.
struct LevelRun {
    pose: Pose,
    iterations: u32,
    obs: Option<Observability>,
    /// The robust cost (sum over `points`) at the starting pose and at `pose`: each is
    /// `robust_cost` of that pose bit for bit, having been formed by `sample_points`, which adds
    /// the same per-point values in the same order.
    start_cost: f64,
    cost: f64,
}

/// [`lm_level`], also handing back the robust costs it computed at its first and last pose, so
/// that [`lm_pyramid`] need not evaluate them again.
fn lm_level_costed(
    map: &impl CostMap,
    pin: &Pinhole,
    mut pose: Pose,
    points: &[[f32; 3]],
    pivot_o: &Vector3<f64>,
    radius_m: f64,
    params: &LmParams,
) -> LevelRun {
    let mut mu = params.mu_initial;
    let mut iterations = 0;
    let pivot_of = |pose: &Pose| {
        let c = pose * nalgebra::Point3::from(*pivot_o);
        [c.x as f32, c.y as f32, c.z as f32]
    };
    // The points sampled at `pose`, and at the candidate being judged.
    let mut at_pose = Vec::with_capacity(points.len());
    let mut at_candidate = Vec::with_capacity(points.len());
    let mut cost = sample_points(map, pin, &pose, points, params, &mut at_pose);
    let (h, mut g) = normal_equations(pin, &at_pose, pivot_of(&pose), params);
    let start_cost = cost;
    // The cost at `pose` as it moves (`cost` itself is only refreshed with the normal equations).
    let mut cost_at_pose = cost;
    if h.diagonal().max() <= 0.0 {
        // No point sees a gradient: nothing to register against.
        return LevelRun {
            pose,
            iterations: 0,
            obs: None,
            start_cost,
            cost: cost_at_pose,
        };
    }
    let mut obs = Observability::new(&h, radius_m, params.weak_ratio);
    while iterations < params.max_iterations {
        iterations += 1;
        let step = obs.step(&g, mu);
        let pivot_c = pose * nalgebra::Point3::from(*pivot_o);
        let candidate = super::cost::apply_increment(&pose, &step, &pivot_c.coords);
        let new_cost = sample_points(map, pin, &candidate, points, params, &mut at_candidate);
        if new_cost.is_finite() && new_cost < cost {
            pose = candidate;
            cost_at_pose = new_cost;
            mu = (mu / 10.0).max(1e-9);
            if step.amax() < params.min_step
                || cost - new_cost < params.min_relative_decrease * cost
            {
                break;
            }
            std::mem::swap(&mut at_pose, &mut at_candidate);
            let (h, g2) = normal_equations(pin, &at_pose, pivot_of(&pose), params);
            if h.diagonal().max() <= 0.0 {
                break;
            }
            (g, cost) = (g2, new_cost);
            obs = Observability::new(&h, radius_m, params.weak_ratio);
        } else {
            mu *= 10.0;
            if mu > params.mu_max || step.amax() < params.min_step {
                break;
            }
        }
    }
    LevelRun {
        pose,
        iterations,
        obs: Some(obs),
        start_cost,
        cost: cost_at_pose,
    }
}

/// The lower-cost of two (cost, pose) pairs; the first on a tie.
fn min_cost(a: (f64, Pose), b: (f64, Pose)) -> (f64, Pose) {
    if b.0 < a.0 {
        b
    } else {
        a
    }
}

/// Coarse levels keep at least this many points when they are thinned.
const MIN_COARSE_POINTS: usize = 128;

/// One pyramidal LM step (Eq. 2): `levels` ordered coarse to fine, each a map with its pinhole;
/// each level starts from the previous level's result. A level 2^ℓ times coarser uses every
/// 2^ℓ-th point: its pixels are that much larger, so denser points add cost but no information.
pub fn lm_pyramid<M: CostMap>(
    levels: &[(&M, Pinhole)],
    pose: Pose,
    points: &[[f32; 3]],
    pivot_o: &Vector3<f64>,
    params: &LmParams,
) -> LmReport {
    let mut pose_out = pose;
    let mut iterations = 0;
    let radius_m = model_radius(points, pivot_o);
    let mut last_obs = None;
    // The robust costs at full resolution of the pyramid's start and result, when its last level
    // (full resolution, every point: the judge's own map and points) computed them.
    let (mut start_cost, mut out_cost) = (None, None);
    for (i, (map, pin)) in levels.iter().enumerate() {
        let coarseness = levels.len() - 1 - i;
        let stride = (1usize << coarseness).min((points.len() / MIN_COARSE_POINTS).max(1));
        let thinned: Cow<[[f32; 3]]> = if stride == 1 {
            Cow::Borrowed(points)
        } else {
            Cow::Owned(points.iter().step_by(stride).copied().collect())
        };
        let run = lm_level_costed(*map, pin, pose_out, &thinned, pivot_o, radius_m, params);
        if coarseness == 0 && stride == 1 {
            // Started from `pose` only when it is the only level.
            start_cost = (levels.len() == 1).then_some(run.start_cost);
            out_cost = Some(run.cost);
        }
        pose_out = run.pose;
        iterations += run.iterations;
        last_obs = run.obs;
    }
    // Coarse levels can lock onto the wrong edge: with part of the outline out of view or hidden,
    // their wide basins reach edges the missing part would have ruled out (benches/RESULTS.md,
    // issue 13). The step is therefore kept only if it lowers the robust cost at full resolution,
    // and lowers it more than refining at full resolution alone does. The judge is the robust
    // cost, not Eq. (1): Eq. (1) charges a point τ however far it is from every event, so a pose
    // that drags hidden points from τ to a little less onto edges of the wrong face scores better
    // while the points in view fit worse (box at 1.2 m, 30 % occluded: an 85 mm / 10° jump that
    // lowered Eq. (1) by 2 %); the redescending loss gives points with no event nearby no say.
    //
    // Every cost below is `robust_cost` at full resolution over all points; where an LM run at
    // that level already formed it for the same pose, its value is taken instead (the same bits).
    let mut final_cost = None;
    if let Some((map, pin)) = levels.last() {
        let judged = |c: f64| if c.is_nan() { f64::INFINITY } else { c };
        let judge = |p: &Pose, known: Option<f64>| {
            judged(known.unwrap_or_else(|| robust_cost(*map, pin, p, points, params)))
        };
        let fine = (levels.len() > 1)
            .then(|| lm_level_costed(*map, pin, pose, points, pivot_o, radius_m, params));
        let start_cost = start_cost.or(fine.as_ref().map(|f| f.start_cost));
        let mut best = (judge(&pose, start_cost), pose);
        let mut best_raw = start_cost;
        if pose_out != pose {
            let c = (judge(&pose_out, out_cost), pose_out);
            if c.0 < best.0 {
                best_raw = out_cost;
            }
            best = min_cost(best, c);
        }
        if let Some(fine) = fine {
            iterations += fine.iterations;
            let candidate = (judged(fine.cost), fine.pose);
            if candidate.0 < best.0 {
                best = candidate;
                best_raw = Some(fine.cost);
                last_obs = fine.obs;
            }
        }
        pose_out = best.1;
        final_cost = best_raw;
    }
    let cost = levels.last().map_or(0.0, |(map, pin)| {
        let c = final_cost.unwrap_or_else(|| robust_cost(*map, pin, &pose_out, points, params));
        (c / points.len().max(1) as f64) as f32
    });
    let mut held = [Vector6::zeros(); 6];
    let n_held = last_obs.map_or(0, |o| {
        for (k, h) in held.iter_mut().enumerate().take(o.n_weak) {
            *h = o.eigenvectors.column(k).into_owned();
        }
        o.n_weak
    });
    LmReport {
        pose: pose_out,
        iterations,
        cost,
        held,
        n_held,
        radius_m,
    }
}

#[cfg(test)]
mod tests {
    use super::super::cost::{apply_increment, centroid, testing};
    use super::*;
    use crate::camera::Camera;
    use crate::se3::distance;
    use nalgebra::Isometry3;

    #[test]
    fn converges_from_five_degrees_and_thirty_millimetres_in_depth() {
        let cam = Camera::imx636();
        let truth = Isometry3::new(Vector3::new(0.02, -0.01, 0.6), Vector3::new(0.4, 0.5, 0.2));
        let (points, _) = testing::visible_box_model(&truth);
        let pivot_o = centroid(&points);
        let maps: Vec<_> = (0..3)
            .rev()
            .map(|l| testing::box_map(&Pinhole::at_level(&cam, l), &truth, 10.0))
            .collect();
        let levels: Vec<_> = maps
            .iter()
            .zip((0..3).rev())
            .map(|(m, l)| (m, Pinhole::at_level(&cam, l)))
            .collect();
        let c = truth * nalgebra::Point3::from(pivot_o);
        // 30 mm along the line of sight, 5° about y and a few pixels sideways. A bare wireframe box has
        // shallow false minima for large sideways offsets; the textured models' interior edges remove
        // them (tests/test_tracking.py checks the 20 px case on those).
        let err = Vector6::new(0.003, -0.002, 0.03, 0.0, 5f64.to_radians(), 0.0);
        let mut pose = apply_increment(&truth, &err, &c.coords);
        for _ in 0..3 {
            pose = lm_pyramid(&levels, pose, &points, &pivot_o, &LmParams::default()).pose;
        }
        let (dt, dr) = distance(&pose, &truth);
        assert!(
            dt < 1e-3 && dr.to_degrees() < 0.1,
            "residual {:.2} mm, {:.3} deg",
            dt * 1e3,
            dr.to_degrees()
        );
    }

    #[test]
    fn an_unconstrained_direction_is_held_and_reported() {
        // Two long rails along the object's x: sliding along them changes nothing in the image.
        let cam = Camera::imx636();
        let pin = Pinhole::at_level(&cam, 0);
        let truth = Isometry3::translation(0.0, 0.0, 0.6);
        let points: Vec<[f32; 3]> = (0..200)
            .map(|i| {
                [
                    -0.1 + 0.001 * (i / 2) as f32,
                    if i % 2 == 0 { -0.05 } else { 0.05 },
                    0.0,
                ]
            })
            .collect();
        let rig = Rigid32::from_pose(&truth);
        let segments = [-0.05f32, 0.05]
            .iter()
            .map(|&y| {
                [
                    pin.project(rig.apply([-3.0, y, 0.0])).unwrap(),
                    pin.project(rig.apply([3.0, y, 0.0])).unwrap(),
                ]
            })
            .collect();
        let map = testing::SegmentMap {
            segments,
            tau: 10.0,
        };
        let start = Isometry3::translation(0.005, 0.0015, 0.6);
        let levels = [(&map, pin)];
        let out = lm_pyramid(
            &levels,
            start,
            &points,
            &centroid(&points),
            &LmParams::default(),
        );
        let t = out.pose.translation.vector;
        assert!((t.y).abs() < 1e-4, "y residual {:.3} mm", t.y * 1e3);
        assert!((t.x - 0.005).abs() < 1e-6, "x moved to {:.4} mm", t.x * 1e3);
        // Sliding along x is held; so may be a depth/tilt mix (the rails are planar), never more.
        assert!((1..=2).contains(&out.n_held), "{} held", out.n_held);
        let along_x: f64 = out.held[..out.n_held].iter().map(|h| h[0] * h[0]).sum();
        assert!(along_x > 0.99, "x lies outside the held span: {along_x}");
    }

    #[test]
    fn search_increments_lose_only_their_held_part() {
        // Held: sliding along x (scaled by the radius) and the spin about z.
        let mut report = LmReport {
            pose: Pose::identity(),
            iterations: 0,
            cost: 0.0,
            held: [Vector6::zeros(); 6],
            n_held: 2,
            radius_m: 0.05,
        };
        report.held[0] = Vector6::new(1.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        report.held[1] = Vector6::new(0.0, 0.0, 0.0, 0.0, 0.0, 1.0);
        let xi = Vector6::new(0.002, -0.001, 0.003, 0.01, -0.02, 0.03);
        let kept = report.without_held(&xi);
        assert_eq!(kept, Vector6::new(0.0, -0.001, 0.003, 0.01, -0.02, 0.0));
        // A held direction mixing translation and rotation is removed in the scaled coordinates.
        report.n_held = 1;
        report.held[0] = Vector6::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0) / 2f64.sqrt();
        let along = report.without_held(&Vector6::new(0.05 * 0.01, 0.0, 0.0, 0.0, 0.01, 0.0));
        assert!(along.amax() < 1e-15, "{along:?}");
        report.n_held = 0;
        assert_eq!(report.without_held(&xi), xi);
    }

    #[test]
    fn tukey_ignores_far_outliers_that_pull_huber() {
        let (r, k) = (5.0f32, 2.0);
        assert_eq!(robust_loss(Robust::Tukey, r, k).1, 0.0);
        assert!(robust_loss(Robust::Huber, r, k).1 > 0.0);
        // Both are least squares near zero.
        for kind in [Robust::Huber, Robust::Tukey] {
            let (rho, w) = robust_loss(kind, 0.01, k);
            assert!((rho - 0.5e-4).abs() < 1e-7 && (w - 1.0).abs() < 1e-4);
        }
    }

    /// The AVX2 sampling must give the scalar sampling's positions, values, slopes and cost bit
    /// for bit: chunks wholly inside the field, chunks across its border or off it, points behind
    /// the camera, and the tail after the last chunk of eight.
    #[test]
    fn sampling_eight_at_a_time_matches_one_at_a_time() {
        let cam = Camera::imx636();
        let pin = Pinhole::at_level(&cam, 0);
        let (truth, points, field) = testing::partial_field(11, 40);
        let map = field.level(0);
        let params = LmParams::default();
        let pivot = centroid(&points);
        let bits = |s: &[Sampled]| -> Vec<[u32; 6]> {
            s.iter()
                .map(|s| {
                    let a = s.at.unwrap_or([f32::NAN; 3]);
                    [s.p[0], s.p[1], s.p[2], a[0], a[1], a[2]].map(f32::to_bits)
                })
                .collect()
        };
        let (mut vector_chunks, mut fallback_chunks) = (0, 0);
        for i in 0..40 {
            let s = f64::from(i) / 40.0;
            let mut pose = apply_increment(
                &truth,
                &Vector6::new(0.02 * s - 0.01, 0.03 * s, 0.0, 0.2 * s, -0.1 * s, 0.3 * s),
                &(truth * nalgebra::Point3::from(pivot)).coords,
            );
            if i == 39 {
                // Half the box behind the camera plane.
                pose = Isometry3::translation(0.0, 0.0, -0.6) * pose;
            }
            let (mut one, mut wide) = (Vec::new(), Vec::new());
            let c1 = sample_points_in::<_, false>(map, &pin, &pose, &points, &params, &mut one);
            let c8 = sample_points(map, &pin, &pose, &points, &params, &mut wide);
            assert_eq!(c1.to_bits(), c8.to_bits(), "pose {i}");
            assert_eq!(bits(&one), bits(&wide), "pose {i}");
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") {
                let rig = Rigid32::from_pose(&pose);
                for chunk in points.chunks_exact(8) {
                    // SAFETY: the CPU has AVX2 and the chunk holds eight points.
                    match unsafe { sampled8_avx2(map, &pin, &rig, chunk) } {
                        Some(_) => vector_chunks += 1,
                        None => fallback_chunks += 1,
                    }
                }
            }
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            assert!(
                vector_chunks > 100 && fallback_chunks > 100,
                "{vector_chunks} {fallback_chunks}"
            );
        }
    }

    #[test]
    fn no_gradient_leaves_the_pose_alone() {
        let cam = Camera::imx636();
        let far_away = Isometry3::translation(5.0, 5.0, 0.6);
        let truth = Isometry3::translation(0.0, 0.0, 0.6);
        let (points, _) = testing::visible_box_model(&truth);
        let map = testing::box_map(&Pinhole::at_level(&cam, 0), &far_away, 10.0);
        let levels = [(&map, Pinhole::at_level(&cam, 0))];
        let out = lm_pyramid(
            &levels,
            truth,
            &points,
            &centroid(&points),
            &LmParams::default(),
        );
        assert_eq!(out.pose, truth);
    }
}
