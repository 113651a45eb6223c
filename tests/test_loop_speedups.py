"""The closed loop's per-tick shortcuts (issue 15) give the results of the straightforward code they
replace: each against its reference, and a short episode run with every reference patched back in
against the same episode as it runs now, tick for tick."""

import numpy as np
import pytest
import qpsolvers
from scipy.spatial.transform import Rotation

from evservo import _evcore, geometry, synth, trajectories
from evservo.robots import follow, ik, sim_arm
from evservo.robots.base import shift_twist
from evservo.sim import episode
from evservo.sim.episode import EpisodeConfig, run_episode, summarize
from evservo.sim.scene import DualArmScene
from evservo.tracking import model_point_set


def reference_shift_twist(v_a_w, p_a_w, p_b_w):
    v = np.asarray(v_a_w, dtype=float)
    return np.concatenate([v[:3] + np.cross(v[3:], np.asarray(p_b_w) - np.asarray(p_a_w)), v[3:]])


def reference_solve(J, v, q, qd, dt_s, limits, q_rest=None, damping=1e-4, posture_weight=1e-3, posture_gain=1.0,
                    weights=None, qdd=None):  # fmt: skip
    """The QP through qpsolvers' generic interface, regularisers added as matrices, np.clip."""
    n = limits.n
    lb, ub = reference_bounds(q, qd, dt_s, limits, qdd)
    JW = J.T if weights is None else J.T @ weights
    P = JW @ J + damping * np.eye(n)
    c = -JW @ v
    if q_rest is not None:
        P += posture_weight * np.eye(n)
        c -= posture_weight * posture_gain * (q_rest - q)
    if np.all(lb == ub):
        return lb
    return np.clip(qpsolvers.solve_qp(P, c, lb=lb, ub=ub, solver="daqp"), lb, ub)


def reference_bounds(q, qd, dt_s, limits, qdd):
    d_hi, d_lo = np.maximum(limits.q_max - q, 0.0), np.maximum(q - limits.q_min, 0.0)
    a = limits.qdd_max
    pv_hi = np.minimum(limits.qd_max, np.minimum(np.sqrt(2.0 * a * d_hi), d_hi / dt_s))
    pv_lo = -np.minimum(limits.qd_max, np.minimum(np.sqrt(2.0 * a * d_lo), d_lo / dt_s))
    a_now = np.clip(qdd, -a, a)
    w_lo = np.maximum(qd - a * dt_s, qd + (a_now - limits.qddd_max * dt_s) * dt_s)
    w_hi = np.minimum(qd + a * dt_s, qd + (a_now + limits.qddd_max * dt_s) * dt_s)
    lb, ub = np.maximum(pv_lo, w_lo), np.minimum(pv_hi, w_hi)
    above = lb > ub
    lb = np.where(above, np.where(w_lo > pv_hi, pv_hi, pv_lo), lb)
    return lb, np.where(above, lb, ub)


def reference_integrate(self, h_s):
    L = self.limits
    wanted = (self.qd_target - self.qd) / max(self._target_in_s, h_s)
    self._target_in_s = max(self._target_in_s - h_s, 0.0)
    jerk = L.qddd_max * h_s
    qdd = np.clip(np.clip(wanted, self.qdd - jerk, self.qdd + jerk), -L.qdd_max, L.qdd_max)
    qd = np.clip(self.qd + qdd * h_s, -L.qd_max, L.qd_max)
    self.qdd, self.qd = (qd - self.qd) / h_s, qd
    q = self.data.qpos[self._qadr] + self.qd * h_s
    at_limit = (q <= L.q_min) | (q >= L.q_max)
    self.qd[at_limit] = 0.0
    self.qdd[at_limit] = 0.0
    self.data.qpos[self._qadr] = np.clip(q, L.q_min, L.q_max)


def reference_vee_log(R):
    w = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s = float(np.linalg.norm(w))
    return w if s < 1e-12 else w * (np.arcsin(min(s, 1.0)) / s)


def reference_compose(trans, rotvec):
    D = np.tile(np.eye(4), (len(trans), 1, 1))
    D[:, :3, :3] = Rotation.from_rotvec(np.zeros_like(trans) if rotvec is None else rotvec).as_matrix()
    D[:, :3, 3] = trans
    return D


def reference_in_view(camera, points, T_c_o):
    p = points @ T_c_o[:3, :3].T + T_c_o[:3, 3]
    front = p[:, 2] > 1e-3
    if np.mean(front) < 0.5:
        return False
    uv = camera.project(p[front])
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    return bool(np.sum(inside) >= 0.5 * len(points))


def test_shift_twist_equals_the_cross_product_form():
    rng = np.random.default_rng(0)
    for _ in range(200):
        v, a, b = rng.normal(size=6), rng.normal(size=3), rng.normal(size=3)
        assert np.array_equal(shift_twist(v, a, b), reference_shift_twist(v, a, b))


def test_direct_daqp_ik_equals_the_qpsolvers_path():
    scene = DualArmScene()
    rng = np.random.default_rng(1)
    for arm in (scene.panda, scene.ur):
        J, q = arm.jacobian(), arm.joint_positions()
        n_clamped = 0
        for _ in range(100):
            v = rng.normal(scale=[0.5, 0.5, 0.5, 1.0, 1.0, 1.0])
            qd = rng.normal(scale=0.5 * arm.limits.qd_max)
            qdd = rng.normal(scale=0.5 * arm.limits.qdd_max)
            got = ik.solve_joint_velocities(J, v, q, qd, 0.001, arm.limits, q_rest=arm.q_rest, qdd=qdd)
            want = reference_solve(J, v, q, qd, 0.001, arm.limits, q_rest=arm.q_rest, qdd=qdd)
            assert np.array_equal(got, want)
            lb, ub = ik.joint_velocity_bounds(q, qd, 0.001, arm.limits, qdd)
            assert all(
                np.array_equal(x, y)
                for x, y in zip((lb, ub), reference_bounds(q, qd, 0.001, arm.limits, qdd), strict=True)
            )
            n_clamped += int(np.sum((got == lb) | (got == ub)))
        assert n_clamped > 50  # the bounds were active, not only the unconstrained optimum


def test_batched_view_test_equals_the_per_pose_one():
    camera = _evcore.Camera.imx636()
    T0 = np.eye(4)
    T0[:3, 3] = (0.0, 0.0, 0.9)
    rng = np.random.default_rng(2)
    poses = np.repeat(T0[None], 600, axis=0)
    poses[:, :3, 3] += rng.uniform(-0.6, 0.6, size=(600, 3)) * [1.0, 0.6, 1.5]  # in, at the edge, out, behind
    in_view = episode._view_test(camera, "box", T0, seed=1, chunk=97)
    points = model_point_set(camera, "box", T0, n_points=200, seed=1)
    want = np.array([reference_in_view(camera, points, T) for T in poses])
    got = in_view(poses)
    assert np.array_equal(got, want)
    assert 100 < np.sum(got) < 500  # both outcomes occur


def test_edge_events_keep_the_structured_sort_order():
    camera = _evcore.Camera.imx636()
    T0 = np.eye(4)
    T0[:3, 3] = (0.0, 0.0, 0.6)
    points = model_point_set(camera, "box", T0, n_points=3000, seed=3)
    gen = synth.EdgeEventGenerator(camera, points, T0, 0, noise_fraction=0.5, seed=3)
    T = T0.copy()
    for k in range(1, 20):
        T[:3, 3] += (0.0004, -0.0002, 0.0)
        ev = gen.events_until(k * 100, T)  # 100 µs batches: many equal time stamps
        want = ev.copy()
        want.sort(order="t", kind="stable")
        assert len(ev) > 100 and len(np.unique(ev["t"])) < len(ev)
        assert np.array_equal(ev, want)


def test_edge_events_are_the_distinct_pixels_points_move_into():
    """Without noise, each interval fires once per pixel that some point entered from another pixel,
    and a point not seen before or now (behind the camera) fires nothing."""
    camera = _evcore.Camera.imx636()
    T = np.eye(4)
    T[:3, 3] = (0.0, 0.0, 0.6)
    points = model_point_set(camera, "box", T, n_points=3000, seed=3)
    gen = synth.EdgeEventGenerator(camera, points, T, 0, noise_fraction=0.0, seed=3)
    poses = [T.copy() for _ in range(4)]
    poses[0][:3, 3] += (0.003, 0.001, 0.0)
    poses[1][:3, 3] = (0.0, 0.0, -0.6)  # behind the camera
    poses[3][:3, 3] += (0.003, 0.002, 0.0)
    prev = np.floor(camera.project(points @ T[:3, :3].T + T[:3, 3]) + 0.5)
    for k, P in enumerate(poses, start=1):
        cur = np.floor(camera.project(points @ P[:3, :3].T + P[:3, 3]) + 0.5)
        seen = np.all(np.isfinite(cur), axis=1) & np.all(np.isfinite(prev), axis=1)
        on = seen & (cur[:, 0] >= 0) & (cur[:, 0] < camera.width) & (cur[:, 1] >= 0) & (cur[:, 1] < camera.height)
        entered = cur[on & np.any(cur != prev, axis=1)].astype(np.int64)
        want = np.unique(entered[:, 1] * camera.width + entered[:, 0])
        ev = gen.events_until(k * 1000, P)
        got = np.sort(ev["y"].astype(np.int64) * camera.width + ev["x"])
        assert np.array_equal(got, want)
        assert (len(want) > 100) == (k in (1, 4))  # nothing fires into or out of the pose behind
        prev = cur


@pytest.mark.parametrize("ff", [True])
def test_an_episode_with_the_reference_code_is_identical(monkeypatch, ff):
    """Tick for tick, the same episode (0.15 s, edges, fixed costs) before and after the shortcuts."""
    cfg = EpisodeConfig(duration_s=0.15, cost_model="fixed", seed=1, feedforward=ff, speed_mps=0.5)
    scene = DualArmScene()
    now = run_episode(cfg, scene)
    monkeypatch.setattr(episode, "shift_twist", reference_shift_twist)
    monkeypatch.setattr(sim_arm, "solve_joint_velocities", reference_solve)
    monkeypatch.setattr(sim_arm.SimArm, "integrate", reference_integrate)
    monkeypatch.setattr(follow, "_vee_log", reference_vee_log)
    monkeypatch.setattr(trajectories, "_compose", reference_compose)
    before = run_episode(cfg, scene)
    for name in ("T_w_o", "T_w_c", "T_c_o_est", "est_t_s", "v_cmd_w", "v_cam_w", "joint_speed_ratio", "seen"):
        assert np.array_equal(getattr(now, name), getattr(before, name)), name
    a, b = summarize(now), summarize(before)
    a.pop("wall_s"), b.pop("wall_s")
    assert a == b
    assert a["completed"] and a["events"] > 10_000


def reference_as_pose(T, name="pose"):
    M = np.asarray(T, dtype=np.float64)
    if M.shape != (4, 4) or not np.all(np.isfinite(M)):
        raise ValueError(name)
    R = M[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-6 or np.linalg.det(R) <= 0:
        raise ValueError(name)
    if np.abs(M[3] - [0, 0, 0, 1]).max() > 1e-9:
        raise ValueError(name)
    return np.ascontiguousarray(M)


def test_pose_checks_and_rotation_error_equal_their_references():
    rng = np.random.default_rng(4)
    for k in range(600):
        T = geometry.pose(rng.normal(size=3), rng.normal(size=3) * [1.0, 1e-7, 3.0][k % 3])
        U = geometry.pose(rng.normal(size=3), rng.normal(size=3))
        want = float(np.arccos(np.clip((np.trace(T[:3, :3].T @ U[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
        assert geometry.rotation_error_rad(T, U) == want
        assert geometry.rotation_error_rad(T, T) == float(
            np.arccos(np.clip((np.trace(T[:3, :3].T @ T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))
        )
        bad = T.copy()
        kind = k % 5
        if kind == 1:
            bad[:3, 0] *= -1.0  # a reflection
        elif kind == 2:
            bad[:3, :3] *= 1.0 + 2e-6  # not orthonormal
        elif kind == 3:
            bad[3, 2] = 1e-8  # bottom row
        elif kind == 4:
            bad[1, 3] = np.nan
        outcomes = []
        for check in (geometry.as_pose, reference_as_pose):
            try:
                outcomes.append(check(bad).tobytes())
            except ValueError:
                outcomes.append(None)
        assert outcomes[0] == outcomes[1]
        assert (outcomes[0] is None) == (kind != 0)


def test_poses_from_rotation_vectors_and_quaternions_equal_scipys():
    # The closed forms that let `import evservo` skip scipy, against scipy's Rotation.
    rng = np.random.default_rng(7)
    for k in range(500):
        t = rng.normal(size=3)
        w = rng.normal(size=3) * [3.0, 1e-9, 0.3][k % 3]
        q = rng.normal(size=4) * rng.uniform(0.1, 10.0)
        want = np.eye(4)
        want[:3, :3], want[:3, 3] = Rotation.from_rotvec(w).as_matrix(), t
        np.testing.assert_allclose(geometry.pose(t, w), want, rtol=0, atol=1e-12)
        want[:3, :3] = Rotation.from_quat(q).as_matrix()
        np.testing.assert_allclose(geometry.pose_from_xyz_quat(*t, *q), want, rtol=0, atol=1e-12)


def test_rendered_and_noise_filled_batches_reach_the_tracker_as_event_cd_without_a_copy(camera):
    """numpy's concatenate packs EVENT_CD (drops the padding before t) unless told the dtype; the
    tracker then copies every event back into its layout, which in the brief's rendered drill
    episode was 0.45 of the producer's charged time at 33 Mev/s (benches/RESULTS.md, issue 11,
    round 14)."""
    from conftest import box_start_pose
    from evservo.events import EVENT_CD, as_event_cd
    from evservo.sim.disturb import Disturbances
    from evservo.sim.sources import RenderedSource

    T0 = box_start_pose(0.6)
    batches = []
    for interpolate in (False, True):  # a render per tick, and several ticks' renders handed out at once
        src = RenderedSource(camera, "box", T0, 0, seed=3, interpolate=interpolate)
        for k in range(1, 6):
            batches.append(src.events_until(1000 * k, geometry.pose((4e-4 * k, 0.0, 0.0)) @ T0))
    noisy = Disturbances(camera.width, camera.height, noise=(0.002, 0.004), noise_rate_hz=1e6)
    batches.append(noisy.events(1000, 5000, batches[-1]))
    assert sum(len(b) for b in batches) > 1000
    for b in batches:
        assert b.dtype == EVENT_CD
        assert as_event_cd(b) is b or not len(b)
