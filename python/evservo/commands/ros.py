"""``evservo ros play|track``: the ROS 2 nodes of :mod:`evservo.ros.nodes` (after ``make ros``)."""

from __future__ import annotations

import argparse


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

    if args.solver not in SOLVERS:
        raise ValueError(f"unknown solver {args.solver!r}; choose one of {SOLVERS}")
    camera = load_camera_file(args.camera) if args.camera else None
    n = track(
        args.model, parse_pose(args.init_pose), camera=camera, events_topic=args.events_topic,
        camera_info_topic=args.camera_info_topic, pose_topic=args.pose_topic, status_topic=args.status_topic,
        solver=args.solver, idle_exit_s=args.idle_exit,
    )  # fmt: skip
    print(f"ros track: {n} poses on {args.pose_topic}")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser("ros", help="ROS 2 nodes (after `make ros`): play a file, track from a topic")
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
    t.set_defaults(func=run_track)
