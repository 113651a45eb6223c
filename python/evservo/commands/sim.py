"""``evservo sim record``: simulate an object moving in front of a static event camera into one HDF5
recording with ground truth (layout in :mod:`evservo.sim.record`)."""

from __future__ import annotations

import argparse


def run_record(args: argparse.Namespace) -> int:
    from evservo.outputs import check_out_file
    from evservo.sim.record import RecordConfig, record

    check_out_file(args.out, (".h5", ".hdf5"))
    config = RecordConfig(
        object=args.object, trajectory=args.trajectory, speed_mps=args.speed, rot_rate_dps=args.rot_rate,
        distance_m=args.distance, duration_s=args.duration, seed=args.seed, preset=args.preset,
        background_behind_m=args.background_behind, cell_m=args.cell, scale=args.scale, max_px=args.max_px,
    )  # fmt: skip
    s = record(args.out, config, progress=not args.quiet)
    print(
        f"{args.out}: {s['width']}x{s['height']}, {s['n_events']} events ({s['events_per_s'] / 1e6:.2f} Mev/s), "
        f"{s['n_renders']} renders, {s['compute_s']:.1f} s compute, real-time factor {s['realtime_factor']:.3f}"
    )
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("sim", help="event-camera simulation")
    ssub = s.add_subparsers(dest="sim_command", required=True)
    r = ssub.add_parser("record", help="render a moving object through the sensor model into an HDF5 recording")
    r.add_argument("--object", default="box", help="built-in object (box, drill, football) or a mesh file path")
    r.add_argument("--trajectory", default="trans-rot", help="trans, trans-rot, circle, figure8, stop-go or a CSV path")
    r.add_argument("--speed", type=float, default=0.4, help="peak target speed, m/s")
    r.add_argument("--rot-rate", type=float, default=30.0, help="peak angular rate of trans-rot, deg/s")
    r.add_argument("--distance", type=float, default=0.6, help="start depth Z of the object, m")
    r.add_argument("--duration", type=float, default=5.0, help="seconds")
    r.add_argument("--seed", type=int, default=1)
    r.add_argument("--preset", default="imx636", help="sensor model: clean, imx636, noisy")
    r.add_argument("--background-behind", type=float, default=0.6, help="background plane behind the object, m")
    r.add_argument("--cell", type=float, default=0.04, help="background texture cell, m")
    r.add_argument("--scale", type=float, default=1.0, help="sensor scale per side (0.5 = 640x360 IMX636)")
    r.add_argument("--max-px", type=float, default=0.5, help="adaptive sampling: max vertex motion per render, px")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument("--out", required=True, help="output .h5 file")
    r.set_defaults(func=run_record)
