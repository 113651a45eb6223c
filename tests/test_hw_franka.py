"""FrankaArm against franky-sim: the real franky client talking the libfranka protocol to a MuJoCo FR3
served on a loopback address (realtime checks off)."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest

franky = pytest.importorskip("franky", reason="needs franky-control")
pytest.importorskip("franky_sim", reason="needs franky-sim")

from evservo.robots import Arm  # noqa: E402
from evservo.robots.franka import FrankaArm  # noqa: E402
from franka_sim import Sim  # noqa: E402

V_Y = np.array([0.0, 0.05, 0.0, 0.0, 0.0, 0.0])  # 5 cm/s along the base y axis


@pytest.fixture(scope="module")
def sim():
    s = Sim()
    yield s
    s.close()


def stream(arm: FrankaArm, v: np.ndarray, seconds: float, period_s: float = 0.002) -> int:
    n, t_end = 0, time.monotonic() + seconds
    while time.monotonic() < t_end:
        arm.command_twist(v, period_s)
        n += 1
        time.sleep(period_s)
    return n


def velocity_from_poses(arm: FrankaArm, v: np.ndarray, window_s: float = 0.3) -> np.ndarray:
    """Mean EE linear velocity while streaming ``v`` for ``window_s`` (wall clock), from measured poses
    over the robot's own clock (m/s): franky-sim runs slower than real time on a small machine. Pose
    and time come from one state sample so that they match."""

    def sample() -> tuple[np.ndarray, float]:
        state = arm.robot.state
        return np.asarray(state.O_T_EE.translation, dtype=float), state.time.to_sec()

    p0, t0 = sample()
    stream(arm, v, window_s)
    p1, t1 = sample()
    return (p1 - p0) / (t1 - t0)


def at_rest(arm: FrankaArm, window_s: float = 0.2) -> bool:
    p0 = arm.T_w_e()[:3, 3]
    time.sleep(window_s)
    return float(np.linalg.norm(arm.T_w_e()[:3, 3] - p0)) < 1e-3


def wait_for(cond, timeout_s: float) -> bool:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if cond():
            return True
        time.sleep(0.01)
    return cond()


def test_connect_stream_and_watchdog_stop(sim):
    with FrankaArm(sim.host, realtime="ignore", watchdog_s=0.05) as arm:
        assert isinstance(arm, Arm)
        assert arm.joint_positions().shape == (7,)
        T0 = arm.T_w_e()
        assert np.allclose(T0[:3, :3].T @ T0[:3, :3], np.eye(3), atol=1e-6)
        assert stream(arm, V_Y, 0.3) > 50
        # Once up to speed the EE moves at the commanded twist (base frame), measured from its poses.
        np.testing.assert_allclose(velocity_from_poses(arm, V_Y), V_Y[:3], atol=5e-3)
        moved = arm.T_w_e()[:3, 3] - T0[:3, 3]
        assert 0.005 < moved[1] < 0.04 and abs(moved[0]) < 2e-3 and abs(moved[2]) < 2e-3
        # Commands stop (the pose went stale upstream): the gate halts and the arm comes to rest.
        assert wait_for(lambda: arm.gate.watchdog_halts == 1, 2.0)
        assert wait_for(lambda: at_rest(arm), 2.0)


def test_connecting_leaves_the_calling_threads_scheduling_alone(sim):
    # libfranka raises the connecting thread to SCHED_FIFO 99 where it may (root, as in CI); every
    # thread started from it then inherited that, e.g. a tracker's solver spinning at top priority.
    before = os.sched_getscheduler(0), os.sched_getparam(0)
    with FrankaArm(sim.host, realtime="ignore") as arm:
        stream(arm, V_Y, 0.05)
        assert (os.sched_getscheduler(0), os.sched_getparam(0)) == before
        seen: list[int] = []
        th = threading.Thread(target=lambda: seen.append(os.sched_getscheduler(0)))
        th.start()
        th.join()
        assert seen == [before[0]]


def test_limits_reach_the_robot(sim):
    from evservo.limits import CartesianLimits

    limits = CartesianLimits(max_lin_vel=0.02, max_ang_vel=0.1)
    with FrankaArm(sim.host, realtime="ignore", limits=limits) as arm:
        stream(arm, 5 * V_Y, 0.3)  # asks for 0.25 m/s, gets 0.02
        # What franky's 1 kHz loop sends to the robot (libfranka's O_dP_EE_c, base frame).
        sent = arm.robot.state.O_dP_EE_c
        np.testing.assert_allclose(np.concatenate([sent.linear, sent.angular]), 0.4 * V_Y, atol=1e-6)
        # And the simulated arm follows (sim tracking lags a few mm/s behind its command).
        np.testing.assert_allclose(velocity_from_poses(arm, 5 * V_Y), [0, 0.02, 0], atol=5e-3)


def test_dry_run_does_not_move(sim):
    with FrankaArm(sim.host, realtime="ignore", dry_run=True) as arm:
        p0 = arm.T_w_e()[:3, 3]
        stream(arm, V_Y, 0.2)
        assert np.linalg.norm(arm.T_w_e()[:3, 3] - p0) < 1e-4
        assert sum(r.kind == "command" for r in arm.gate.history) > 10


def test_clean_shutdown_leaves_arm_at_rest_and_reconnectable(sim):
    arm = FrankaArm(sim.host, realtime="ignore", watchdog_s=1.0)  # only close() may stop it here
    stream(arm, V_Y, 0.2)
    arm.close()
    with pytest.raises(ConnectionError, match="closed"):
        arm.T_w_e()
    with FrankaArm(sim.host, realtime="ignore") as again:  # the first connection was released
        assert at_rest(again)


def test_server_loss_raises_connection_error_naming_host():
    s = Sim()
    arm = FrankaArm(s.host, realtime="ignore")
    try:
        stream(arm, V_Y, 0.1)
        s.close()
        with pytest.raises(ConnectionError, match=s.host.replace(".", r"\.")):
            stream(arm, V_Y, 10.0)
        assert any(r.kind == "halt" and r.reason.startswith("connection lost") for r in arm.gate.history)
    finally:
        arm.close()
