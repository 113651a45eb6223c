"""``evservo calib intrinsics|hand-eye|capture``: calibrate the rig from events (:mod:`evservo.calib`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _board(args: argparse.Namespace):
    from evservo.calib.board import parse_board

    return parse_board(args.board, args.square)


def _check_out(path: str | None) -> None:
    """A YAML file can be written at ``--out`` (checked before any work)."""
    from evservo.outputs import check_out_file

    if path is not None:
        check_out_file(path, (".yaml", ".yml"))


def _scan(recording: str, board):
    """The recording's views; a clear error when it has no blinks or never the whole board."""
    from evservo.calib.views import scan_recording

    if not Path(recording).is_file():
        raise FileNotFoundError(f"no such recording: {recording}")
    scan = scan_recording(recording, board)
    if scan.n_blinks == 0:
        raise ValueError(f"{recording}: no blinks found (the event rate never peaks); the screen must blink the board")
    if not scan.views:
        larger = f" ({scan.n_larger} showed a board with more squares)" if scan.n_larger else ""
        raise ValueError(
            f"{recording}: the whole {board} board was found in none of the {scan.n_blinks} blinks{larger}; "
            "check --board (inner corners, COLSxROWS) and that the whole board is in view"
        )
    return scan


def run_intrinsics(args: argparse.Namespace) -> int:
    from evservo.calib.camfile import write_camera_file
    from evservo.calib.intrinsics import calibrate_intrinsics

    board = _board(args)
    _check_out(args.out)
    scan = _scan(args.recording, board)
    result = calibrate_intrinsics(scan.views, board, scan.width, scan.height, args.model)
    log = sys.stderr if args.json else sys.stdout
    print(
        f"{args.recording}: {scan.n_blinks} blinks, whole board in {scan.n_detected}, {len(scan.views)} views", file=log
    )
    for i, (view, e) in enumerate(zip(scan.views, result.view_rms_px, strict=True)):
        state = "rejected (outlier)" if i in result.rejected else f"{e:.3f} px"
        print(f"  view {i + 1:2d} at {view.t_mid_us * 1e-6:8.3f} s, {view.n_blinks} blink(s): {state}", file=log)
    c = result.camera
    print(
        f"{args.model}: fx {c.fx:.2f} fy {c.fy:.2f} cx {c.cx:.2f} cy {c.cy:.2f} dist "
        f"{' '.join(f'{v:.5f}' for v in c.dist)}; RMS {result.rms_px:.3f} px over {len(result.used)} views",
        file=log,
    )
    if args.out:
        write_camera_file(args.out, c, f"{args.model} model, RMS {result.rms_px:.3f} px, {len(result.used)} views")
        print(f"wrote {args.out}", file=log)
    if args.json:
        print(json.dumps(result.summary()))
    return 0


def run_hand_eye(args: argparse.Namespace) -> int:
    from evservo.calib.camfile import merge_rig_file
    from evservo.calib.handeye import calibrate_hand_eye, match_views, read_poses
    from evservo.camera_file import load_camera_file

    board = _board(args)
    _check_out(args.out)
    if not args.max_dt > 0:
        raise ValueError(f"--max-dt must be > 0 s, got {args.max_dt}")
    camera = load_camera_file(args.camera)
    t_s, T_b_e = read_poses(args.poses)
    scan = _scan(args.recording, board)
    if (camera.width, camera.height) != (scan.width, scan.height):
        raise ValueError(
            f"{args.camera} is for a {camera.width}x{camera.height} sensor, "
            f"the recording's is {scan.width}x{scan.height}"
        )
    order = match_views(scan.views, t_s, args.max_dt)
    result = calibrate_hand_eye([scan.views[i] for i in order], T_b_e, board, camera)
    log = sys.stderr if args.json else sys.stdout
    for name, T in result.methods.items():
        print(f"  {name:10s} t = {' '.join(f'{v * 1e3:8.2f}' for v in T[:3, 3])} mm", file=log)
    t = result.T_e_c[:3, 3] * 1e3
    print(
        f"T_e_c (refined): t = {t[0]:.2f} {t[1]:.2f} {t[2]:.2f} mm; methods spread {result.rot_spread_deg:.3f} deg, "
        f"{result.trans_spread_mm:.2f} mm; reprojection RMS {result.rms_px:.3f} px over {result.views_used} views",
        file=log,
    )
    if args.out:
        existed = merge_rig_file(
            args.out, camera, result.T_e_c, f"{result.views_used} views, RMS {result.rms_px:.3f} px"
        )
        print(f"{'updated' if existed else 'wrote'} {args.out}", file=log)
    if args.json:
        print(json.dumps(result.summary()))
    return 0


def run_capture(args: argparse.Namespace) -> int:
    from evservo.calib.capture import capture
    from evservo.cameras import open_source
    from evservo.outputs import make_out_dir, prepare_out_dir
    from evservo.robots.open import open_arm, parse_robot

    board = _board(args)
    robot = parse_robot(args.robot)
    out = prepare_out_dir(args.out)
    try:
        source = open_source(args.camera)
    except ImportError as err:
        raise RuntimeError(str(err)) from err
    try:
        arm = open_arm(robot, None, dry_run=True)  # read-only: capture only reads the flange pose
    except (ImportError, ConnectionError) as err:  # a missing driver package, an unreachable controller
        source.close()
        raise RuntimeError(str(err)) from err
    except BaseException:
        source.close()
        raise
    make_out_dir(out)
    try:
        result = capture(source, arm, board, args.views, out / "calib.h5", out / "poses.csv", hold_s=args.hold)
    finally:
        arm.close()
    print(f"wrote {out / 'calib.h5'} ({result.n_events} events) and {out / 'poses.csv'} ({len(result.t_s)} views)")
    return 0


def _board_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--board", required=True, help="inner corners COLSxROWS, as OpenCV counts them (e.g. 9x6)")
    p.add_argument("--square", type=float, required=True, help="side of a board square on the screen, metres")


def add_parser(sub: argparse._SubParsersAction) -> None:
    c = sub.add_parser("calib", help="calibrate the camera and the hand-eye transform from a blinking checkerboard")
    csub = c.add_subparsers(dest="calib_command", required=True)

    i = csub.add_parser("intrinsics", help="intrinsics and distortion from a blinking-checkerboard recording")
    i.add_argument("recording", help="event file (any format evservo reads)")
    _board_options(i)
    i.add_argument("--model", default="k1k2", choices=("k1", "k1k2", "full"), help="distortion terms to estimate")
    i.add_argument("--out", help="camera file to write (YAML, evservo's camera-file layout)")
    i.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    i.set_defaults(func=run_intrinsics)

    h = csub.add_parser("hand-eye", help="camera-to-flange transform T_e_c from board views and arm poses")
    h.add_argument("recording", help="event file of the views")
    h.add_argument("--poses", required=True, help="CSV t_s,x_m,y_m,z_m,qx,qy,qz,qw: flange in base at each view")
    _board_options(h)
    h.add_argument("--camera", required=True, help="camera file (from calib intrinsics; OpenCV, ROS YAML too)")
    h.add_argument("--max-dt", type=float, default=0.5, help="largest time between a pose and its view, s")
    h.add_argument("--out", help="rig config to write or update (hand_eye and camera sections)")
    h.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    h.set_defaults(func=run_hand_eye)

    k = csub.add_parser("capture", help="record calibration views on a real rig (the arm is only read)")
    k.add_argument("--robot", required=True, help="ur:HOST, franka:HOST or sim")
    k.add_argument("--camera", required=True, help="prophesee[:SERIAL], dv[:SERIAL] or an event file")
    _board_options(k)
    k.add_argument("--views", type=int, default=20, help="views to record")
    k.add_argument("--hold", type=float, default=1.0, help="seconds of events per view")
    k.add_argument("--out", required=True, help="output folder: calib.h5 and poses.csv")
    k.set_defaults(func=run_capture)
