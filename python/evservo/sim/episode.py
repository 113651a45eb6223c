"""One closed-loop servoing episode on the simulated dual-arm bench (paper Sec. III-C and IV).

Everything runs on the scene's simulated 1 kHz clock, in this order per millisecond tick ``t``:

1. the UR5e is commanded (every ``ur_period_s``, 2 ms: RTDE's rate) to carry the target along the
   trajectory: a displacement of the object in the world frame from its start pose, entered with a
   smooth velocity ramp; each command reaches the arm ``ur_latency_s`` later;
2. the controller (:class:`~evservo.control.Pbvs`, every ``control_period_s``) reads the newest pose
   the tracker has *published by t* and returns a camera twist, which is sent to the Panda every
   ``panda_period_s`` (1 ms, like Franka's FCI), reaches it ``panda_latency_s`` later and is resolved
   there through the joint-limited QP. The controller's
   velocity state is its own previous command, as mc_rtc integrates its QP's output, not the
   measured twist: the regularised IK realises ~1 % less than asked, and re-basing on that every
   2 ms would silently eat ~1 m/s² of the commanded acceleration;
3. the arms move one tick;
4. the event source turns the true relative pose ``T_c_o`` at the new time into the events of the
   last millisecond, which reach the tracker ``sensing_latency_s`` later (3.5 ms measured in the
   paper), unless an injected dropout swallows them; the ``render-fast`` source renders only when
   something may have moved half a pixel and hands out the ticks in between with that render (ESIM's
   adaptive sampling, :class:`~evservo.sim.sources.RenderedSource`), so its events can be up to 5 ms later;
5. the synchronous tracker runs on the same clock: whenever it is free it takes every batch that
   has arrived and runs one step (one LM or one search step of the cascade); the step's compute
   time, measured or from a fixed cost model, is *charged to the clock*, so its pose is published
   only that much later and a slower solver sees staler events. After a full cycle without new
   events it idles until the next batch arrives, like the threaded tracker.

The episode ends at ``duration_s`` or when tracking is lost against ground truth (``lost_pos_m``,
``lost_rot_deg``); it reports what happened instead of raising (watchdog stops, loss, an arm that
cannot follow). :func:`summarize` computes the paper's metrics and ground-truth ones; :func:`write_outputs`
writes ``summary.json``, ``log.csv`` and ``motion.png`` (the paper's Fig. 5).

Frames: w world, c camera optical frame, o object; ``T_a_b`` is b in a (4×4, metres).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from evservo import _evcore, geometry, trajectories
from evservo.control import Pbvs
from evservo.control.hold import LossHold
from evservo.geometry import pose_errors, rotation_from_first_rad
from evservo.interrupt import INTERRUPTED, StopOnInterrupt
from evservo.limits import CartesianLimits
from evservo.outputs import make_out_dir
from evservo.robots import PoseFollower, shift_twist
from evservo.robots.delay import DelayedArm
from evservo.robots.limits import PANDA_CARTESIAN
from evservo.robots.reach import ReachableTwist
from evservo.runtime.loss import loss_metrics, wrong_pose
from evservo.runtime.metrics import estimate_lag_s, rms
from evservo.runtime.report import plot_motion, write_log, write_summary
from evservo.runtime.watchdog import WatchdogSpell, spells_from_flags
from evservo.sim.arms import ArmMeshes
from evservo.sim.disturb import Disturbances, within
from evservo.sim.episode_config import TICK_US, EpisodeConfig
from evservo.sim.scene import DualArmScene
from evservo.sim.sources import EventSource, make_event_source
from evservo.tracking import Tracker, model_point_set

#: The files :func:`write_outputs` writes into an episode's directory.
OUTPUTS = ("summary.json", "log.csv", "motion.png")


@dataclass
class EpisodeResult:
    """Per-tick record of an episode (index k is simulated time ``t_s[k]``, 1 kHz) and its outcome.

    ``T_w_o``, ``T_w_c``: true object and camera poses. ``T_c_o_est``: the newest tracker pose
    published by ``t_s`` and ``est_t_s`` its time stamp (newest event behind it). ``v_cmd_w``: the
    controller's camera twist (world; m/s, rad/s); ``v_cam_w``: the camera's actual twist.
    ``watchdog``: the controller was braking for lack of a fresh pose. ``arm_limited``: the controller's
    command was cut to what the Panda can deliver. ``joint_speed_ratio``: the Panda's fastest joint
    against its velocity limit (1 = at the limit). ``ended``: ``"duration"``,
    ``"tracking lost"`` or ``"arm error: …"``. ``steps``: tracker steps published, per kind.
    ``busy_s``: solver time charged to the clock; ``ingest_busy_s``: producer (ingest) time charged.
    ``lost``: the tracker's flag on that estimate; ``holding``: the loop was not servoing on it
    (:class:`~evservo.control.hold.LossHold` holding, searching or ramping back in); ``coasting``: it
    followed the object's predicted motion through a loss (LossHold coasting); ``seen``: the
    object's events reached the tracker and at least half of it was in the image.
    """

    config: EpisodeConfig
    T_c_o_des: np.ndarray
    t_s: np.ndarray
    T_w_o: np.ndarray
    T_w_c: np.ndarray
    T_c_o_est: np.ndarray
    est_t_s: np.ndarray
    v_cmd_w: np.ndarray
    v_cam_w: np.ndarray
    watchdog: np.ndarray
    arm_limited: np.ndarray
    joint_speed_ratio: np.ndarray
    ended: str
    lost_at_s: float | None
    steps: dict[str, int]
    busy_s: float
    wall_s: float
    events: int
    watchdog_events: list[WatchdogSpell] = field(default_factory=list)
    lost: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    holding: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    seen: np.ndarray = field(default_factory=lambda: np.ones(0, bool))
    coasting: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    ingest_busy_s: float = 0.0

    @property
    def T_c_o_true(self) -> np.ndarray:
        """True object pose in the camera frame per tick (N, 4, 4)."""
        return np.linalg.inv(self.T_w_c) @ self.T_w_o


class ClockedTracker:
    """The synchronous :class:`~evservo.tracking.Tracker` run on the simulated clock (µs), with the
    threaded tracker's two timelines.

    On a rig, ingest (validation, undistortion, the SCARF insert: ``Tracker.push``) runs on the
    producer's core, in parallel with the solver, which only reads the active set. So each batch is
    ingested on a *producer* timeline: it starts when it has arrived and the previous batch is done,
    and takes its own cost there. The solver's timeline is charged only its steps; a step sees every
    batch whose ingest has started by the step's start (SCARF is written in place, so a batch being
    ingested is already partly visible to a concurrent reader). With ``thin``, the producer thins
    each batch under overload as ``Tracker.push`` does (within ``ingest_core_share`` of its core, by
    measured costs), so it keeps up with the stream and the solver sees fresh events; without, a
    producer slower than the stream falls behind.
    Batches are queued with their arrival time and the stream time they cover up to, which is
    handed on with them (``Tracker.advance_time``, as a driver's empty packet would): a batch left
    empty by a dropout still tells the tracker that time went on without events, and it steps on it.
    :meth:`advance` runs the steps whose start time has come, and :meth:`latest` returns what had
    been published by a given time.
    """

    def __init__(self, tracker: Tracker, cost: Callable[[str, float, int], float], thin: bool = True) -> None:
        """``cost(kind, cpu_s, n_events)``: seconds to charge for ``kind`` "lm" or "search" (a solver
        step) or "ingest" (a batch of ``n_events`` on the producer), which took ``cpu_s`` of this
        thread's CPU time."""
        self.tracker = tracker
        self.cost = cost
        self.thin = thin
        self.cycle_len = tracker.cycle_len
        self.free_us = 0  # when the solver can start its next step
        self.producer_free_us = -(2**62)  # when the producer can start ingesting the next batch
        self._queue: deque[tuple[int, np.ndarray, int | None]] = deque()
        self._pending: deque[tuple[int, _evcore.Estimate]] = deque()
        self._latest = tracker.step(0)
        self._steps_without_events = self.cycle_len  # nothing to do before the first batch
        self.steps = {"lm": 0, "search": 0}
        self.busy_us = 0  # solver time charged
        self.ingest_busy_us = 0  # producer time charged

    def deliver(self, arrival_us: int, events: np.ndarray, until_us: int | None = None) -> None:
        """Queue a batch that reaches the tracker at ``arrival_us`` (non-decreasing over calls) and
        covers the stream up to ``until_us`` (µs; None: up to its last event, and an empty batch is
        dropped)."""
        if len(events) or until_us is not None:
            self._queue.append((arrival_us, events, until_us))

    def _next_ingest_us(self) -> int | None:
        """When the producer starts ingesting the next queued batch (None: nothing queued)."""
        return max(self._queue[0][0], self.producer_free_us) if self._queue else None

    def _ingest_until(self, now_us: int) -> bool:
        """Ingest, on the producer's timeline, every batch whose ingest starts by ``now_us``."""
        ingested = False
        while (start := self._next_ingest_us()) is not None and start <= now_us:
            _, events, until_us = self._queue.popleft()
            started = time.thread_time()
            self.tracker.ingest(events, thin=self.thin)
            if until_us is not None:
                self.tracker.advance_time(until_us)
            cost_us = max(1, round(self.cost("ingest", time.thread_time() - started, len(events)) * 1e6))
            self.producer_free_us = start + cost_us
            self.ingest_busy_us += cost_us
            ingested = True
        return ingested

    def advance(self, now_us: int) -> None:
        """Run every step that starts by ``now_us``."""
        while True:
            if self._steps_without_events >= self.cycle_len:
                # Nothing new since a full cycle: the field cannot change, wait for the next batch.
                start = self._next_ingest_us()
                if start is None or start > now_us:
                    self.free_us = max(self.free_us, now_us)
                    return
                self.free_us = max(self.free_us, start)
            if self.free_us > now_us:
                return
            if self._ingest_until(self.free_us):
                self._steps_without_events = 0
            started = time.thread_time()
            est = self.tracker.step(1)
            cost_us = max(1, round(self.cost(est.step, time.thread_time() - started, 0) * 1e6))
            self.free_us += cost_us
            self.busy_us += cost_us
            self._steps_without_events += 1
            self.steps[est.step] += 1
            self._pending.append((self.free_us, est))

    def latest(self, now_us: int) -> _evcore.Estimate:
        """The newest estimate published by ``now_us``."""
        while self._pending and self._pending[0][0] <= now_us:
            self._latest = self._pending.popleft()[1]
        return self._latest


def ramped_time(t_s: float, ramp_s: float) -> float:
    """Trajectory time after a smooth start: its rate rises from 0 to 1 as ``(1 − cos)/2`` over
    ``ramp_s``, so the target starts from rest without a velocity step (which no arm can follow)."""
    if t_s >= ramp_s:
        return t_s - 0.5 * ramp_s
    if t_s <= 0:
        return 0.0
    return 0.5 * t_s - ramp_s / (2 * np.pi) * np.sin(np.pi * t_s / ramp_s)


PREROLL_US = 100_000
PREROLL_OFFSET_C = np.array([0.006, -0.004, 0.0])  # m, in the camera frame


def _primed_source(
    config: EpisodeConfig,
    camera: _evcore.Camera,
    T_c_o0: np.ndarray,
    tracker: Tracker,
    arms: ArmMeshes | None = None,
) -> EventSource:
    """The event source, after a 0.1 s pre-roll whose events fill the tracker's front-end.

    At rest nothing fires, and a front-end that has never seen the object holds only noise; on the
    bench the tracker has locked on while the UR5e brought the target into place. The pre-roll plays
    that: the target glides the last few millimetres into its start pose (a smooth stop), and the
    tracker ingests those events without stepping, so servoing starts from the true pose with the
    object's edges in its active set. The arms (if drawn) hold still during the pre-roll."""

    def pose_at(t_us: int) -> np.ndarray:
        s = min(1.0, (t_us + PREROLL_US) / PREROLL_US)
        T = T_c_o0.copy()
        T[:3, 3] += (1.0 - s * s * (3.0 - 2.0 * s)) * PREROLL_OFFSET_C  # smoothstep to rest
        return T

    source = make_event_source(
        config.event_source, camera, config.object, pose_at(-PREROLL_US), -PREROLL_US, config.seed, arms=arms
    )
    for t_us in range(-PREROLL_US + TICK_US, 1, TICK_US):
        tracker.ingest(source.events_until(t_us, pose_at(t_us)))
    # A source that renders only every few ticks still holds the last ones: the loop starts complete.
    for events in getattr(source, "flush", list)():
        tracker.ingest(events)
    return source


def _view_test(
    camera: _evcore.Camera, obj: str, T_c_o0: np.ndarray, seed: int, chunk: int = 2000
) -> Callable[[np.ndarray], np.ndarray]:
    """``in_view(T_c_o)``: per pose of a stack (N, 4, 4), whether at least half of the object's edge
    points (200 of them) are in front of the camera and project into the image. Run once over the
    episode's ticks (``chunk`` poses at a time) rather than once per tick: it is the same arithmetic
    per pose, without the per-call overhead."""
    points = model_point_set(camera, obj, T_c_o0, n_points=200, seed=seed)

    def in_view(T_c_o: np.ndarray) -> np.ndarray:
        out = np.zeros(len(T_c_o), bool)
        for a in range(0, len(T_c_o), chunk):
            T = T_c_o[a : a + chunk]
            p = points @ T[:, :3, :3].transpose(0, 2, 1) + T[:, None, :3, 3]  # (n, 200, 3), camera frame
            front = p[..., 2] > 1e-3
            uv = camera.project(p[front])
            inside = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
            row = np.nonzero(front)[0]  # the pose of each projected point
            n_inside = np.bincount(row[inside], minlength=len(T))
            out[a : a + chunk] = (np.mean(front, axis=1) >= 0.5) & (n_inside >= 0.5 * len(points))
        return out

    return in_view


def _cost_model(config: EpisodeConfig) -> Callable[[str, float, int], float]:
    if config.cost_model == "measured":
        return lambda _kind, cpu_s, _n: cpu_s
    fixed = {"lm": config.lm_cost_s, "search": config.search_cost_s, "ingest": 0.0}
    return lambda kind, _cpu_s, n: fixed[kind] + (n * config.ingest_event_cost_s if kind == "ingest" else 0.0)


def run_episode(
    config: EpisodeConfig,
    scene: DualArmScene | None = None,
    progress: Callable[[int], None] | None = None,
    viewer: Any = None,
) -> EpisodeResult:
    """Run one closed-loop episode; ``progress`` is called with the number of simulated
    milliseconds done since its previous call. ``scene`` may be reused across episodes (it is reset).
    ``viewer`` (a :class:`~evservo.viewer.RerunViewer`) is shown every tick; the caller closes it."""
    cfg = config
    wall0 = time.perf_counter()
    scene = scene or DualArmScene()
    T_c_o0 = scene.reset_to_start(cfg.distance_m, cfg.view_rotvec_rad)
    T_w_o0 = scene.T_w_o()
    camera = _evcore.Camera.imx636()
    core = Tracker(camera, cfg.model or cfg.object, None if cfg.start_lost else T_c_o0, solver=cfg.tracker,
                   frontend=cfg.frontend, seed=cfg.seed, reacquire=cfg.reacquire or cfg.start_lost)  # fmt: skip
    arms = ArmMeshes(scene) if cfg.render_arms else None
    source = _primed_source(cfg, camera, T_c_o0, core, arms)
    # Thinning decides by measured costs: the fixed cost model keeps every event to stay reproducible.
    tracker = ClockedTracker(core, _cost_model(cfg), thin=cfg.cost_model == "measured")
    traj = trajectories.make_trajectory(cfg.trajectory, speed_mps=cfg.speed_mps, rot_rate_dps=cfg.rot_rate_dps)
    ur = DelayedArm(scene.ur, cfg.ur_latency_s)
    panda = DelayedArm(scene.panda, cfg.panda_latency_s)
    follower = PoseFollower(
        ur,
        lambda t: trajectories.apply(traj(np.array([ramped_time(t, cfg.ramp_s)])), T_w_o0)[0],
        T_e_x=scene.config.T_e_o,
        period_s=cfg.ur_period_s,
    )
    pbvs = Pbvs(
        k=cfg.stiffness,
        feedforward=cfg.feedforward,
        period_s=cfg.control_period_s,
        max_image_rate_rad_s=cfg.max_image_rate_rad_s,
        reach=ReachableTwist(scene.panda) if cfg.feedforward else None,
        limits=PANDA_CARTESIAN if cfg.feedforward else None,
        lookahead_s=cfg.panda_latency_s,
        predict_accel=cfg.predictor == "acceleration",
    )
    hold = LossHold(pbvs, coast_s=cfg.coast_s)
    if cfg.start_lost:
        hold.search()  # the desired pose is captured once the tracker has locked
    else:
        # The paper captures the tracker's pose at servo start as the desired pose.
        hold.start(scene.T_w_c(), tracker.latest(0).T_c_o, t_s=0.0)
    disturb = Disturbances(camera.width, camera.height, cfg.occlusions, cfg.dropout_s, cfg.noise_s,
                           cfg.noise_rate_hz, cfg.seed)  # fmt: skip
    in_view = _view_test(camera, cfg.object, T_c_o0, cfg.seed)

    n = round(cfg.duration_s * 1e6) // TICK_US
    ctrl_every = round(cfg.control_period_s * 1e6) // TICK_US
    ur_every = round(cfg.ur_period_s * 1e6) // TICK_US
    panda_every = round(cfg.panda_period_s * 1e6) // TICK_US
    latency_us = round(cfg.sensing_latency_s * 1e6)
    lost_rot = np.deg2rad(cfg.lost_rot_deg)
    rec = {
        "T_w_o": np.empty((n, 4, 4)),
        "T_w_c": np.empty((n, 4, 4)),
        "T_c_o_est": np.empty((n, 4, 4)),
        "est_t_s": np.empty(n),
        "v_cmd_w": np.empty((n, 6)),
        "v_cam_w": np.empty((n, 6)),
        "watchdog": np.zeros(n, bool),
        "arm_limited": np.zeros(n, bool),
        "joint_speed_ratio": np.zeros(n),
        "lost": np.zeros(n, bool),
        "holding": np.zeros(n, bool),
        "coasting": np.zeros(n, bool),
        "seen": np.zeros(n, bool),
    }
    T_c_o_true = [T_c_o0]  # per tick, to score an estimate against the truth at its own time
    qd_max = scene.panda.limits.qd_max
    # The poses of the current tick: read once after each physics step (nothing moves the arms between
    # a step and the next tick's commands), not again by every user.
    T_w_c, T_w_o = scene.T_w_c(), scene.T_w_o()
    v_cmd, watchdog, arm_limited, mode = np.zeros(6), False, False, hold.mode
    last_seq, ended, lost_at, n_events, done = 0, "duration", None, 0, 0
    # The stream time up to which the source's events are all out (µs): the tick's end, or for a source
    # that renders every few ticks and hands their events out together (``covered_us``), its last render.
    covered_us = 0
    with StopOnInterrupt() as stop:
        for k in range(n):
            if stop.requested:  # Ctrl-C: the ticks done so far make a partial result
                ended = INTERRUPTED
                break
            t_us = k * TICK_US
            t = t_us * 1e-6
            try:
                ur.deliver(t_us)
                panda.deliver(t_us)
                if k % ur_every == 0:
                    follower.command(t)
                T_w_e = scene.panda.T_w_e()
                v_cam = shift_twist(scene.panda.twist_w(), T_w_e[:3, 3], T_w_c[:3, 3])
                est = tracker.latest(t_us)
                # The start estimate (seq 0) reads lost before any update: a loss only without a start pose.
                lost = (est.lost and (est.seq > 0 or cfg.start_lost)) or within(t, cfg.false_losses)
                if k % ctrl_every == 0:
                    # A pose counts once, and not at all when the tracker flags itself lost.
                    fresh = est.seq != last_seq and not (est.lost or lost)
                    last_seq = est.seq
                    cmd = hold.update(t, T_w_c, v_cmd, est.T_c_o if fresh else None, est.t_us * 1e-6, lost)
                    v_cmd, watchdog, mode = cmd.v_c_w, cmd.watchdog, cmd.mode
                    arm_limited = cmd.pbvs is not None and cmd.pbvs.arm_limited
                if k % panda_every == 0:
                    if (watchdog or mode in ("holding", "searching")) and not v_cmd.any():
                        panda.stop()  # braked to rest: hold still rather than keep resolving a zero twist
                    else:
                        panda.command_twist(shift_twist(v_cmd, T_w_c[:3, 3], T_w_e[:3, 3]), cfg.panda_period_s)
            except RuntimeError as err:  # an infeasible IK QP: report it, do not crash the run
                ended = f"arm error: {err}"
                break
            T_est = est.T_c_o
            j = min(round(est.t_us / TICK_US), k)
            if cfg.end_on_loss and (
                geometry.translation_error_m(T_est, T_c_o_true[j]) > cfg.lost_pos_m
                or geometry.rotation_error_rad(T_est, T_c_o_true[j]) > lost_rot
            ):
                ended, lost_at = "tracking lost", t
                break
            rec["T_w_o"][k], rec["T_w_c"][k], rec["T_c_o_est"][k] = T_w_o, T_w_c, T_est
            rec["est_t_s"][k], rec["v_cmd_w"][k], rec["v_cam_w"][k] = est.t_us * 1e-6, v_cmd, v_cam
            rec["watchdog"][k], rec["arm_limited"][k] = watchdog, arm_limited
            rec["joint_speed_ratio"][k] = (np.abs(scene.panda.qd) / qd_max).max()
            rec["lost"][k], rec["holding"][k] = lost, mode not in ("servoing", "coasting")
            rec["coasting"][k] = mode == "coasting"
            rec["seen"][k] = disturb.seen(t)  # and in view: after the loop, for all ticks at once
            done = k + 1

            scene.step(1)
            t_next = t_us + TICK_US
            T_w_c, T_w_o = scene.T_w_c(), scene.T_w_o()
            T_now = geometry.inv(T_w_c) @ T_w_o
            T_c_o_true.append(T_now)
            T_shown = disturb.source_pose(source, t_next, T_now)
            if arms is None:
                events = source.events_until(t_next, T_shown, T_w_c)
            else:
                events = source.events_until(t_next, T_shown, T_w_c, occluders=arms.camera_poses(T_w_c))  # type: ignore[call-arg]
            covered0_us, covered_us = covered_us, getattr(source, "covered_us", t_next)
            events = disturb.events(covered0_us, covered_us, events)
            n_events += len(events)
            if viewer is not None:
                # The tick's poses (before the step), with the events simulated over it.
                T_w_c_k, T_w_o_k = rec["T_w_c"][k], rec["T_w_o"][k]
                des = hold.T_c_o_des if hold.T_c_o_des is not None else T_c_o0
                viewer.servo(t_us, events, est, core, T_w_c=T_w_c_k, T_c_o_des=des, T_w_o_true=T_w_o_k)
            # Nothing new while the source waits for its next render: no batch (not even an empty one).
            tracker.deliver(t_next + latency_us, events, until_us=covered_us if covered_us > covered0_us else None)
            tracker.advance(t_next)
            if progress is not None and (k + 1) % 100 == 0:
                progress(100)
    if progress is not None and done % 100:
        progress(done % 100)
    rec["seen"][:done] &= in_view(np.asarray(T_c_o_true[:done]).reshape(-1, 4, 4))

    result = EpisodeResult(
        config=cfg,
        # Started without a pose and never locked: no desired pose; the start pose stands in for scoring.
        T_c_o_des=hold.T_c_o_des if hold.T_c_o_des is not None else T_c_o0,
        t_s=np.arange(done) * TICK_US * 1e-6,
        **{key: v[:done] for key, v in rec.items()},
        ended=ended,
        lost_at_s=lost_at,
        steps=dict(tracker.steps),
        busy_s=tracker.busy_us * 1e-6,
        ingest_busy_s=tracker.ingest_busy_us * 1e-6,
        wall_s=time.perf_counter() - wall0,
        events=n_events,
    )
    result.watchdog_events = spells_from_flags(result.t_s, result.watchdog, result.est_t_s, result.v_cmd_w)
    return result


def timing(result: EpisodeResult) -> dict:
    """The loop's timing (ms, Hz): what the episode simulated, and the tracker's measured share."""
    cfg, r = result.config, result
    n_steps = sum(r.steps.values())
    return {
        "sensing_latency_ms": cfg.sensing_latency_s * 1e3,
        "tracker_step_mean_ms": r.busy_s / n_steps * 1e3 if n_steps else float("nan"),
        "pose_age_mean_ms": float(np.mean(r.t_s - r.est_t_s) * 1e3) if len(r.t_s) else float("nan"),
        "control_period_ms": cfg.control_period_s * 1e3,
        "ur_rate_hz": 1.0 / cfg.ur_period_s,
        "ur_latency_ms": cfg.ur_latency_s * 1e3,
        "panda_rate_hz": 1.0 / cfg.panda_period_s,
        "panda_latency_ms": cfg.panda_latency_s * 1e3,
    }


def gave_out(result: EpisodeResult, window_s: float = 0.5) -> str | None:
    """Why an episode ended early: ``"tracker"`` when, in the ``window_s`` before, the watchdog braked
    for want of fresh poses; else ``"arm"`` when the Panda was at a joint velocity limit, or the
    controller's command was at its Cartesian velocity limit or cut to what the arm could deliver
    most of the time; else ``"tracker"``; the end reason when it was not tracking loss; None when it
    ran its course."""
    r = result
    if r.ended == "duration":
        return None
    if r.ended != "tracking lost":
        return r.ended
    recent = r.t_s >= r.t_s[-1] - window_s if len(r.t_s) else np.zeros(0, bool)
    L = PANDA_CARTESIAN if r.config.feedforward else CartesianLimits()
    v = r.v_cmd_w[recent]
    at_cartesian = np.any(np.linalg.norm(v[:, :3], axis=1) >= 0.999 * L.max_lin_vel) or np.any(
        np.linalg.norm(v[:, 3:], axis=1) >= 0.999 * L.max_ang_vel
    )
    if np.any(r.watchdog[recent]):
        return "tracker"
    at_limit = np.any(r.joint_speed_ratio[recent] > 0.99) or np.mean(r.arm_limited[recent]) > 0.5 or at_cartesian
    return "arm" if at_limit else "tracker"


def overshoot_m(d_lead: np.ndarray, d_follow: np.ndarray) -> float:
    """How far ``d_follow`` (N, 3) travels past the extremes of ``d_lead`` (N, 3) along the leader's main
    direction of motion (metres, ≥ 0): a camera overshooting where its target stopped or turned back."""
    if len(d_lead) < 2 or not np.any(d_lead):
        return 0.0
    axis = np.linalg.svd(d_lead - d_lead.mean(axis=0), full_matrices=False)[2][0]
    a, b = d_lead @ axis, d_follow @ axis
    return float(max(0.0, b.max() - a.max(), a.min() - b.min()))


def loss_summary(result: EpisodeResult, pos_err_m: np.ndarray, rot_err_rad: np.ndarray, z_m: np.ndarray) -> dict:
    """How the tracker's ``lost`` flag did (:func:`evservo.runtime.loss.loss_metrics`) given each
    tick's tracking error (m, rad) and true depth (m): a pose is wrong beyond the issue's bounds, while
    the object is not seen, or always when the tracker's model is not the object's. Adds the time the
    loop spent not servoing (holding, searching or ramping back in) and the time it followed the
    object's predicted motion through a loss (coasting)."""
    r, cfg = result, result.config
    mismatch = cfg.model is not None and cfg.model != cfg.object
    wrong = wrong_pose(pos_err_m, rot_err_rad, z_m) | ~r.seen | mismatch
    out = loss_metrics(r.t_s, r.lost, wrong, r.seen, started_lost=cfg.start_lost)
    out["holding_s"] = float(np.sum(r.holding)) * TICK_US * 1e-6
    out["coasting_s"] = float(np.sum(r.coasting)) * TICK_US * 1e-6
    return out


def summarize(result: EpisodeResult) -> dict:
    """Metrics of an episode (JSON-ready): the paper's servoing error (estimated vs desired relative
    pose), the same with the true relative pose, the tracking error (estimate vs truth at the
    estimate's time), the camera's lag behind the target and its rotation, rates, watchdog spells."""
    r, cfg = result, result.config
    n = len(r.t_s)
    des = np.broadcast_to(r.T_c_o_des, (n, 4, 4))
    truth = r.T_c_o_true
    s_pos, s_rot = pose_errors(r.T_c_o_est, des)
    g_pos, g_rot = pose_errors(truth, des)
    # The truth at each estimate's own time stamp (nearest tick).
    idx = np.clip(np.round(r.est_t_s / (TICK_US * 1e-6)).astype(int), 0, max(n - 1, 0))
    k_pos, k_rot = pose_errors(r.T_c_o_est, truth[idx])
    cam_rot = rotation_from_first_rad(r.T_w_c)
    d_obj = r.T_w_o[:, :3, 3] - r.T_w_o[:1, :3, 3]
    d_cam = r.T_w_c[:, :3, 3] - r.T_w_c[:1, :3, 3]
    sim_s = n * TICK_US * 1e-6
    n_steps = sum(r.steps.values())
    return {
        "completed": r.ended == "duration",
        "interrupted": r.ended == INTERRUPTED,
        "ended": r.ended,
        "lost_at_s": r.lost_at_s,
        "simulated_s": sim_s,
        "servo_pos_rms_mm": rms(s_pos) * 1e3,
        "servo_rot_rms_deg": float(np.rad2deg(rms(s_rot))),
        "gt_servo_pos_rms_mm": rms(g_pos) * 1e3,
        "gt_servo_rot_rms_deg": float(np.rad2deg(rms(g_rot))),
        "gt_track_pos_rms_mm": rms(k_pos) * 1e3,
        "gt_track_rot_rms_deg": float(np.rad2deg(rms(k_rot))),
        "lag_s": estimate_lag_s(r.t_s, d_obj, d_cam) if n > 100 else float("nan"),
        "overshoot_mm": overshoot_m(d_obj, d_cam) * 1e3,
        "camera_rot_mean_deg": float(np.rad2deg(np.mean(cam_rot))) if n else float("nan"),
        "object_travel_max_m": float(np.max(np.linalg.norm(d_obj, axis=1))) if n else 0.0,
        "tracker_rate_hz": n_steps / sim_s if sim_s else 0.0,
        "tracker_steps": r.steps,
        "tracker_busy_fraction": r.busy_s / sim_s if sim_s else 0.0,
        "ingest_busy_fraction": r.ingest_busy_s / sim_s if sim_s else 0.0,
        "pose_age_mean_ms": float(np.mean(r.t_s - r.est_t_s) * 1e3) if n else float("nan"),
        "events": r.events,
        "watchdog": [asdict(w) for w in r.watchdog_events],
        "arm_limited_fraction": float(np.mean(r.arm_limited)) if n else 0.0,
        "joint_speed_max_ratio": float(np.max(r.joint_speed_ratio)) if n else 0.0,
        "gave_out": gave_out(r),
        "loss": loss_summary(r, k_pos, k_rot, truth[idx, 2, 3]),
        "timing": timing(r),
        "wall_s": r.wall_s,
        "config": asdict(cfg),
        "versions": {"evservo": _evcore.__version__},
    }


def write_outputs(result: EpisodeResult, out_dir: str | Path, summary: dict | None = None) -> dict[str, Path]:
    """Write ``summary.json``, ``log.csv`` (at ``config.log_rate_hz``) and ``motion.png`` (the paper's
    Fig. 5) into ``out_dir``; returns their paths by name. The summary is written last (and
    atomically): a ``summary.json`` is there only when the episode's other outputs are."""
    r, cfg = result, result.config
    out = make_out_dir(out_dir, stale=OUTPUTS)
    paths = {"summary": out / "summary.json", "log": out / "log.csv", "motion": out / "motion.png"}
    summary = summary if summary is not None else summarize(result)
    every = max(1, round(1.0 / (cfg.log_rate_hz * TICK_US * 1e-6)))
    k = np.arange(0, len(r.t_s), every)
    truth = r.T_c_o_true[k]
    des = np.broadcast_to(r.T_c_o_des, (len(k), 4, 4))
    s_pos, s_rot = pose_errors(r.T_c_o_est[k], des)
    g_pos, _ = pose_errors(truth, des)
    header = [
        "t_s", "obj_x_m", "obj_y_m", "obj_z_m", "cam_x_m", "cam_y_m", "cam_z_m",
        "est_x_m", "est_y_m", "est_z_m", "true_x_m", "true_y_m", "true_z_m",
        "servo_pos_mm", "servo_rot_deg", "gt_servo_pos_mm", "pose_age_ms",
        "v_cmd_mps", "w_cmd_dps", "v_cam_mps", "watchdog",
    ]  # fmt: skip
    cols = np.column_stack([
        r.t_s[k], r.T_w_o[k, :3, 3], r.T_w_c[k, :3, 3], r.T_c_o_est[k, :3, 3], truth[:, :3, 3], s_pos * 1e3,
        np.rad2deg(s_rot), g_pos * 1e3, (r.t_s[k] - r.est_t_s[k]) * 1e3, np.linalg.norm(r.v_cmd_w[k, :3], axis=1),
        np.rad2deg(np.linalg.norm(r.v_cmd_w[k, 3:], axis=1)), np.linalg.norm(r.v_cam_w[k, :3], axis=1),
        r.watchdog[k].astype(float),
    ])  # fmt: skip
    write_log(paths["log"], header, cols)
    title = f"{cfg.object}, {cfg.tracker}, Z = {cfg.distance_m} m, {cfg.trajectory} at {cfg.speed_mps} m/s" + (
        f", feed-forward ({cfg.predictor})" if cfg.feedforward else ", paper's law"
    )
    plot_motion(
        paths["motion"], r.t_s, r.T_w_c, r.T_w_c @ r.T_c_o_est, title, T_w_o_true=r.T_w_o, spells=r.watchdog_events
    )
    write_summary(paths["summary"], summary)
    return paths
