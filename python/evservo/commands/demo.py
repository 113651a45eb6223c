"""``evservo demo``: the default end-to-end run."""

from __future__ import annotations

import argparse

import numpy as np


def run(args: argparse.Namespace) -> int:
    """Open-loop tracking of the built-in box on events synthesised from its edges, all three solvers."""
    from tqdm import tqdm

    import evservo
    from evservo import geometry, trajectories
    from evservo.openloop import track_batches
    from evservo.synth import edge_events
    from evservo.tracking import model_point_set

    cam = evservo.Camera.imx636()
    T0 = geometry.pose((0.0, 0.0, args.distance), (0.35, -0.45, 0.1))
    n_ms = int(args.duration * 1000)
    times = np.arange(0, n_ms * 1000 + 1, 1000, dtype=np.int64)
    traj = trajectories.make_trajectory(args.trajectory, speed_mps=args.speed)
    truth = trajectories.apply(traj(times * 1e-6), T0)
    print(
        f"evservo {evservo.__version__} demo: {args.object} at Z = {args.distance} m, {args.trajectory} at "
        f"{args.speed} m/s for {args.duration} s; events from the model's edges + 20 % noise, 1 ms batches"
    )
    dense = model_point_set(cam, args.object, T0, n_points=30000, seed=args.seed)
    batches = edge_events(cam, dense, truth, times, noise_fraction=0.2, seed=args.seed)
    rows = []
    for solver in ("edft+", "edopts", "edft"):
        trk = evservo.Tracker(cam, args.object, T0, solver=solver)
        res = track_batches(trk, tqdm(batches, desc=f"{solver:>7}", unit="ms", leave=False), truth[1:])
        rows.append((solver, res))
    print(f"\n{'solver':>8} {'pos RMS mm':>11} {'rot RMS deg':>12} {'lost at end':>12} {'updates/s':>10}")
    for solver, res in rows:
        print(
            f"{solver:>8} {res.pos_rms_mm:11.2f} {res.rot_rms_deg:12.3f} {bool(res.lost[-1]):>12} {res.rate_hz:10.0f}"
        )
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    d = sub.add_parser("demo", help="run the default end-to-end demo")
    d.add_argument("--object", default="box")
    d.add_argument("--trajectory", default="trans-rot")
    d.add_argument("--speed", type=float, default=0.4, help="peak target speed, m/s")
    d.add_argument("--distance", type=float, default=0.6, help="camera–object distance Z, m")
    d.add_argument("--duration", type=float, default=3.0, help="seconds")
    d.add_argument("--seed", type=int, default=1)
    d.set_defaults(func=run)
