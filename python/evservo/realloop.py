"""The real closed loop: event camera → threaded tracker → PBVS at a fixed rate → arm (paper Sec. III-C).

Three threads share the work:

* the **camera thread** iterates the event source (a live camera, or a recording replayed at
  ``speed`` × real time by :class:`~evservo.cameras.ReplaySource`), clamps time that steps backwards
  (as ``evservo track`` does) and pushes each batch to the tracker (``push`` never blocks: if the
  solver falls behind, its queue drops the oldest batches and counts them); an empty batch from a
  source that knows its sensor time (``stream_time_us``) advances the tracker's stream time
  (``Tracker.advance_time``), so events stopping is flagged ``lost`` by the tracker itself;
* the **tracker thread** (Rust, no GIL) steps EDFT⁺ on whatever has arrived and publishes poses;
* the **control loop** (the calling thread) runs every ``1/rate_hz`` seconds against absolute
  deadlines of ``time.monotonic``: it reads the newest pose, runs :class:`~evservo.control.Pbvs`
  (Eq. 5–6, EMA, optional feed-forward, limits) and sends the camera twist, moved to the end effector
  through the hand–eye ``T_e_c``, to the arm, whose :class:`~evservo.robots.safety.SafetyGate`
  applies the rig's limits, workspace and its own watchdog. A deadline that passed before the loop
  got to it (by more than half a period) is a *missed cycle*: counted, never made up for. While the
  loop runs, the interpreter's GIL switch interval is cut to 0.5 ms (so the camera thread cannot hold
  the loop up for the default 5 ms) and, while servoing, the cyclic garbage collector is off; both
  are restored on the way out.

Clocks: tracker poses are stamped with the time of the newest event behind them (sensor clock, µs).
The camera thread maps sensor time to host time with the lowest offset seen, ``min(t_recv −
t_event / speed)`` over batches (the least delayed batch bounds the offset from above), so a pose's
age is ``now − (offset + t_pose / speed)``; a pose is passed on once (by its time stamp), never dated
after ``now`` and never before the previous one.

Sequence: the tracker starts from ``T_c_o_init``; once the first events have reached it (within
``start_timeout_s``) it tracks for ``settle_s`` while the arm stays still, and must then have
published a pose the tracker itself does not flag as lost. Then servoing starts:
the desired pose ``T_c_o_des`` is the tracked pose at that instant unless given. With ``search`` (a
tracker started without a pose) the loop instead starts at rest and waits for the tracker to lock;
the desired pose is captured then, as in the paper.

While the tracker flags the object lost, the loop holds (:class:`~evservo.control.hold.LossHold`, as
the simulated bench does): no pose reaches the controller; the camera coasts on the object's
predicted motion until the newest trusted pose is ``coast_s`` old (a short false loss costs nothing),
then brakes to rest at the acceleration limit and stays there, the desired pose kept; once the
tracker has locked again the controller restarts from the new pose and its command is ramped in. Servoing ends, with the
commanded twist braked to zero at the acceleration limit and then an explicit arm stop, on:

* ``duration_s`` reached, or the replayed recording ended — a normal end (``completed``);
* **watchdog**: no fresh pose for ``stale_after_s`` while the tracker does not flag the object lost
  (tracker stalled, no events), or a pose **jump** refused by the controller (farther than
  ``max_jump_m``/``max_jump_rad`` from the prediction). Unlike the simulated bench, the real loop
  does not resume after a watchdog spell: it brakes and stops, and reports the spell;

and with an immediate arm stop on an exception (lost link to the arm, camera failure) or Ctrl-C.
Whatever happens the arm is told to stop before :func:`run_real_loop` returns or raises, and the
tracker and camera threads are ended; a Ctrl-C while that stop runs lets it finish (and marks the
run ``interrupted``), as the commands do while they write the outputs (exit code 130).

Outputs (:func:`summarize`, :func:`write_outputs`) use the simulated episode's key names where the
concept is the same (``completed``, ``ended``, ``servo_pos_rms_mm``, ``servo_rot_rms_deg``,
``tracker_rate_hz``, ``tracker_steps``, ``pose_age_mean_ms``, ``events``, ``watchdog``,
``camera_rot_mean_deg``, ``wall_s``, ``config``, ``versions``) and add the loop's own (``servo_s``,
``control_cycles``, ``missed_cycles``, …). Times are seconds since servo start.
"""

from __future__ import annotations

import gc
import logging
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from evservo import _evcore, events, geometry
from evservo.control import Pbvs
from evservo.control.hold import LossHold
from evservo.geometry import pose_errors, rotation_from_first_rad
from evservo.interrupt import StopOnInterrupt, ctrl_c_held_back
from evservo.limits import CartesianLimits
from evservo.outputs import make_out_dir
from evservo.robots.base import Arm, shift_twist
from evservo.robots.gated import GatedArm
from evservo.robots.safety import SafetyGate
from evservo.runtime.loss import loss_metrics, wrong_pose
from evservo.runtime.metrics import rms
from evservo.runtime.record import CycleRecord
from evservo.runtime.report import plot_motion, write_log, write_summary
from evservo.runtime.watchdog import WatchdogSpell

__all__ = [
    "RealLoopConfig", "RealLoopResult", "TrackingError", "WatchdogSpell", "run_real_loop", "summarize", "write_outputs",
]  # fmt: skip

log = logging.getLogger(__name__)

#: Most control cycles one run records (preallocated, ~0.4 kB each: 1 h at 500 Hz is ~0.7 GB).
MAX_CYCLES = 1_800_000

#: The files :func:`write_outputs` writes into the run's directory.
OUTPUTS = ("summary.json", "log.csv", "motion.png")


class TrackingError(RuntimeError):
    """The tracker could not lock on before servoing (no pose, or the object flagged lost)."""


@dataclass(frozen=True)
class RealLoopConfig:
    """How to run the real loop. Times in seconds, rates in Hz.

    ``rate_hz``: control rate (the period is also the hold time of each command).
    ``settle_s``: tracking before servoing, arm still, counted from the first pose.
    ``start_timeout_s``: longest wait for the source's first events. ``duration_s``: servoing time.
    ``stiffness``: k of Eq. 6 (1/s²). ``feedforward``: feed the target's estimated motion forward.
    ``stale_after_s``, ``max_jump_m``, ``max_jump_rad``: the controller's watchdog and jump gate.
    ``max_brake_s``: longest braking before the arm is stopped outright.
    ``speed``: sensor seconds per host second (the replay speed; 1 for a live camera).
    ``log_rate_hz``: rows per second in ``log.csv``. ``dry_run``: only recorded in the summary (the
    arm itself must be opened in dry run). ``search``: the tracker was started without a pose: servo
    from a search (the module docstring) instead of requiring a lock after ``settle_s``.
    """

    rate_hz: float = 500.0
    settle_s: float = 0.5
    start_timeout_s: float = 5.0
    duration_s: float = 20.0
    stiffness: float = 20.0
    feedforward: bool = False
    stale_after_s: float = 0.1
    max_jump_m: float = 0.05
    max_jump_rad: float = 0.3
    max_brake_s: float = 1.0
    speed: float = 1.0
    log_rate_hz: float = 100.0
    dry_run: bool = False
    search: bool = False

    def __post_init__(self) -> None:
        positive = dict(
            rate_hz=self.rate_hz, duration_s=self.duration_s, stiffness=self.stiffness,
            stale_after_s=self.stale_after_s, max_jump_m=self.max_jump_m, max_jump_rad=self.max_jump_rad,
            max_brake_s=self.max_brake_s, speed=self.speed, log_rate_hz=self.log_rate_hz,
            start_timeout_s=self.start_timeout_s,
        )  # fmt: skip
        for name, v in positive.items():
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v}")
        if not (np.isfinite(self.settle_s) and self.settle_s >= 0):
            raise ValueError(f"settle_s must be finite and >= 0, got {self.settle_s}")
        if self.rate_hz > 2000:
            raise ValueError(f"rate_hz above 2000 Hz is beyond any arm's command rate, got {self.rate_hz}")
        if self.max_cycles() > MAX_CYCLES:
            raise ValueError(
                f"duration {self.duration_s:g} s at {self.rate_hz:g} Hz is {self.max_cycles()} control cycles; the "
                f"per-cycle record holds at most {MAX_CYCLES} (1 h at 500 Hz): run shorter sessions"
            )

    def max_cycles(self) -> int:
        """Control cycles the run may record: servoing plus the longest braking."""
        return int(np.ceil((self.duration_s + self.max_brake_s) * self.rate_hz)) + 2


@dataclass
class RealLoopResult:
    """What happened. Per control cycle (index k, time ``t_s[k]`` since servo start): ``T_w_c`` the
    camera pose, ``T_c_o_est`` the newest tracker pose and ``est_t_s`` its host time, ``v_cmd_w`` the
    controller's camera twist (world frame), ``v_sent_w`` the end-effector twist the gate let through,
    ``state`` the controller's state (``"holding"``, ``"searching"`` while the loop holds for a lost
    object), ``lost`` the tracker's flag, ``holding`` the loop was not servoing on the tracker (holding,
    searching or ramping back in), ``cycle_s`` the cycle's compute time, ``late_s`` how late it began,
    ``est_t_us`` the pose's time stamp on the sensor clock.
    """

    config: RealLoopConfig
    T_c_o_des: np.ndarray
    t_s: np.ndarray
    T_w_c: np.ndarray
    T_c_o_est: np.ndarray
    est_t_s: np.ndarray
    v_cmd_w: np.ndarray
    v_sent_w: np.ndarray
    state: list[str]
    lost: np.ndarray
    holding: np.ndarray
    cycle_s: np.ndarray
    late_s: np.ndarray
    est_t_us: np.ndarray
    ended: str
    completed: bool
    interrupted: bool
    error: str | None
    servo_s: float
    missed_cycles: int
    watchdog: list[WatchdogSpell]
    tracker_steps: dict[str, int]
    tracker_s: float
    events: int
    events_dropped: int
    events_time_clamped: int
    gate: dict[str, Any]
    wall_s: float
    meta: dict[str, Any] = field(default_factory=dict)


def _wait(clock: Callable[[], float], until: float, pump: _CameraPump, done: Callable[[], bool]) -> None:
    """Sleep until ``clock() >= until`` or ``done()``; raise the camera's error, or if it ended."""
    while clock() < until and not done():
        if pump.error is not None:
            raise pump.error
        if pump.done.is_set():
            raise TrackingError("the event source ended during the settle time")
        time.sleep(0.002)


class _CameraPump(threading.Thread):
    """Source → tracker, with the sensor-to-host clock offset (see the module docstring)."""

    def __init__(self, source: Any, tracker: Any, speed: float, clock: Callable[[], float]) -> None:
        super().__init__(name="evservo-camera", daemon=True)
        self.source, self.tracker, self.speed, self.clock = source, tracker, float(speed), clock
        self.offset_s: float | None = None
        self.events = self.batches = self.clamped = 0
        self.error: BaseException | None = None
        self.ended = False  # the source ran out (end of a recording)
        self.done = threading.Event()
        self._halt = threading.Event()
        self._t_max: int | None = None

    def run(self) -> None:
        try:
            for ev in self.source:
                if self._halt.is_set():
                    return
                if not len(ev):
                    self._advance()
                    continue
                ev, n, self._t_max = events.clamp_time(ev, self._t_max)
                off = self.clock() - int(ev["t"][-1]) * 1e-6 / self.speed
                self.offset_s = off if self.offset_s is None else min(self.offset_s, off)
                self.tracker.push(ev)
                self.events += len(ev)
                self.batches += 1
                self.clamped += n
            self.ended = True
        except BaseException as err:  # reported by the control loop, which stops the arm
            self.error = err
        finally:
            self.done.set()

    def _advance(self) -> None:
        """An empty batch: hand the tracker the sensor time the source vouches for (its
        ``stream_time_us``: a file's slice end, a camera driver's slice end), so that events stopping
        while the sensor's clock runs reads ``lost`` 20 ms in rather than only as a stale pose. A
        source that cannot tell (None) tells nothing: no time is made up from the host clock."""
        t_us = getattr(self.source, "stream_time_us", None)
        advance = getattr(self.tracker, "advance_time", None)
        if t_us is None or advance is None or self._t_max is None or t_us < self._t_max:
            return
        advance(int(t_us))

    def host_time(self, t_us: int) -> float | None:
        """Host time (``clock`` seconds) of sensor time ``t_us``; None before the first batch."""
        off = self.offset_s
        return None if off is None else off + t_us * 1e-6 / self.speed

    def halt(self, timeout_s: float = 2.0) -> None:
        self._halt.set()
        if self.is_alive():
            self.join(timeout_s)


def _gate_of(arm: Arm) -> SafetyGate | None:
    """The arm's safety gate, whose limits bound the controller and whose output is logged; an arm
    without one (a bare :class:`Arm`) is commanded as it is."""
    return arm.gate if isinstance(arm, GatedArm) else None


def run_real_loop(
    arm: Arm,
    source: Any,
    tracker: Any,
    config: RealLoopConfig,
    T_c_o_des: np.ndarray | None = None,
    progress: Callable[[str], None] | None = None,
    meta: dict[str, Any] | None = None,
    clock: Callable[[], float] = time.monotonic,
    on_cycle: Callable[[float, np.ndarray, np.ndarray], None] | None = None,
) -> RealLoopResult:
    """Run the loop (see the module docstring) and return what happened.

    ``arm``: an opened :class:`~evservo.robots.base.Arm` (its ``T_e_c`` is the hand–eye). ``source``:
    an iterable of event batches. ``tracker``: a :class:`~evservo.tracking.Tracker` not yet started,
    initialised at the object's start pose (or anything with ``start/push/latest/stop/stats``).
    ``T_c_o_des``: desired object pose in the camera (default: the tracked pose at servo start).
    ``progress``: called with status lines. ``meta``: copied into the summary (robot, camera, …).
    ``on_cycle``: called on every servo cycle with its time (s since servo start), the camera pose
    ``T_w_c`` and the desired ``T_c_o``; it must return at once (a live viewer stores them).
    The caller keeps ownership of ``arm`` and ``source`` (close them afterwards); the arm is stopped
    and the tracker stopped before this returns. Raises :class:`TrackingError` if the tracker has no
    usable pose after the settle time, and the camera's error if the source fails while settling.
    """
    cfg = config
    say = progress or (lambda _msg: None)
    wall0 = time.perf_counter()
    period = 1.0 / cfg.rate_hz
    T_e_c = geometry.as_pose(arm.T_e_c, "T_e_c")
    gate = _gate_of(arm)
    pbvs = Pbvs(
        k=cfg.stiffness, feedforward=cfg.feedforward, period_s=period,
        limits=gate.limits if gate is not None else CartesianLimits(), stale_after_s=cfg.stale_after_s,
        max_jump_m=cfg.max_jump_m, max_jump_rad=cfg.max_jump_rad,
    )  # fmt: skip
    hold = LossHold(pbvs)
    rec = CycleRecord(
        cfg.max_cycles(),
        t_s=(), T_w_c=(4, 4), T_c_o_est=(4, 4), est_t_s=(), v_cmd_w=(6,), v_sent_w=(6,), cycle_s=(), late_s=(),
        est_t_us=((), np.int64), lost=((), bool), holding=((), bool),
    )  # fmt: skip
    states: list[str] = []
    spells: list[WatchdogSpell] = []
    ended, completed, interrupted, error = "not started", False, False, None
    des: np.ndarray | None = None
    cadence: _Cadence | None = None
    switch, gc_was_enabled = sys.getswitchinterval(), gc.isenabled()
    pump = _CameraPump(source, tracker, cfg.speed, clock)
    tracker_t0 = clock()
    tracker_t1 = None
    tracker.start()
    try:
        # Short GIL slices: the camera thread must not hold the control loop up for 5 ms at a time.
        sys.setswitchinterval(min(switch, 0.0005))
        pump.start()
        # No cyclic garbage collection while servoing: a full collection can take longer than a period,
        # and the loop makes no reference cycles. Collected after the arm has stopped. The collection
        # before it (up to 0.5 s on a loaded machine) runs while the tracker settles, so it delays
        # neither the servo clock nor the age of the pose servoing starts from.
        gc.collect()
        gc.disable()
        est = _settle(tracker, pump, cfg, clock, say)
        t0 = clock()
        feed = _PoseFeed(tracker, pump, t0, est)
        given = None if T_c_o_des is None else geometry.as_pose(T_c_o_des, "T_c_o_des")
        if est.lost:  # only with cfg.search: hold still until the tracker locks
            hold.search(given)
            say("searching: the arm holds still until the tracker locks on the object")
        else:
            hold.start(arm.T_w_e() @ T_e_c, est.T_c_o, t_s=feed.t_s)
            des = est.T_c_o.copy() if given is None else given
            hold.set_desired(des)
        if T_c_o_des is not None and not est.lost:
            d_mm = geometry.translation_error_m(des, est.T_c_o) * 1e3
            d_deg = np.rad2deg(geometry.rotation_error_rad(des, est.T_c_o))
            say(f"desired pose is {d_mm:.1f} mm / {d_deg:.1f} deg from the tracked one: the arm will move to it")
        say(f"servoing for {cfg.duration_s:.2f} s at {cfg.rate_hz:.0f} Hz" + (" (DRY RUN)" if cfg.dry_run else ""))
        cadence = _Cadence(clock, t0, period)
        stopping: str | None = None  # why the loop is braking to its end
        stop_t, v_cmd, last_accepted_t = 0.0, np.zeros(6), feed.t_s
        while not rec.full:
            now, deadline = cadence.wait()
            t = now - t0
            # -- what ends the run --------------------------------------------------------
            if pump.error is not None:
                raise RuntimeError(f"event source failed: {pump.error}") from pump.error
            if stopping is None and (t >= cfg.duration_s or pump.ended):
                stopping, stop_t = ("duration" if t >= cfg.duration_s else "end of recording"), t
                hold.stop()
            # -- pose and control ---------------------------------------------------------
            pose, p_t = feed.poll(t)
            T_w_e = arm.T_w_e()
            T_w_c = T_w_e @ T_e_c
            p_e, p_c = T_w_e[:3, 3], T_w_c[:3, 3]
            # The twist in force (what the gate let through), as the controller's velocity state.
            v_c_now = shift_twist(gate.last_sent, p_e, p_c) if gate is not None else v_cmd
            cmd = hold.update(t, T_w_c, v_c_now, pose, p_t, feed.lost)
            ctrl = cmd.pbvs  # None while holding for a lost object: the controller is not run
            if ctrl is not None and ctrl.state == "ok" and pose is not None:
                last_accepted_t = p_t
            if stopping is None and ctrl is not None and (ctrl.watchdog or ctrl.state == "rejected"):
                why = _watchdog_reason(ctrl, cfg.stale_after_s)
                stopping, stop_t = f"watchdog: {why}", t
                spells.append(WatchdogSpell(t, last_accepted_t, None, None, why))
                log.info("watchdog at %.3f s: %s; braking to a stop", t, why)
                say(f"WATCHDOG at {t:.3f} s: {why}; braking to a stop")
                hold.stop()
            v_cmd = cmd.v_c_w
            # Every twist that reaches the arm has its row: a Ctrl-C waits for the row to be written.
            with ctrl_c_held_back():
                # What the gate let through, as it returned it: its watchdog may halt the arm meanwhile.
                sent = arm.command_twist(shift_twist(v_cmd, p_c, p_e), period)
                done_t = clock()
                rec.add(
                    t_s=t, T_w_c=T_w_c, T_c_o_est=feed.T_c_o, est_t_s=feed.t_s, v_cmd_w=v_cmd, est_t_us=feed.t_us,
                    v_sent_w=sent if sent is not None else shift_twist(v_cmd, p_c, p_e),
                    late_s=now - deadline, cycle_s=done_t - now, lost=feed.lost, holding=cmd.mode != "servoing",
                )  # fmt: skip
                states.append(ctrl.state if ctrl is not None else cmd.mode)
            if on_cycle is not None and hold.T_c_o_des is not None:  # no desired pose yet while searching
                on_cycle(t, T_w_c, hold.T_c_o_des)
            if stopping is not None:
                at_rest = not np.any(v_cmd)
                if at_rest and spells and spells[-1].zero_s is None and stopping.startswith("watchdog"):
                    spells[-1] = replace(spells[-1], zero_s=t)
                if at_rest or t - stop_t >= cfg.max_brake_s:
                    break
            cadence.advance(done_t)
        ended = stopping or "duration"
        completed = stopping in ("duration", "end of recording")
    except KeyboardInterrupt:
        ended, interrupted = "interrupted (Ctrl-C)", True
        say("interrupted: stopping the arm")
    except TrackingError:
        ended = "tracking not locked"
        raise
    except Exception as err:
        ended, error = f"error: {err}", str(err)
        # The message, not the exception: a log record keeping an exception keeps its traceback's
        # frames alive, and with them a driver's connection that a reconnect would wait for.
        log.error("real loop: %s; stopping the arm", error)
        if rec.n == 0 and des is None:
            raise  # nothing ran: the caller reports the error
    finally:
        # A Ctrl-C while the loop stops asks for what is already happening: it must not cut the arm's
        # stop short (a second one still raises, for a stop that hangs).
        with StopOnInterrupt() as late:
            sys.setswitchinterval(switch)
            if gc_was_enabled:
                gc.enable()
            try:
                arm.stop()
            except Exception as err:  # the link is gone: the arm's own watchdogs stop it
                log.error("stopping the arm failed: %s", repr(err))
            pump.halt()
            try:
                tracker.stop()
            finally:
                tracker_t1 = clock()
        interrupted = interrupted or late.requested
    recorded = rec.arrays()
    stats = tracker.stats()
    des = des if des is not None else hold.T_c_o_des
    return RealLoopResult(
        config=cfg,
        T_c_o_des=des if des is not None else np.eye(4),
        **recorded,
        state=states,
        ended=ended,
        completed=completed,
        interrupted=interrupted,
        error=error,
        servo_s=float(recorded["t_s"][-1]) if rec.n else 0.0,
        missed_cycles=cadence.missed if cadence is not None else 0,
        watchdog=spells,
        tracker_steps={
            "lm": int(stats.get("lm_steps", 0)),
            "search": int(stats.get("search_steps", 0)),
            "global": int(stats.get("reacquire_passes", 0)),
        },
        tracker_s=max(tracker_t1 - tracker_t0, 1e-9),
        events=pump.events,
        events_dropped=int(stats.get("events_dropped", 0)),
        events_time_clamped=pump.clamped,
        gate=_gate_summary(gate),
        wall_s=time.perf_counter() - wall0,
        meta=dict(meta or {}),
    )


def _settle(tracker: Any, pump: _CameraPump, cfg: RealLoopConfig, clock: Callable[[], float], say: Callable) -> Any:
    """Wait for the first pose (up to ``start_timeout_s``), then track ``settle_s`` with the arm still;
    return the tracker's estimate then (which may be lost only with ``cfg.search``). A camera (or a
    file being opened) takes a while to deliver its first events, so the settle time counts from the
    first pose: a slow start is not a blind tracker."""
    say(f"waiting up to {cfg.start_timeout_s:.1f} s for the first events")
    _wait(clock, clock() + cfg.start_timeout_s, pump, lambda: pump.offset_s is not None and tracker.latest().seq > 0)
    if pump.offset_s is None or tracker.latest().seq == 0:
        raise TrackingError(f"no pose {cfg.start_timeout_s} s after start: no events reached the tracker")
    say(f"settling: tracking for {cfg.settle_s:.2f} s before moving")
    _wait(clock, clock() + cfg.settle_s, pump, lambda: False)
    if pump.error is not None:
        raise pump.error
    est = tracker.latest()
    if est.lost and not cfg.search:
        raise TrackingError(
            f"the tracker lost the object while settling (inlier fraction {est.inlier_fraction:.2f}): "
            "check the initial pose (--init-pose) and the model"
        )
    return est


def _watchdog_reason(cmd: Any, stale_after_s: float) -> str:
    if cmd.state == "rejected" and not cmd.watchdog:
        return f"pose jump: {cmd.reason}"
    return f"no fresh pose for {stale_after_s} s"


class _Cadence:
    """Fixed-rate deadlines ``t0 + k·period`` on ``clock``. A cycle less than half a period late runs
    at once; deadlines already further past are skipped and counted in :attr:`missed`, never made up."""

    def __init__(self, clock: Callable[[], float], t0: float, period_s: float) -> None:
        self.clock, self.t0, self.period_s = clock, t0, period_s
        self.k = 0
        self.missed = 0

    def wait(self) -> tuple[float, float]:
        """Sleep until the current deadline; return ``(now, deadline)``."""
        deadline = self.t0 + self.k * self.period_s
        now = self.clock()
        if now < deadline:
            time.sleep(deadline - now)
            now = self.clock()
        return now, deadline

    def advance(self, done_t: float) -> None:
        """Move to the next deadline after a cycle that finished at ``done_t``."""
        self.k += 1
        behind = done_t - (self.t0 + self.k * self.period_s)
        if behind > 0.5 * self.period_s:
            skip = int(np.ceil(behind / self.period_s - 0.5))
            self.missed += skip
            self.k += skip


class _PoseFeed:
    """The tracker's poses as the controller takes them: each new one once and not when the tracker
    flags it lost, in time order, dated on the host clock in seconds since servo start (never after
    the cycle's time, never before the previous pose). :attr:`T_c_o`, :attr:`t_s`, :attr:`t_us` hold
    the newest pose passed on; :attr:`lost` is the tracker's flag at the last poll."""

    def __init__(self, tracker: Any, pump: _CameraPump, t0: float, est: Any) -> None:
        self.tracker, self.pump, self.t0 = tracker, pump, t0
        self.seq = est.seq
        self.t_us = int(est.t_us)
        host = pump.host_time(self.t_us)
        self.t_s = min(host - t0, 0.0) if host is not None else 0.0
        self.T_c_o = est.T_c_o.copy()
        self.lost = bool(est.lost)

    def poll(self, t: float) -> tuple[np.ndarray | None, float | None]:
        """The pose to hand the controller at cycle time ``t`` (s) and its time, or ``(None, None)``."""
        est = self.tracker.latest()
        self.lost = bool(est.lost)
        if est.seq == self.seq:
            return None, None
        self.seq = est.seq
        if est.lost or est.t_us <= self.t_us:
            return None, None
        self.t_us = int(est.t_us)
        host = self.pump.host_time(self.t_us)
        self.t_s = min(max(host - self.t0, self.t_s + 1e-6), t)
        self.T_c_o = est.T_c_o.copy()
        return self.T_c_o, self.t_s


def _gate_summary(gate: SafetyGate | None) -> dict[str, Any]:
    """Counts from the gate's history (its last ``history.maxlen`` records)."""
    if gate is None:
        return {}
    hist = list(gate.history)
    commands = [r for r in hist if r.kind == "command"]
    return {
        "commands": len(commands),
        "halts": sum(r.kind == "halt" for r in hist),
        "watchdog_halts": int(getattr(gate, "watchdog_halts", 0)),
        "limited": {k: sum(k in r.notes for r in commands) for k in ("velocity", "acceleration", "workspace")},
        "dry_run": bool(gate.dry_run),
        "history_truncated": len(hist) == gate.history.maxlen,
    }


def summarize(r: RealLoopResult, gt: tuple[np.ndarray, np.ndarray] | None = None) -> dict:
    """Metrics of a run (JSON-ready); keys as in :func:`evservo.sim.episode.summarize` where the
    concept is the same. ``gt``: ground truth of a replayed simulated recording, ``(t_us (N,),
    T_c_o (N, 4, 4))``, to score the tracker (``gt_track_pos_rms_mm``, ``gt_track_rot_rms_deg``; None
    without)."""
    n = len(r.t_s)
    gt_pos = gt_rot = loss = None
    if gt is not None and n:
        from evservo.sim.record import gt_at

        T_gt = gt_at(gt[0], gt[1], r.est_t_us)
        k_pos, k_rot = pose_errors(r.T_c_o_est, T_gt)
        gt_pos, gt_rot = rms(k_pos) * 1e3, float(np.rad2deg(rms(k_rot)))
        # Whether the object could be seen is not known here: every cycle counts as seen.
        wrong = wrong_pose(k_pos, k_rot, T_gt[:, 2, 3])
        loss = loss_metrics(r.t_s, r.lost, wrong, np.ones(n, bool), started_lost=r.config.search)
    s_pos, s_rot = pose_errors(r.T_c_o_est, np.broadcast_to(r.T_c_o_des, (n, 4, 4)))
    cam_rot = rotation_from_first_rad(r.T_w_c)
    d_cam = r.T_w_c[:, :3, 3] - r.T_w_c[:1, :3, 3] if n else np.zeros((0, 3))
    # Pose steps: a global pass (while lost) is no update of a tracked pose.
    n_steps = r.tracker_steps["lm"] + r.tracker_steps["search"]
    nominal = r.config.rate_hz * r.servo_s
    return {
        "completed": r.completed,
        "ended": r.ended,
        "error": r.error,
        "interrupted": r.interrupted,
        "dry_run": r.config.dry_run,
        "servo_s": r.servo_s,
        "servo_pos_rms_mm": rms(s_pos) * 1e3,
        "servo_rot_rms_deg": float(np.rad2deg(rms(s_rot))),
        "servo_pos_max_mm": float(np.max(s_pos) * 1e3) if n else float("nan"),
        "gt_track_pos_rms_mm": gt_pos,
        "gt_track_rot_rms_deg": gt_rot,
        "loss": loss,
        "lost_fraction": float(np.mean(r.lost)) if n else 0.0,
        # Each cycle holds until the next one (missed cycles included).
        "holding_s": float(np.sum(np.diff(r.t_s, append=r.t_s[-1:])[r.holding])) if n else 0.0,
        "camera_rot_mean_deg": float(np.rad2deg(np.mean(cam_rot))) if n else float("nan"),
        "camera_travel_max_m": float(np.max(np.linalg.norm(d_cam, axis=1))) if n else 0.0,
        "tracker_rate_hz": n_steps / r.tracker_s,
        "tracker_steps": r.tracker_steps,
        "pose_age_mean_ms": float(np.mean(r.t_s - r.est_t_s) * 1e3) if n else float("nan"),
        "pose_age_max_ms": float(np.max(r.t_s - r.est_t_s) * 1e3) if n else float("nan"),
        "events": r.events,
        "events_dropped": r.events_dropped,
        "events_time_clamped": r.events_time_clamped,
        "watchdog": [asdict(w) for w in r.watchdog],
        "control_rate_hz": r.config.rate_hz,
        "control_cycles": n,
        "missed_cycles": r.missed_cycles,
        "missed_fraction": r.missed_cycles / nominal if nominal > 0 else 0.0,
        "late_mean_ms": float(np.mean(r.late_s) * 1e3) if n else float("nan"),
        "cycle_time_mean_ms": float(np.mean(r.cycle_s) * 1e3) if n else float("nan"),
        "cycle_time_max_ms": float(np.max(r.cycle_s) * 1e3) if n else float("nan"),
        "gate": r.gate,
        "T_c_o_des": r.T_c_o_des.tolist(),
        "wall_s": r.wall_s,
        **r.meta,
        "config": asdict(r.config),
        "versions": {"evservo": _evcore.__version__},
    }


def write_outputs(r: RealLoopResult, out_dir: str | Path, summary: dict | None = None) -> dict[str, Path]:
    """Write ``summary.json``, ``log.csv`` (``config.log_rate_hz`` rows per second, plus every
    cycle whose controller state was not ``ok``) and ``motion.png`` (:func:`plot_motion`) into
    ``out_dir``; returns their paths by name.

    ``log.csv``: camera position (world, m), estimate ``T_c_o`` translation (m), servo error (mm, deg),
    pose age (ms), norms of the controller's camera twist and of the end-effector twist the gate let
    through (m/s, deg/s), that twist's components in the robot base frame (in a dry run: what would
    have been sent — check its directions before the first real run), cycle time and lateness (ms),
    the controller's state."""
    out = make_out_dir(out_dir, stale=OUTPUTS)
    paths = {"summary": out / "summary.json", "log": out / "log.csv", "motion": out / "motion.png"}
    summary = summary if summary is not None else summarize(r)
    n = len(r.t_s)
    every = max(1, round(r.config.rate_hz / r.config.log_rate_hz))
    keep = np.zeros(n, bool)
    keep[::every] = True
    keep |= np.array([s != "ok" for s in r.state], bool)
    if n:
        keep[-1] = True
    k = np.flatnonzero(keep)
    s_pos, s_rot = pose_errors(r.T_c_o_est[k], np.broadcast_to(r.T_c_o_des, (len(k), 4, 4)))
    header = [
        "t_s", "cam_x_m", "cam_y_m", "cam_z_m", "est_x_m", "est_y_m", "est_z_m", "servo_pos_mm",
        "servo_rot_deg", "pose_age_ms", "v_cmd_mps", "w_cmd_dps", "v_sent_mps", "w_sent_dps",
        "sent_vx_mps", "sent_vy_mps", "sent_vz_mps", "sent_wx_dps", "sent_wy_dps", "sent_wz_dps", "cycle_ms",
        "late_ms", "state",
    ]  # fmt: skip
    cols = np.column_stack([
        r.t_s[k], r.T_w_c[k, :3, 3], r.T_c_o_est[k, :3, 3], s_pos * 1e3, np.rad2deg(s_rot),
        (r.t_s[k] - r.est_t_s[k]) * 1e3, np.linalg.norm(r.v_cmd_w[k, :3], axis=1),
        np.rad2deg(np.linalg.norm(r.v_cmd_w[k, 3:], axis=1)), np.linalg.norm(r.v_sent_w[k, :3], axis=1),
        np.rad2deg(np.linalg.norm(r.v_sent_w[k, 3:], axis=1)), r.v_sent_w[k, :3], np.rad2deg(r.v_sent_w[k, 3:]),
        r.cycle_s[k] * 1e3, r.late_s[k] * 1e3,
    ]) if len(k) else np.zeros((0, len(header) - 1))  # fmt: skip
    write_log(paths["log"], header, cols, [r.state[i] for i in k])
    title = f"{r.meta.get('robot', 'arm')}, {r.meta.get('camera', 'camera')}: {r.ended}"
    plot_motion(paths["motion"], r.t_s, r.T_w_c, r.T_w_c @ r.T_c_o_est, title, spells=r.watchdog)
    write_summary(paths["summary"], summary)  # last: a summary.json is there only when the other outputs are
    return paths
