"""UrArm against a loopback RTDE peer.

ur-rtde's ``RTDEReceiveInterface`` has no port argument (it always dials 30004), so the peer listens
on 30004 of a random 127.x.y.z address: the real ur_rtde receive client talks RTDE to it (protocol
version, controller version, output setup, start, 500 Hz data packages). ``RTDEControlInterface`` is
not exercised: it also needs the script and dashboard ports and a running URScript that acknowledges
every command through registers, so the control side is a recording fake injected through
``control_factory``. The peer runs in a subprocess because ur_rtde's constructors hold the GIL
while they wait for the peer's replies.

Run as ``python test_hw_ur.py --rtde-peer HOST`` this file is the peer itself: it prints ``READY``
once listening and then obeys lines on stdin (see ``_peer_main``).
"""

from __future__ import annotations

import json
import math
import random
import socket
import struct
import subprocess
import sys
import threading
import time

RTDE_PORT = 30004
# RTDE output types of the variables UrArm subscribes to (UR's RTDE guide), with struct codes.
_PEER_TYPES = {
    "timestamp": ("DOUBLE", "d"),
    "actual_q": ("VECTOR6D", "6d"),
    "actual_qd": ("VECTOR6D", "6d"),
    "actual_TCP_pose": ("VECTOR6D", "6d"),
    "actual_TCP_speed": ("VECTOR6D", "6d"),
    "robot_mode": ("INT32", "i"),
    "safety_mode": ("INT32", "i"),
}


def _peer_main(host: str) -> None:
    """A minimal RTDE server: enough of the protocol for a receive client.

    stdin commands: ``pose x y z rx ry rz``, ``modes ROBOT SAFETY``, ``pause`` (stop sending data
    while keeping the socket open), ``drop`` (close the client's socket), ``log`` (print a JSON
    line: connections accepted and message types received, in order), ``quit``.
    """
    state = {"pose": [0.4, -0.1, 0.3, 0.0, math.pi, 0.0], "q": [0.1, -1.2, 1.3, -1.6, -1.5, 0.2], "modes": [7, 1]}
    lock = threading.Lock()
    streaming, log, conns = threading.Event(), [], []
    srv = socket.create_server((host, RTDE_PORT))
    print("READY", flush=True)

    def frame(kind: str, payload: bytes = b"") -> bytes:
        return struct.pack(">HB", 3 + len(payload), ord(kind)) + payload

    def recv_exact(c: socket.socket, n: int) -> bytes:
        buf = b""
        while len(buf) < n:
            chunk = c.recv(n - len(buf))
            if not chunk:
                raise EOFError
            buf += chunk
        return buf

    def stream(c: socket.socket, names: list[str]) -> None:
        k = 0
        while streaming.is_set():
            with lock:
                values = {"timestamp": [k * 0.002], "actual_q": state["q"], "actual_qd": [0.0] * 6,
                          "actual_TCP_pose": state["pose"], "actual_TCP_speed": [0.0] * 6,
                          "robot_mode": [state["modes"][0]], "safety_mode": [state["modes"][1]]}  # fmt: skip
            body = b"\x01" + b"".join(struct.pack(">" + _PEER_TYPES[n][1], *values[n]) for n in names)
            try:
                c.sendall(frame("U", body))
            except OSError:
                return
            k += 1
            time.sleep(0.002)

    def serve() -> None:
        while True:
            c, _ = srv.accept()
            conns.append(c)
            names: list[str] = []
            try:
                while True:
                    size, kind = struct.unpack(">HB", recv_exact(c, 3))
                    payload = recv_exact(c, size - 3)
                    log.append(chr(kind))
                    if kind == ord("V"):  # request protocol version: accept
                        c.sendall(frame("V", b"\x01"))
                    elif kind == ord("v"):  # controller version 5.15: an e-Series, hence 500 Hz
                        c.sendall(frame("v", struct.pack(">IIII", 5, 15, 0, 0)))
                    elif kind == ord("O"):  # output setup: frequency, then comma-separated names
                        names = [n for n in payload[8:].decode().split(",") if n]
                        types = [_PEER_TYPES.get(n, ("NOT_FOUND", ""))[0] for n in names]
                        c.sendall(frame("O", b"\x01" + ",".join(types).encode()))
                    elif kind == ord("S"):
                        c.sendall(frame("S", b"\x01"))
                        streaming.set()
                        threading.Thread(target=stream, args=(c, names), daemon=True).start()
                    elif kind == ord("P"):
                        streaming.clear()
                        c.sendall(frame("P", b"\x01"))
            except (EOFError, OSError):
                streaming.clear()

    threading.Thread(target=serve, daemon=True).start()
    for line in sys.stdin:
        cmd, *args = line.split()
        with lock:
            if cmd == "pose":
                state["pose"] = [float(a) for a in args]
            elif cmd == "modes":
                state["modes"] = [int(a) for a in args]
        if cmd == "pause":
            streaming.clear()
        elif cmd == "drop":
            streaming.clear()
            for c in conns:
                c.shutdown(socket.SHUT_RDWR)
                c.close()
        elif cmd == "log":
            print(json.dumps({"connections": len(conns), "received": log}), flush=True)
        elif cmd == "quit":
            break


# Started as the peer, stop here: the peer needs only the standard library and should start fast.
if __name__ == "__main__" and sys.argv[1:2] == ["--rtde-peer"]:
    _peer_main(sys.argv[2])
    sys.exit(0)

import numpy as np  # noqa: E402
import pytest  # noqa: E402


class Peer:
    """The RTDE peer subprocess, driven from the test."""

    def __init__(self) -> None:
        for _ in range(20):
            self.host = f"127.{random.randint(1, 254)}.{random.randint(1, 254)}.{random.randint(2, 254)}"
            self.proc = subprocess.Popen(
                [sys.executable, __file__, "--rtde-peer", self.host],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
            )  # fmt: skip
            if self.proc.stdout.readline().strip() == "READY":
                return
            self.proc.wait(timeout=10)
        raise RuntimeError("could not start the RTDE peer")

    def send(self, line: str) -> None:
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def log(self) -> dict:
        self.send("log")
        return json.loads(self.proc.stdout.readline())

    def close(self) -> None:
        try:
            self.send("quit")
            self.proc.wait(timeout=5)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait(timeout=5)


class FakeControl:
    """Records what UrArm asks of ``RTDEControlInterface``."""

    def __init__(self, host: str) -> None:
        self.host, self.calls, self.connected = host, [], True

    def _rec(self, name: str, *args: object) -> bool:
        self.calls.append((name, args))
        return True

    def speedL(self, xd: list[float], acceleration: float, time: float) -> bool:
        return self._rec("speedL", list(xd), acceleration, time)

    def speedStop(self, a: float) -> bool:
        return self._rec("speedStop", a)

    def setWatchdog(self, hz: float) -> bool:
        return self._rec("setWatchdog", hz)

    def kickWatchdog(self) -> bool:
        return True  # called every few ms from the watchdog thread: not recorded

    def isConnected(self) -> bool:
        return self.connected

    def disconnect(self) -> None:
        self._rec("disconnect")

    def names(self) -> list[str]:
        return [c[0] for c in self.calls]

    def twists(self) -> list[np.ndarray]:
        return [np.array(a[0]) for n, a in self.calls if n == "speedL"]


rtde_receive = pytest.importorskip("rtde_receive", reason="needs ur-rtde")

from evservo.control import CartesianLimits  # noqa: E402
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


def make_arm(peer: Peer, **kw) -> tuple[UrArm, FakeControl]:
    fakes: list[FakeControl] = []

    def control(host: str) -> FakeControl:
        fakes.append(FakeControl(host))
        return fakes[-1]

    arm = UrArm(peer.host, control_factory=control, **kw)
    return arm, fakes[0]


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
