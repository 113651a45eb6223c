"""Open-loop tracking of an event recording (``evservo track``), scored against ground truth when the
recording has it (simulated recordings of :mod:`evservo.sim.record`).

Events are fed to the synchronous tracker in time slices of ``batch_us`` (1 ms), one
``Tracker.update`` per slice; an empty slice first advances the tracker's stream time to its end
(``Tracker.advance_time``: the file vouches that no event came), so a gap in the recording is flagged
``lost`` 20 ms in. A Prophesee RAW file (without a viewer) is decoded, sliced and tracked in a Rust
thread (``Tracker.replay(mode="update")``: the same updates, stream time included, without Python
per slice); other formats go through ``evservo.io.open_events`` here. Outputs: ``poses.csv`` (one
row per update), ``summary.json``, ``overlay.png`` (S* reprojected over the distance field at four
instants) and ``error.png``.

Time that steps backwards (real recordings, e.g. EVT3 files where the time base wraps or the
sensor reorders slightly): the tracker needs a non-decreasing stream, so each event older than the
newest one already seen is stamped with that newest time (a clamp, never a drop); the count is
reported as ``n_time_clamped``.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from evservo import _evcore
from evservo.geometry import pose_errors
from evservo.input_files import require_regular_file
from evservo.interrupt import StopOnInterrupt
from evservo.outputs import make_out_dir
from evservo.runtime.inputs import resolve_camera
from evservo.runtime.report import write_summary

#: The files one tracking run writes into its output directory.
OUTPUTS = ("summary.json", "poses.csv", "overlay.png", "error.png")


def track_file(
    path: str | Path, solver: str, out: Path, *, model: str | None = None, init_pose: np.ndarray | str | None = None,
    camera: _evcore.Camera | None = None, frontend: str = "scarf", batch_us: int = 1000,
    max_seconds: float | None = None, progress: bool = True, notes: list[str] | None = None,
    viewer: Any = None, topic: str | None = None,
) -> dict:  # fmt: skip
    """Track one recording with one solver and write the outputs to ``out``; returns the summary.

    ``model``, ``init_pose`` (``T_c_o`` at the first event, 4×4) and ``camera`` default to what a
    simulated recording carries (the IMX636 for a bare 1280×720 file); without a start pose the tracker
    starts lost and searches the image for the object (``first_lock_s`` in the summary: seconds from
    the first event to the first update not flagged lost); ``init_pose="search"`` starts so even when
    the recording has ground truth, whose error over the locked updates is then ``gt_locked_*``.
    ``notes`` collects lines about such choices for the user. ``viewer`` (a
    :class:`~evservo.viewer.RerunViewer`) is shown every update; the caller closes it. ``topic``
    picks the event topic of a ROS bag."""
    from tqdm import tqdm

    from evservo import bags, io
    from evservo.sim.record import gt_at, is_recording, load_recording
    from evservo.tracking import Tracker

    path = Path(path) if bags.is_bag(Path(path)) else require_regular_file(path, "recording")
    meta = io.info(path, topic)
    rec = load_recording(path) if is_recording(path) else None
    cam = resolve_camera(
        str(path), (meta["width"], meta["height"]), camera, rec.camera if rec else None, "give --camera FILE", notes
    )
    obj = model or (rec.object if rec else None)
    if obj is None:
        raise ValueError(f"{path} has no object model: give --model")
    search = isinstance(init_pose, str)
    if search and init_pose != "search":
        raise ValueError(f"init_pose must be a 4x4 pose, None or 'search', got {init_pose!r}")
    if search:
        init_pose = None
    elif init_pose is None and rec is not None:
        init_pose = rec.gt_T[0]
    if init_pose is None and notes is not None:
        notes.append(f"{path} has no start pose: the tracker starts lost and searches for the object")
    if meta["n_events"] == 0:
        raise ValueError(f"{path} holds no events")
    if batch_us < 1:
        raise ValueError(f"--batch-us must be >= 1, got {batch_us}")
    if max_seconds is not None and not (np.isfinite(max_seconds) and max_seconds > 0):
        raise ValueError(f"--max-seconds must be a finite number of seconds > 0, got {max_seconds}")

    trk = Tracker(cam, obj, init_pose, solver=solver, frontend=frontend)
    t_first, t_last = meta["t_first_us"], meta["t_last_us"]
    if max_seconds is not None:
        t_last = min(t_last, t_first + int(max_seconds * 1e6))
    n_slices = max(1, (t_last - t_first) // batch_us + 1)
    snap_at = set(np.linspace(0, n_slices - 1, 4).round().astype(int).tolist())
    bar = tqdm(total=n_slices, unit="batch", desc=f"{solver:>7}", disable=not progress, leave=False)
    with StopOnInterrupt() as stop:
        if path.suffix.lower() == ".raw" and viewer is None:
            run = _replay_slices(trk, path, batch_us, t_last, snap_at, bar, stop)
        else:
            first_end = (t_first // batch_us + 1) * batch_us
            gt = (lambda t: gt_at(rec.gt_t_us, rec.gt_T, np.array([t]))[0]) if rec else None
            run = _push_slices(trk, io.open_events(path, delta_t_us=batch_us, topic=topic), first_end, batch_us,
                               t_last, snap_at, bar, stop, viewer, gt)  # fmt: skip
    bar.close()
    ts, T_est, lost = np.array(run.ts), np.array(run.Ts).reshape(-1, 4, 4), np.array(run.lost, bool)
    solve_s = run.solve_s
    summary = dict(
        recording=str(path), interrupted=run.interrupted, solver=solver, frontend=frontend, object=str(obj),
        batch_us=batch_us,
        n_updates=len(ts), n_events=int(np.sum(run.counts)), n_time_clamped=run.n_clamped, solve_s=solve_s,
        tracker_rate_hz=len(ts) / solve_s if solve_s > 0 else 0.0, lost=bool(lost[-1]) if len(lost) else False,
        lost_fraction=float(lost.mean()) if len(lost) else 0.0, width=cam.width, height=cam.height,
        started_lost=init_pose is None, first_lock_s=_first_lock_s(ts, lost, t_first),
    )  # fmt: skip
    err_mm = err_deg = None
    if rec is not None and len(ts):
        T_gt = gt_at(rec.gt_t_us, rec.gt_T, ts)
        pos_m, rot_rad = pose_errors(T_est, T_gt)
        err_mm, err_deg = pos_m * 1e3, np.rad2deg(rot_rad)
        summary.update(
            gt_track_pos_rms_mm=float(np.sqrt(np.mean(err_mm**2))),
            gt_track_rot_rms_deg=float(np.sqrt(np.mean(err_deg**2))),
            gt_track_pos_max_mm=float(err_mm.max()), gt_track_rot_max_deg=float(err_deg.max()),
        )  # fmt: skip
        locked = ~lost
        if locked.any():
            summary.update(
                gt_locked_pos_rms_mm=float(np.sqrt(np.mean(err_mm[locked] ** 2))),
                gt_locked_rot_rms_deg=float(np.sqrt(np.mean(err_deg[locked] ** 2))),
                gt_locked_pos_max_mm=float(err_mm[locked].max()), gt_locked_rot_max_deg=float(err_deg[locked].max()),
            )  # fmt: skip
    else:
        summary.update(gt_track_pos_rms_mm=None, gt_track_rot_rms_deg=None)
    out = make_out_dir(out, stale=OUTPUTS)
    _write_poses(out / "poses.csv", ts, T_est, lost, np.array(run.confidence), err_mm, err_deg)
    _plot_overlay(out / "overlay.png", run.snaps, solver)
    _plot_error(out / "error.png", ts, err_mm, err_deg, lost, solver)
    write_summary(out / "summary.json", summary)  # last: a summary.json is there only when the others are
    return summary


@dataclass
class _Slices:
    """What tracking the slices of a recording gave: per update the slice end (µs), T_c_o, lost, the
    confidence (0–1) and the slice's event count; the overlay snapshots; time in the updates (s); clamped events."""

    ts: list[int] = dataclasses.field(default_factory=list)
    Ts: list[np.ndarray] = dataclasses.field(default_factory=list)
    lost: list[bool] = dataclasses.field(default_factory=list)
    confidence: list[float] = dataclasses.field(default_factory=list)
    counts: list[int] = dataclasses.field(default_factory=list)
    snaps: list[tuple] = dataclasses.field(default_factory=list)
    solve_s: float = 0.0
    n_clamped: int = 0
    interrupted: bool = False

    def add(self, end_us: int, n_events: int, est: _evcore.Estimate) -> None:
        self.ts.append(end_us)
        self.Ts.append(est.T_c_o)
        self.lost.append(est.lost)
        self.confidence.append(est.confidence)
        self.counts.append(n_events)


def _push_slices(trk, slices, end: int, batch_us: int, t_last: int, snap_at: set[int], bar, stop, viewer,
                 gt) -> _Slices:  # fmt: skip
    """One ``update`` per slice from Python (any format; the viewer is shown every update). ``end``:
    the first slice's end (µs); ``gt(t_us)``: ground truth T_c_o for the viewer, or None."""
    from evservo import events

    run, t_max = _Slices(), None
    for k, ev in enumerate(slices):
        if stop.requested:  # Ctrl-C: keep what was tracked, marked as interrupted
            run.interrupted = True
            break
        if end - batch_us > t_last:
            break
        ev, n, t_max = events.clamp_time(ev, t_max)
        run.n_clamped += n
        started = time.perf_counter()
        est = trk.update_slice(ev, end, t_max)  # an empty slice: the file holds no event before its end
        run.solve_s += time.perf_counter() - started
        if viewer is not None:
            viewer.track(end, ev, est, trk, gt(end) if gt else None)
        run.add(end, len(ev), est)
        if k in snap_at:
            field_img, origin = trk.field()
            run.snaps.append((end, field_img.copy(), origin, trk.projected_points().copy()))
        end += batch_us
        bar.update()
    return run


def _replay_slices(trk, path: Path, batch_us: int, t_last: int, snap_at: set[int], bar, stop) -> _Slices:
    """A RAW file decoded, sliced and tracked in a Rust thread, one synchronous update per slice as
    :func:`_push_slices` does (``Tracker.replay(mode="update")``); this thread only shows progress
    and passes a Ctrl-C on (the update in progress completes, the replay stops before the next)."""
    run = _Slices()
    with trk.replay(path, batch_us, speed=None, mode="update", until_us=t_last, snapshots_at=sorted(snap_at)) as rp:
        while not rp.wait(timeout=0.1):
            bar.update(rp.stats()["slices"] - bar.n)
            if stop.requested:
                rp.stop()
                run.interrupted = True
                break
        stats = rp.stats()
        for end_us, n_events, est in rp.updates():
            run.add(end_us, n_events, est)
        run.snaps = rp.snapshots()
    bar.update(stats["slices"] - bar.n)
    run.solve_s, run.n_clamped = float(stats["update_seconds"]), int(stats["clamped"])
    return run


def _first_lock_s(ts: np.ndarray, lost: np.ndarray, t_first_us: int) -> float | None:
    """Seconds from the first event to the first update not flagged lost (None if never)."""
    locked = np.flatnonzero(~lost)
    return float((ts[locked[0]] - t_first_us) * 1e-6) if len(locked) else None


def _write_poses(path: Path, ts, T_est, lost, confidence, err_mm, err_deg) -> None:
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(T_est[:, :3, :3]).as_quat() if len(T_est) else np.zeros((0, 4))
    cols = [ts, T_est[:, 0, 3], T_est[:, 1, 3], T_est[:, 2, 3], *q.T, lost.astype(int), confidence]
    header = "t_us,x_m,y_m,z_m,qx,qy,qz,qw,lost,confidence"
    fmt = ["%d", "%.6f", "%.6f", "%.6f", "%.8f", "%.8f", "%.8f", "%.8f", "%d", "%.6f"]
    if err_mm is not None:
        cols += [err_mm, err_deg]
        header += ",pos_err_mm,rot_err_deg"
        fmt += ["%.4f", "%.5f"]
    np.savetxt(path, np.column_stack(cols), delimiter=",", header=header, comments="", fmt=fmt)


def _plot_overlay(path: Path, snaps, solver: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, max(1, len(snaps)), figsize=(4.2 * max(1, len(snaps)), 3.6), squeeze=False)
    for ax, (t_us, field, (x0, y0), pts) in zip(axes[0], snaps, strict=False):
        h, w = field.shape
        ax.imshow(field, cmap="viridis", extent=(x0 - 0.5, x0 + w - 0.5, y0 + h - 0.5, y0 - 0.5))
        ax.scatter(pts[:, 0], pts[:, 1], s=1.0, c="r", linewidths=0)
        ax.set_xlim(x0 - 0.5, x0 + w - 0.5)
        ax.set_ylim(y0 + h - 0.5, y0 - 0.5)
        ax.set_title(f"t = {t_us / 1e3:.0f} ms", fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(f"{solver}: S* (red) over the event distance field", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_error(path: Path, ts, err_mm, err_deg, lost, solver: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.2))
    t_s = (ts - ts[0]) * 1e-6 if len(ts) else ts
    if err_mm is not None:
        ax.plot(t_s, err_mm, lw=0.8, label="position error (mm)")
        ax2 = ax.twinx()
        ax2.plot(t_s, err_deg, lw=0.8, color="C1", label="rotation error (deg)")
        ax2.set_ylabel("deg")
        ax.set_ylabel("mm")
        ax.legend(loc="upper left", fontsize=8)
        ax2.legend(loc="upper right", fontsize=8)
    else:
        ax.plot(t_s, lost.astype(int), lw=0.8, label="lost (no ground truth)")
        ax.legend(fontsize=8)
    ax.set_xlabel("time (s)")
    ax.set_title(f"{solver}: error against ground truth", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
