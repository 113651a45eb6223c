"""Type stubs for the compiled core (crates/evpy). Frames: ``T_c_o`` = object in camera (4×4, metres).
Pixels: raw sensor grid unless a name says rectified. Time: integer microseconds."""

from typing import Any

import numpy as np
import numpy.typing as npt

__version__: str

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
U16 = npt.NDArray[np.uint16]
I16 = npt.NDArray[np.int16]
I64 = npt.NDArray[np.int64]

class DecodeError(ValueError): ...

class Camera:
    def __init__(
        self,
        width: int,
        height: int,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        dist: tuple[float, float, float, float, float] = ...,
    ) -> None: ...
    @staticmethod
    def imx636() -> Camera: ...
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float]
    k: F64
    def rectified(self) -> Camera: ...
    def project(self, points_c: F64, distort: bool = True) -> F64: ...
    def rectify_pixels(self, pixels: F64) -> F64: ...

class Estimate:
    T_c_o: F64
    t_us: int
    seq: int
    step: str
    cost: float
    inlier_fraction: float
    visible_fraction: float
    n_events: int
    lost: bool

class Tracker:
    def __init__(
        self,
        camera: Camera,
        points_o: F64,
        T_c_o: F64,
        solver: str = "edft+",
        frontend: str = "scarf",
        n_search: int = 4,
        tau_px: float = 10.0,
        levels: int = 3,
        lm_iterations: int = 6,
        roi_margin_px: float = 48.0,
        held_axes: F64 | None = None,
    ) -> None: ...
    def update(self, x: U16, y: U16, p: I16, t: I64) -> Estimate: ...
    def ingest(self, x: U16, y: U16, p: I16, t: I64) -> None: ...
    def step(self, n: int = 1) -> Estimate: ...
    def start(self) -> None: ...
    def push(self, x: U16, y: U16, p: I16, t: I64) -> None: ...
    def latest(self) -> Estimate: ...
    def stop(self) -> None: ...
    running: bool
    def reset_pose(self, T_c_o: F64) -> None: ...
    def stats(self) -> dict[str, float]: ...
    def projected_points(self) -> F32: ...
    def field(self) -> tuple[F32, tuple[int, int]]: ...
    def active_mask(self) -> npt.NDArray[np.uint8]: ...

class Mesh:
    def __init__(
        self,
        vertices: F64,
        faces: npt.NDArray[np.integer[Any]],
        vertex_intensity: F64 | None = None,
        uv: F64 | None = None,
        texture: F32 | None = None,
        intensity: float = 0.7,
    ) -> None: ...
    n_vertices: int
    n_faces: int
    vertices: F64
    bounding_radius: float
    centroid: F64

def render(
    mesh: Mesh,
    camera: Camera,
    T_c_o: F64,
    roi: tuple[int, int, int, int] | None = None,
    ambient: float = 0.35,
    diffuse: float = 0.65,
    background: float = 0.0,
) -> dict[str, Any]: ...
def extract_point_set(
    mesh: Mesh,
    camera: Camera,
    T_c_o: F64,
    max_points: int = 1000,
    seed: int = 0,
    depth_jump_m: float = 0.01,
    crease_deg: float = 30.0,
    texture_grad: float = 0.08,
) -> tuple[F64, npt.NDArray[np.uint8]]: ...
def euclidean_distance(mask: npt.NDArray[np.uint8]) -> F32: ...
def distance_field(
    mask: npt.NDArray[np.uint8], tau_px: float = 10.0, levels: int = 3, x0: int = 0, y0: int = 0
) -> list[F32]: ...

class EventSimulator:
    def __init__(self, width: int, height: int, preset: str = "imx636", seed: int = 0, **overrides: float) -> None: ...
    width: int
    height: int
    time_us: int
    params: dict[str, float]
    thresholds: tuple[F32, F32]
    leak_rates_hz: F64
    def reset(self, frame: F32, t_us: int) -> None: ...
    def step(self, frame: F32, t_us: int) -> npt.NDArray[np.void]: ...
    def step_roi(self, frame: F32, roi: tuple[int, int, int, int], t_us: int) -> npt.NDArray[np.void]: ...

class SimCamera:
    """The rendered event camera: object mesh (and optional occluder meshes, e.g. the robot arms)
    over a uniform or textured-plane background, the lens's distortion, the sensor model."""

    def __init__(
        self,
        camera: Camera,
        mesh: Mesh,
        preset: str = "imx636",
        seed: int = 0,
        T_c_bg: F64 | None = None,
        cell_m: float = 0.04,
        background_intensity: float = 0.1,
        ambient: float = 0.35,
        diffuse: float = 0.65,
        margin_px: int = 4,
        **overrides: float,
    ) -> None: ...
    def advance(
        self, T_c_o: F64, t_us: int, T_c_bg: F64 | None = None, occluders: F64 | None = None
    ) -> npt.NDArray[np.void]:
        """Render at ``t_us`` and step the sensor; ``occluders``: (N, 4, 4) poses of the N
        occluder meshes in the camera (required once occluders are set)."""
        ...
    def set_occluders(self, meshes: list[Mesh]) -> None:
        """Meshes drawn with the object and z-tested against it; the next frame is a full frame."""
        ...
    def max_displacement_px(self, T_a: F64, T_b: F64) -> float: ...
    def occluder_displacement_px(self, A: F64, B: F64) -> float:
        """Largest raw-pixel motion of the occluders' visible vertices between (N, 4, 4) pose stacks."""
        ...
    def frame(self) -> F32: ...
    n_occluders: int
    last_roi: tuple[int, int, int, int, bool] | None
    time_us: int | None
    camera: Camera
    canvas: Camera

def adaptive_dt_us(max_flow_px_per_s: float, lam: float = 0.5, min_rate_hz: float = 30.0) -> int: ...

class RawReader:
    def __init__(self, path: str) -> None: ...
    width: int
    height: int
    format: str
    header: dict[str, str]
    def read_n_events(self, n: int) -> dict[str, npt.NDArray[Any]] | None: ...
    def read_until(self, t_us: int) -> dict[str, npt.NDArray[Any]] | None: ...
