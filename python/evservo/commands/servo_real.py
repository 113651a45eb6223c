"""``evservo servo --robot ur:HOST|franka:HOST|sim``: assemble and run the real loop (:mod:`evservo.realloop`).

Inputs are checked before anything connects to the arm, in this order: robot spec, rig config, poses,
event source (camera or file), camera geometry, object model; then the arm is opened (read-only in
``--dry-run``) and the loop runs. Every failure of the inputs, of a driver package, of a camera or of
the link to the arm ends with one ``evservo: error: …`` line and a non-zero exit code (2 for bad
input or an unreachable device, 1 when a run that had started was stopped by its watchdog or an
error, 130 on Ctrl-C); a run that ends normally exits 0.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from evservo.interrupt import StopOnInterrupt

#: Options of the real loop that set a :class:`~evservo.realloop.RealLoopConfig` field (its defaults hold).
CONFIG_OPTIONS = {"settle": "settle_s", "stiffness": "stiffness", "rate": "rate_hz", "stale_after": "stale_after_s",
                  "max_jump": "max_jump_m", "max_jump_rad": "max_jump_rad", "replay_speed": "speed"}  # fmt: skip


def add_real_loop_arguments(group: Any) -> None:
    """The real loop's options that ``servo --robot`` and ``ros servo`` share: the desired pose and the
    controller's :class:`~evservo.realloop.RealLoopConfig` fields, their defaults in the help texts
    (``group``: a parser or an argument group)."""
    from dataclasses import fields

    from evservo.realloop import RealLoopConfig

    real = {f.name: f.default for f in fields(RealLoopConfig)}
    group.add_argument(
        "--desired-pose",
        metavar="x,y,z,qx,qy,qz,qw",
        help="object in camera to servo to (default: the config's, else the tracked pose when servoing starts)",
    )
    group.add_argument(
        "--settle",
        type=float,
        help=f"tracking before the arm moves, s from the first pose (default {real['settle_s']})",
    )
    group.add_argument("--stiffness", type=float, help=f"k of Eq. 6, 1/s² (default {real['stiffness']}, the paper's)")
    group.add_argument("--rate", type=float, help=f"control rate, Hz (default {real['rate_hz']})")
    group.add_argument(
        "--stale-after",
        type=float,
        help=f"watchdog: stop when no fresh pose for this long, s (default {real['stale_after_s']})",
    )
    group.add_argument(
        "--max-jump",
        type=float,
        metavar="M",
        help=f"watchdog: stop on a pose this far from the prediction, m (default {real['max_jump_m']})",
    )
    group.add_argument(
        "--max-jump-rad",
        type=float,
        metavar="RAD",
        help=f"the same in rotation, rad (default {real['max_jump_rad']})",
    )


class InputError(ValueError):
    """Bad command-line input (exit code 2)."""


def _pose(text: str, option: str) -> np.ndarray:
    from evservo.runtime.inputs import parse_object_pose

    try:
        return parse_object_pose(text, option)
    except ValueError as err:
        raise InputError(str(err)) from None


def _recording(path: Path) -> Any:
    from evservo.sim.record import is_recording, load_recording

    return load_recording(path) if path.suffix.lower() in (".h5", ".hdf5") and is_recording(path) else None


def run_real(args: argparse.Namespace) -> int:
    try:
        return _run_real(args)
    except (ImportError, OSError) as err:  # a missing driver package, an unreachable arm or camera
        print(f"evservo: error: {err}", file=sys.stderr)
        return 2


def _run_real(args: argparse.Namespace) -> int:
    from evservo import cameras, io
    from evservo.outputs import prepare_out_dir
    from evservo.realloop import OUTPUTS, RealLoopConfig, run_real_loop
    from evservo.robots.config import load_rig_config
    from evservo.robots.open import open_arm, parse_robot
    from evservo.runtime.inputs import resolve_camera
    from evservo.runtime.live_view import viewing
    from evservo.tracking import Tracker
    from evservo.viewer import open_viewer

    try:
        spec = parse_robot(args.robot)
    except ValueError as err:
        raise InputError(str(err)) from None
    if args.camera is None:
        raise InputError("--robot needs --camera prophesee|dv|FILE")
    if spec.kind != "sim" and args.config is None:
        raise InputError(f"--robot {spec.kind}:… needs --config RIG.yaml (camera intrinsics, hand-eye, limits)")
    if spec.kind != "franka" and args.realtime is not None:
        raise InputError("--realtime applies to franka:HOST only")
    # The outputs are checked before anything opens the camera or the arm: never a failure after a run.
    out = prepare_out_dir(Path(args.out) if args.out else Path("runs") / "servo-real", stale=OUTPUTS)
    rig = load_rig_config(args.config) if args.config else None
    given = {field: getattr(args, opt) for opt, field in CONFIG_OPTIONS.items() if getattr(args, opt) is not None}
    cfg = RealLoopConfig(duration_s=args.duration, feedforward=args.feedforward, dry_run=args.dry_run, **given)
    speed = cfg.speed
    # "search": start lost even where a start pose is known (a simulated recording's ground truth, the
    # rig's), as `evservo track --init-pose search` does; that ground truth then scores the lock.
    search = args.init_pose == "search"
    init = _pose(args.init_pose, "--init-pose") if args.init_pose and not search else None
    desired = _pose(args.desired_pose, "--desired-pose") if args.desired_pose else None

    # The event source, and what a simulated recording can stand in for (intrinsics, model, start pose).
    live = args.camera.partition(":")[0].lower() in cameras.LIVE_KINDS
    rec = None if live else (_recording(Path(args.camera)) if Path(args.camera).is_file() else None)
    source = cameras.open_source(args.camera, speed=speed)
    try:
        if live and rig is None:
            raise InputError(f"{args.camera} carries no camera intrinsics: give --config RIG.yaml")
        notes: list[str] = []
        try:
            camera = resolve_camera(
                args.camera, (source.width, source.height), rig.camera if rig else None,
                rec.camera if rec else None, "give --config RIG.yaml", notes,
            )  # fmt: skip
        except ValueError as err:
            raise InputError(f"{err}" + (f" (rig config {rig.path})" if rig else "")) from None
        for line in notes:
            print(f"note: {line}")
        model = args.model or (rig.model if rig else None) or (rec.object if rec else None)
        if model is None:
            raise InputError("give --model (a built-in name or a mesh path) or object.model in the rig config")
        if init is None and not search and rig is not None:
            init = rig.init_pose
        if init is None and not search and rec is not None:
            t_first = io.info(args.camera)["t_first_us"] or 0
            init = rec.gt_T[int(np.argmin(np.abs(rec.gt_t_us - t_first)))]
        if init is None:
            why = "--init-pose search" if search else "no start pose (--init-pose, object.init_pose in the config)"
            print(f"note: {why}: the tracker searches for the object and the arm holds still until it has locked; "
                  "the desired pose is captured then")  # fmt: skip
            cfg = replace(cfg, search=True)
        if desired is None and rig is not None:
            desired = rig.desired_pose
        # Re-acquisition on: after a loss the loop holds still until the tracker has found the object again.
        tracker = Tracker(camera, model, init, solver=args.tracker, reacquire=True)
        viewer = open_viewer(args.viewer, args.viewer_save)  # before the arm: a missing rerun is bad input
        try:
            arm = open_arm(spec, rig, args.dry_run, args.realtime or "enforce")
        except BaseException:
            if viewer is not None:
                viewer.close()
            raise
        meta = {
            "robot": args.robot, "camera": args.camera, "model": str(model), "tracker": args.tracker,
            "rig_config": str(rig.path) if rig else None, "T_c_o_init": None if init is None else init.tolist(),
            "replay_speed": speed,
        }  # fmt: skip
        print(
            f"servo (real): robot {args.robot}{' DRY RUN (the arm will not move)' if args.dry_run else ''}, "
            f"camera {args.camera} ({source.width}x{source.height}), model {model}, {args.tracker}, "
            f"{cfg.rate_hz:.0f} Hz, k = {cfg.stiffness}, {cfg.duration_s} s"
        )
        try:
            with viewing(viewer, tracker, source) as (events, on_cycle):
                result = run_real_loop(arm, events, tracker, cfg, desired, progress=print, meta=meta, on_cycle=on_cycle)
        finally:
            with StopOnInterrupt() as late:  # a Ctrl-C now must not cut the arm's close (or the outputs) short
                arm.close()
    finally:
        source.close()
    if late.requested:
        result = replace(result, interrupted=True)
    return report_real(result, out, gt=(rec.gt_t_us, rec.gt_T) if rec is not None else None)


def report_real(result: Any, out: Path, gt: tuple[np.ndarray, np.ndarray] | None = None) -> int:
    """Write a real run's outputs into ``out``, print its summary and return the exit code: 0 when
    it ended normally, 130 on Ctrl-C, 1 when its watchdog or an error stopped it."""
    from evservo.realloop import summarize, write_outputs

    # The run is over: a Ctrl-C while its outputs are written must not lose them (a second one still
    # raises, for a write that hangs).
    with StopOnInterrupt() as late:
        summary = summarize(result, gt=gt)
        paths = write_outputs(result, out, summary)
        print_real_summary(summary)
        print(f"figure: {paths['motion']}\nsummary: {paths['summary']}\nlog: {paths['log']}")
    if result.interrupted or late.requested:
        return 130
    if not result.completed:
        why = result.error or result.ended
        print(f"evservo: error: servoing stopped (arm stopped): {why}", file=sys.stderr)
        return 1
    return 0


def print_real_summary(s: dict) -> None:
    state = "ended normally" if s["completed"] else "STOPPED"
    print(f"\n{state} after {s['servo_s']:.2f} s of servoing: {s['ended']}")
    print(f"tracker {s['tracker_rate_hz']:.0f} steps/s, pose age {s['pose_age_mean_ms']:.1f} ms mean "
          f"({s['pose_age_max_ms']:.1f} max), {s['events']} events, {s['events_dropped']} dropped")  # fmt: skip
    passes = s["tracker_steps"].get("global", 0)
    if s["control_cycles"] and s["lost_fraction"] == 1.0:
        # Every pose was the search's placeholder: errors against it would be numbers about nothing.
        print(f"the tracker never locked on the object ({passes} global searches); the arm held still")
    else:
        print(f"servo error (estimate vs desired): {s['servo_pos_rms_mm']:.2f} mm, "
              f"{s['servo_rot_rms_deg']:.2f} deg RMS")  # fmt: skip
        if s.get("gt_track_pos_rms_mm") is not None:
            print(f"tracking error (estimate vs the recording's truth): {s['gt_track_pos_rms_mm']:.2f} mm, "
                  f"{s['gt_track_rot_rms_deg']:.2f} deg RMS")  # fmt: skip
    if s.get("loss") is not None and (s["config"]["search"] or s["loss"]["wrong_spells"] or passes):
        from evservo.runtime.loss import describe as describe_loss

        print(describe_loss(s["loss"], s["holding_s"]))
    print(f"control: {s['control_cycles']} cycles at {s['control_rate_hz']:.0f} Hz, {s['missed_cycles']} missed, "
          f"cycle {s['cycle_time_mean_ms']:.2f} ms mean / {s['cycle_time_max_ms']:.2f} max")  # fmt: skip
    g = s.get("gate") or {}
    if g:
        lim = ", ".join(f"{k} {v}" for k, v in g["limited"].items())
        verb = "logged (dry run)" if g["dry_run"] else "sent"
        print(f"arm: {g['commands']} commands {verb}; limited: {lim}; {g['halts']} stops")
    from evservo.runtime.watchdog import describe_spell

    for w in s["watchdog"]:
        print(describe_spell(w))
