"""``evservo servo``: closed-loop servoing of a moving object, on the simulated bench (``--sim``) or on a
real rig (``--robot ur:HOST|franka:HOST|sim`` with ``--camera``, ``--model`` and ``--config``; the loop
itself is :mod:`evservo.realloop`)."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

# The paper's Tables I and II (RMS servoing error over the run: pos. mm, rot. deg), for comparison.
PAPER_TABLE = {
    ("box", 0.9, "trans", "edft+"): (20.57, 1.85),
    ("box", 0.9, "trans", "edopts"): (21.41, 3.63),
    ("box", 0.6, "trans", "edft+"): (22.01, 5.68),
    ("box", 0.6, "trans", "edopts"): (26.27, 8.38),
    ("box", 0.6, "trans-rot", "edft+"): (30.78, 5.28),
    ("box", 0.6, "trans-rot", "edopts"): (58.20, 5.42),
    ("drill", 0.9, "trans", "edft+"): (18.90, 1.88),
    ("football", 0.9, "trans", "edft+"): (21.64, 3.53),
}


def add_episode_arguments(
    p: argparse.ArgumentParser, *, distance: float, speed: float, duration: float, feedforward: bool = False
) -> None:
    """Options shared by ``servo`` and ``demo`` (defaults differ)."""
    from evservo.sim.episode import COST_MODELS, PREDICTORS
    from evservo.tracking import SOLVERS

    p.add_argument("--object", default="box", help="box, drill, football or a mesh path")
    p.add_argument("--tracker", default="edft+", choices=SOLVERS)
    p.add_argument(
        "--trajectory", default="trans", help="trans, trans-rot, circle, figure8, stop-go, reversal or a CSV"
    )
    p.add_argument("--speed", type=float, default=speed, help="peak target speed, m/s")
    p.add_argument("--rot-rate", type=float, default=30.0, help="peak target rotation rate (trans-rot), deg/s")
    p.add_argument("--distance", type=float, default=distance, help="camera–object distance Z, m")
    p.add_argument("--duration", type=float, default=duration, help="servoing time, s")
    p.add_argument("--seed", type=int, default=1)
    law = p.add_mutually_exclusive_group()
    law.add_argument(
        "--feedforward",
        action="store_true",
        default=feedforward,
        help="our controller: the target's motion fed forward within what the arm can deliver"
        + (" (default)" if feedforward else ""),
    )
    law.add_argument(
        "--paper-law",
        dest="feedforward",
        action="store_false",
        help="the paper's literal Eq. (5)-(6) loop" + ("" if feedforward else " (default)"),
    )
    p.add_argument(
        "--predictor",
        default="velocity",
        choices=PREDICTORS,
        help="feed-forward: extrapolate the target across the latencies at constant velocity or acceleration",
    )
    p.add_argument("--cost-model", default="measured", choices=COST_MODELS, help="tracker time charged to the clock")
    p.add_argument("--dropout", type=float, nargs=2, metavar=("START", "END"), help="lose all events in [START, END) s")
    p.add_argument(
        "--events",
        default="edges",
        choices=("edges", "render"),
        help="event source: the model's edges (fast) or the rendered event camera (realistic, slow)",
    )
    p.add_argument(
        "--render-arms",
        action="store_true",
        help="also draw the UR5e and Panda arms into the rendered event camera (needs --events render)",
    )
    p.add_argument("--out", type=Path, help="output directory (summary.json, log.csv, motion.png)")


def config_from_args(args: argparse.Namespace):
    """The :class:`~evservo.sim.episode.EpisodeConfig` of parsed options."""
    from evservo.sim.episode import EpisodeConfig

    return EpisodeConfig(
        object=args.object,
        tracker=args.tracker,
        trajectory=args.trajectory,
        speed_mps=args.speed,
        rot_rate_dps=args.rot_rate,
        distance_m=args.distance,
        duration_s=args.duration,
        seed=args.seed,
        feedforward=args.feedforward,
        predictor=args.predictor,
        cost_model=args.cost_model,
        dropout_s=tuple(args.dropout) if args.dropout else None,
        event_source=args.events,
        render_arms=getattr(args, "render_arms", False),
    )


def run_with_report(args: argparse.Namespace, default_out: Path, compare_paper_law: bool = False) -> int:
    """Run the episode with a progress bar, write the outputs, print the summary beside the paper; with
    ``compare_paper_law`` and feed-forward on, run the same episode with the paper's literal law too
    (into ``OUT/paper-law``) and print one line for each and one for the paper."""
    if getattr(args, "render_arms", False) and args.events != "render":
        print(
            "evservo: error: --render-arms draws the arms in the rendered event camera: "
            f"it needs --events render, not --events {args.events}",
            file=sys.stderr,
        )
        return 2
    cfg = config_from_args(args)
    out = args.out or default_out
    print(
        f"servo (sim): {cfg.object}, {cfg.tracker}, Z = {cfg.distance_m} m, {cfg.trajectory} at {cfg.speed_mps} m/s, "
        f"{cfg.duration_s} s, {_law(cfg.feedforward, cfg.predictor)}, cost model {cfg.cost_model}"
    )
    summary = _run_and_write(cfg, out)
    print_summary(summary)
    if compare_paper_law and cfg.feedforward:
        literal = replace(cfg, feedforward=False)
        print(f"\nthe same episode with the paper's literal Eq. (5)-(6) loop ({out / 'paper-law'}):")
        lit = _run_and_write(literal, out / "paper-law")
        print_comparison(summary, lit)
    return 0


def _law(feedforward: bool, predictor: str) -> str:
    return f"our controller (feed-forward, {predictor} predictor)" if feedforward else "the paper's literal law"


def _run_and_write(cfg, out: Path) -> dict:
    """Run one episode with a progress bar and write its outputs into ``out``; returns its summary."""
    from tqdm import tqdm

    from evservo.sim.episode import run_episode, summarize, write_outputs

    with tqdm(total=round(cfg.duration_s * 1000), unit="ms", desc="simulated", leave=False) as bar:
        result = run_episode(cfg, progress=bar.update)
    summary = summarize(result)
    paths = write_outputs(result, out, summary)
    print(f"figure: {paths['motion']}\nsummary: {paths['summary']}\nlog: {paths['log']}")
    return summary


def print_comparison(ours: dict, literal: dict) -> None:
    """One line each: our controller, the paper's literal law on the same episode, the paper's numbers."""
    c = ours["config"]
    print(f"\n{'':40}{'servo pos mm':>13}{'rot deg':>9}{'lag s':>8}  tracking")
    for name, s in (("ours (feed-forward within arm limits)", ours), ("paper's literal Eq. (5)-(6)", literal)):
        held = "held" if s["completed"] else f"lost at {s['simulated_s']:.2f} s"
        print(f"{name:40}{s['servo_pos_rms_mm']:13.2f}{s['servo_rot_rms_deg']:9.2f}{s['lag_s']:8.3f}  {held}")
    row = PAPER_TABLE.get((c["object"], round(c["distance_m"], 2), c["trajectory"], c["tracker"]))
    if row:
        print(f"{'paper, Table I/II (real bench)':40}{row[0]:13.2f}{row[1]:9.2f}{'≈0.15':>8}")


def print_summary(s: dict) -> None:
    """The main metrics, next to the paper's row when there is one."""
    c = s["config"]
    state = "held to the end" if s["completed"] else f"ENDED EARLY at {s['simulated_s']:.2f} s: {s['ended']}"
    print(f"\ntracking {state}; tracker {s['tracker_rate_hz']:.0f} steps/s, pose age {s['pose_age_mean_ms']:.1f} ms")
    print(f"{'':34}{'pos. RMS mm':>12}{'rot. RMS deg':>14}")
    print(f"{'servo error (estimate vs desired)':34}{s['servo_pos_rms_mm']:12.2f}{s['servo_rot_rms_deg']:14.2f}")
    print(f"{'servo error (truth vs desired)':34}{s['gt_servo_pos_rms_mm']:12.2f}{s['gt_servo_rot_rms_deg']:14.2f}")
    print(f"{'tracking error (estimate vs truth)':34}{s['gt_track_pos_rms_mm']:12.2f}{s['gt_track_rot_rms_deg']:14.2f}")
    row = PAPER_TABLE.get((c["object"], round(c["distance_m"], 2), c["trajectory"], c["tracker"]))
    if row:
        print(f"{'paper, Table I/II (real bench)':34}{row[0]:12.2f}{row[1]:14.2f}")
    print(f"camera lag behind target {s['lag_s']:.3f} s (paper ≈ 0.15 s); camera rotation mean "
          f"{s['camera_rot_mean_deg']:.2f}° (paper 1.89° at Z = 0.6 m)")  # fmt: skip
    for w in s["watchdog"]:
        print(f"watchdog: no fresh pose since {w['last_pose_s']:.3f} s, braking from {w['start_s']:.3f} s, "
              f"at rest {w['zero_s']} s, servoing again {w['end_s']} s")  # fmt: skip


def run(args: argparse.Namespace) -> int:
    if not args.sim:
        from evservo.commands.servo_real import run_real

        return run_real(args)
    given = [f"--{name.replace('_', '-')}" for name in REAL_ONLY if getattr(args, name) not in (None, False)]
    if given:
        raise ValueError(f"{', '.join(given)} only apply with --robot (the real loop), not with --sim")
    return run_with_report(args, Path("runs") / "servo")


#: Options of the real loop only (``--sim`` refuses them).
REAL_ONLY = ("camera", "model", "config", "init_pose", "desired_pose", "settle", "stiffness", "rate", "dry_run",
             "replay_speed", "stale_after", "realtime")  # fmt: skip


def add_parser(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("servo", help="closed-loop servoing of a moving object")
    mode = s.add_mutually_exclusive_group(required=True)
    mode.add_argument("--sim", action="store_true", help="the simulated dual-arm bench")
    mode.add_argument(
        "--robot",
        metavar="ur:HOST|franka:HOST|sim",
        help="the real loop on a UR (ur-rtde) or Franka (franky) arm, or on a kinematic stand-in arm (sim)",
    )
    add_episode_arguments(s, distance=0.9, speed=0.4, duration=20.0)
    r = s.add_argument_group("real loop (--robot)")
    r.add_argument("--camera", metavar="prophesee[:SERIAL]|dv[:SERIAL]|FILE",
                   help="live camera, or an event file replayed at real time")  # fmt: skip
    r.add_argument("--model", help="object: built-in name (box, drill, football) or mesh path (default: config's)")
    r.add_argument("--config", metavar="RIG.yaml", help="rig config: camera intrinsics, hand-eye T_e_c, limits")
    r.add_argument("--init-pose", metavar="x,y,z,qx,qy,qz,qw", help="object in camera at start (default: config's)")
    r.add_argument("--desired-pose", metavar="x,y,z,qx,qy,qz,qw",
                   help="object in camera to servo to (default: the tracked pose when servoing starts)")  # fmt: skip
    r.add_argument("--settle", type=float, help="tracking before the arm moves, s from the first pose (default 0.5)")
    r.add_argument("--stiffness", type=float, help="k of Eq. 6, 1/s² (default 20, the paper's)")
    r.add_argument("--rate", type=float, help="control rate, Hz (default 500)")
    r.add_argument("--stale-after", type=float, help="watchdog: stop when no fresh pose for this long, s (default 0.1)")
    r.add_argument("--replay-speed", type=float, help="replay FILE this many times faster than real time (default 1)")
    r.add_argument("--dry-run", action="store_true", help="run everything but never move the arm (commands logged)")
    r.add_argument("--realtime", choices=("enforce", "ignore"),
                   help="franka: libfranka's realtime check (default enforce; ignore for franky-sim)")  # fmt: skip
    s.set_defaults(func=run)
