"""One closed-loop servoing episode on the simulated dual-arm bench (paper Sec. III-C and IV).

Everything runs on the scene's simulated 1 kHz clock, in this order per millisecond tick ``t``:

1. the UR5e is commanded (every 2 ms, RTDE's rate) to carry the target along the trajectory: a
   displacement of the object in the world frame from its start pose, entered with a smooth
   velocity ramp;
2. the controller (:class:`~evservo.control.Pbvs`, every ``control_period_s``) reads the newest pose
   the tracker has *published by t* and returns a camera twist, which the Panda's command path
   resolves through the joint-limited QP every tick (1 kHz, like Franka's FCI). The controller's
   velocity state is its own previous command, as mc_rtc integrates its QP's output, not the
   measured twist: the regularised IK realises ~1 % less than asked, and re-basing on that every
   2 ms would silently eat ~1 m/s² of the commanded acceleration;
3. the arms move one tick;
4. the event source turns the true relative pose ``T_c_o`` at the new time into the events of the
   last millisecond, which reach the tracker ``sensing_latency_s`` later (3.5 ms measured in the
   paper), unless an injected dropout swallows them;
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

import csv
import json
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from evservo import _evcore, geometry, trajectories
from evservo.control import Pbvs
from evservo.robots import PoseFollower, shift_twist
from evservo.sim.arms import ArmMeshes
from evservo.sim.scene import DualArmScene
from evservo.sim.sources import EVENT_SOURCES, RENDERED_SOURCES, EventSource, make_event_source
from evservo.tracking import FRONTENDS, SOLVERS, Tracker

COST_MODELS = ("measured", "fixed")
TICK_US = 1000  # physics step, event batch and Panda command period
UR_PERIOD_US = 2000


@dataclass(frozen=True)
class EpisodeConfig:
    """What to run. Lengths in metres, times in seconds, speeds in m/s.

    ``trajectory``: a kind of :mod:`evservo.trajectories` or a CSV path; the displacement of the object
    in the world frame from its start pose, at peak speed ``speed_mps`` (``rot_rate_dps`` for the
    rotating kinds), entered over ``ramp_s`` with a smooth velocity ramp.
    ``distance_m``: camera–object depth Z at the start. ``view_rotvec_rad``: the object's start
    orientation relative to facing the camera (camera frame); the default shows three faces of the
    box, as on the bench (a face-on plane leaves its out-of-plane rotation nearly unobservable, and
    PBVS turns rotation noise into camera motion through the Z lever arm).
    ``tracker``: solver (``edft+``, ``edopts``, ``edft``).
    ``cost_model``: ``measured`` charges the tracker's compute time to the simulated clock (CPU time
    of the calling thread: the solver is single-threaded, and on a shared machine wall time would
    also charge whatever other processes took); ``fixed`` charges ``lm_cost_s`` per LM step and
    ``search_cost_s`` per search step (reproducible).
    ``dropout_s``: ``(start, end)`` window whose events are lost (sensor or link failure).
    ``lost_pos_m``, ``lost_rot_deg``: tracking counts as lost, and the episode ends, once the estimate
    is this far from the truth at the estimate's time.
    ``render_arms``: draw the UR5e and the Panda into the rendered event camera too (their moving
    links occlude the scene and fire events; see :mod:`evservo.sim.arms`); needs ``event_source``
    ``"render"``.
    """

    object: str = "box"
    tracker: str = "edft+"
    frontend: str = "scarf"
    trajectory: str = "trans"
    speed_mps: float = 0.3
    rot_rate_dps: float = 30.0
    distance_m: float = 0.9
    view_rotvec_rad: tuple[float, float, float] = (0.35, -0.45, 0.1)
    duration_s: float = 20.0
    seed: int = 1
    feedforward: bool = False
    cost_model: str = "measured"
    lm_cost_s: float = 0.001
    search_cost_s: float = 0.0004
    event_source: str = "edges"
    sensing_latency_s: float = 0.0035
    control_period_s: float = 0.002
    stiffness: float = 20.0
    ramp_s: float = 0.5
    dropout_s: tuple[float, float] | None = None
    lost_pos_m: float = 0.05
    lost_rot_deg: float = 15.0
    log_rate_hz: float = 100.0
    render_arms: bool = False

    def __post_init__(self) -> None:
        if self.tracker not in SOLVERS:
            raise ValueError(f"unknown tracker {self.tracker!r}; choose one of {SOLVERS}")
        if self.frontend not in FRONTENDS:
            raise ValueError(f"unknown front-end {self.frontend!r}; choose one of {FRONTENDS}")
        if self.cost_model not in COST_MODELS:
            raise ValueError(f"unknown cost model {self.cost_model!r}; choose one of {COST_MODELS}")
        if self.event_source not in EVENT_SOURCES:
            raise ValueError(f"unknown event source {self.event_source!r}; choose one of {sorted(EVENT_SOURCES)}")
        if not (self.duration_s > 0 and self.distance_m > 0 and self.speed_mps >= 0 and self.ramp_s >= 0):
            raise ValueError("duration and distance must be > 0, speed and ramp >= 0")
        if not (self.lm_cost_s > 0 and self.search_cost_s > 0 and self.sensing_latency_s >= 0):
            raise ValueError("step costs must be > 0 and the latency >= 0")
        if round(self.control_period_s * 1e6) % TICK_US or self.control_period_s <= 0:
            raise ValueError("control_period_s must be a positive multiple of 1 ms")
        if self.render_arms and self.event_source not in RENDERED_SOURCES:
            raise ValueError(
                f"render_arms draws the arms in the rendered event camera: it needs event_source 'render', "
                f"not {self.event_source!r}"
            )
        if self.dropout_s is not None and not self.dropout_s[0] < self.dropout_s[1]:
            raise ValueError("dropout_s must be (start, end) with start < end")


@dataclass(frozen=True)
class WatchdogEvent:
    """One spell of the controller's watchdog (no fresh pose for ``stale_after_s``), in seconds.

    ``last_pose_s``: time stamp of the last pose accepted before it; ``start_s``: first control cycle
    that braked; ``zero_s``: first tick the commanded camera twist was exactly zero (None if never);
    ``end_s``: first cycle servoing again (None if it lasted to the end)."""

    start_s: float
    last_pose_s: float
    zero_s: float | None
    end_s: float | None


@dataclass
class EpisodeResult:
    """Per-tick record of an episode (index k is simulated time ``t_s[k]``, 1 kHz) and its outcome.

    ``T_w_o``, ``T_w_c``: true object and camera poses. ``T_c_o_est``: the newest tracker pose
    published by ``t_s`` and ``est_t_s`` its time stamp (newest event behind it). ``v_cmd_w``: the
    controller's camera twist (world; m/s, rad/s); ``v_cam_w``: the camera's actual twist.
    ``watchdog``: the controller was braking for lack of a fresh pose. ``ended``: ``"duration"``,
    ``"tracking lost"`` or ``"arm error: …"``. ``steps``: tracker steps published, per kind.
    ``busy_s``: tracker time charged to the clock.
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
    ended: str
    lost_at_s: float | None
    steps: dict[str, int]
    busy_s: float
    wall_s: float
    events: int
    watchdog_events: list[WatchdogEvent] = field(default_factory=list)

    @property
    def T_c_o_true(self) -> np.ndarray:
        """True object pose in the camera frame per tick (N, 4, 4)."""
        return np.linalg.inv(self.T_w_c) @ self.T_w_o


class ClockedTracker:
    """The synchronous :class:`~evservo.tracking.Tracker` run on the simulated clock (µs).

    Batches are queued with their arrival time; :meth:`advance` runs the steps whose start time has
    come, charging each its cost, and :meth:`latest` returns what had been published by a given time.
    """

    def __init__(self, tracker: Tracker, cost: Callable[[str, float], float]) -> None:
        """``cost(kind, cpu_s)``: seconds to charge for a step of ``kind`` ("lm"/"search") that took
        ``cpu_s`` of this thread's CPU time (ingest included)."""
        self.tracker = tracker
        self.cost = cost
        # One cycle is 1 LM + 4 search steps (edft+) or 5 steps of a single solver (n_search = 4).
        self.cycle_len = 5
        self.free_us = 0  # when the solver can start its next step
        self._queue: deque[tuple[int, np.ndarray]] = deque()
        self._pending: deque[tuple[int, _evcore.Estimate]] = deque()
        self._latest = tracker.step(0)
        self._steps_without_events = self.cycle_len  # nothing to do before the first batch
        self.steps = {"lm": 0, "search": 0}
        self.busy_us = 0

    def deliver(self, arrival_us: int, events: np.ndarray) -> None:
        """Queue a batch that reaches the tracker at ``arrival_us`` (non-decreasing over calls)."""
        if len(events):
            self._queue.append((arrival_us, events))

    def advance(self, now_us: int) -> None:
        """Run every step that starts by ``now_us``."""
        while True:
            if self._steps_without_events >= self.cycle_len:
                # Nothing new since a full cycle: the field cannot change, wait for the next batch.
                if not self._queue or self._queue[0][0] > now_us:
                    self.free_us = max(self.free_us, now_us)
                    return
                self.free_us = max(self.free_us, self._queue[0][0])
            if self.free_us > now_us:
                return
            started = time.thread_time()
            arrived = []
            while self._queue and self._queue[0][0] <= self.free_us:
                arrived.append(self._queue.popleft()[1])
            if arrived:
                self.tracker.ingest(np.concatenate(arrived))
                self._steps_without_events = 0
            est = self.tracker.step(1)
            cpu = time.thread_time() - started
            cost_us = max(1, round(self.cost(est.step, cpu) * 1e6))
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
    return source


def _cost_model(config: EpisodeConfig) -> Callable[[str, float], float]:
    if config.cost_model == "measured":
        return lambda _kind, cpu_s: cpu_s
    return lambda kind, _cpu_s: config.lm_cost_s if kind == "lm" else config.search_cost_s


def run_episode(
    config: EpisodeConfig, scene: DualArmScene | None = None, progress: Callable[[int], None] | None = None
) -> EpisodeResult:
    """Run one closed-loop episode; ``progress`` is called with the number of simulated
    milliseconds done since its previous call. ``scene`` may be reused across episodes (it is reset)."""
    cfg = config
    wall0 = time.perf_counter()
    scene = scene or DualArmScene()
    T_c_o0 = scene.reset_to_start(cfg.distance_m, cfg.view_rotvec_rad)
    T_w_o0 = scene.T_w_o()
    camera = _evcore.Camera.imx636()
    core = Tracker(camera, cfg.object, T_c_o0, solver=cfg.tracker, frontend=cfg.frontend, seed=cfg.seed)
    arms = ArmMeshes(scene) if cfg.render_arms else None
    source = _primed_source(cfg, camera, T_c_o0, core, arms)
    tracker = ClockedTracker(core, _cost_model(cfg))
    traj = trajectories.make_trajectory(cfg.trajectory, speed_mps=cfg.speed_mps, rot_rate_dps=cfg.rot_rate_dps)
    follower = PoseFollower(
        scene.ur,
        lambda t: trajectories.apply(traj(np.array([ramped_time(t, cfg.ramp_s)])), T_w_o0)[0],
        T_e_x=scene.config.T_e_o,
        period_s=UR_PERIOD_US * 1e-6,
    )
    pbvs = Pbvs(k=cfg.stiffness, feedforward=cfg.feedforward, period_s=cfg.control_period_s)
    # The paper captures the tracker's pose at servo start as the desired pose.
    T_c_o_des = tracker.latest(0).T_c_o
    pbvs.start(scene.T_w_c(), T_c_o_des, t_s=0.0)

    n = round(cfg.duration_s * 1e6) // TICK_US
    ctrl_every = round(cfg.control_period_s * 1e6) // TICK_US
    latency_us = round(cfg.sensing_latency_s * 1e6)
    drop = None if cfg.dropout_s is None else (round(cfg.dropout_s[0] * 1e6), round(cfg.dropout_s[1] * 1e6))
    lost_rot = np.deg2rad(cfg.lost_rot_deg)
    rec = {
        "T_w_o": np.empty((n, 4, 4)),
        "T_w_c": np.empty((n, 4, 4)),
        "T_c_o_est": np.empty((n, 4, 4)),
        "est_t_s": np.empty(n),
        "v_cmd_w": np.empty((n, 6)),
        "v_cam_w": np.empty((n, 6)),
        "watchdog": np.zeros(n, bool),
    }
    T_c_o_true = [T_c_o0]  # per tick, to score an estimate against the truth at its own time
    v_cmd, watchdog = np.zeros(6), False
    last_seq, ended, lost_at, n_events, done = 0, "duration", None, 0, 0
    for k in range(n):
        t_us = k * TICK_US
        t = t_us * 1e-6
        try:
            if t_us % UR_PERIOD_US == 0:
                follower.command(t)
            T_w_c, T_w_e = scene.T_w_c(), scene.panda.T_w_e()
            v_cam = shift_twist(scene.panda.twist_w(), T_w_e[:3, 3], T_w_c[:3, 3])
            est = tracker.latest(t_us)
            if k % ctrl_every == 0:
                # A pose counts once, and not at all when the tracker flags itself lost.
                fresh = est.seq != last_seq and not est.lost
                last_seq = est.seq
                cmd = pbvs.update(t, T_w_c, v_cmd, est.T_c_o if fresh else None, est.t_us * 1e-6)
                v_cmd, watchdog = cmd.v_c_w, cmd.watchdog
            if watchdog and not np.any(v_cmd):
                scene.panda.stop()  # braked to rest: hold still rather than keep resolving a zero twist
            else:
                scene.panda.command_twist(shift_twist(v_cmd, T_w_c[:3, 3], T_w_e[:3, 3]), TICK_US * 1e-6)
        except RuntimeError as err:  # an infeasible IK QP: report it, do not crash the run
            ended = f"arm error: {err}"
            break
        T_est = est.T_c_o
        j = min(round(est.t_us / TICK_US), k)
        if geometry.translation_error_m(T_est, T_c_o_true[j]) > cfg.lost_pos_m or (
            geometry.rotation_error_rad(T_est, T_c_o_true[j]) > lost_rot
        ):
            ended, lost_at = "tracking lost", t
            break
        rec["T_w_o"][k], rec["T_w_c"][k], rec["T_c_o_est"][k] = scene.T_w_o(), T_w_c, T_est
        rec["est_t_s"][k], rec["v_cmd_w"][k], rec["v_cam_w"][k] = est.t_us * 1e-6, v_cmd, v_cam
        rec["watchdog"][k] = watchdog
        done = k + 1

        scene.step(1)
        t_next = t_us + TICK_US
        T_now = scene.T_c_o()
        T_c_o_true.append(T_now)
        if arms is None:
            events = source.events_until(t_next, T_now, scene.T_w_c())
        else:
            T_w_c = scene.T_w_c()
            events = source.events_until(t_next, T_now, T_w_c, occluders=arms.camera_poses(T_w_c))  # type: ignore[call-arg]
        if drop is not None and len(events):
            events = events[(events["t"] < drop[0]) | (events["t"] >= drop[1])]
        n_events += len(events)
        tracker.deliver(t_next + latency_us, events)
        tracker.advance(t_next)
        if progress is not None and (k + 1) % 100 == 0:
            progress(100)
    if progress is not None and done % 100:
        progress(done % 100)

    result = EpisodeResult(
        config=cfg,
        T_c_o_des=T_c_o_des,
        t_s=np.arange(done) * TICK_US * 1e-6,
        **{key: v[:done] for key, v in rec.items()},
        ended=ended,
        lost_at_s=lost_at,
        steps=dict(tracker.steps),
        busy_s=tracker.busy_us * 1e-6,
        wall_s=time.perf_counter() - wall0,
        events=n_events,
    )
    result.watchdog_events = watchdog_events(result)
    return result


def watchdog_events(result: EpisodeResult) -> list[WatchdogEvent]:
    """The watchdog's spells from the per-tick record."""
    w, t = result.watchdog, result.t_s
    out = []
    starts = np.flatnonzero(w & ~np.concatenate([[False], w[:-1]]))
    for s in starts:
        after = np.flatnonzero(~w[s:])
        e = s + after[0] if len(after) else None
        span = slice(s, e)
        zero = np.flatnonzero(~np.any(result.v_cmd_w[span], axis=1))
        out.append(
            WatchdogEvent(
                start_s=float(t[s]),
                last_pose_s=float(result.est_t_s[s]),
                zero_s=float(t[s + zero[0]]) if len(zero) else None,
                end_s=float(t[e]) if e is not None else None,
            )
        )
    return out


def pose_errors(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation distance (m) and geodesic angle (rad) between pose stacks ``A`` and ``B`` (N, 4, 4)."""
    pos = np.linalg.norm(A[:, :3, 3] - B[:, :3, 3], axis=1)
    tr = np.einsum("nji,nji->n", A[:, :3, :3], B[:, :3, :3])  # trace(Aᵀ B)
    return pos, np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))


def camera_rotation_rad(T_w_c: np.ndarray) -> np.ndarray:
    """Geodesic angle (rad) of each camera orientation in ``T_w_c`` (N, 4, 4) from the first one."""
    if not len(T_w_c):
        return np.zeros(0)
    tr = np.einsum("ji,nji->n", T_w_c[0, :3, :3], T_w_c[:, :3, :3])
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))


def estimate_lag_s(t_s: np.ndarray, d_lead: np.ndarray, d_follow: np.ndarray, max_lag_s: float = 1.0) -> float:
    """How far ``d_follow`` (N, 3) trails ``d_lead`` (N, 3), both sampled at uniform times ``t_s``:
    the shift maximising their normalised cross-correlation (summed over the axes, means removed),
    searched in ``[−max_lag_s/2, max_lag_s]`` and refined by a parabola through the peak. NaN if
    either signal is flat."""
    dt = float(t_s[1] - t_s[0])
    a = d_lead - d_lead.mean(axis=0)
    b = d_follow - d_follow.mean(axis=0)
    if np.sum(a * a) < 1e-12 or np.sum(b * b) < 1e-12:
        return float("nan")
    max_k = min(round(max_lag_s / dt), len(a) // 2)
    lags = np.arange(-max_k // 2, max_k + 1)
    c = np.empty(len(lags))
    for i, L in enumerate(lags):
        x, y = (a[: len(a) - L], b[L:]) if L >= 0 else (a[-L:], b[: len(b) + L])
        c[i] = np.sum(x * y) / np.sqrt(np.sum(x * x) * np.sum(y * y))
    i = int(np.argmax(c))
    shift = 0.0
    if 0 < i < len(c) - 1:
        den = c[i - 1] - 2 * c[i] + c[i + 1]
        shift = 0.5 * (c[i - 1] - c[i + 1]) / den if den < 0 else 0.0
    return float((lags[i] + shift) * dt)


def rms(x: np.ndarray) -> float:
    """Root mean square of ``x``; NaN when empty."""
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


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
    cam_rot = camera_rotation_rad(r.T_w_c)
    d_obj = r.T_w_o[:, :3, 3] - r.T_w_o[:1, :3, 3]
    d_cam = r.T_w_c[:, :3, 3] - r.T_w_c[:1, :3, 3]
    sim_s = n * TICK_US * 1e-6
    n_steps = sum(r.steps.values())
    return {
        "completed": r.ended == "duration",
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
        "camera_rot_mean_deg": float(np.rad2deg(np.mean(cam_rot))) if n else float("nan"),
        "object_travel_max_m": float(np.max(np.linalg.norm(d_obj, axis=1))) if n else 0.0,
        "tracker_rate_hz": n_steps / sim_s if sim_s else 0.0,
        "tracker_steps": r.steps,
        "tracker_busy_fraction": r.busy_s / sim_s if sim_s else 0.0,
        "pose_age_mean_ms": float(np.mean(r.t_s - r.est_t_s) * 1e3) if n else float("nan"),
        "events": r.events,
        "watchdog": [asdict(w) for w in r.watchdog_events],
        "wall_s": r.wall_s,
        "config": asdict(cfg),
        "versions": {"evservo": _evcore.__version__},
    }


def write_outputs(result: EpisodeResult, out_dir: str | Path, summary: dict | None = None) -> dict[str, Path]:
    """Write ``summary.json``, ``log.csv`` (at ``config.log_rate_hz``) and ``motion.png`` into
    ``out_dir``; returns their paths by name."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"summary": out / "summary.json", "log": out / "log.csv", "motion": out / "motion.png"}
    summary = summary if summary is not None else summarize(result)
    paths["summary"].write_text(json.dumps(summary, indent=2, default=float) + "\n")
    _write_log(result, paths["log"])
    plot_motion(result, paths["motion"])
    return paths


def _write_log(r: EpisodeResult, path: Path) -> None:
    n = len(r.t_s)
    every = max(1, round(1.0 / (r.config.log_rate_hz * TICK_US * 1e-6)))
    k = np.arange(0, n, every)
    truth = r.T_c_o_true[k]
    s_pos, s_rot = pose_errors(r.T_c_o_est[k], np.broadcast_to(r.T_c_o_des, (len(k), 4, 4)))
    g_pos, _ = pose_errors(truth, np.broadcast_to(r.T_c_o_des, (len(k), 4, 4)))
    header = [
        "t_s", "obj_x_m", "obj_y_m", "obj_z_m", "cam_x_m", "cam_y_m", "cam_z_m",
        "est_x_m", "est_y_m", "est_z_m", "true_x_m", "true_y_m", "true_z_m",
        "servo_pos_mm", "servo_rot_deg", "gt_servo_pos_mm", "pose_age_ms",
        "v_cmd_mps", "w_cmd_dps", "v_cam_mps", "watchdog",
    ]  # fmt: skip
    cols = np.column_stack(
        [
            r.t_s[k],
            r.T_w_o[k, :3, 3],
            r.T_w_c[k, :3, 3],
            r.T_c_o_est[k, :3, 3],
            truth[:, :3, 3],
            s_pos * 1e3,
            np.rad2deg(s_rot),
            g_pos * 1e3,
            (r.t_s[k] - r.est_t_s[k]) * 1e3,
            np.linalg.norm(r.v_cmd_w[k, :3], axis=1),
            np.rad2deg(np.linalg.norm(r.v_cmd_w[k, 3:], axis=1)),
            np.linalg.norm(r.v_cam_w[k, :3], axis=1),
            r.watchdog[k].astype(float),
        ]
    )
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows([[f"{v:.6g}" for v in row] for row in cols])


def plot_motion(r: EpisodeResult, path: str | Path) -> None:
    """The paper's Fig. 5: camera and object displacement along each world axis from their start
    poses (mm), the object also as reconstructed from the camera pose and the estimate (what the
    paper could plot), and the camera's rotation in the world from its start orientation (deg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = r.t_s
    d_obj = (r.T_w_o[:, :3, 3] - r.T_w_o[:1, :3, 3]) * 1e3
    d_cam = (r.T_w_c[:, :3, 3] - r.T_w_c[:1, :3, 3]) * 1e3
    recon = r.T_w_c @ r.T_c_o_est
    d_rec = (recon[:, :3, 3] - recon[:1, :3, 3]) * 1e3
    cam_rot = np.rad2deg(camera_rotation_rad(r.T_w_c))
    fig, axes = plt.subplots(4, 1, sharex=True, figsize=(8, 8), constrained_layout=True)
    for i, name in enumerate("xyz"):
        ax = axes[i]
        ax.plot(t, d_cam[:, i], color="tab:blue", label="camera")
        ax.plot(t, d_obj[:, i], color="tab:orange", label="object (true)")
        ax.plot(t, d_rec[:, i], color="tab:orange", ls=":", lw=1, label="object (camera · estimate)")
        ax.set_ylabel(f"{name} (mm)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[3].plot(t, cam_rot, color="tab:blue")
    axes[3].set_ylabel("camera rot. (deg)")
    axes[3].set_xlabel("time since servo start (s)")
    axes[3].grid(alpha=0.3)
    cfg = r.config
    fig.suptitle(
        f"{cfg.object}, {cfg.tracker}, Z = {cfg.distance_m} m, {cfg.trajectory} at {cfg.speed_mps} m/s"
        + (", feed-forward" if cfg.feedforward else "")
    )
    fig.savefig(path, dpi=110)
    plt.close(fig)
