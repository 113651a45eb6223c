"""The Python face of the EDFT⁺ tracker.

``Tracker(camera, mesh, T_c_o)`` renders the model once at the initial pose ``T_c_o`` (object in
camera, 4×4, metres) to get the sparse point set S*, then registers S* to the event distance field
built from the front-end's active set. Events are numpy structured arrays in OpenEB's ``EventCD``
layout (``x`` u16, ``y`` u16, ``p`` i16, ``t`` i64 µs) in raw sensor pixels.
"""

from __future__ import annotations

import numpy as np

from evservo import _evcore
from evservo.geometry import as_pose
from evservo.models import Symmetry, builtin_symmetries, load_object, to_core_mesh

SOLVERS = ("edft+", "edopts", "edft")
FRONTENDS = ("scarf", "fixed-count", "eros")

Estimate = _evcore.Estimate


def event_columns(events: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Split an EventCD structured array into contiguous x (u16), y (u16), p (i16), t (i64 µs) columns."""
    names = getattr(getattr(events, "dtype", None), "names", None) or ()
    missing = [f for f in ("x", "y", "p", "t") if f not in names]
    if missing:
        raise ValueError(f"events must be a structured array with fields x, y, p, t; missing {missing}")
    x = np.asarray(events["x"])
    y = np.asarray(events["y"])
    if x.size and (x.min() < 0 or y.min() < 0 or x.max() > 65535 or y.max() > 65535):
        raise ValueError("event coordinates must lie in 0..65535")
    return (
        np.ascontiguousarray(x, dtype=np.uint16),
        np.ascontiguousarray(y, dtype=np.uint16),
        np.ascontiguousarray(events["p"], dtype=np.int16),
        np.ascontiguousarray(events["t"], dtype=np.int64),
    )


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


class Tracker:
    """Event-based 6-DoF object tracker (EDFT⁺ and its two baselines).

    Args:
        camera: the event camera (raw sensor geometry with distortion).
        mesh: a built-in object name ("box", "drill", "football"), a mesh path, or a ``trimesh.Trimesh``.
        T_c_o: initial pose of the object in the camera optical frame (4×4, metres).
        solver: "edft+" (1 LM step then ``n_search`` search steps), "edopts" (search only), "edft" (LM only).
        frontend: "scarf" (velocity-invariant, default), "fixed-count" or "eros".
        n_points: size of the model point set S*.
        tau_px, levels: truncation of the distance field (full-resolution pixels) and pyramid depth;
            default: from the object's size in the image (:func:`field_scale`).
        symmetries: the object's rotation symmetries (:func:`evservo.models.symmetries`); default:
            known ones of a built-in object, none otherwise. Rotation about a continuous one is
            unobservable and held at the initial pose's (:attr:`unobservable_axes`); discrete ones
            are ambiguities the tracker cannot resolve (:attr:`ambiguities`).
    """

    def __init__(
        self,
        camera: _evcore.Camera,
        mesh: object,
        T_c_o: np.ndarray,
        solver: str = "edft+",
        frontend: str = "scarf",
        *,
        n_points: int = 1000,
        n_search: int = 4,
        tau_px: float | None = None,
        levels: int | None = None,
        seed: int = 0,
        symmetries: list[Symmetry] | None = None,
    ) -> None:
        if solver not in SOLVERS:
            raise ValueError(f"unknown solver {solver!r}; choose one of {SOLVERS}")
        if frontend not in FRONTENDS:
            raise ValueError(f"unknown front-end {frontend!r}; choose one of {FRONTENDS}")
        T = as_pose(T_c_o, "T_c_o")
        self.camera = camera
        self.solver = solver
        self.frontend = frontend
        self.points_o = model_point_set(camera, mesh, T, n_points=n_points, seed=seed)
        auto_levels, auto_tau = field_scale(image_extent_px(camera, self.points_o, T))
        levels = auto_levels if levels is None else levels
        tau_px = auto_tau if tau_px is None else tau_px
        if symmetries is None:
            symmetries = builtin_symmetries(mesh) if isinstance(mesh, str) else []
        self.symmetries = list(symmetries)
        held = [(*s.axis_o, *s.centre_o) for s in self.symmetries if s.continuous]
        self._core = _evcore.Tracker(
            camera, self.points_o, T, solver=solver, frontend=frontend, n_search=n_search, tau_px=tau_px,
            levels=levels, held_axes=np.array(held, float).reshape(-1, 6),
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
        return self._core.update(*event_columns(events))

    def ingest(self, events: np.ndarray) -> None:
        """Synchronous: ingest a batch without solving."""
        self._core.ingest(*event_columns(events))

    def step(self, n: int = 1) -> Estimate:
        """Synchronous: run ``n`` single updates (one LM or one search step each) on the current events."""
        return self._core.step(n)

    def start(self) -> None:
        """Start the solver thread; then feed it with ``push`` and read ``latest``."""
        self._core.start()

    def push(self, events: np.ndarray) -> None:
        """Queue a batch for the solver thread. Never blocks; if the tracker falls far behind, the oldest
        queued batches are dropped and counted in ``stats()['events_dropped']``."""
        self._core.push(*event_columns(events))

    def latest(self) -> Estimate:
        """The newest estimate."""
        return self._core.latest()

    def stop(self) -> None:
        """Stop the solver thread (no-op if not running)."""
        self._core.stop()

    @property
    def running(self) -> bool:
        return self._core.running

    def reset_pose(self, T_c_o: np.ndarray) -> None:
        """Re-initialise the pose; the front-end keeps its events."""
        self._core.reset_pose(as_pose(T_c_o, "T_c_o"))

    def stats(self) -> dict:
        """Step counts and seconds per kind, dropped events, rejected jumps."""
        return self._core.stats()

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
