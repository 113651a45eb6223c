//! Hypothesis search (Eq. 3–4): the 2×6+1 candidates {0} ∪ {±δ_k e_k}, δ_k the increment along axis
//! k that moves the projected model by one pixel (from the image Jacobian), each scored by Eq. (1)
//! on the same field as LM; the lowest cost wins.

use super::cost::{apply_increment, image_jacobian, CostMap, Pinhole, Rigid32};
use crate::se3::{unit_twist, Pose};
use nalgebra::{Point3, Vector3};

/// Number of candidates: the null increment and ± one per axis.
pub const N_CANDIDATES: usize = 13;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SearchOutcome {
    pub pose: Pose,
    /// 0 = null, 2k+1 = +δ_k e_k, 2k+2 = −δ_k e_k.
    pub candidate: usize,
    /// Eq. (1) of every candidate, mean per point (pixels).
    pub costs: [f32; N_CANDIDATES],
}

/// δ_k for the six axes (metres, radians): the increment whose image motion has an RMS of one
/// pixel over the points. `stride` subsamples the points (the RMS needs few of them).
pub fn axis_steps(
    pin: &Pinhole,
    pose: &Pose,
    points: &[[f32; 3]],
    pivot_o: &Vector3<f64>,
    stride: usize,
) -> [f64; 6] {
    let rig = Rigid32::from_pose(pose);
    let c = pose * Point3::from(*pivot_o);
    let pivot = [c.x as f32, c.y as f32, c.z as f32];
    let mut sq = [0.0f64; 6];
    let mut n = 0usize;
    for &x in points.iter().step_by(stride.max(1)) {
        let p = rig.apply(x);
        if p[2] < super::cost::MIN_DEPTH_M {
            continue;
        }
        let j = image_jacobian(pin, p, pivot);
        for k in 0..6 {
            sq[k] += f64::from(j[0][k] * j[0][k] + j[1][k] * j[1][k]);
        }
        n += 1;
    }
    std::array::from_fn(|k| {
        let rms = (sq[k] / n.max(1) as f64).sqrt();
        if rms > 1e-12 {
            1.0 / rms
        } else {
            0.0
        }
    })
}

/// One search step from `pose` with per-axis steps `deltas` (see [`axis_steps`]).
///
/// Each candidate moves a point by at most about a pixel, so its image position is taken to first
/// order, u + s·δ_k·∂u/∂ξ_k: one projection and one Jacobian per point serve all 13 candidates,
/// and the 13 samples of a point fall on the same few cache lines of the field. The winner's pose
/// is then composed exactly.
pub fn search_step<M: CostMap>(
    map: &M,
    pin: &Pinhole,
    pose: &Pose,
    points: &[[f32; 3]],
    pivot_o: &Vector3<f64>,
    deltas: &[f64; 6],
) -> SearchOutcome {
    let pivot_c = (pose * Point3::from(*pivot_o)).coords;
    let pivot = [pivot_c.x as f32, pivot_c.y as f32, pivot_c.z as f32];
    let rig = Rigid32::from_pose(pose);
    let d: [f32; 6] = std::array::from_fn(|k| deltas[k] as f32);
    let far = map.max_value();
    // Serial on purpose: the tracker owns one core and leaves the other to the event source; on two
    // cores rayon's spinning workers cost more than they save (measured in benches/RESULTS.md).
    let mut sums = [0.0f32; N_CANDIDATES];
    for &x in points {
        let p = rig.apply(x);
        let Some((u, v)) = pin.project(p) else {
            sums.iter_mut().for_each(|s| *s += far);
            continue;
        };
        let j = image_jacobian(pin, p, pivot);
        let du: [f32; 6] = std::array::from_fn(|k| d[k] * j[0][k]);
        let dv: [f32; 6] = std::array::from_fn(|k| d[k] * j[1][k]);
        map.add_star(u, v, &du, &dv, &mut sums);
    }
    let n = points.len().max(1) as f32;
    let costs: [f32; N_CANDIDATES] = std::array::from_fn(|i| sums[i] / n);
    // Ties keep the lower index, so the null candidate wins unless something is strictly better.
    let best = (0..N_CANDIDATES).fold(0, |b, i| if costs[i] < costs[b] { i } else { b });
    let pose_out = if best == 0 {
        *pose
    } else {
        let k = (best - 1) / 2;
        let sign = if best % 2 == 1 { 1.0 } else { -1.0 };
        apply_increment(pose, &(unit_twist(k) * (sign * deltas[k])), &pivot_c)
    };
    SearchOutcome {
        pose: pose_out,
        candidate: best,
        costs,
    }
}

#[cfg(test)]
mod tests {
    use super::super::cost::{centroid, testing};
    use super::*;
    use crate::camera::Camera;
    use crate::se3::distance;
    use nalgebra::{Isometry3, Vector6};

    fn setup() -> (Pinhole, Isometry3<f64>, Vec<[f32; 3]>, Vector3<f64>) {
        let pin = Pinhole::at_level(&Camera::imx636(), 0);
        let truth = Isometry3::new(Vector3::new(0.01, 0.02, 0.6), Vector3::new(0.3, 0.4, 0.1));
        let (points, _) = testing::visible_box_model(&truth);
        let pivot = centroid(&points);
        (pin, truth, points, pivot)
    }

    #[test]
    fn one_pixel_steps_move_the_model_by_one_pixel_rms() {
        let (pin, truth, points, pivot) = setup();
        let deltas = axis_steps(&pin, &truth, &points, &pivot, 1);
        let rig0 = Rigid32::from_pose(&truth);
        let c = (truth * Point3::from(pivot)).coords;
        for k in 0..6 {
            let moved =
                Rigid32::from_pose(&apply_increment(&truth, &(unit_twist(k) * deltas[k]), &c));
            let ms: f32 = points
                .iter()
                .map(|&x| {
                    let (a, b) = (
                        pin.project(rig0.apply(x)).unwrap(),
                        pin.project(moved.apply(x)).unwrap(),
                    );
                    (a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)
                })
                .sum::<f32>()
                / points.len() as f32;
            assert!(
                (ms.sqrt() - 1.0).abs() < 0.05,
                "axis {k}: rms {}",
                ms.sqrt()
            );
        }
    }

    #[test]
    fn each_step_moves_by_exactly_one_candidate_towards_the_truth() {
        let (pin, truth, points, pivot) = setup();
        let map = testing::box_map(&pin, &truth, 10.0);
        let deltas = axis_steps(&pin, &truth, &points, &pivot, 1);
        let c = (truth * Point3::from(pivot)).coords;
        // Start three candidates off along +x and check each step takes back exactly one −δ_x.
        let mut pose = apply_increment(&truth, &(unit_twist(0) * (3.0 * deltas[0])), &c);
        for expected_left in [2.0, 1.0, 0.0] {
            let before = pose;
            let out = search_step(&map, &pin, &pose, &points, &pivot, &deltas);
            assert_eq!(out.candidate, 2, "costs {:?}", out.costs);
            let (dt, _) = distance(&before, &out.pose);
            assert!((dt - deltas[0]).abs() < 1e-9 * deltas[0].max(1.0) + 1e-9);
            pose = out.pose;
            let (left, _) = distance(&pose, &truth);
            assert!(
                (left - expected_left * deltas[0]).abs() < 1e-6,
                "left {left}"
            );
        }
        let out = search_step(&map, &pin, &pose, &points, &pivot, &deltas);
        assert_eq!(
            out.candidate, 0,
            "at the truth the null candidate wins: {:?}",
            out.costs
        );
    }

    #[test]
    fn search_recovers_a_mixed_offset_within_one_candidate() {
        let (pin, truth, points, pivot) = setup();
        let map = testing::box_map(&pin, &truth, 10.0);
        let c = (truth * Point3::from(pivot)).coords;
        let mut pose = apply_increment(
            &truth,
            &Vector6::new(0.002, -0.0015, 0.01, 0.01, -0.01, 0.02),
            &c,
        );
        for _ in 0..60 {
            let deltas = axis_steps(&pin, &pose, &points, &pivot, 4);
            pose = search_step(&map, &pin, &pose, &points, &pivot, &deltas).pose;
        }
        let (dt, dr) = distance(&pose, &truth);
        // The grid's spacing bounds the accuracy: out-of-plane rotations of a thin box need about a
        // degree to move it by one pixel, which is why the cascade follows with LM.
        let deltas = axis_steps(&pin, &pose, &points, &pivot, 1);
        assert!(
            dt < 2.5e-3 && dr < 1.5 * deltas[3].max(deltas[4]),
            "{:.2} mm {:.2} deg",
            dt * 1e3,
            dr.to_degrees()
        );
        assert_eq!(
            search_step(&map, &pin, &pose, &points, &pivot, &deltas).candidate,
            0
        );
    }
}
