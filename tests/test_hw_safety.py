"""SafetyGate on its own: limits, workspace, watchdog, stop on errors, dry run (a fake clock; no threads
except in the one test of the watchdog thread)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from evservo.limits import CartesianLimits
from evservo.robots.safety import SafetyGate, Workspace

LIM = CartesianLimits(max_lin_vel=0.5, max_ang_vel=1.0, max_lin_acc=2.0, max_ang_acc=4.0)
P0 = np.zeros(3)


class Rig:
    """Records what the gate forwards; the clock is set by the test."""

    def __init__(self, **kw) -> None:
        self.now, self.sent, self.halts = 0.0, [], 0
        self.fail_send = False
        self.gate = SafetyGate(self.send, self.halt, kw.pop("limits", LIM), clock=lambda: self.now, **kw)

    def send(self, v: np.ndarray, dt_s: float) -> None:
        if self.fail_send:
            raise OSError("link down")
        self.sent.append(v.copy())

    def halt(self) -> None:
        self.halts += 1


def ramp(rig: Rig, v: np.ndarray, n: int, dt: float = 0.01, p: np.ndarray = P0) -> np.ndarray:
    out = None
    for _ in range(n):
        out = rig.gate.command(v, p, dt)
        rig.now += dt
    return out


def test_velocity_scaling_is_uniform():
    rig = Rig(limits=CartesianLimits(max_lin_vel=0.5, max_ang_vel=1.0, max_lin_acc=1e3, max_ang_acc=1e3))
    v = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 1.0])  # linear 2× over, angular at the limit
    out = rig.gate.command(v, P0, 0.01)
    np.testing.assert_allclose(out, 0.5 * v)  # both parts shrink by the same factor
    assert rig.gate.history[-1].notes == ("velocity",)
    inside = np.array([0.1, 0.2, 0.0, 0.3, 0.0, 0.0])
    np.testing.assert_allclose(rig.gate.command(inside, P0, 0.01), inside)


def test_acceleration_ramps_from_rest_along_the_request():
    rig = Rig()
    v = np.array([0.4, 0.0, 0.0, 0.0, 0.0, 0.8])
    first = rig.gate.command(v, P0, 0.01)
    # |Δv_lin| ≤ 2 m/s² · 0.01 s and |Δω| ≤ 4 rad/s² · 0.01 s, one factor for both: the linear one binds.
    np.testing.assert_allclose(first, 0.05 * v)
    assert "acceleration" in rig.gate.history[-1].notes
    assert np.allclose(ramp(rig, v, 30), v)  # reached within (0.4 / 0.02 = 20) periods
    # A held period longer than the watchdog cannot justify a larger step.
    rig.gate.stop()
    np.testing.assert_allclose(rig.gate.command(v, P0, 10.0), v * (2.0 * rig.gate.watchdog_s / 0.4))


def test_workspace_brakes_before_a_face_and_lets_the_arm_back_in():
    box = Workspace(lo=[-1, -1, 0.2], hi=[1, 1, 1.0])
    rig = Rig(workspace=box, limits=CartesianLimits(max_lin_acc=2.0, max_ang_acc=4.0))
    ramp(rig, np.array([0.0, 0.0, -0.3, 0.0, 0.0, 0.0]), 40, p=np.array([0.0, 0.0, 0.6]))
    # 1 cm above the floor the downward speed is capped at √(2·2·0.01) = 0.2 m/s; x passes freely.
    out = rig.gate.command(np.array([0.1, 0.0, -0.3, 0.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.21]), 0.01)
    np.testing.assert_allclose(out[2], -0.2)
    assert "workspace" in rig.gate.history[-1].notes
    # Below the floor: nothing further down, motion back up allowed (within the acceleration limit).
    out = rig.gate.command(np.array([0.0, 0.0, -0.3, 0.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.19]), 0.01)
    assert out[2] == 0.0
    out = rig.gate.command(np.array([0.0, 0.0, 0.01, 0.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.19]), 0.01)
    assert out[2] == pytest.approx(0.01)
    assert box.contains([0, 0, 0.5]) and not box.contains([0, 0, 0.19])
    with pytest.raises(ValueError, match="lo < hi"):
        Workspace(lo=[0, 0, 1], hi=[1, 1, 1])


def test_watchdog_halts_once_then_resumes_from_rest():
    rig = Rig(watchdog_s=0.05)
    ramp(rig, np.array([0.1, 0, 0, 0, 0, 0]), 10)
    assert not rig.gate.check_watchdog()
    rig.now += 0.06
    assert rig.gate.check_watchdog() and rig.halts == 1
    assert not rig.gate.check_watchdog()  # at rest: nothing more to do
    np.testing.assert_array_equal(rig.gate.last_sent, np.zeros(6))
    out = rig.gate.command(np.array([0.1, 0, 0, 0, 0, 0]), P0, 0.01)
    assert out[0] == pytest.approx(0.02)  # ramps again from rest


def test_watchdog_thread_halts_in_real_time():
    halted = []
    gate = SafetyGate(lambda v, dt: None, lambda: halted.append(time.monotonic()), LIM, watchdog_s=0.03)
    with gate:
        t0 = time.monotonic()
        gate.command(np.array([0.01, 0, 0, 0, 0, 0]), P0, 0.002)
        deadline = t0 + 2.0
        while not halted and time.monotonic() < deadline:
            time.sleep(0.005)
        assert halted and halted[0] - t0 >= 0.03
    assert len(halted) == 2  # the watchdog's, then the one on leaving the block


def test_errors_halt_before_propagating():
    rig = Rig()
    with pytest.raises(ValueError, match="finite"):
        rig.gate.command(np.array([np.nan, 0, 0, 0, 0, 0]), P0, 0.01)
    assert rig.halts == 1
    rig.fail_send = True
    with pytest.raises(OSError, match="link down"):
        rig.gate.command(np.zeros(6), P0, 0.01)
    assert rig.halts == 2 and rig.gate.history[-1].reason.startswith("send failed")


def test_leaving_the_block_halts_even_on_ctrl_c():
    rig = Rig()
    with pytest.raises(KeyboardInterrupt), rig.gate:
        rig.gate.command(np.array([0.01, 0, 0, 0, 0, 0]), P0, 0.01)
        raise KeyboardInterrupt
    assert rig.halts == 1


def test_dry_run_forwards_nothing_but_records_and_logs(caplog):
    rig = Rig(dry_run=True)
    with caplog.at_level("INFO", logger="evservo.robots.safety"):
        out = rig.gate.command(np.array([0.01, 0, 0, 0, 0, 0]), P0, 0.01)
        rig.gate.stop()
    assert rig.sent == [] and rig.halts == 0
    assert [r.kind for r in rig.gate.history] == ["command", "halt"]
    np.testing.assert_allclose(rig.gate.history[0].sent, out)
    assert "would send" in caplog.text and "would halt" in caplog.text
