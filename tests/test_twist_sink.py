"""The twist-sink arm (what ``evservo ros servo`` publishes through): every twist the gate lets through
is handed over in end-effector axes, every halt (stop, the gate's watchdog, close) hands over a zero
twist, dead reckoning follows the sent twists, and a stale pose source is a lost link."""

import time

import numpy as np
import pytest

from evservo import geometry
from evservo.limits import CartesianLimits
from evservo.robots.twist_sink import TwistSink, twist_in_frame


def _sink(**kw):
    sent = []
    arm = TwistSink(lambda v, dt: sent.append((np.array(v), dt)), **kw)
    return arm, sent


def test_twists_are_handed_over_in_end_effector_axes_and_halts_as_zero():
    T0 = geometry.pose((0.4, 0.0, 0.4), (0.3, -0.2, 1.1))
    arm, sent = _sink(T_w_e0=T0, limits=CartesianLimits(1.0, 2.0, 100.0, 200.0), watchdog_s=0.5)
    try:
        v_w = np.array([0.1, -0.05, 0.02, 0.2, 0.0, -0.1])
        arm.command_twist(v_w, 0.01)
        v_e, dt = sent[-1]
        assert dt == 0.01
        np.testing.assert_allclose(T0[:3, :3] @ v_e[:3], v_w[:3], atol=1e-12)  # back to world axes
        np.testing.assert_allclose(T0[:3, :3] @ v_e[3:], v_w[3:], atol=1e-12)
        np.testing.assert_allclose(arm.gate.last_sent, v_w)  # within the limits: unchanged
        arm.stop()
        assert not np.any(sent[-1][0])
    finally:
        arm.close()
    assert not np.any(sent[-1][0])


def test_the_gate_watchdog_hands_over_a_zero_twist():
    arm, sent = _sink(watchdog_s=0.02)
    try:
        arm.command_twist(np.array([0.01, 0, 0, 0, 0, 0]), 0.01)
        deadline = time.monotonic() + 5
        # The gate counts the halt before its thread hands the zero twist over: wait for both.
        while (arm.gate.watchdog_halts == 0 or len(sent) < 2) and time.monotonic() < deadline:
            time.sleep(0.005)
        assert arm.gate.watchdog_halts == 1
        assert len(sent) == 2 and np.any(sent[0][0]) and not np.any(sent[1][0])
    finally:
        arm.close()


def test_dead_reckoning_follows_the_sent_twist():
    arm, _ = _sink(limits=CartesianLimits(1.0, 2.0, 100.0, 200.0), watchdog_s=1.0)
    try:
        p0 = arm.T_w_e()[:3, 3]
        arm.command_twist(np.array([0.1, 0.0, 0.0, 0.0, 0.0, 0.0]), 0.2)
        t0 = time.monotonic()
        time.sleep(0.1)
        arm.stop()
        dt = time.monotonic() - t0
        moved = arm.T_w_e()[:3, 3] - p0
        assert moved[0] == pytest.approx(0.1 * dt, abs=0.1 * 0.02)  # the sleep's measured length, ±20 ms
        assert moved[1:] == pytest.approx([0.0, 0.0])
    finally:
        arm.close()


def test_a_stale_pose_source_is_a_lost_link_and_stops_the_arm():
    T = geometry.pose((0.5, 0.1, 0.3), (0.0, 0.0, 0.5))
    fresh = [True]

    def pose():
        if not fresh[0]:
            raise ConnectionError("end-effector pose is 0.5 s old")
        return T

    arm, sent = _sink(pose=pose, watchdog_s=1.0)
    try:
        np.testing.assert_array_equal(arm.T_w_e(), T)
        v_w = np.array([0.0, 0.02, 0.0, 0.0, 0.0, 0.1])
        arm.command_twist(v_w, 0.01)
        np.testing.assert_allclose(twist_in_frame(arm.gate.last_sent, T[:3, :3]), sent[-1][0])  # as gated
        fresh[0] = False
        with pytest.raises(ConnectionError, match=r"0\.5 s old"):
            arm.command_twist(v_w, 0.01)
        assert not np.any(sent[-1][0])
        with pytest.raises(ConnectionError):
            arm.T_w_e()
    finally:
        arm.close()
