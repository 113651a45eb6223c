"""The Python face of the EDFT⁺ tracker.

``Tracker(camera, mesh, T_c_o)`` renders the model once at the initial pose ``T_c_o`` (object in
camera, 4×4, metres) to get the sparse point set S*, then registers S* to the event distance field
built from the front-end's active set. Events are numpy structured arrays in OpenEB's ``EventCD``
layout (``x`` u16, ``y`` u16, ``p`` i16, ``t`` i64 µs) in raw sensor pixels.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterable

import numpy as np

from evservo import _evcore
from evservo.events import as_event_cd
from evservo.geometry import as_pose
from evservo.models import BUILTIN_OBJECTS, Symmetry, builtin_symmetries, load_object, to_core_mesh
from evservo.models import symmetries as find_symmetries

#: The solver and front-end names the core accepts (parsed in Rust only; these lists come from it).
SOLVERS: tuple[str, ...] = tuple(_evcore.SOLVERS)
FRONTENDS: tuple[str, ...] = tuple(_evcore.FRONTENDS)

PRIORITIES = ("normal", "high")
#: SCHED_FIFO priority of the solver thread with priority="high": above ordinary real-time helpers
#: (1-49 by convention) and below the kernel's own threaded interrupt handlers (50).
FIFO_PRIORITY = 40
#: With priority="high" the solver thread keeps busy at most this share of the time while it has
#: work, resting in short pauses after its steps. Linux reserves 5 % of every second (by default)
#: for ordinary tasks on a CPU a real-time thread keeps busy and takes it in one ~50 ms piece, which
#: would stall the solver once a second; resting 10 % in slivers leaves nothing to take.
REALTIME_BUSY_SHARE = 0.9
_REALTIME_POLICIES = {getattr(os, name) for name in ("SCHED_FIFO", "SCHED_RR") if hasattr(os, name)}

Estimate = _evcore.Estimate


def _frequencies(hz: float | Iterable[float] | None) -> list[float]:
    if hz is None:
        return []
    return [float(hz)] if isinstance(hz, int | float) else [float(f) for f in hz]


def _usable_cpus() -> set[int]:
    if hasattr(os, "sched_getaffinity"):
        return set(os.sched_getaffinity(0))
    return set(range(os.cpu_count() or 1))


def model_point_set(
    camera: _evcore.Camera, mesh: object, T_c_o: np.ndarray, n_points: int = 1000, seed: int = 0
) -> np.ndarray:
    """S*: edge points of one rendering of ``mesh`` at ``T_c_o``, back-projected, in the object frame (N, 3)."""
    core_mesh = mesh if isinstance(mesh, _evcore.Mesh) else to_core_mesh(load_object(mesh))
    points, _kinds = _evcore.extract_point_set(
        core_mesh, camera.rectified(), as_pose(T_c_o, "T_c_o"), max_points=n_points, seed=seed
    )
    return points


def image_extent_px(camera: _evcore.Camera, points_o: np.ndarray, T_c_o: np.ndarray) -> float:
    """Diagonal (pixels) of the bounding box of ``points_o`` (object frame) projected at ``T_c_o``."""
    p = points_o @ T_c_o[:3, :3].T + T_c_o[:3, 3]
    uv = np.column_stack([camera.fx * p[:, 0] / p[:, 2], camera.fy * p[:, 1] / p[:, 2]])
    return float(np.hypot(*(uv.max(axis=0) - uv.min(axis=0))))


def field_scale(extent_px: float) -> tuple[int, float]:
    """(pyramid levels, truncation τ in full-resolution pixels) for an object spanning ``extent_px``.

    The coarsest level must still show the object at about 40 px or more (at 10 px its edges merge
    into one blob and LM registers to the blob), and τ must stay below about an eighth of its size
    (a wider basin reaches across the object to the opposite edge). Objects of 160 px and more get
    the paper's 3 levels and τ = 10 px."""
    levels = 1 + int(extent_px >= 80.0) + int(extent_px >= 160.0)
    return levels, float(np.clip(extent_px / 8.0, 4.0, 10.0))


class AmbiguousModelWarning(UserWarning):
    """The model has a continuous rotation symmetry (a sphere, a plain cylinder): part of its
    attitude cannot be observed, and the tracker's full pose is only as good as its prior there."""


def _default_symmetries(mesh: object, camera: _evcore.Camera) -> list[Symmetry]:
    """A built-in's known symmetries; any other mesh's found by rendering it (a core mesh,
    without its source shape, is taken to have none)."""
    if isinstance(mesh, str) and mesh in BUILTIN_OBJECTS:
        return builtin_symmetries(mesh)
    if isinstance(mesh, _evcore.Mesh):
        return []
    return find_symmetries(mesh, camera)  # type: ignore[arg-type]


class Tracker:
    """Event-based 6-DoF object tracker (EDFT⁺ and its two baselines).

    Args:
        camera: the event camera (raw sensor geometry with distortion).
        mesh: a built-in object name ("box", "drill", "football"), a mesh path, or a ``trimesh.Trimesh``.
        T_c_o: initial pose of the object in the camera optical frame (4×4, metres), or None to start
            lost and search the whole image for the object (this turns ``reacquire`` on).
        solver: "edft+" (1 LM step then ``n_search`` search steps), "edopts" (search only), "edft" (LM only).
        frontend: "scarf" (velocity-invariant, default), "fixed-count" or "eros".
        n_points: size of the model point set S*.
        tau_px, levels: truncation of the distance field (full-resolution pixels) and pyramid depth;
            default: from the object's size in the image (:func:`field_scale`).
        symmetries: the object's rotation symmetries (:func:`evservo.models.symmetries`); default:
            known ones of a built-in object, found by rendering for any other mesh (a second or
            two). Rotation about a continuous one is
            unobservable and held at the initial pose's (:attr:`unobservable_axes`); discrete ones
            are ambiguities the tracker cannot resolve (:attr:`ambiguities`).
        ingest_core_share: while running, ``push`` thins the stream so that ingest uses at most this
            share of the caller's core (measured on the fly); None keeps every event.
        max_ingest_rate: instead, a fixed cap on the events ingested per second of event time.
        anti_flicker_hz: drop events of pixels firing periodically at these light flicker frequencies
            (Hz; 100 under 50 Hz mains, 120 under 60 Hz, or both) before the front-end.
        reacquire: render a bank of viewpoint templates at start-up (S* every ``view_spacing_deg``
            over the viewing sphere, searched over ``depth_range_m``, metres), so that the tracker
            finds the object again by itself while lost (one global search per update) and takes S*
            from the view nearest to the current attitude. It costs a few hundred renders at
            construction (seconds). Default: only when ``T_c_o`` is None.
        lost_below, relock_above: the estimate turns ``lost`` when its confidence falls below
            ``lost_below`` and is trusted again from ``relock_above`` on (default: the core's,
            calibrated in benches/RESULTS.md "Confidence and loss").
        search_min_t: while the object is partly out of view, a search step moves to its best candidate only
            when that candidate beats staying put by this many standard errors of the per-point gains in
            LM's robust loss (noise-level wins ratchet small, far objects at the border; benches/RESULTS.md,
            issue 13 rounds 7 and 8); with it on, the pose is also held after an event dropout until the
            fresh field has as many fired pixels as S* has points. Default None: 3 for "edft+", 0 (the
            paper's plain argmin) else.

    Every estimate carries ``confidence`` (0–1: how much better than chance the events support the
    pose) and ``lost`` (the pose is not to be trusted: not yet confirmed by an update, confidence
    below the tracker's threshold, the model mostly out of view, or stale events while the object
    was moving). ``latest()`` reads ``lost=True`` until the first update has locked onto the events.
    """

    def __init__(
        self,
        camera: _evcore.Camera,
        mesh: object,
        T_c_o: np.ndarray | None,
        solver: str = "edft+",
        frontend: str = "scarf",
        *,
        n_points: int = 1000,
        n_search: int = 4,
        tau_px: float | None = None,
        levels: int | None = None,
        seed: int = 0,
        ingest_core_share: float | None = 0.5,
        max_ingest_rate: float | None = None,
        anti_flicker_hz: float | Iterable[float] | None = None,
        symmetries: list[Symmetry] | None = None,
        reacquire: bool | None = None,
        view_spacing_deg: float = 15.0,
        depth_range_m: tuple[float, float] = (0.3, 1.5),
        lost_below: float | None = None,
        relock_above: float | None = None,
        search_min_t: float | None = None,
    ) -> None:
        T = None if T_c_o is None else as_pose(T_c_o, "T_c_o")
        if reacquire is None:
            reacquire = T is None
        elif T is None and not reacquire:
            raise ValueError("starting without a pose (T_c_o=None) needs reacquire=True to search for the object")
        core_mesh = mesh if isinstance(mesh, _evcore.Mesh) else to_core_mesh(load_object(mesh))
        self.camera = camera
        self.solver = solver
        self.frontend = frontend
        #: S* at the initial pose (None when starting without one: the bank's views provide it).
        self.points_o = None if T is None else model_point_set(camera, core_mesh, T, n_points=n_points, seed=seed)
        # Without a pose the object's image size is unknown: the paper's pyramid and τ.
        auto_levels, auto_tau = (3, 10.0) if T is None else field_scale(image_extent_px(camera, self.points_o, T))
        levels = auto_levels if levels is None else levels
        tau_px = auto_tau if tau_px is None else tau_px
        if symmetries is None:
            symmetries = _default_symmetries(mesh, camera)
        self.symmetries = list(symmetries)
        if self.unobservable_axes:
            warnings.warn(
                "the model's attitude is ambiguous: rotation about the object-frame axes "
                f"{[tuple(round(a, 3) for a in ax) for ax in self.unobservable_axes]} is unobservable from its "
                "edges; the tracker holds it at the initial pose's (Tracker.unobservable_axes)",
                AmbiguousModelWarning,
                stacklevel=2,
            )
        held = [(*s.axis_o, *s.centre_o) for s in self.symmetries if s.continuous]
        self._core = _evcore.Tracker(
            camera, self.points_o, T, solver=solver, frontend=frontend, n_search=n_search, tau_px=tau_px,
            levels=levels, ingest_core_share=ingest_core_share, max_ingest_rate=max_ingest_rate,
            anti_flicker_hz=_frequencies(anti_flicker_hz), held_axes=np.array(held, float).reshape(-1, 6),
            mesh=core_mesh if reacquire else None, view_spacing_deg=view_spacing_deg,
            depth_range_m=depth_range_m, n_points=n_points, seed=seed, search_min_t=search_min_t,
            **{k: v for k, v in (("lost_below", lost_below), ("relock_above", relock_above)) if v is not None},
        )  # fmt: skip

    @property
    def unobservable_axes(self) -> list[tuple[float, float, float]]:
        """Object-frame axes whose rotation the edges cannot observe (held at the initial pose's)."""
        return [s.axis_o for s in self.symmetries if s.continuous]

    @property
    def ambiguities(self) -> list[Symmetry]:
        """Discrete symmetries: turns by a multiple of ``period_deg`` about ``axis_o`` look the same."""
        return [s for s in self.symmetries if not s.continuous]

    def update(self, events: np.ndarray) -> Estimate:
        """Synchronous: ingest the batch, run one cycle (1 LM + N search, or N+1 steps), return the estimate."""
        return self._core.update(as_event_cd(events))

    def ingest(self, events: np.ndarray, thin: bool = False) -> None:
        """Synchronous: ingest a batch without solving; with ``thin``, keep the uniform fraction that
        :meth:`push` would keep under overload (``ingest_core_share`` / ``max_ingest_rate``)."""
        self._core.ingest(as_event_cd(events), thin=thin)

    def advance_time(self, t_us: int) -> None:
        """The stream has reached ``t_us`` (µs) with no events after those given (running or not), as a
        decoder's empty slice or a driver's empty packet says. The sensor's background activity fires
        every few µs, so 20 ms of stream time without one is a dropout: the estimate reads ``lost``
        until the events are back and support the pose again. ``ValueError`` for a time before the
        newest event."""
        self._core.advance_time(int(t_us))

    def update_slice(self, events: np.ndarray, end_us: int, newest_us: int | None) -> Estimate:
        """Synchronous: ``update`` with one time slice of a stream, ending at ``end_us`` (µs,
        exclusive), all of whose earlier events were given (``newest_us``: the newest of them, None
        before any). An empty slice first advances the stream time to its end (``advance_time``): the
        source vouches that no event came, so a gap in the events reads ``lost`` 20 ms in."""
        if not len(events):
            self.advance_time(end_us - 1 if newest_us is None else max(end_us - 1, newest_us))
        return self.update(events)

    def step(self, n: int = 1) -> Estimate:
        """Synchronous: run ``n`` single updates (one LM or one search step each) on the current events."""
        return self._core.step(n)

    @property
    def cycle_len(self) -> int:
        """Steps per cycle (1 LM + N search for edft+, N + 1 steps otherwise); the thread rests after
        this many steps without new events. Read it before :meth:`start`."""
        return self._core.cycle_len

    def start(self, cpu: int | Iterable[int] | None = None, priority: str = "normal") -> str:
        """Start the solver thread; then feed it with ``push`` and read ``latest``.

        Args:
            cpu: pin the solver thread to this CPU (or set of CPUs), e.g. one the producer does not
                use; None leaves it to the OS.
            priority: "normal" (also when the calling thread runs at real-time priority, whose
                policy a new thread would inherit), or "high" for real-time scheduling (SCHED_FIFO)
                so that other processes cannot preempt the solver. That needs CAP_SYS_NICE or an rtprio limit
                (``ulimit -r``); where the OS refuses, the thread runs at normal priority and a
                :class:`RuntimeWarning` says why.

        Returns the priority in effect ("normal" or "high"). A bad ``cpu`` or ``priority`` raises
        ``ValueError`` and leaves the tracker stopped.
        """
        if priority not in PRIORITIES:
            raise ValueError(f"unknown priority {priority!r}; choose one of {PRIORITIES}")
        cpus = None if cpu is None else ({int(cpu)} if isinstance(cpu, int) else {int(c) for c in cpu})
        if cpus is not None and not cpus <= _usable_cpus():
            raise ValueError(f"cpu {sorted(cpus)} is not among this process's CPUs {sorted(_usable_cpus())}")
        self._core.start()
        # A new thread inherits its creator's policy: from a real-time caller, "normal" would not be.
        inherited_realtime = hasattr(os, "sched_getscheduler") and os.sched_getscheduler(0) in _REALTIME_POLICIES
        if cpus is None and priority == "normal" and not inherited_realtime:
            return "normal"
        tid = self._core.solver_thread_id
        if tid is None or not hasattr(os, "sched_setaffinity"):
            self._core.stop()
            raise ValueError("CPU pinning and priority need Linux (the solver thread id is unknown here)")
        if cpus is not None:
            os.sched_setaffinity(tid, cpus)
        if priority == "normal":
            if inherited_realtime:
                os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
            return "normal"
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))
        except PermissionError:
            warnings.warn(
                "priority='high': the OS does not permit SCHED_FIFO for this process (it needs CAP_SYS_NICE, "
                "or an rtprio limit, e.g. `ulimit -r 50` or @realtime in /etc/security/limits.conf); "
                "the solver runs at normal priority",
                RuntimeWarning,
                stacklevel=2,
            )
            return "normal"
        self._core.limit_busy_share(REALTIME_BUSY_SHARE)
        return "high"

    def push(self, events: np.ndarray) -> None:
        """Ingest a batch into the running tracker on the calling thread (the GIL is released) and wake
        the solver, which never waits for it. When the offered rate is more than ingest can take
        within its share of this core (``ingest_core_share``, or ``max_ingest_rate``), a uniform
        fraction of each batch is kept, so the pose stays fresh; ``stats()`` counts events offered,
        ingested and dropped. Raises ``ValueError`` for a bad batch (nothing of it is ingested)."""
        self._core.push(as_event_cd(events))

    def replay(
        self, path: str | os.PathLike, batch_us: int = 1000, speed: float | None = 1.0, *, mode: str = "push",
        until_us: int | None = None, snapshots_at: Iterable[int] = (),
    ) -> _evcore.Replay:  # fmt: skip
        """Feed a Prophesee RAW file to the tracker from a Rust thread: decoded, cut into time slices
        of ``batch_us`` (µs; the slices of ``evservo.io.open_events``, with times that step back
        clamped to the newest one, none starting after ``until_us``), without the GIL or any Python
        per batch. ``speed`` 1.0 replays in real time, 2.0 twice as fast, None as fast as the
        tracker takes it.

        ``mode="push"``: into the running tracker, ingested as ``push`` does. ``mode="update"``: the
        tracker is stopped and each slice (empty ones too) is one synchronous ``update``, so the
        poses are exactly those of calling ``update`` per slice; ``Replay.updates()`` returns
        (slice end µs, events, Estimate) for every update so far and ``Replay.snapshots()`` the
        field and projected model after the slices numbered in ``snapshots_at`` (0 = the first).
        In both modes an empty slice advances the stream time to its end (:meth:`advance_time`: the
        file vouches that no event came), so a gap in the recording reads ``lost`` after 20 ms.

        Returns a :class:`~evservo._evcore.Replay`: ``wait(timeout)`` (raises the replay's error:
        ``DecodeError`` for a corrupt file; Ctrl-C stops it), ``stop()``, ``running``, ``stats()``;
        a ``with`` block stops it on exit. Raises ``FileNotFoundError``, ``DecodeError`` for an
        unreadable header, ``RuntimeError`` unless the tracker is running (push) or stopped (update)."""
        return _evcore.replay_into(
            self._core, os.fspath(path), batch_us, speed, mode=mode, until_us=until_us, snapshots_at=list(snapshots_at)
        )

    def latest(self) -> Estimate:
        """The newest estimate, without any lock (safe from any thread, also during start/stop)."""
        return self._core.latest()

    def stop(self) -> None:
        """Stop the solver thread (no-op if not running)."""
        self._core.stop()

    @property
    def running(self) -> bool:
        return self._core.running

    @property
    def solver_thread_id(self) -> int | None:
        """Kernel id of the running solver thread (Linux; None when not running or unknown)."""
        return self._core.solver_thread_id

    def reset_pose(self, T_c_o: np.ndarray) -> None:
        """Re-initialise the pose (synchronous only); the front-end keeps its events. The estimate
        reads ``lost`` until the next update confirms the pose."""
        self._core.reset_pose(as_pose(T_c_o, "T_c_o"))

    def reset_events(self) -> None:
        """Forget every event and the time line (running or not); the pose stays. Time may then start
        anew, e.g. after the camera restarted its clock or a batch with corrupt times was refused."""
        self._core.reset_events()

    def evidence(self) -> dict[str, float]:
        """The parts of the last tracked pose's confidence (synchronous only; fractions 0–1):
        ``support`` (model points near an active pixel, and near a recent event while the model
        moves), ``support_any`` (without the freshness test), ``chance`` (pixels around the model
        near an active pixel), ``support_tight`` and ``chance_tight`` (the same within 1 px),
        ``visible`` (model points in the image), ``explained`` (the share of the active pixels around the
        model that lie near it: measured for global-search candidates only, else 0), and ``active`` /
        ``active_around`` (the share of the model's 8×8 sensor blocks, and of the other blocks around
        it, that fired within the last 10 ms)."""
        return self._core.evidence()

    def stats(self) -> dict[str, float]:
        """Live counters: ``lm_steps``, ``search_steps``, ``lm_seconds``, ``search_seconds``,
        ``events_offered``, ``events_ingested``, ``events_dropped`` (thinned under overload),
        ``jumps_rejected``, and the global searches run while lost: ``reacquire_passes``,
        ``reacquire_seconds``."""
        return self._core.stats()

    def latency(self) -> dict[str, float | None]:
        """Event-to-pose latency booked by the tracker itself (seconds; see ``Estimate.latency_s``
        and ``Estimate.oldest_latency_s``): ``batch_*`` over every pushed batch (publication of the
        first pose that contains it minus its own push: the latency of each of its events),
        ``newest_*`` over the batches that were the newest event behind some pose, ``oldest_*`` a
        bound for every batch (the same publication minus the push of the oldest batch that pose
        took in). Keys ``*_n`` (samples), ``*_p50_s``, ``*_p99_s``, ``*_max_s`` (None before any
        sample)."""
        return self._core.latency()

    def projected_points(self) -> np.ndarray:
        """S* projected at the current pose, (N, 2) rectified pixels."""
        return self._core.projected_points()

    def field(self) -> tuple[np.ndarray, tuple[int, int]]:
        """The last full-resolution distance field and the (x0, y0) of its region."""
        return self._core.field()

    def active_mask(self) -> np.ndarray:
        """The front-end's active pixels, (H, W) uint8 in the rectified grid."""
        return self._core.active_mask()

    def __enter__(self) -> Tracker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
