"""Target trajectories: displacement of the object from its start pose as a function of time.

Every trajectory maps times ``t_s`` (seconds, shape (N,)) to displacements ``D`` (N, 4, 4) that are
applied on the left of the start pose, ``T(t) = D(t) · T(0)`` with the rotation of D taken about the
object's own start position, so a rotating object spins in place rather than swinging around the
origin. For open-loop recordings the frame is the camera's; in the closed loop it is the world.

Kinds (peak speed along x ``speed_mps``, peak angular rate ``rot_rate_dps``):
- ``trans``: back and forth along x with a smaller y component (a flattened figure of eight).
- ``trans-rot``: ``trans`` plus oscillating rotations about all three axes (peak rate ``rot_rate_dps``
  about y, about 0.8× that about x and z).
- ``circle``: a circle in the x–y plane.
- ``figure8``: a Lissajous figure of eight in the x–y plane.
- ``stop-go``: moves along x for the first half, then stands still (where activity-based
  representations fade and SCARF does not).
- ``reversal``: along x at constant speed, turning back abruptly at ±amplitude (a triangle wave).
- ``leave-return``: leaves the view and comes back elsewhere (issue 12): after 0.2 s a dash of
  :data:`LEAVE_M` across the view (along :data:`LEAVE_DIR`) at peak speed ``speed_mps``, faster than
  a camera can follow, then 0.4 s out there, then back, at a peak of ``speed_mps`` or
  :data:`RETURN_MPS` if slower, to another place (``0.3·LEAVE_M`` along :data:`LEAVE_DIR` and 0.05 m
  down z from the start) turned by 25° about z, and rest: set down where a camera that braked after
  following the dash for a moment sees it whole.
- a CSV path with header ``t_s,x_m,y_m,z_m,rx_rad,ry_rad,rz_rad`` (displacement, rotation vector),
  interpolated linearly (rotation by slerp) and held constant beyond its ends.
"""

from __future__ import annotations

import csv
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from evservo.input_files import require_regular_file

KINDS = ("trans", "trans-rot", "circle", "figure8", "stop-go", "reversal", "leave-return")
#: Kinds whose object leaves a following camera's view (the episode then scores loss and re-lock).
LEAVING_KINDS = ("leave-return",)
#: How far ``leave-return`` dashes (m): beyond the view's half-width at 0.6 m (0.33 m on the IMX636).
LEAVE_M = 0.7
#: Which way (unit vector) ``leave-return`` dashes: across the view, both in the camera frame of an
#: open-loop recording (no depth component) and in the closed-loop scene's world frame, where it is the
#: start camera's x axis (``SceneConfig.view_dir_w`` is (0.5, 0.75, 0.05)). Along world x, as before,
#: the dash also ran 0.28 m towards the camera, and at 1.5 m/s the target arm overshot it by 0.3 m:
#: the object left the view by nearly touching the lens (Z 0.1 m) (benches/RESULTS.md, issue 12,
#: "Round 15").
LEAVE_DIR = np.array([-0.832, 0.555, 0.0]) / np.hypot(0.832, 0.555)
#: Peak speed of ``leave-return``'s way back (m/s): slow enough that the target arm follows it and
#: comes to rest where it is sent (at the dash's speed it swung 0.3–0.4 m past it and back).
RETURN_MPS = 0.6
CSV_COLUMNS = ("t_s", "x_m", "y_m", "z_m", "rx_rad", "ry_rad", "rz_rad")

Trajectory = Callable[[np.ndarray], np.ndarray]


def _compose(trans: np.ndarray, rotvec: np.ndarray | None) -> np.ndarray:
    """Displacements (N, 4, 4) from translations (N, 3) and rotation vectors (N, 3; None: no rotation)."""
    D = np.tile(np.eye(4), (len(trans), 1, 1))
    if rotvec is not None:  # (a zero rotation vector gives the identity exactly; this skips scipy's cost)
        D[:, :3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    D[:, :3, 3] = trans
    return D


def make_trajectory(
    kind: str, speed_mps: float = 0.3, rot_rate_dps: float = 30.0, amplitude_m: float = 0.12
) -> Trajectory:
    """A trajectory by name (see the module docstring) or from a CSV file path."""
    if kind not in KINDS:
        path = Path(kind)
        if path.suffix.lower() == ".csv":
            return load_csv_trajectory(path)
        raise ValueError(f"unknown trajectory {kind!r}; choose one of {KINDS} or a .csv file")
    if not (np.isfinite(speed_mps) and speed_mps >= 0 and np.isfinite(amplitude_m) and amplitude_m > 0):
        raise ValueError("speed must be >= 0 and amplitude > 0 (finite)")
    if not (np.isfinite(rot_rate_dps) and rot_rate_dps >= 0):
        raise ValueError(f"rotation rate must be finite and >= 0 deg/s, got {rot_rate_dps}")
    A = amplitude_m
    w = speed_mps / A  # rad/s so that the peak speed along x is speed_mps
    rot_amp = np.deg2rad(rot_rate_dps) / max(w, 1e-9) if kind == "trans-rot" else 0.0
    rot_amp = min(rot_amp, np.deg2rad(25.0))  # keep the object facing the camera

    def traj(t_s: np.ndarray) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        zeros = np.zeros_like(t)
        if kind in ("trans", "trans-rot"):
            trans = np.stack([A * np.sin(w * t), 0.3 * A * np.sin(0.5 * w * t), zeros], axis=1)
        elif kind == "circle":
            trans = np.stack([A * np.sin(w * t), A * (1 - np.cos(w * t)), zeros], axis=1)
        elif kind == "figure8":
            trans = np.stack([A * np.sin(w * t), 0.5 * A * np.sin(2 * w * t), zeros], axis=1)
        elif kind == "reversal":
            # arcsin∘sin is a triangle wave of slope ±1: constant speed, reversing at ±A.
            x = (2 * A / np.pi) * np.arcsin(np.sin(0.5 * np.pi * w * t))
            trans = np.stack([x, zeros, zeros], axis=1)
        elif kind == "leave-return":
            return _leave_return(t, max(speed_mps, 1e-3))
        else:  # stop-go: constant speed for the first period's quarter, then rest
            t_stop = 0.5 * A / max(speed_mps, 1e-9)
            x = speed_mps * np.minimum(t, t_stop)
            trans = np.stack([x, zeros, zeros], axis=1)
        if rot_amp > 0:
            rot = np.stack(
                [rot_amp * np.sin(0.8 * w * t), rot_amp * np.sin(w * t), 0.6 * rot_amp * np.sin(1.3 * w * t)],
                axis=1,
            )
        else:
            rot = None
        return _compose(trans, rot)

    return traj


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _leave_return(t: np.ndarray, speed_mps: float) -> np.ndarray:
    """The ``leave-return`` kind (module docstring); a smoothstep over a distance d and time T peaks at
    1.5·d/T."""
    t_out = 1.5 * LEAVE_M / speed_mps
    t_back0 = 0.2 + t_out + 0.4
    out = LEAVE_M * LEAVE_DIR
    back = 0.3 * LEAVE_M * LEAVE_DIR - np.array([0.0, 0.0, 0.05])
    t_back = 1.5 * float(np.linalg.norm(back - out)) / min(speed_mps, RETURN_MPS)
    s_out = _smoothstep((t - 0.2) / t_out)[:, None]
    s_back = _smoothstep((t - t_back0) / t_back)[:, None]
    trans = (1 - s_back) * s_out * out + s_back * back
    rot = s_back * np.array([0.0, 0.0, np.deg2rad(25.0)])
    return _compose(trans, rot)


def load_csv_trajectory(path: str | Path) -> Trajectory:
    """Read a CSV trajectory (header ``t_s,x_m,y_m,z_m,rx_rad,ry_rad,rz_rad``)."""
    path = require_regular_file(path, "trajectory file")
    with path.open(newline="") as fh:
        reader = csv.reader(fh)
        header = [h.strip() for h in next(reader, [])]
        if tuple(header) != CSV_COLUMNS:
            raise ValueError(f"{path}: header must be {','.join(CSV_COLUMNS)}, got {','.join(header)}")
        try:
            rows = np.array([[float(v) for v in row] for row in reader if row], dtype=float)
        except ValueError as e:
            raise ValueError(f"{path}: non-numeric value ({e})") from None
    if rows.ndim != 2 or rows.shape[0] < 2 or rows.shape[1] != 7:
        raise ValueError(f"{path}: need at least two rows of 7 values")
    if not np.all(np.isfinite(rows)) or np.any(np.diff(rows[:, 0]) <= 0):
        raise ValueError(f"{path}: values must be finite and t_s strictly increasing")
    times = rows[:, 0]
    slerp = Slerp(times, Rotation.from_rotvec(rows[:, 4:7]))

    def traj(t_s: np.ndarray) -> np.ndarray:
        t = np.clip(np.asarray(t_s, dtype=float), times[0], times[-1])
        trans = np.stack([np.interp(t, times, rows[:, i]) for i in (1, 2, 3)], axis=1)
        D = np.tile(np.eye(4), (len(t), 1, 1))
        D[:, :3, :3] = slerp(t).as_matrix()
        D[:, :3, 3] = trans
        return D

    return traj


def apply(D: np.ndarray, T_start: np.ndarray) -> np.ndarray:
    """Poses ``T(t)`` (N, 4, 4) from displacements D(t) and the start pose: the translation adds, the
    rotation turns the object about its own start position."""
    out = np.empty_like(D)
    out[:, :3, :3] = D[:, :3, :3] @ T_start[:3, :3]
    out[:, :3, 3] = T_start[:3, 3] + D[:, :3, 3]
    out[:, 3] = [0, 0, 0, 1]
    return out
