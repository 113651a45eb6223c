"""A loopback RTDE peer for testing ``UrArm`` without a robot (shared by the UR tests).

ur-rtde's ``RTDEReceiveInterface`` has no port argument (it always dials 30004), so the peer listens
on 30004 of a random 127.x.y.z address: the real ur_rtde receive client talks RTDE to it (protocol
version, controller version, output setup, start, 500 Hz data packages). ``RTDEControlInterface`` is
not exercised: it also needs the script and dashboard ports and a running URScript that acknowledges
every command through registers, so the control side is a recording fake (:class:`FakeControl`)
injected through ``control_factory`` (:func:`make_arm`). The peer runs in a subprocess because
ur_rtde's constructors hold the GIL while they wait for the peer's replies.

Run as ``python rtde_peer.py --rtde-peer HOST`` this file is the peer itself: it prints ``READY``
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


def make_arm(peer: Peer, **kw):
    """A ``UrArm`` on the peer's receive stream with a :class:`FakeControl`; returns (arm, control)."""
    from evservo.robots.ur import UrArm

    fakes: list[FakeControl] = []

    def control(host: str) -> FakeControl:
        fakes.append(FakeControl(host))
        return fakes[-1]

    arm = UrArm(peer.host, control_factory=control, **kw)
    return arm, fakes[0]
