"""The safety layer every real arm driver puts between the controller and the hardware.

:class:`SafetyGate` receives the end-effector twist the application asks for (world frame: linear
velocity of the end-effector origin in m/s, angular velocity in rad/s, both in world coordinates) and
forwards a safe version of it to the driver's ``send`` callable. In order:

1. **Velocity**: the whole twist is scaled by one factor so that neither the linear nor the angular
   speed exceeds its limit (uniform scaling, as ViSP's ``vpRobot::saturateVelocities``): the direction
   of motion is kept, only its speed shrinks.
2. **Acceleration**: the change from the previously sent twist is scaled, again by one factor, so that
   it is reachable within the command's hold time at the linear and angular acceleration limits.
3. **Workspace**: per world axis, the component of the linear velocity that carries the end-effector
   origin towards a face of the box is capped at ``√(2·a_max·d)`` (``d`` the distance to that face):
   the speed from which it can still brake at the acceleration limit before the face. Outside the box
   only motion back inwards is let through. This step is applied last and clips per axis rather than
   uniformly, so the arm can slide along a face; the box is a hard limit and wins over smoothness.

A watchdog thread halts the arm (the driver's ``halt`` callable: zero velocity within the arm's own
deceleration limits) when no command has arrived for ``watchdog_s``; the next command resumes from
rest. A failing ``send`` or a non-finite twist also halts the arm before the error propagates. Used as
a context manager (drivers do this for you) the gate halts the arm on leaving the block, however it
is left: normally, on an exception or on Ctrl-C (``KeyboardInterrupt``). In ``dry_run`` mode nothing is
sent: each command is logged and recorded in :attr:`SafetyGate.history` only.
"""

from __future__ import annotations

import atexit
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from evservo.limits import CartesianLimits

__all__ = ["GateRecord", "SafetyGate", "Workspace"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Workspace:
    """Axis-aligned box for the end-effector origin, in the world (robot base) frame, metres."""

    lo: np.ndarray
    hi: np.ndarray

    def __post_init__(self) -> None:
        lo = np.asarray(self.lo, dtype=float).reshape(-1)
        hi = np.asarray(self.hi, dtype=float).reshape(-1)
        if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError("workspace lo and hi must be finite 3-vectors (metres)")
        if np.any(lo >= hi):
            raise ValueError(f"workspace needs lo < hi on every axis, got lo={lo}, hi={hi}")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    def contains(self, p_w: np.ndarray) -> bool:
        """Whether the point ``p_w`` (world frame, metres) lies inside the box (faces included)."""
        p = np.asarray(p_w, dtype=float)
        return bool(np.all(p >= self.lo) and np.all(p <= self.hi))


@dataclass(frozen=True)
class GateRecord:
    """One event at the gate, at monotonic time ``t_s`` (seconds).

    ``kind``: ``"command"`` (a twist was forwarded, or only logged in dry run), ``"halt"`` (the arm was
    told to stop; ``reason`` says why). ``requested`` and ``sent`` are the twists asked for and let
    through (world frame, m/s and rad/s; zeros for a halt). ``notes`` names the limits that acted:
    any of ``"velocity"``, ``"acceleration"``, ``"workspace"``.
    """

    t_s: float
    kind: str
    requested: np.ndarray
    sent: np.ndarray
    notes: tuple[str, ...] = ()
    reason: str = ""


def _norm(x: np.ndarray) -> float:
    return float(np.linalg.norm(x))


class SafetyGate:
    """Limits, workspace, watchdog and guaranteed stop around a driver's twist command.

    ``send(v_e_w, dt_s)`` forwards a twist to the arm (world frame, (6,), held for ``dt_s`` seconds);
    ``halt()`` brings the arm to rest. Both are called with the gate's lock held, never concurrently.
    ``limits``: Cartesian velocity and acceleration limits of the end effector. ``workspace``: box for
    the end-effector origin (None: no box). ``watchdog_s``: halt when no command came for this long.
    ``tick``: called on every watchdog period from the watchdog thread (e.g. to keep a controller-side
    watchdog alive: if this process hangs, the controller stops the arm itself). ``clock``: monotonic
    time in seconds (injectable for tests). ``history``: how many :class:`GateRecord` to keep.
    """

    def __init__(
        self,
        send: Callable[[np.ndarray, float], None],
        halt: Callable[[], None],
        limits: CartesianLimits | None = None,
        workspace: Workspace | None = None,
        watchdog_s: float = 0.05,
        dry_run: bool = False,
        name: str = "arm",
        tick: Callable[[], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        history: int = 10_000,
    ) -> None:
        if not (np.isfinite(watchdog_s) and watchdog_s > 0):
            raise ValueError(f"watchdog_s must be finite and > 0, got {watchdog_s}")
        self._send, self._halt, self._tick = send, halt, tick
        self.limits = limits or CartesianLimits()
        self.workspace = workspace
        self.watchdog_s = float(watchdog_s)
        self.dry_run = bool(dry_run)
        self.name = name
        self._clock = clock
        self.history: deque[GateRecord] = deque(maxlen=history)
        self._lock = threading.RLock()
        self._v_sent = np.zeros(6)
        self._t_last: float | None = None  # time of the last forwarded command; None while at rest
        self._thread: threading.Thread | None = None
        self._closing = threading.Event()
        self.watchdog_halts = 0

    # -- the pure part ---------------------------------------------------------------------------

    def limit(self, v_e_w: np.ndarray, p_e_w: np.ndarray, dt_s: float) -> tuple[np.ndarray, tuple[str, ...]]:
        """The twist the gate would send for ``v_e_w`` with the end-effector origin at ``p_e_w`` (world,
        metres), held for ``dt_s`` seconds, given the twist sent last; and the limits that acted.
        Raises ``ValueError`` for a non-finite twist or position or a non-positive ``dt_s``."""
        v = np.asarray(v_e_w, dtype=float).reshape(6)
        p = np.asarray(p_e_w, dtype=float).reshape(3)
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(p))):
            raise ValueError("twist and end-effector position must be finite")
        if not (np.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_s must be finite and > 0, got {dt_s}")
        L, notes = self.limits, []
        s = min(1.0, L.max_lin_vel / max(_norm(v[:3]), 1e-300), L.max_ang_vel / max(_norm(v[3:]), 1e-300))
        if s < 1.0:
            v, notes = v * s, ["velocity"]
        # No command is held longer than the watchdog allows, so that bounds the time to reach it.
        h = min(float(dt_s), self.watchdog_s)
        dv = v - self._v_sent
        s = min(1.0, L.max_lin_acc * h / max(_norm(dv[:3]), 1e-300), L.max_ang_acc * h / max(_norm(dv[3:]), 1e-300))
        if s < 1.0:
            v, notes = self._v_sent + s * dv, [*notes, "acceleration"]
        if self.workspace is not None:
            ws = self.workspace
            cap_up = np.sqrt(2.0 * L.max_lin_acc * np.maximum(ws.hi - p, 0.0))
            cap_down = np.sqrt(2.0 * L.max_lin_acc * np.maximum(p - ws.lo, 0.0))
            lin = np.clip(v[:3], -cap_down, cap_up)
            if np.any(lin != v[:3]):
                v, notes = np.concatenate([lin, v[3:]]), [*notes, "workspace"]
        return v, tuple(notes)

    # -- commands --------------------------------------------------------------------------------

    def command(self, v_e_w: np.ndarray, p_e_w: np.ndarray, dt_s: float) -> np.ndarray:
        """Limit ``v_e_w`` (see :meth:`limit`) and forward it; returns the twist sent (world frame).

        On a bad twist or a failing ``send`` the arm is halted before the error is raised."""
        with self._lock:
            try:
                v, notes = self.limit(v_e_w, p_e_w, dt_s)
            except ValueError as err:
                self._halt_locked(f"refused command: {err}")
                raise
            now = self._clock()
            if self.dry_run:
                log.info("%s dry run: would send twist %s for %.4f s (%s)", self.name, np.round(v, 5), dt_s,
                         ", ".join(notes) or "unlimited")  # fmt: skip
            else:
                try:
                    self._send(v, float(dt_s))
                except BaseException as err:
                    self._halt_locked(f"send failed: {err!r}")
                    raise
            self._v_sent, self._t_last = v, now
            self.history.append(GateRecord(now, "command", np.asarray(v_e_w, dtype=float).reshape(6), v, notes))
            return v.copy()

    def stop(self, reason: str = "stop requested") -> None:
        """Halt the arm now (zero velocity within its deceleration limits)."""
        with self._lock:
            self._halt_locked(reason)

    def _halt_locked(self, reason: str) -> None:
        self._v_sent, self._t_last = np.zeros(6), None
        self.history.append(GateRecord(self._clock(), "halt", np.zeros(6), np.zeros(6), (), reason))
        if self.dry_run:
            log.info("%s dry run: would halt (%s)", self.name, reason)
            return
        try:
            self._halt()
        except Exception as err:
            # The stop itself failed (e.g. the link is gone): nothing more can be done from here, and
            # the original error, if any, matters more to the caller than this one.
            log.error("%s: halt failed (%s): %s", self.name, reason, repr(err))

    @property
    def last_sent(self) -> np.ndarray:
        """The twist in force (world frame; zeros after a halt)."""
        with self._lock:
            return self._v_sent.copy()

    # -- watchdog --------------------------------------------------------------------------------

    def check_watchdog(self) -> bool:
        """Halt if the last command is older than ``watchdog_s``; returns whether it halted."""
        with self._lock:
            if self._t_last is None or self._clock() - self._t_last <= self.watchdog_s:
                return False
            self.watchdog_halts += 1
            log.warning("%s: no command for %.3f s, halting", self.name, self.watchdog_s)
            self._halt_locked("watchdog: no fresh command")
            return True

    def _watch(self) -> None:
        period = max(self.watchdog_s / 5.0, 0.001)
        while not self._closing.wait(period):
            try:
                self.check_watchdog()
                if self._tick is not None and not self.dry_run:
                    with self._lock:  # drivers need not make their client thread-safe
                        self._tick()
            except Exception:
                log.exception("%s: watchdog error, halting", self.name)
                self.stop("watchdog error")

    def open(self) -> SafetyGate:
        """Start the watchdog thread (idempotent) and halt the arm at interpreter exit."""
        with self._lock:
            if self._thread is None:
                self._closing.clear()
                self._thread = threading.Thread(target=self._watch, name=f"{self.name}-watchdog", daemon=True)
                self._thread.start()
                atexit.register(self.close)
        return self

    def close(self) -> None:
        """Halt the arm and stop the watchdog thread (idempotent)."""
        self.stop("gate closed")
        thread, self._thread = self._thread, None
        if thread is not None:
            self._closing.set()
            thread.join(timeout=5.0)
            atexit.unregister(self.close)

    def __enter__(self) -> SafetyGate:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()
