"""The loop's reaction to a lost object (evservo.control.hold.LossHold) on an exact kinematic camera: it
brakes to rest within the acceleration limit without a velocity step, keeps the desired pose, and
ramps back in after a re-lock; started without a pose it waits and captures the desired pose once locked."""

import numpy as np
import pytest

from evservo import geometry
from evservo.control import Pbvs
from evservo.control.hold import LossHold, ramp_weight
from evservo.limits import CartesianLimits

H = 0.002  # control period (s)
LIMITS = CartesianLimits(max_lin_vel=0.8, max_ang_vel=1.5, max_lin_acc=4.0, max_ang_acc=8.0)
V_OBJ = np.array([0.3, 0.0, 0.0])  # the object's world velocity (m/s)


def _linear(t: float) -> np.ndarray:
    T = geometry.pose((0.0, 0.0, 0.9), (0.2, -0.3, 0.1))
    T[:3, 3] += V_OBJ * t
    return T


def _run(hold: LossHold, lost_at, t_end: float, start: bool = True):
    """Close the loop on a camera that moves exactly as commanded; ``lost_at(t)`` says whether the
    tracker flags the object lost. Returns per-period times, commanded twists, modes and camera poses."""
    T_w_c = np.eye(4)
    if start:
        hold.start(T_w_c, geometry.inv(T_w_c) @ _linear(0.0), t_s=0.0)
    v = np.zeros(6)
    ts, vs, modes, cams = [], [], [], []
    for k in range(round(t_end / H)):
        t = k * H
        lost = lost_at(t)
        T_c_o = None if lost else geometry.inv(T_w_c) @ _linear(t)
        cmd = hold.update(t, T_w_c, v, T_c_o, t, lost)
        v = cmd.v_c_w
        ts.append(t)
        vs.append(v.copy())
        modes.append(cmd.mode)
        cams.append(T_w_c.copy())
        T_w_c = geometry.advance(T_w_c, v, H)
    return np.array(ts), np.array(vs), modes, np.array(cams)


def _hold() -> LossHold:
    return LossHold(Pbvs(k=20.0, feedforward=True, period_s=H, limits=LIMITS), confirm_s=0.02, ramp_s=0.3)


def test_a_lost_object_brings_the_camera_to_rest_within_the_limits_and_keeps_the_desired_pose():
    hold = _hold()
    des0 = geometry.inv(np.eye(4)) @ _linear(0.0)
    t, v, modes, _ = _run(hold, lambda t: 1.0 <= t < 1.6, 1.6)
    speed = np.linalg.norm(v[:, :3], axis=1)
    at_loss = np.searchsorted(t, 1.0)
    assert speed[at_loss - 1] > 0.25, "the camera must be following the object at the moment of loss"
    # Deceleration within the limit, no velocity step: |Δv| ≤ a_max · h every period.
    dv = np.linalg.norm(np.diff(v[:, :3], axis=0), axis=1)
    assert dv.max() <= LIMITS.max_lin_acc * H * (1 + 1e-9)
    # At rest as fast as the limit allows (v/a_max), and it stays at rest.
    rest_by = 1.0 + speed[at_loss - 1] / LIMITS.max_lin_acc + 2 * H
    assert np.all(speed[t >= rest_by] == 0.0) and np.all(v[t >= rest_by] == 0.0)
    assert np.all(np.diff(speed[at_loss:]) <= 0), "braking only: the speed never rises while lost"
    assert set(modes[at_loss:]) == {"holding"}
    np.testing.assert_array_equal(hold.T_c_o_des, des0)
    np.testing.assert_array_equal(hold.pbvs.T_c_o_des, des0)


def test_after_a_relock_servoing_ramps_back_in_and_catches_the_object_again():
    hold = _hold()
    des0 = _linear(0.0)
    t, v, modes, cams = _run(hold, lambda t: 1.0 <= t < 1.5, 3.5)
    resume = next(i for i, m in enumerate(modes) if t[i] >= 1.5 and m == "resuming")
    # Re-locked at 1.5 s; resumes once the tracker has reported the object found for confirm_s.
    assert 1.5 + hold.confirm_s - H <= t[resume] <= 1.5 + hold.confirm_s + 2 * H
    # No acceleration step at the resumption: it starts from (nearly) zero and grows.
    a = np.linalg.norm(np.diff(v[:, :3], axis=0), axis=1) / H
    assert a[resume] < 0.01 * LIMITS.max_lin_acc
    assert a.max() <= LIMITS.max_lin_acc * (1 + 1e-9)
    assert modes[-1] == "servoing"
    # The desired pose is the one from the start, and the camera gets there again: the object moved
    # ~0.15 m while the camera stood still, and two seconds later the servo error is small.
    np.testing.assert_array_equal(hold.T_c_o_des, des0)
    err = geometry.translation_error_m(geometry.inv(cams[-1]) @ _linear(t[-1]), des0)
    assert err < 0.01, err


def test_a_flickering_lost_flag_does_not_restart_the_controller():
    hold = _hold()
    flicker = lambda t: 1.0 <= t < 1.5 and int(t / 0.01) % 2 == 0  # noqa: E731 — 10 ms on, 10 ms off
    t, _, modes, _ = _run(hold, flicker, 1.5)
    assert all(m == "holding" for m, ti in zip(modes, t, strict=True) if 1.0 <= ti < 1.5)


def test_starting_without_a_pose_waits_at_rest_and_captures_the_desired_pose_once_locked():
    hold = _hold()
    hold.search()
    t, v, modes, cams = _run(hold, lambda t: t < 0.5, 1.0, start=False)
    assert np.all(v[t < 0.5] == 0.0) and set(modes[: np.searchsorted(t, 0.5)]) == {"searching"}
    locked = next(i for i, m in enumerate(modes) if m != "searching")
    np.testing.assert_allclose(hold.T_c_o_des, geometry.inv(cams[locked]) @ _linear(t[locked]), atol=1e-12)


def test_stopped_it_never_resumes():
    hold = _hold()
    T_w_c = np.eye(4)
    hold.start(T_w_c, _linear(0.0), 0.0)
    hold.update(0.0, T_w_c, np.zeros(6), None, None, lost=True)
    hold.stop()
    for k in range(1, 50):
        cmd = hold.update(k * H, T_w_c, np.zeros(6), _linear(k * H), k * H, lost=False)
        assert cmd.mode == "holding" and not np.any(cmd.v_c_w)


def test_ramp_weight_is_a_smoothstep():
    assert ramp_weight(0.0, 0.3) == 0.0 and ramp_weight(0.3, 0.3) == 1.0 and ramp_weight(0.15, 0.3) == 0.5
    assert ramp_weight(1.0, 0.0) == 1.0
    with pytest.raises(ValueError):
        LossHold(Pbvs(), confirm_s=-1.0)
