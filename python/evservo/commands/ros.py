"""``evservo ros play|track|servo``: the ROS 2 nodes of :mod:`evservo.ros.nodes` and
:mod:`evservo.ros.servo` (after ``make ros``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def run_play(args: argparse.Namespace) -> int:
    from evservo.ros.nodes import play

    n = play(args.file, args.topic, rate=args.rate, wait_s=args.wait)
    print(f"ros play: {n} EventPacket messages on {args.topic}")
    return 0


def run_track(args: argparse.Namespace) -> int:
    from evservo.camera_file import load_camera_file
    from evservo.ros.nodes import track
    from evservo.runtime.inputs import parse_pose
    from evservo.tracking import SOLVERS
    from evservo.viewer import open_viewer

    if args.solver not in SOLVERS:
        raise ValueError(f"unknown solver {args.solver!r}; choose one of {SOLVERS}")
    camera = load_camera_file(args.camera) if args.camera else None
    viewer = open_viewer(args.viewer, args.viewer_save)
    try:
        n = track(
            args.model, parse_pose(args.init_pose), camera=camera, events_topic=args.events_topic,
            camera_info_topic=args.camera_info_topic, pose_topic=args.pose_topic, status_topic=args.status_topic,
            solver=args.solver, idle_exit_s=args.idle_exit, viewer=viewer,
        )  # fmt: skip
    finally:
        if viewer is not None:
            viewer.close()
    print(f"ros track: {n} poses on {args.pose_topic}")
    return 0


def run_servo(args: argparse.Namespace) -> int:
    try:
        return _run_servo(args)
    except OSError as err:  # no CameraInfo or end-effector pose in time, a lost pose topic
        print(f"evservo: error: {err}", file=sys.stderr)
        return 2


def _run_servo(args: argparse.Namespace) -> int:
    from evservo.camera_file import load_camera_file
    from evservo.commands.servo_real import CONFIG_OPTIONS, report_real
    from evservo.outputs import prepare_out_dir
    from evservo.realloop import OUTPUTS, RealLoopConfig
    from evservo.robots.config import load_rig_config
    from evservo.ros.nodes import _ros
    from evservo.ros.servo import run_servo
    from evservo.runtime.inputs import parse_object_pose
    from evservo.tracking import SOLVERS
    from evservo.viewer import open_viewer

    if args.tracker not in SOLVERS:
        raise ValueError(f"unknown solver {args.tracker!r}; choose one of {SOLVERS}")
    _ros()  # ROS 2 installed, or the install hint before anything else
    rig = load_rig_config(args.config)
    out = prepare_out_dir(Path(args.out) if args.out else Path("runs") / "ros-servo", stale=OUTPUTS)
    options = {**CONFIG_OPTIONS, "start_timeout": "start_timeout_s"}
    given = {field: getattr(args, opt) for opt, field in options.items() if getattr(args, opt, None) is not None}
    cfg = RealLoopConfig(duration_s=args.duration, feedforward=args.feedforward, dry_run=args.dry_run, **given)
    init = parse_object_pose(args.init_pose, "--init-pose") if args.init_pose else rig.init_pose
    if init is None:
        raise ValueError("give --init-pose x,y,z,qx,qy,qz,qw (object in camera) or object.init_pose in the config")
    desired = parse_object_pose(args.desired_pose, "--desired-pose") if args.desired_pose else rig.desired_pose
    model = args.model or rig.model
    if model is None:
        raise ValueError("give --model (a built-in name or a mesh path) or object.model in the config")
    camera = load_camera_file(args.camera) if args.camera else (None if args.camera_from_topic else rig.camera)
    if args.ee_pose_timeout is not None and not args.ee_pose_timeout > 0:
        raise ValueError(f"--ee-pose-timeout must be > 0, got {args.ee_pose_timeout}")
    viewer = open_viewer(args.viewer, args.viewer_save)
    meta = {"robot": f"ros:{args.twist_topic}", "camera": f"ros:{args.events_topic}", "model": str(model),
            "tracker": args.tracker, "rig_config": str(rig.path), "T_c_o_init": init.tolist(),
            "ee_pose_topic": args.ee_pose_topic}  # fmt: skip
    print(
        f"ros servo: events {args.events_topic}, twists on {args.twist_topic} (frame {args.ee_frame})"
        f"{' DRY RUN (nothing published)' if args.dry_run else ''}, model {model}, {args.tracker}, "
        f"{cfg.rate_hz:.0f} Hz, k = {cfg.stiffness}, {cfg.duration_s} s"
    )
    result = run_servo(
        model, init, rig, cfg, camera=camera, desired=desired, solver=args.tracker, events_topic=args.events_topic,
        camera_info_topic=args.camera_info_topic, twist_topic=args.twist_topic, ee_frame=args.ee_frame,
        ee_pose_topic=args.ee_pose_topic, ee_pose_timeout_s=args.ee_pose_timeout or 0.2, viewer=viewer, meta=meta,
        progress=print,
    )  # fmt: skip
    return report_real(result, out)


def add_parser(sub: argparse._SubParsersAction) -> None:
    from evservo.commands.track import add_viewer_arguments

    r = sub.add_parser("ros", help="ROS 2 nodes (after `make ros`): play a file, track or servo from a topic")
    rs = r.add_subparsers(dest="ros_command", required=True)
    p = rs.add_parser("play", help="publish an event file as event_camera_msgs/EventPacket (evt3) in real time")
    p.add_argument("file", help="any event file evservo.io reads (.raw, .h5, a bag, ...)")
    p.add_argument("--topic", default="/event_camera/events")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed (1 = real time)")
    p.add_argument("--wait", type=float, default=10.0, help="seconds to wait for a subscriber before playing")
    p.set_defaults(func=run_play)
    t = rs.add_parser("track", help="track from EventPacket; publish PoseStamped, /tf and a status")
    t.add_argument("--model", required=True, help="object: built-in name or mesh path")
    t.add_argument("--init-pose", required=True, help="initial T_c_o as x,y,z,qx,qy,qz,qw")
    t.add_argument("--camera", help="camera file (default: the first CameraInfo on --camera-info-topic)")
    t.add_argument("--events-topic", default="/event_camera/events")
    t.add_argument("--camera-info-topic", default="/event_camera/camera_info")
    t.add_argument("--pose-topic", default="/evservo/pose")
    t.add_argument("--status-topic", default="/evservo/status")
    t.add_argument("--solver", default="edft+", help="edft+, edopts or edft")
    t.add_argument("--idle-exit", type=float, help="exit after this many seconds without packets (once some came)")
    add_viewer_arguments(t)
    t.set_defaults(func=run_track)
    _add_servo_parser(rs)


def _add_servo_parser(rs: argparse._SubParsersAction) -> None:
    from dataclasses import fields

    from evservo.commands.servo_real import add_real_loop_arguments
    from evservo.commands.track import add_viewer_arguments
    from evservo.realloop import RealLoopConfig

    real = {f.name: f.default for f in fields(RealLoopConfig)}
    s = rs.add_parser(
        "servo", help="the real loop through ROS: EventPacket in, PBVS as TwistStamped out (MoveIt Servo, ...)"
    )
    s.add_argument(
        "--config",
        required=True,
        metavar="RIG.yaml",
        help="rig config: hand-eye T_e_c, limits, workspace, intrinsics, object defaults",
    )
    s.add_argument("--model", help="object: built-in name or mesh path (default: the config's)")
    s.add_argument("--init-pose", metavar="x,y,z,qx,qy,qz,qw", help="object in camera at start (default: config's)")
    cam = s.add_mutually_exclusive_group()
    cam.add_argument("--camera", help="camera file (default: the config's intrinsics)")
    cam.add_argument(
        "--camera-from-topic",
        action="store_true",
        help="take the intrinsics from the first CameraInfo on --camera-info-topic",
    )
    s.add_argument("--events-topic", default="/event_camera/events")
    s.add_argument("--camera-info-topic", default="/event_camera/camera_info")
    s.add_argument(
        "--twist-topic", default="/servo_node/delta_twist_cmds", help="TwistStamped out (default: MoveIt Servo's input)"
    )
    s.add_argument("--ee-frame", default="tool0", help="frame_id of the twists: the end effector (default tool0)")
    s.add_argument(
        "--ee-pose-topic",
        help="PoseStamped of the end effector in the robot base frame (default: integrate the twists)",
    )
    s.add_argument("--ee-pose-timeout", type=float, help="a pose older than this (s) is a lost link (default 0.2)")
    s.add_argument("--tracker", default="edft+", help="edft+, edopts or edft")
    s.add_argument("--duration", type=float, default=real["duration_s"], help="servoing time, s")
    s.add_argument("--feedforward", action="store_true", help="feed the target's estimated motion forward")
    add_real_loop_arguments(s)
    s.add_argument(
        "--start-timeout", type=float, help=f"longest wait for the first events, s (default {real['start_timeout_s']})"
    )
    s.add_argument("--dry-run", action="store_true", help="run everything but publish no twist (commands logged)")
    s.add_argument("--out", help="output directory (summary.json, log.csv, motion.png; default runs/ros-servo)")
    add_viewer_arguments(s)
    s.set_defaults(func=run_servo)
