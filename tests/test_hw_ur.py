"""UrArm against a loopback RTDE peer (tests/rtde_peer.py: the real ur_rtde receive client talks RTDE
to a subprocess on 127.x.y.z:30004; the control side is a recording fake)."""

from __future__ import annotations

import random
import time

import numpy as np
import pytest

from rtde_peer import FakeControl, Peer, make_arm

rtde_receive = pytest.importorskip("rtde_receive", reason="needs ur-rtde")

from evservo.limits import CartesianLimits  # noqa: E402
from evservo.robots.safety import Workspace  # noqa: E402
from evservo.robots.ur import UrArm, pose_from_rtde  # noqa: E402


@pytest.fixture
def peer():
    p = Peer()
    yield p
    p.close()


def wait_for(cond, timeout_s: float = 3.0) -> bool:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if cond():
            return True
        time.sleep(0.005)
    return cond()


def test_receive_path_reads_pose_and_joints(peer):
    with UrArm(peer.host, dry_run=True) as arm:
        assert wait_for(lambda: np.allclose(arm.joint_positions(), [0.1, -1.2, 1.3, -1.6, -1.5, 0.2]))
        T = arm.T_w_e()
        np.testing.assert_allclose(T, pose_from_rtde([0.4, -0.1, 0.3, 0.0, np.pi, 0.0]), atol=1e-12)
        assert T[2, 2] == pytest.approx(-1.0)  # the TCP points down
        peer.send("pose 0.5 0.0 0.2 0 0 0.3")
        assert wait_for(lambda: np.allclose(arm.T_w_e()[:3, 3], [0.5, 0.0, 0.2]))
        np.testing.assert_allclose(arm.T_w_e()[:3, :3], pose_from_rtde([0, 0, 0, 0, 0, 0.3])[:3, :3], atol=1e-12)


def test_dry_run_sends_nothing(peer):
    with UrArm(peer.host, dry_run=True) as arm:
        arm.command_twist(np.array([0.1, 0, 0, 0, 0, 0]), 0.002)
        arm.stop()
        assert [r.kind for r in arm.gate.history] == ["command", "halt"]
        seen = peer.log()
    # One connection (receive only: no control interface, no script), and only the receive handshake.
    assert seen["connections"] == 1
    assert seen["received"] == ["V", "v", "O", "S"]


def test_limits_scale_commanded_twists(peer):
    limits = CartesianLimits(max_lin_vel=0.25, max_ang_vel=0.5, max_lin_acc=100.0, max_ang_acc=100.0)
    arm, ctl = make_arm(peer, limits=limits)
    with arm:
        v = np.array([1.0, 0.5, 0.0, 0.0, 0.0, 0.4])
        arm.command_twist(v, 0.01)
        sent = ctl.twists()[-1]
        # Uniform scaling: the same direction, the linear speed at its limit.
        assert np.linalg.norm(sent[:3]) == pytest.approx(0.25)
        np.testing.assert_allclose(sent / np.linalg.norm(sent), v / np.linalg.norm(v), atol=1e-12)
        name, (_, acc, _) = ctl.calls[-1]
        assert name == "speedL" and acc == pytest.approx(100.0)
        # From rest the acceleration limit governs instead: |Δv| ≤ a·dt.
    gentle = CartesianLimits(max_lin_vel=0.25, max_ang_vel=0.5, max_lin_acc=1.0, max_ang_acc=2.0)
    arm, ctl = make_arm(peer, limits=gentle)
    with arm:
        arm.command_twist(np.array([0.2, 0, 0, 0, 0, 0]), 0.002)
        np.testing.assert_allclose(ctl.twists()[-1], [0.002, 0, 0, 0, 0, 0], atol=1e-12)


def test_workspace_blocks_outward_motion(peer):
    # The peer's TCP sits at z = 0.3; a box whose top face is there lets it move down, not up.
    box = Workspace(lo=[-1, -1, 0.0], hi=[1, 1, 0.3])
    arm, ctl = make_arm(peer, workspace=box, limits=CartesianLimits(max_lin_acc=100.0, max_ang_acc=100.0))
    with arm:
        assert wait_for(lambda: arm.T_w_e()[2, 3] == pytest.approx(0.3))
        arm.command_twist(np.array([0.1, 0, 0.2, 0, 0, 0]), 0.01)
        np.testing.assert_allclose(ctl.twists()[-1], [0.1, 0, 0, 0, 0, 0], atol=1e-12)
        arm.command_twist(np.array([0.1, 0, -0.2, 0, 0, 0]), 0.01)
        np.testing.assert_allclose(ctl.twists()[-1], [0.1, 0, -0.2, 0, 0, 0], atol=1e-12)


def test_watchdog_stops_when_commands_stop(peer):
    arm, ctl = make_arm(peer, watchdog_s=0.05)
    with arm:
        assert ("setWatchdog", (10.0,)) in ctl.calls
        arm.command_twist(np.array([0.01, 0, 0, 0, 0, 0]), 0.002)
        assert "speedStop" not in ctl.names()
        assert wait_for(lambda: "speedStop" in ctl.names(), 2.0)
        assert arm.gate.watchdog_halts == 1
        assert arm.gate.history[-1].reason.startswith("watchdog")
        np.testing.assert_array_equal(arm.gate.last_sent, np.zeros(6))


@pytest.mark.parametrize(("how", "why"), [("drop", "closed"), ("pause", "no new robot state")])
def test_connection_loss_stops_and_names_host(peer, how, why):
    arm, ctl = make_arm(peer, state_timeout_s=0.1)
    with arm:
        arm.command_twist(np.array([0.01, 0, 0, 0, 0, 0]), 0.002)
        n_before = ctl.names().count("speedStop")
        peer.send(how)
        with pytest.raises(ConnectionError, match=peer.host.replace(".", r"\.")) as err:
            t_end = time.monotonic() + 3.0
            while time.monotonic() < t_end:
                arm.command_twist(np.array([0.01, 0, 0, 0, 0, 0]), 0.002)
                time.sleep(0.002)
        assert why in str(err.value)
        assert ctl.names().count("speedStop") > n_before  # a stop was attempted
        with pytest.raises(ConnectionError):
            arm.T_w_e()  # stays lost


def test_arm_not_running_refuses_to_move(peer):
    arm, ctl = make_arm(peer)
    with arm:
        peer.send("modes 7 3")  # protective stop
        assert wait_for(lambda: arm._read(lambda r: r.getSafetyMode()) == 3)
        with pytest.raises(RuntimeError, match="safety_mode 3"):
            arm.command_twist(np.zeros(6), 0.002)
        assert "speedL" not in ctl.names() and "speedStop" in ctl.names()


def test_exception_in_block_stops_and_disconnects(peer):
    arm, ctl = make_arm(peer)
    with pytest.raises(KeyboardInterrupt), arm:
        arm.command_twist(np.array([0.01, 0, 0, 0, 0, 0]), 0.002)
        raise KeyboardInterrupt
    assert ctl.names()[-2:] == ["speedStop", "disconnect"]


def test_connect_failure_names_host():
    host = f"127.{random.randint(1, 254)}.{random.randint(1, 254)}.1"  # nothing listens there
    with pytest.raises(ConnectionError, match=host.replace(".", r"\.")):
        UrArm(host, control_factory=FakeControl)
