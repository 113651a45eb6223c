"""Type stubs for the compiled core (crates/evpy). Frames: ``T_c_o`` = object in camera (4×4, metres).
Pixels: raw sensor grid unless a name says rectified. Time: integer microseconds."""

import os
from collections.abc import Sequence
from typing import Any, TypeAlias, final

import numpy as np
import numpy.typing as npt

__version__: str
__all__ = [
    "EVENT_CD",
    "FRONTENDS",
    "LOST_BELOW",
    "RELOCK_ABOVE",
    "SOLVERS",
    "Camera",
    "DecodeError",
    "Estimate",
    "EventSimulator",
    "Evt3Decoder",
    "Evt3Encoder",
    "Mesh",
    "RawReader",
    "RawSlices",
    "Replay",
    "SimCamera",
    "Tracker",
    "__version__",
    "adaptive_dt_us",
    "distance_field",
    "euclidean_distance",
    "extract_point_set",
    "render",
    "replay_into",
]

# PyO3 classes are built by ``__new__`` and cannot be subclassed (``@final``).
_F64: TypeAlias = npt.NDArray[np.float64]
_F32: TypeAlias = npt.NDArray[np.float32]
_U16: TypeAlias = npt.NDArray[np.uint16]
_I16: TypeAlias = npt.NDArray[np.int16]
_I64: TypeAlias = npt.NDArray[np.int64]

class DecodeError(ValueError): ...

#: OpenEB's EventCD record (x u16 @0, y u16 @2, p i16 @4, t i64 @8; 16 bytes), defined by evcore::EventCd.
EVENT_CD: np.dtype[np.void]
_Events: TypeAlias = npt.NDArray[np.void]

#: The solver and front-end names ``Tracker`` accepts: the only spellings.
SOLVERS: list[str]
FRONTENDS: list[str]
LOST_BELOW: float
RELOCK_ABOVE: float

@final
class Camera:
    def __new__(
        cls,
        width: int,
        height: int,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        dist: tuple[float, float, float, float, float] = ...,
    ) -> Camera: ...
    @staticmethod
    def imx636() -> Camera: ...
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float]
    k: _F64
    def rectified(self) -> Camera: ...
    def project(self, points_c: _F64, distort: bool = True) -> _F64: ...
    def rectify_pixels(self, pixels: _F64) -> _F64: ...

@final
class Estimate:
    T_c_o: _F64
    t_us: int
    seq: int
    step: str
    cost: float
    inlier_fraction: float
    visible_fraction: float
    n_events: int
    confidence: float
    lost: bool
    pushed_ns: int
    published_ns: int
    latency_s: float | None
    oldest_pushed_ns: int
    oldest_latency_s: float | None

@final
class Tracker:
    def __new__(
        cls,
        camera: Camera,
        points_o: _F64 | None,
        T_c_o: _F64 | None,
        solver: str = "edft+",
        frontend: str = "scarf",
        n_search: int = 4,
        tau_px: float = 10.0,
        levels: int = 3,
        lm_iterations: int = 6,
        roi_margin_px: float = 48.0,
        ingest_core_share: float | None = ...,  # 0.5
        max_ingest_rate: float | None = None,
        anti_flicker_hz: list[float] = ...,
        held_axes: _F64 | None = None,
        mesh: Mesh | None = None,
        view_spacing_deg: float = 15.0,
        depth_range_m: tuple[float, float] = ...,  # (0.3, 1.5)
        n_points: int = 1000,
        seed: int = 0,
        lost_below: float = ...,
        relock_above: float = ...,
        search_min_t: float | None = None,
    ) -> Tracker: ...
    def update(self, events: _Events) -> Estimate: ...
    def ingest(self, events: _Events, thin: bool = False) -> None: ...
    def step(self, n: int = 1) -> Estimate: ...
    def start(self) -> None: ...
    def push(self, events: _Events) -> None: ...
    def latest(self) -> Estimate: ...
    def stop(self) -> None: ...
    @property
    def running(self) -> bool: ...
    @property
    def cycle_len(self) -> int: ...
    @property
    def solver_thread_id(self) -> int | None: ...
    def limit_busy_share(self, share: float | None) -> None: ...
    def reset_pose(self, T_c_o: _F64) -> None: ...
    def reset_events(self) -> None: ...
    def advance_time(self, t_us: int) -> None: ...
    def evidence(self) -> dict[str, float]: ...
    def _global_candidates(self, extra: npt.NDArray[np.float64] | None = None) -> list[dict[str, Any]]: ...
    def stats(self) -> dict[str, float]: ...
    def latency(self) -> dict[str, float | None]: ...
    def projected_points(self) -> _F32: ...
    def field(self) -> tuple[_F32, tuple[int, int]]: ...
    def active_mask(self) -> npt.NDArray[np.uint8]: ...

@final
class Mesh:
    def __new__(
        cls,
        vertices: _F64,
        faces: npt.NDArray[np.integer[Any]],
        vertex_intensity: _F64 | None = None,
        uv: _F64 | None = None,
        texture: _F32 | None = None,
        intensity: float = 0.7,
    ) -> Mesh: ...
    n_vertices: int
    n_faces: int
    vertices: _F64
    bounding_radius: float
    centroid: _F64

def render(
    mesh: Mesh,
    camera: Camera,
    T_c_o: _F64,
    roi: tuple[int, int, int, int] | None = None,
    ambient: float = 0.35,
    diffuse: float = 0.65,
    background: float = 0.0,
) -> dict[str, Any]: ...
def extract_point_set(
    mesh: Mesh,
    camera: Camera,
    T_c_o: _F64,
    max_points: int = 1000,
    seed: int = 0,
    depth_jump_m: float = 0.01,
    crease_deg: float = 30.0,
    texture_grad: float = 0.08,
    balance: float = 0.0,
) -> tuple[_F64, npt.NDArray[np.uint8]]: ...
def euclidean_distance(mask: npt.NDArray[np.uint8]) -> _F32: ...
def distance_field(
    mask: npt.NDArray[np.uint8], tau_px: float = ..., levels: int = 3, x0: int = 0, y0: int = 0
) -> list[_F32]: ...

@final
class EventSimulator:
    def __new__(
        cls, width: int, height: int, preset: str = "imx636", seed: int = 0, **overrides: float
    ) -> EventSimulator: ...
    width: int
    height: int
    #: None before the first frame.
    time_us: int | None
    params: dict[str, float]
    thresholds: tuple[_F32, _F32]
    leak_rates_hz: _F64
    def reset(self, frame: _F32, t_us: int) -> None: ...
    def step(self, frame: _F32, t_us: int) -> npt.NDArray[np.void]: ...
    def step_roi(self, frame: _F32, roi: tuple[int, int, int, int], t_us: int) -> npt.NDArray[np.void]: ...

@final
class SimCamera:
    """The rendered event camera: object mesh (and optional occluder meshes, e.g. the robot arms)
    over a uniform or textured-plane background, the lens's distortion, the sensor model."""

    def __new__(
        cls,
        camera: Camera,
        mesh: Mesh,
        preset: str = "imx636",
        seed: int = 0,
        T_c_bg: _F64 | None = None,
        cell_m: float = 0.04,
        background_intensity: float = 0.1,
        ambient: float = 0.35,
        diffuse: float = 0.65,
        margin_px: int = 4,
        sparse: bool = True,
        **overrides: float,
    ) -> SimCamera:
        """``sparse``: redraw and step only the tiles that can change (default); False is the
        full-frame reference path, with the same events."""
        ...
    def advance(
        self,
        T_c_o: _F64,
        t_us: int,
        T_c_bg: _F64 | None = None,
        occluders: _F64 | None = None,
        ticks: list[int] | None = None,
    ) -> npt.NDArray[np.void]:
        """Render at ``t_us`` and step the sensor; ``occluders``: (N, 4, 4) poses of the N
        occluder meshes in the camera (required once occluders are set); ``ticks`` (µs, between
        the previous frame and ``t_us``): also step the sensor at these times on the intensities
        interpolated linearly between the previous render and this one."""
        ...
    def set_occluders(self, meshes: list[Mesh]) -> None:
        """Meshes drawn with the object and z-tested against it; the next frame is a full frame."""
        ...
    def max_displacement_px(self, T_a: _F64, T_b: _F64) -> float: ...
    def occluder_displacement_px(self, A: _F64, B: _F64) -> float:
        """Largest raw-pixel motion of the occluders' visible vertices between (N, 4, 4) pose stacks."""
        ...
    def frame(self) -> _F32: ...
    n_occluders: int
    last_roi: tuple[int, int, int, int, bool] | None
    time_us: int | None
    camera: Camera
    canvas: Camera

def adaptive_dt_us(max_flow_px_per_s: float, lam: float = 0.5, min_rate_hz: float = 30.0) -> int: ...

@final
class RawReader:
    def __new__(cls, path: str | os.PathLike[str]) -> RawReader: ...
    width: int
    height: int
    format: str
    header: list[tuple[str, str]]
    def read_n_events(self, n: int) -> _Events | None: ...
    def read_until(self, t_us: int) -> _Events | None: ...
    def read_all(self) -> _Events: ...
    def peek_t(self) -> int | None: ...

@final
class RawSlices:
    def __new__(
        cls, path: str | os.PathLike[str], *, delta_t_us: int | None = None, n_events: int | None = None
    ) -> RawSlices: ...
    def __iter__(self) -> RawSlices: ...
    def __next__(self) -> tuple[_Events, list[int]]: ...

@final
class Replay:
    @property
    def running(self) -> bool: ...
    def wait(self, timeout: float | None = None) -> bool: ...
    def stop(self) -> None: ...
    def stats(self) -> dict[str, int | float | None]: ...
    def updates(self) -> list[tuple[int, int, Estimate]]: ...
    def snapshots(self) -> list[tuple[int, _F32, tuple[int, int], _F32]]: ...
    def __enter__(self) -> Replay: ...
    def __exit__(self, _exc_type: object | None, _exc: object | None, _tb: object | None) -> bool: ...

def replay_into(
    tracker: Tracker,
    path: str | os.PathLike[str],
    batch_us: int = 1000,
    speed: float | None = ...,
    mode: str = "push",
    until_us: int | None = None,
    snapshots_at: Sequence[int] = ...,
) -> Replay: ...

@final
class Evt3Decoder:
    def __new__(cls, width: int, height: int) -> Evt3Decoder: ...
    def decode(self, data: bytes) -> _Events: ...
    @property
    def pending_bytes(self) -> int: ...

@final
class Evt3Encoder:
    def __new__(cls, width: int, height: int) -> Evt3Encoder: ...
    def encode(self, events: _Events) -> bytes: ...
