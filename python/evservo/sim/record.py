"""Simulated event recordings: an object moving in front of a static event camera, rendered and run
through the sensor model (:class:`evservo._evcore.SimCamera`), written to one HDF5 file with ground truth.

The object starts at depth Z on the optical axis, turned by :data:`START_ROTVEC` so that three faces
show (a face-on box gives the solvers a degenerate, flat silhouette), and follows a trajectory of
:mod:`evservo.trajectories` in the camera frame. Behind it, ``background_behind_m`` further away, stands
a plane of high-contrast square cells facing the camera.

Sampling follows ESIM's adaptive rule: ground truth is taken every ``1 / gt_rate_hz`` (the floor rate),
and each such interval is split into the fewest equal sub-steps that keep every mesh vertex within
``max_px`` raw pixels of its previous rendered position.

HDF5 layout (everything a reader needs; :func:`load_recording` reads it back):

``/events/{x,y,p,t}``
    the evservo event layout of :mod:`evservo.io` (u16, u16, i16 0/1, i64 µs; chunked, compressed
    as ``evservo.io.H5_COMPRESSION`` says), with ``width`` and ``height`` attributes on ``/events``.
``/gt/t_us`` (N,) i64 and ``/gt/T_c_o`` (N, 4, 4) f64
    object pose in the camera optical frame (metres) at the floor rate, from t = 0 to the end.
``/camera``
    attributes ``width``, ``height``, ``fx``, ``fy``, ``cx``, ``cy`` (pixels) and ``dist`` (k1 k2 p1 p2 k3,
    OpenCV convention) of the raw sensor.
root attributes
    ``evservo_recording`` = 1, ``object`` (built-in name or mesh path), ``trajectory``, ``speed_mps``,
    ``rot_rate_dps``, ``distance_m``, ``duration_s``, ``seed``, ``preset``, ``background_behind_m``,
    ``cell_m``, ``gt_rate_hz``, ``max_px``, ``T_c_bg`` (4×4), ``evservo_version``, the statistics
    ``n_renders`` and ``compute_s`` (wall time of the simulation), and ``evservo_complete``: 0 while
    the file is written, set to 1 as the last write (readers refuse a file where it is 0).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path

import h5py
import numpy as np

import evservo
from evservo import _evcore, geometry, trajectories
from evservo import io as evio
from evservo.io import EVENT_CD
from evservo.models import load_object, to_core_mesh
from evservo.outputs import atomic_path, check_out_file
from evservo.sim.sources import scaled_camera

#: Start rotation of the object (rotation vector, radians): facing the camera, turned ~33° so that
#: three faces show.
START_ROTVEC = (0.35, -0.45, 0.1)

#: Events per HDF5 chunk and per write.
_CHUNK_EVENTS = 1 << 18


@dataclass(frozen=True)
class RecordConfig:
    """What to simulate. Lengths in metres, speeds m/s, rates Hz, times s."""

    object: str = "box"
    trajectory: str = "trans-rot"
    speed_mps: float = 0.4
    rot_rate_dps: float = 30.0
    distance_m: float = 0.6
    duration_s: float = 5.0
    seed: int = 1
    preset: str = "imx636"
    background_behind_m: float = 0.6
    cell_m: float = 0.04
    gt_rate_hz: float = 1000.0
    max_px: float = 0.5
    scale: float = 1.0

    def validate(self) -> None:
        positive = dict(
            distance_m=self.distance_m, duration_s=self.duration_s, background_behind_m=self.background_behind_m,
            cell_m=self.cell_m, gt_rate_hz=self.gt_rate_hz, max_px=self.max_px, scale=self.scale,
        )  # fmt: skip
        for name, v in positive.items():
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v}")
        if not (np.isfinite(self.speed_mps) and self.speed_mps >= 0):
            raise ValueError(f"speed must be finite and >= 0 m/s, got {self.speed_mps}")
        if not (np.isfinite(self.rot_rate_dps) and self.rot_rate_dps >= 0):
            raise ValueError(f"rotation rate must be finite and >= 0 deg/s, got {self.rot_rate_dps}")
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")
        trajectories.make_trajectory(self.trajectory, speed_mps=self.speed_mps, rot_rate_dps=self.rot_rate_dps)
        if self.duration_s > 3600:
            raise ValueError(f"duration must be at most 3600 s (ground truth is held at 1 kHz), got {self.duration_s}")
        if self.gt_rate_hz < 1000:
            raise ValueError(f"ground truth needs >= 1000 Hz, got {self.gt_rate_hz}")


def start_pose(distance_m: float) -> np.ndarray:
    """The object's start pose ``T_c_o``: on the optical axis at ``distance_m``, turned by START_ROTVEC."""
    return geometry.pose((0.0, 0.0, distance_m), START_ROTVEC)


def background_pose(distance_m: float, behind_m: float) -> np.ndarray:
    """``T_c_bg``: the background plane facing the camera ``behind_m`` behind the object's start depth."""
    return geometry.pose((0.0, 0.0, distance_m + behind_m))


def substep_times(sim: _evcore.SimCamera, pose_at, t_a_us: int, t_b_us: int, max_px: float) -> np.ndarray:
    """Render times in (t_a_us, t_b_us]: the fewest equal sub-steps such that no mesh vertex moves more
    than ``max_px`` raw pixels between renders, judged from the displacement over the whole interval
    (ESIM's rule with the flow taken as constant over it). ``pose_at(times_us)`` gives (K, 4, 4)."""
    Ta, Tb = pose_at(np.array([t_a_us, t_b_us]))
    d = sim.max_displacement_px(Ta, Tb)
    span = t_b_us - t_a_us
    # A vertex at or behind the camera plane has no pixel motion to bound; the renderer clips it
    # and takes a full frame, so one step is as good as many.
    n = 1 if not np.isfinite(d) else int(min(span, max(1, np.ceil(d / max_px))))
    return np.unique(np.round(np.linspace(t_a_us, t_b_us, n + 1)[1:]).astype(np.int64))


class _EventWriter:
    """Appends events to ``/events/{x,y,p,t}`` as resizable chunked datasets (the evservo.io layout),
    compressed as :data:`evservo.io.H5_COMPRESSION` says."""

    def __init__(self, f: h5py.File, width: int, height: int) -> None:
        g = f.create_group("events")
        g.attrs["width"] = int(width)
        g.attrs["height"] = int(height)
        opts = dict(shape=(0,), maxshape=(None,), chunks=(_CHUNK_EVENTS,), **evio.h5_compression_options())
        self.ds = {n: g.create_dataset(n, dtype=EVENT_CD[n], **opts) for n in EVENT_CD.names}
        self.pending: list[np.ndarray] = []
        self.n_pending = 0
        self.n = 0

    def append(self, ev: np.ndarray) -> None:
        if len(ev):
            self.pending.append(ev)
            self.n_pending += len(ev)
        if self.n_pending >= _CHUNK_EVENTS:
            self.flush()

    def flush(self) -> None:
        if not self.pending:
            return
        ev = np.concatenate(self.pending, dtype=EVENT_CD)
        for name, ds in self.ds.items():
            ds.resize((self.n + len(ev),))
            ds[self.n :] = ev[name]
        self.n += len(ev)
        self.pending, self.n_pending = [], 0


def record(out: str | Path, config: RecordConfig, camera: _evcore.Camera | None = None, progress: bool = True) -> dict:
    """Simulate ``config`` and write the recording to ``out`` (``.h5``); returns a summary dict
    (n_events, n_renders, compute_s, realtime_factor)."""
    from tqdm import tqdm

    config.validate()
    out = Path(out)
    if out.suffix.lower() not in (".h5", ".hdf5"):
        raise ValueError(f"recordings are HDF5 files (.h5/.hdf5), got {out.name}")
    check_out_file(out, (".h5", ".hdf5"))
    cam = scaled_camera(camera or _evcore.Camera.imx636(), config.scale)
    mesh = to_core_mesh(load_object(config.object))
    traj = trajectories.make_trajectory(config.trajectory, speed_mps=config.speed_mps, rot_rate_dps=config.rot_rate_dps)
    T0 = start_pose(config.distance_m)
    T_c_bg = background_pose(config.distance_m, config.background_behind_m)

    def pose_at(t_us: np.ndarray) -> np.ndarray:
        return trajectories.apply(traj(np.asarray(t_us) * 1e-6), T0)

    gt_dt_us = 1e6 / config.gt_rate_hz
    gt_t = np.round(np.arange(0, round(config.duration_s * 1e6) + 1, gt_dt_us)).astype(np.int64)
    gt_t = np.unique(gt_t)
    gt_T = pose_at(gt_t)
    sim = _evcore.SimCamera(cam, mesh, preset=config.preset, seed=config.seed, T_c_bg=T_c_bg, cell_m=config.cell_m)
    started = time.perf_counter()
    n_renders = 1
    # Written under a temporary name and renamed when complete: an interrupted run leaves neither a
    # half-written recording nor a damaged previous one at ``out``.
    with atomic_path(out) as tmp, h5py.File(tmp, "w") as f:
        f.attrs["evservo_recording"] = 1
        f.attrs[evio.RECORDING_COMPLETE_ATTR] = 0
        writer = _EventWriter(f, cam.width, cam.height)
        sim.advance(gt_T[0], int(gt_t[0]))
        bar = tqdm(total=len(gt_t) - 1, unit="ms", desc="simulating", disable=not progress or len(gt_t) < 200)
        for k in range(1, len(gt_t)):
            times = substep_times(sim, pose_at, int(gt_t[k - 1]), int(gt_t[k]), config.max_px)
            poses = pose_at(times)
            poses[-1] = gt_T[k]
            for t, T in zip(times, poses, strict=True):
                writer.append(sim.advance(T, int(t)))
            n_renders += len(times)
            bar.update()
        bar.close()
        writer.flush()
        compute_s = time.perf_counter() - started
        g = f.create_group("gt")
        g.create_dataset("t_us", data=gt_t)
        g.create_dataset("T_c_o", data=gt_T)
        c = f.create_group("camera")
        for name in ("width", "height", "fx", "fy", "cx", "cy"):
            c.attrs[name] = getattr(cam, name)
        c.attrs["dist"] = np.array(cam.dist, float)
        f.attrs["evservo_version"] = evservo.__version__
        for key, value in asdict(config).items():
            f.attrs[key] = value
        f.attrs["T_c_bg"] = T_c_bg
        f.attrs["n_renders"] = n_renders
        f.attrs["compute_s"] = compute_s
        n_events = writer.n
        f.attrs[evio.RECORDING_COMPLETE_ATTR] = 1  # last: everything above is in the file
    return dict(
        n_events=n_events, n_renders=n_renders, compute_s=compute_s,
        realtime_factor=config.duration_s / compute_s, events_per_s=n_events / config.duration_s,
        width=cam.width, height=cam.height,
    )  # fmt: skip


@dataclass
class Recording:
    """A recording's metadata and ground truth (events stay on disk; stream them with
    :func:`evservo.io.open_events`)."""

    path: Path
    camera: _evcore.Camera
    object: str
    gt_t_us: np.ndarray
    #: Ground-truth T_c_o (N, 4, 4) at ``gt_t_us``.
    gt_T: np.ndarray  # noqa: N815 - the frame names follow the project's T_a_b convention
    attrs: dict


def gt_at(gt_t_us: np.ndarray, gt_T: np.ndarray, t_us: np.ndarray) -> np.ndarray:
    """A recording's ground truth ``gt_T`` (N, 4, 4) at ``gt_t_us`` (µs) interpolated to ``t_us``
    (linear translation, slerp rotation), held at the ends; (len(t_us), 4, 4)."""
    from scipy.spatial.transform import Rotation, Slerp

    t = np.clip(t_us, gt_t_us[0], gt_t_us[-1]).astype(float)
    out = np.tile(np.eye(4), (len(t), 1, 1))
    out[:, :3, :3] = Slerp(gt_t_us.astype(float), Rotation.from_matrix(gt_T[:, :3, :3]))(t).as_matrix()
    for i in range(3):
        out[:, i, 3] = np.interp(t, gt_t_us, gt_T[:, i, 3])
    return out


def is_recording(path: str | Path) -> bool:
    """True for an HDF5 file written by :func:`record`."""
    p = Path(path)
    if p.suffix.lower() not in (".h5", ".hdf5") or not p.is_file():
        return False
    try:
        with h5py.File(p, "r") as f:
            return bool(f.attrs.get("evservo_recording", 0))
    except OSError:
        return False


def load_recording(path: str | Path) -> Recording:
    """Metadata and ground truth of a recording written by :func:`record`."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such recording: {p}")
    try:
        with h5py.File(p, "r") as f:
            if not f.attrs.get("evservo_recording", 0):
                raise ValueError(f"{p} is not an evservo recording (no evservo_recording attribute)")
            evio.check_complete_recording(p, f)
            c = f["camera"].attrs
            cam = _evcore.Camera(
                int(c["width"]), int(c["height"]), float(c["fx"]), float(c["fy"]), float(c["cx"]), float(c["cy"]),
                tuple(float(v) for v in c["dist"]),
            )  # fmt: skip
            attrs = {k: (v.item() if hasattr(v, "item") and np.ndim(v) == 0 else v) for k, v in f.attrs.items()}
            return Recording(
                path=p, camera=cam, object=str(attrs["object"]), gt_t_us=f["gt/t_us"][()],
                gt_T=f["gt/T_c_o"][()], attrs=attrs,
            )  # fmt: skip
    except (KeyError, OSError) as e:
        raise ValueError(f"{p}: unreadable recording: {e}") from e
