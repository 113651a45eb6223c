"""``evservo track``: open-loop tracking of an event recording, scored against ground truth when the
recording has it (simulated recordings of :mod:`evservo.sim.record`).

Events are fed to the synchronous tracker in time slices of ``--batch-us`` (1 ms), one
``Tracker.update`` per slice. Outputs in ``--out``: ``poses.csv`` (one row per update), ``summary.json``,
``overlay.png`` (S* reprojected over the distance field at four instants) and ``error.png``.

Time that steps backwards (real recordings, e.g. EVT3 files where the time base wraps or the
sensor reorders slightly): the tracker needs a non-decreasing stream, so each event older than the
newest one already seen is stamped with that newest time (a clamp, never a drop); the count is
reported as ``n_time_clamped``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from evservo.inputs import require_regular_file
from evservo.interrupt import StopOnInterrupt
from evservo.outputs import make_out_dir, prepare_out_dir, write_text_atomic

#: The files one tracking run writes into its output directory.
OUTPUTS = ("summary.json", "poses.csv", "overlay.png", "error.png")


def load_camera_file(path: str | Path):
    """A camera from JSON or YAML with OpenCV-style fields: ``width``, ``height``, and either ``K``
    (3×3, or ``camera_matrix`` with a ``data`` list) or ``fx, fy, cx, cy``; distortion as ``dist`` /
    ``distortion_coefficients`` (list, or mapping with ``data``; up to 5 values k1 k2 p1 p2 k3)."""
    from evservo import _evcore

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such camera file: {p}")
    text = p.read_text()
    try:
        if p.suffix.lower() in (".yaml", ".yml"):
            import yaml

            d = yaml.safe_load(text)
        else:
            d = json.loads(text)
    except Exception as e:  # any parse error means a bad file for the user
        raise ValueError(f"{p}: cannot parse camera file: {e}") from None
    if not isinstance(d, dict):
        raise ValueError(f"{p}: camera file must hold a mapping")

    def data(v):
        return v["data"] if isinstance(v, dict) and "data" in v else v

    try:
        width, height = int(d.get("width", d.get("image_width"))), int(d.get("height", d.get("image_height")))
        K = data(d.get("K", d.get("camera_matrix")))
        if K is not None:
            K = np.asarray(K, float).reshape(3, 3)
            fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        else:
            fx, fy, cx, cy = (float(d[k]) for k in ("fx", "fy", "cx", "cy"))
        dist = np.asarray(data(d.get("dist", d.get("distortion_coefficients", []))) or [], float).ravel()
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{p}: camera file needs width, height, K or fx/fy/cx/cy ({e})") from None
    if len(dist) > 5:
        raise ValueError(f"{p}: at most 5 distortion coefficients (k1 k2 p1 p2 k3), got {len(dist)}")
    dist = tuple(np.pad(dist, (0, 5 - len(dist))))
    try:
        return _evcore.Camera(width, height, float(fx), float(fy), float(cx), float(cy), dist)
    except ValueError as e:
        raise ValueError(f"{p}: {e}") from None


def parse_pose(text: str) -> np.ndarray:
    """``x,y,z,qx,qy,qz,qw`` (metres, unit quaternion) as a 4×4 pose."""
    from evservo import geometry

    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"--init-pose must be 7 numbers x,y,z,qx,qy,qz,qw; got {text!r}") from None
    if len(values) != 7 or not np.all(np.isfinite(values)):
        raise ValueError(f"--init-pose must be 7 finite numbers x,y,z,qx,qy,qz,qw; got {text!r}")
    return geometry.pose_from_xyz_quat(*values)


def track_file(
    path: str | Path, solver: str, out: Path, *, model: str | None = None, init_pose: np.ndarray | None = None,
    camera=None, frontend: str = "scarf", batch_us: int = 1000, max_seconds: float | None = None,
    progress: bool = True,
) -> dict:  # fmt: skip
    """Track one recording with one solver and write the outputs to ``out``; returns the summary."""
    from tqdm import tqdm

    from evservo import _evcore, events, io
    from evservo.geometry import rotation_error_rad, translation_error_m
    from evservo.sim.record import gt_at, is_recording, load_recording
    from evservo.tracking import Tracker

    path = require_regular_file(path, "recording")
    meta = io.info(path)
    rec = load_recording(path) if is_recording(path) else None
    cam = camera or (rec.camera if rec else None)
    if cam is None:
        if (meta["width"], meta["height"]) != (1280, 720):
            raise ValueError(f"{path} is {meta['width']}x{meta['height']}: give --camera for its intrinsics")
        cam = _evcore.Camera.imx636()
    if (cam.width, cam.height) != (meta["width"], meta["height"]):
        raise ValueError(f"camera is {cam.width}x{cam.height} but {path} is {meta['width']}x{meta['height']}")
    obj = model or (rec.object if rec else None)
    if obj is None:
        raise ValueError(f"{path} has no object model: give --model")
    if init_pose is None:
        if rec is None:
            raise ValueError(f"{path} has no ground truth: give --init-pose x,y,z,qx,qy,qz,qw")
        init_pose = rec.gt_T[0]
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
    snaps, ts, Ts, lost, counts = [], [], [], [], []
    n_clamped, t_max, solve_s = 0, None, 0.0
    end = (t_first // batch_us + 1) * batch_us
    bar = tqdm(total=n_slices, unit="batch", desc=f"{solver:>7}", disable=not progress, leave=False)
    interrupted = False
    with StopOnInterrupt() as stop:
        for k, ev in enumerate(io.open_events(path, delta_t_us=batch_us)):
            if stop.requested:  # Ctrl-C: keep what was tracked, marked as interrupted
                interrupted = True
                break
            if end - batch_us > t_last:
                break
            ev, n, t_max = events.clamp_time(ev, t_max)
            n_clamped += n
            started = time.perf_counter()
            est = trk.update(ev)
            solve_s += time.perf_counter() - started
            ts.append(end)
            Ts.append(est.T_c_o)
            lost.append(est.lost)
            counts.append(len(ev))
            if k in snap_at:
                field, origin = trk.field()
                snaps.append((end, field.copy(), origin, trk.projected_points().copy()))
            end += batch_us
            bar.update()
    bar.close()
    ts, T_est, lost = np.array(ts), np.array(Ts).reshape(-1, 4, 4), np.array(lost, bool)
    summary = dict(
        recording=str(path), interrupted=interrupted, solver=solver, frontend=frontend, object=str(obj),
        batch_us=batch_us,
        n_updates=len(ts), n_events=int(np.sum(counts)), n_time_clamped=n_clamped, solve_s=solve_s,
        tracker_rate_hz=len(ts) / solve_s if solve_s > 0 else 0.0, lost=bool(lost[-1]) if len(lost) else False,
        lost_fraction=float(lost.mean()) if len(lost) else 0.0, width=cam.width, height=cam.height,
    )  # fmt: skip
    err_mm = err_deg = None
    if rec is not None and len(ts):
        T_gt = gt_at(rec.gt_t_us, rec.gt_T, ts)
        err_mm = np.array([translation_error_m(a, b) for a, b in zip(T_est, T_gt, strict=True)]) * 1e3
        err_deg = np.rad2deg([rotation_error_rad(a, b) for a, b in zip(T_est, T_gt, strict=True)])
        summary.update(
            gt_track_pos_rms_mm=float(np.sqrt(np.mean(err_mm**2))),
            gt_track_rot_rms_deg=float(np.sqrt(np.mean(err_deg**2))),
            gt_track_pos_max_mm=float(err_mm.max()), gt_track_rot_max_deg=float(err_deg.max()),
        )  # fmt: skip
    else:
        summary.update(gt_track_pos_rms_mm=None, gt_track_rot_rms_deg=None)
    out = make_out_dir(out, stale=OUTPUTS)
    _write_poses(out / "poses.csv", ts, T_est, lost, err_mm, err_deg)
    _plot_overlay(out / "overlay.png", snaps, solver)
    _plot_error(out / "error.png", ts, err_mm, err_deg, lost, solver)
    # Last and atomically: a summary.json is there only when the run's other outputs are.
    write_text_atomic(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    return summary


def _write_poses(path: Path, ts, T_est, lost, err_mm, err_deg) -> None:
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(T_est[:, :3, :3]).as_quat() if len(T_est) else np.zeros((0, 4))
    cols = [ts, T_est[:, 0, 3], T_est[:, 1, 3], T_est[:, 2, 3], *q.T, lost.astype(int)]
    header = "t_us,x_m,y_m,z_m,qx,qy,qz,qw,lost"
    fmt = ["%d", "%.6f", "%.6f", "%.6f", "%.8f", "%.8f", "%.8f", "%.8f", "%d"]
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


def run(args: argparse.Namespace) -> int:
    from evservo.tracking import SOLVERS

    camera = load_camera_file(args.camera) if args.camera else None
    init = parse_pose(args.init_pose) if args.init_pose else None
    solvers = SOLVERS if args.compare else (args.solver,)
    # Checked (and cleared of an earlier run's files) before any tracking starts.
    outs = {solver: prepare_out_dir(Path(args.out) / solver if args.compare else args.out, stale=OUTPUTS)
            for solver in solvers}  # fmt: skip
    rows = []
    for solver in solvers:
        s = track_file(
            args.recording, solver, outs[solver], model=args.model, init_pose=init,
            camera=camera, frontend=args.frontend, batch_us=args.batch_us, max_seconds=args.max_seconds,
            progress=not args.quiet,
        )  # fmt: skip
        rows.append(s)
        if s["interrupted"]:
            break

    def fmt(v, spec):
        return "n/a" if v is None else format(v, spec)

    print(f"{'solver':>8} {'pos RMS mm':>11} {'rot RMS deg':>12} {'lost':>5} {'updates/s':>10} {'events':>11}")
    for s in rows:
        print(
            f"{s['solver']:>8} {fmt(s['gt_track_pos_rms_mm'], '11.2f')} {fmt(s['gt_track_rot_rms_deg'], '12.3f')} "
            f"{s['lost']!s:>5} {s['tracker_rate_hz']:10.0f} {s['n_events']:11d}"
        )
    if any(s["n_time_clamped"] for s in rows):
        print(f"note: {rows[0]['n_time_clamped']} events stepped back in time and were clamped to the newest time")
    if rows[-1]["interrupted"]:
        print(f"evservo: interrupted: partial outputs (marked interrupted) in {outs[rows[-1]['solver']]}",
              file=sys.stderr)  # fmt: skip
        return 130
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    t = sub.add_parser("track", help="open-loop tracking of an event recording")
    t.add_argument("recording", help="event file: an evservo sim recording (.h5) or any evservo.io format (.raw, ...)")
    from evservo.tracking import FRONTENDS, SOLVERS

    t.add_argument("--solver", default="edft+", choices=SOLVERS)
    t.add_argument("--frontend", default="scarf", choices=FRONTENDS)
    t.add_argument("--compare", action="store_true", help="run edft+, edopts and edft; outputs in OUT/<solver>")
    t.add_argument("--model", help="object: built-in name or mesh path (default: the recording's)")
    t.add_argument("--init-pose", help="initial T_c_o as x,y,z,qx,qy,qz,qw (default: the recording's ground truth)")
    t.add_argument("--camera", help="JSON/YAML camera file (OpenCV-style K and distortion)")
    t.add_argument("--batch-us", type=int, default=1000, help="events per update, as a time slice (µs)")
    t.add_argument("--max-seconds", type=float, help="track only the first seconds of the recording")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.add_argument("--out", required=True, help="output directory")
    t.set_defaults(func=run)
