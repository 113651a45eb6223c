"""Robustness scenarios: open-loop streams in which the tracker's pose becomes wrong on purpose.

The camera is static; the object follows a scripted pose ``T_c_o(t)`` (camera frame, metres), and
its events can be hidden (full occlusion: only the sensor's background activity remains), replaced
by dense uniform noise, or come from another object than the tracker's model. Every millisecond the
tracker ingests that millisecond's events and runs one step (one LM or one search step), and each
update is scored against the truth:

- the pose is *wrong* as :func:`evservo.runtime.loss.wrong_pose` says (the loops' definition: 30 mm
  or 10° at Z = 0.6 m, scaled with depth), or whenever the object cannot be seen (hidden or out of the view);
- *confidently wrong*: wrong while ``est.lost`` is False;
- *false loss*: ``est.lost`` while the pose is right and the object in view.

:func:`score` turns one run into the robustness figures (detection delay, re-lock time, longest
confidently-wrong spell, false-loss rate); the per-update ``confidence`` and ``wrong`` arrays are the
labelled data the confidence's ROC is computed from.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from evservo import _evcore, geometry
from evservo.events import EVENT_CD
from evservo.runtime.loss import spells, wrong_pose
from evservo.sim.sources import EventSource, make_event_source
from evservo.synth import EdgeEventGenerator
from evservo.tracking import Tracker, model_point_set

BACKGROUND_HZ = 50_000.0  # the sensor's background activity over the whole array
TICK_US = 1000
START_Z_M = 0.7
START_ROTVEC = (0.35, -0.45, 0.1)


def start_pose(x_m: float = 0.0, y_m: float = 0.0, z_m: float = START_Z_M, rotvec=START_ROTVEC) -> np.ndarray:
    """The object at (x, y, z) in the camera, turned by ``rotvec`` from facing it."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = (x_m, y_m, z_m)
    return T


@dataclass(frozen=True)
class Scenario:
    """A scripted stream. ``truth(t_s)``: the object in the camera at ``t_s``. ``hidden(t_s)``: its
    events are suppressed. ``noise_hz(t_s)``: extra uniform noise (events/s over the sensor).
    ``model``: the tracker's model (``object`` fires the events). ``start_lost``: the tracker gets no
    initial pose. ``reappear_s``: when the object can be seen again after it was not (for the
    re-lock time), None if it never comes back."""

    name: str
    duration_s: float
    truth: Callable[[float], np.ndarray]
    hidden: Callable[[float], bool] = lambda _t: False
    noise_hz: Callable[[float], float] = lambda _t: 0.0
    object: str = "box"
    model: str = "box"
    start_lost: bool = False
    reappear_s: float | None = None


def _slide(v_mps: np.ndarray, t0_s: float = 0.0, T0: np.ndarray | None = None) -> Callable[[float], np.ndarray]:
    """Constant velocity ``v_mps`` (camera frame) from ``T0`` starting at ``t0_s``."""
    T0 = start_pose() if T0 is None else T0

    def truth(t: float) -> np.ndarray:
        T = T0.copy()
        T[:3, 3] += np.asarray(v_mps) * max(0.0, t - t0_s)
        return T

    return truth


def _circle(radius_m: float = 0.05, period_s: float = 1.5, T0: np.ndarray | None = None):
    T0 = start_pose() if T0 is None else T0

    def truth(t: float) -> np.ndarray:
        T = T0.copy()
        a = 2 * np.pi * t / period_s
        T[:3, 3] += radius_m * np.array([np.sin(a), 1 - np.cos(a), 0.0])
        return T

    return truth


def _leave_and_return(t_out_s: float, t_back_s: float):
    """Slides out to the right at 0.4 m/s from t = 0.3 s; from ``t_back_s`` on it sits at another
    place and attitude on the left, drifting slowly."""
    out = _slide(np.array([0.4, 0.0, 0.0]), 0.3)
    back = _slide(np.array([0.0, 0.05, 0.0]), t_back_s, start_pose(-0.12, -0.04, 0.65, (0.1, 0.6, -0.3)))
    return lambda t: out(t) if t < t_back_s else back(t)


def _between(t0: float, t1: float) -> Callable[[float], bool]:
    return lambda t: t0 <= t < t1


def scenarios() -> dict[str, Scenario]:
    """The robustness suite's scenarios by name."""
    out = [
        Scenario("occlusion-0.5s", 2.5, _circle(), hidden=_between(1.0, 1.5), reappear_s=1.5),
        Scenario("occlusion-2s", 4.0, _circle(), hidden=_between(1.0, 3.0), reappear_s=3.0),
        Scenario("leave-return", 3.0, _leave_and_return(1.0, 1.8), reappear_s=1.8),
        Scenario("slow-leave", 3.0, _slide(np.array([0.15, 0.0, 0.0]), 0.2)),
        Scenario("fast-leave", 1.5, _slide(np.array([1.5, 0.0, 0.0]), 0.3)),
        Scenario("still-then-leave", 2.0, _slide(np.array([0.5, 0.1, 0.0]), 0.5)),
        Scenario("events-stop", 3.0, _circle(), hidden=_between(1.0, 2.0), reappear_s=2.0),
        Scenario("wrong-model", 1.5, _circle(), object="box", model="drill"),
        Scenario("pure-noise", 2.0, _circle(), hidden=lambda t: t >= 1.0, noise_hz=lambda t: 1e7 if t >= 1.0 else 0.0),
        Scenario("start-without-pose", 2.0, _circle(), start_lost=True, reappear_s=0.0),
        Scenario("tracking", 3.0, _circle()),
    ]
    return {s.name: s for s in out}


@dataclass
class ScenarioRun:
    """Per-update record (one update per millisecond tick): time (s), confidence, lost flag, pose
    error against the truth (m, rad), whether the object could be seen, whether the pose is wrong."""

    scenario: Scenario
    t_s: np.ndarray
    confidence: np.ndarray
    lost: np.ndarray
    pos_err_m: np.ndarray
    rot_err_rad: np.ndarray
    visible: np.ndarray
    wrong: np.ndarray


def _in_view(rect: _evcore.Camera, points_o: np.ndarray, T: np.ndarray, min_fraction: float = 0.5) -> bool:
    """At least ``min_fraction`` of the model's points project into the (rectified) image; the
    tracker's own rule (``MIN_VISIBLE`` in evcore's confidence) for an object that left the view."""
    pc = points_o @ T[:3, :3].T + T[:3, 3]
    if np.any(pc[:, 2] <= 0):
        return False
    uv = rect.project(pc)
    camera = rect
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    return bool(np.mean(inside) >= min_fraction)


def _source(name: str, camera: _evcore.Camera, obj: str, T0: np.ndarray, seed: int) -> EventSource:
    """The object's events from ``T0`` at t = −0.1 s: ``edges`` (its edge points, 20 % noise) or
    ``render`` (the rendered event camera, with its background plane)."""
    if name == "edges":
        dense = model_point_set(camera, obj, T0, n_points=10_000, seed=seed)
        return EdgeEventGenerator(camera, dense, T0, -100_000, noise_fraction=0.2, seed=seed)
    return make_event_source(name, camera, obj, T0, -100_000, seed)


def run_scenario(
    sc: Scenario,
    solver: str = "edft+",
    seed: int = 0,
    source: str = "edges",
    make_tracker: Callable[[_evcore.Camera, str, np.ndarray | None, str], Tracker] | None = None,
) -> ScenarioRun:
    """Play ``sc`` on the event ``source`` (``edges`` or ``render``; hiding the object drops all of
    its events, so a rendered scene's background goes dark too) into a tracker
    (``make_tracker(camera, model, T_c_o0 or None, solver)``; default
    :class:`~evservo.tracking.Tracker`) and score every update."""
    camera = _evcore.Camera.imx636()
    rng = np.random.default_rng(seed)
    T0 = sc.truth(0.0)

    def preroll(k: int) -> np.ndarray:
        T = T0.copy()
        T[0, 3] += 0.006 * (k / 100.0) ** 2
        return T

    src = _source(source, camera, sc.object, preroll(-100), seed)
    build = make_tracker or (lambda cam, model, T, s: Tracker(cam, model, T, solver=s, seed=seed))
    tracker = build(camera, sc.model, None if sc.start_lost else T0, solver)
    # Pre-roll: the object glides into its start pose so the front-end holds its edges (as on the bench).
    for k in range(-99, 1):
        tracker.ingest(src.events_until(k * TICK_US, preroll(k)))
    points_model = model_point_set(camera, sc.object, T0, n_points=400, seed=seed)
    n = round(sc.duration_s * 1e6) // TICK_US
    rec = {k: np.empty(n) for k in ("t_s", "confidence", "pos_err_m", "rot_err_rad")}
    lost, visible, wrong = np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool)
    W, H = camera.width, camera.height
    rect = camera.rectified()
    # With another model than the object, no pose of the tracker's model is right.
    mismatch = sc.model != sc.object
    for k in range(n):
        t_us = (k + 1) * TICK_US
        t = t_us * 1e-6
        T = sc.truth(t)
        ev = src.events_until(t_us, T)
        if sc.hidden(t):
            ev = ev[:0]
        n_noise = rng.poisson((BACKGROUND_HZ + sc.noise_hz(t)) * TICK_US * 1e-6)
        if n_noise:
            noise = np.empty(n_noise, EVENT_CD)
            idx = rng.integers(0, W * H, n_noise)
            noise["x"], noise["y"] = idx % W, idx // W
            noise["p"] = rng.integers(0, 2, n_noise)
            noise["t"] = rng.integers(t_us - TICK_US, t_us, n_noise)
            # With the dtype: concatenate would pack EVENT_CD, and the tracker copy it back.
            ev = np.sort(np.concatenate([ev, noise], dtype=EVENT_CD), order="t", kind="stable")
        tracker.ingest(ev)
        est = tracker.step(1)
        seen = not sc.hidden(t) and _in_view(rect, points_model, T)
        rec["t_s"][k], rec["confidence"][k] = t, est.confidence
        rec["pos_err_m"][k] = geometry.translation_error_m(est.T_c_o, T)
        rec["rot_err_rad"][k] = geometry.rotation_error_rad(est.T_c_o, T)
        lost[k], visible[k] = est.lost, seen
        err_m, err_rad = geometry.translation_error_m(est.T_c_o, T), geometry.rotation_error_rad(est.T_c_o, T)
        wrong[k] = mismatch or not seen or bool(wrong_pose(err_m, err_rad, T[2, 3]))
    return ScenarioRun(sc, lost=lost, visible=visible, wrong=wrong, **rec)


def score(run: ScenarioRun) -> dict:
    """Robustness figures of one run (times in ms; NaN where the event did not occur):

    ``detection_delay_ms``: longest time from the pose becoming wrong to ``lost`` (over the spells of
    wrong poses); ``relock_ms``: from ``scenario.reappear_s`` to the first right, trusted update
    (inf if never); ``confident_wrong_ms``: longest spell of wrong and not lost; ``false_loss``:
    fraction of the right, visible updates flagged lost."""
    dt_ms = TICK_US * 1e-3
    cw = run.wrong & ~run.lost
    delays = []
    for s, e in spells(run.wrong):
        flagged = np.flatnonzero(run.lost[s:e])
        delays.append((flagged[0] if len(flagged) else e - s) * dt_ms)
    right = ~run.wrong & run.visible
    relock = float("nan")
    if run.scenario.reappear_s is not None:
        ok = np.flatnonzero(right & ~run.lost & (run.t_s >= run.scenario.reappear_s))
        relock = (run.t_s[ok[0]] - run.scenario.reappear_s) * 1e3 if len(ok) else float("inf")
    longest = max((e - s for s, e in spells(cw)), default=0) * dt_ms
    return {
        "detection_delay_ms": max(delays) if delays else float("nan"),
        "relock_ms": relock,
        "confident_wrong_ms": longest,
        "false_loss": float(np.mean(run.lost[right])) if right.any() else float("nan"),
        "updates": len(run.t_s),
    }
