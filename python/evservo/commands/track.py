"""``evservo track``: open-loop tracking of an event recording (:mod:`evservo.runtime.track`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def run(args: argparse.Namespace) -> int:
    from evservo.camera_file import load_camera_file
    from evservo.outputs import prepare_out_dir
    from evservo.runtime.inputs import parse_pose
    from evservo.runtime.track import OUTPUTS, track_file
    from evservo.tracking import SOLVERS
    from evservo.viewer import open_viewer

    camera = load_camera_file(args.camera) if args.camera else None
    init = "search" if args.init_pose == "search" else parse_pose(args.init_pose) if args.init_pose else None
    solvers = SOLVERS if args.compare else (args.solver,)
    # Checked (and cleared of an earlier run's files) before any tracking starts.
    outs = {solver: prepare_out_dir(Path(args.out) / solver if args.compare else args.out, stale=OUTPUTS)
            for solver in solvers}  # fmt: skip
    rows, notes = [], []
    for solver in solvers:
        viewer = open_viewer(args.viewer, _viewer_file(args.viewer_save, solver, args.compare))
        try:
            s = track_file(
                args.recording, solver, outs[solver], model=args.model, init_pose=init,
                camera=camera, frontend=args.frontend, batch_us=args.batch_us, max_seconds=args.max_seconds,
                progress=not args.quiet, notes=notes, viewer=viewer, topic=args.topic,
            )  # fmt: skip
        finally:
            if viewer is not None:
                viewer.close()
        rows.append(s)
        if s["interrupted"]:
            break
    for line in dict.fromkeys(notes):
        print(f"note: {line}")

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


def _viewer_file(save: str | None, solver: str, compare: bool) -> str | None:
    """``--viewer-save`` for one solver: with ``--compare`` one file per solver (``run-edft.rrd``)."""
    if save is None or not compare:
        return save
    p = Path(save)
    return str(p.with_name(f"{p.stem}-{solver.replace('+', 'plus')}{p.suffix}"))


def add_viewer_arguments(p: argparse.ArgumentParser) -> None:
    """``--viewer`` and ``--viewer-save`` (shared by track and servo)."""
    p.add_argument(
        "--viewer", choices=("rerun",), help="show the run live in rerun's web viewer (pip install 'evservo[viewer]')"
    )
    p.add_argument("--viewer-save", metavar="RUN.rrd", help="write the rerun recording to this .rrd file")


def add_parser(sub: argparse._SubParsersAction) -> None:
    t = sub.add_parser("track", help="open-loop tracking of an event recording")
    t.add_argument("recording", help="event file: an evservo sim recording (.h5) or any evservo.io format (.raw, ...)")
    from evservo.tracking import FRONTENDS, SOLVERS

    t.add_argument("--solver", default="edft+", choices=SOLVERS)
    t.add_argument("--frontend", default="scarf", choices=FRONTENDS)
    t.add_argument("--compare", action="store_true", help="run edft+, edopts and edft; outputs in OUT/<solver>")
    t.add_argument("--model", help="object: built-in name or mesh path (default: the recording's)")
    t.add_argument(
        "--init-pose",
        help="initial T_c_o as x,y,z,qx,qy,qz,qw, or 'search': start lost and search the image for the object "
        "even when the recording has ground truth (default: the recording's ground truth, else search)",
    )
    t.add_argument("--topic", help="the event topic of a ROS bag holding several")
    t.add_argument("--camera", help="camera file (YAML/JSON; evservo's layout, OpenCV YAML or ROS camera_info)")
    t.add_argument("--batch-us", type=int, default=1000, help="events per update, as a time slice (µs)")
    t.add_argument("--max-seconds", type=float, help="track only the first seconds of the recording")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    add_viewer_arguments(t)
    t.add_argument("--out", required=True, help="output directory")
    t.set_defaults(func=run)
