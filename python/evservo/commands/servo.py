"""``evservo servo``: closed-loop servoing of a moving object, on the simulated bench (``--sim``) or on a
real rig (``--robot ur:HOST|franka:HOST|sim`` with ``--camera``, ``--model`` and ``--config``; the loop
itself is :mod:`evservo.realloop`)."""

from __future__ import annotations

import argparse
import math
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


#: Options of the simulated bench only (``--robot`` refuses them), by EpisodeConfig field.
SIM_ONLY = {
    "object": "object", "trajectory": "trajectory", "speed": "speed_mps", "rot_rate": "rot_rate_dps",
    "distance": "distance_m", "seed": "seed", "cost_model": "cost_model", "dropout": "dropout_s",
    "events": "event_source", "render_arms": "render_arms", "predictor": "predictor", "occlude": "occlusions",
}  # fmt: skip


def parse_spells(texts: list[str], option: str = "--occlude") -> tuple[tuple[float, float], ...]:
    """``T0:T1`` spells in seconds (each option a comma list of them), sorted; errors name ``option``."""
    out = []
    for item in (part.strip() for text in texts for part in text.split(",")):
        a, sep, b = item.partition(":")
        try:
            spell = (float(a), float(b))
        except ValueError:
            spell = None
        if not sep or spell is None or not (all(map(math.isfinite, spell)) and 0 <= spell[0] < spell[1]):
            raise ValueError(
                f"{option} takes T0:T1 in seconds with 0 <= T0 < T1 (comma list or repeated), got {item!r}"
            )
        out.append(spell)
    return tuple(sorted(out))


def add_episode_arguments(p: argparse.ArgumentParser, **defaults: object) -> None:
    """Options shared by ``servo`` and ``demo``. ``defaults``: the command's own defaults, as
    :class:`~evservo.sim.episode_config.EpisodeConfig` fields (the config's own defaults hold otherwise).
    Sim-only options parse to None when not given, so ``--robot`` can tell they were."""
    from dataclasses import fields

    from evservo.commands.track import add_viewer_arguments
    from evservo.sim.episode_config import COST_MODELS, PREDICTORS, EpisodeConfig
    from evservo.tracking import SOLVERS

    base = {f.name: f.default for f in fields(EpisodeConfig)}
    unknown = set(defaults) - set(base)
    if unknown:
        raise TypeError(f"not EpisodeConfig fields: {sorted(unknown)}")
    base.update(defaults)
    p.set_defaults(episode_defaults=dict(defaults))

    def d(name: str) -> str:
        return f"(default {base[name]})"

    p.add_argument("--object", help=f"box, drill, football or a mesh path {d('object')}")
    p.add_argument("--tracker", default=base["tracker"], choices=SOLVERS)
    p.add_argument(
        "--trajectory",
        help=f"trans, trans-rot, circle, figure8, stop-go, reversal, leave-return (leaves the view and comes back "
        f"elsewhere) or a CSV {d('trajectory')}",
    )
    p.add_argument("--speed", type=float, help=f"peak target speed, m/s {d('speed_mps')}")
    p.add_argument("--rot-rate", type=float, help=f"peak target rotation rate (trans-rot), deg/s {d('rot_rate_dps')}")
    p.add_argument("--distance", type=float, help=f"camera–object distance Z, m {d('distance_m')}")
    p.add_argument("--duration", type=float, default=base["duration_s"], help="servoing time, s")
    p.add_argument("--seed", type=int, help=f"random seed {d('seed')}")
    ff = bool(base["feedforward"])
    law = p.add_mutually_exclusive_group()
    law.add_argument(
        "--feedforward",
        action="store_true",
        default=ff,
        help="our controller: the target's motion fed forward within what the arm can deliver" + " (default)" * ff,
    )
    law.add_argument(
        "--paper-law",
        dest="feedforward",
        action="store_false",
        help="the paper's literal Eq. (5)-(6) loop" + " (default)" * (not ff),
    )
    p.add_argument(
        "--predictor",
        choices=PREDICTORS,
        help=f"feed-forward: extrapolate the target across the latencies at constant velocity or acceleration "
        f"{d('predictor')}",
    )
    p.add_argument("--cost-model", choices=COST_MODELS, help=f"tracker time charged to the clock {d('cost_model')}")
    p.add_argument("--dropout", type=float, nargs=2, metavar=("START", "END"), help="lose all events in [START, END) s")
    p.add_argument(
        "--occlude",
        action="append",
        metavar="T0:T1",
        help="hide the object fully in [T0, T1) s (no object events; repeat or comma list); the episode then "
        "runs through losses and scores the tracker's lost flag",
    )
    p.add_argument(
        "--events",
        choices=("edges", "render", "render-fast", "render-lab"),
        help="event source: the model's edges (fast), the rendered event camera (slow; the reference, a render "
        "per 1 ms tick), the same camera rendered only every half pixel of image motion (faster, but the ticks "
        "in between reach the tracker with the next render, up to 5 ms late), or the rendered camera with the "
        f"lab preset (mains flicker, clutter) {d('event_source')}",
    )
    p.add_argument(
        "--render-arms",
        action="store_true",
        default=None,
        help="also draw the UR5e and Panda arms into the rendered event camera (needs --events render, "
        "render-fast or render-lab)",
    )
    p.add_argument("--out", type=Path, help="output directory (summary.json, log.csv, motion.png)")
    add_viewer_arguments(p)


def sim_options_given(args: argparse.Namespace) -> list[str]:
    """The sim-only options given on the command line, as ``--name``."""
    return [f"--{opt.replace('_', '-')}" for opt in SIM_ONLY if getattr(args, opt, None) is not None]


def config_from_args(args: argparse.Namespace):
    """The :class:`~evservo.sim.episode_config.EpisodeConfig` of parsed options."""
    from evservo.sim.episode_config import EpisodeConfig
    from evservo.trajectories import LEAVING_KINDS

    values = dict(args.episode_defaults)
    values.update({field: getattr(args, opt) for opt, field in SIM_ONLY.items() if getattr(args, opt) is not None})
    if values.get("dropout_s") is not None:
        values["dropout_s"] = tuple(values["dropout_s"])
    if values.get("occlusions") is not None:
        values["occlusions"] = parse_spells(values["occlusions"])
    # Occlusions and trajectories leaving the view make losses part of the episode: run through them.
    if values.get("occlusions") or values.get("trajectory") in LEAVING_KINDS:
        values.setdefault("end_on_loss", False)
    # The parsed values win over the command's defaults (demo's duration_s and feedforward among them).
    values.update(tracker=args.tracker, duration_s=args.duration, feedforward=args.feedforward)
    return EpisodeConfig(**values)


def run_with_report(args: argparse.Namespace, default_out: Path, compare_paper_law: bool = False) -> int:
    """Run the episode with a progress bar, write the outputs, print the summary beside the paper. With
    ``compare_paper_law`` and our controller, run the same episode with the paper's literal law too (into
    ``OUT/paper-law``) and print one line for each and one for the paper's published numbers."""
    from evservo.outputs import prepare_out_dir
    from evservo.sim.episode import OUTPUTS

    cfg = config_from_args(args)
    literal = compare_paper_law and cfg.feedforward
    # Checked, and cleared of an earlier run's files, before the run: never fails after it.
    out = prepare_out_dir(args.out or default_out, stale=OUTPUTS)
    out_literal = prepare_out_dir(out / "paper-law", stale=OUTPUTS) if literal else None
    print(
        f"servo (sim): {cfg.object}, {cfg.tracker}, Z = {cfg.distance_m} m, {cfg.trajectory} at {cfg.speed_mps} m/s, "
        f"{cfg.duration_s} s, {_law_name(cfg)}, cost model {cfg.cost_model}"
    )
    summary = _run_and_write(cfg, out, args.viewer, args.viewer_save)
    print_summary(summary)
    if summary["interrupted"]:
        print(f"evservo: interrupted: partial outputs (marked interrupted) in {out}", file=sys.stderr)
        return 130
    if out_literal is not None:
        print(f"\nthe same episode with the paper's literal Eq. (5)-(6) loop, into {out_literal}:")
        paper_law = _run_and_write(replace(cfg, feedforward=False), out_literal)
        if paper_law["interrupted"]:
            print(f"evservo: interrupted: partial outputs (marked interrupted) in {out_literal}", file=sys.stderr)
            return 130
        print_comparison(summary, paper_law)
    return 0


def _law_name(cfg) -> str:
    if cfg.feedforward:
        return f"our controller (feed-forward within the arm's limits, {cfg.predictor} predictor)"
    return "the paper's literal Eq. (5)-(6)"


def _run_and_write(cfg, out: Path, viewer_kind: str | None = None, viewer_save: str | None = None) -> dict:
    """Run one episode with a progress bar (and the live viewer, if asked for) and write its outputs
    into ``out``; returns its summary."""
    from tqdm import tqdm

    from evservo.sim.episode import run_episode, summarize, write_outputs
    from evservo.viewer import open_viewer

    viewer = open_viewer(viewer_kind, viewer_save)
    try:
        with tqdm(total=round(cfg.duration_s * 1000), unit="ms", desc="simulated", leave=False) as bar:
            result = run_episode(cfg, progress=bar.update, viewer=viewer)
    finally:
        if viewer is not None:
            viewer.close()
    summary = summarize(result)
    paths = write_outputs(result, out, summary)
    print(f"figure: {paths['motion']}\nsummary: {paths['summary']}\nlog: {paths['log']}")
    return summary


def print_comparison(ours: dict, paper_law: dict) -> None:
    """One line each: our controller, the paper's literal law on the same episode, the paper's numbers."""
    c = ours["config"]
    print(f"\n{'':40}{'servo pos mm':>13}{'rot deg':>9}{'lag s':>8}  tracking")
    for name, s in (("ours (feed-forward within arm limits)", ours), ("paper's law, Eq. (5)-(6), same run", paper_law)):
        held = "held" if s["completed"] else f"lost at {s['simulated_s']:.2f} s"
        print(f"{name:40}{s['servo_pos_rms_mm']:13.2f}{s['servo_rot_rms_deg']:9.2f}{s['lag_s']:8.3f}  {held}")
    row = PAPER_TABLE.get((c["object"], round(c["distance_m"], 2), c["trajectory"], c["tracker"]))
    if row:
        print(f"{'paper, Table I/II (its real bench)':40}{row[0]:13.2f}{row[1]:9.2f}{'≈0.15':>8}")


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
    t = s["timing"]
    print(f"timing: sensing {t['sensing_latency_ms']:.1f} ms, tracker step {t['tracker_step_mean_ms']:.2f} ms, "
          f"control every {t['control_period_ms']:g} ms, "
          f"Panda {t['panda_rate_hz']:g} Hz + {t['panda_latency_ms']:g} ms, "
          f"UR5e {t['ur_rate_hz']:g} Hz + {t['ur_latency_ms']:g} ms; command cut to the arm's reach "
          f"{100 * s['arm_limited_fraction']:.0f} % of the time")  # fmt: skip
    from evservo.runtime.loss import describe as describe_loss
    from evservo.runtime.watchdog import describe_spell

    loss = s.get("loss") or {}
    if loss.get("wrong_spells") or loss.get("holding_s") or c.get("occlusions") or c.get("start_lost"):
        print(describe_loss(loss, loss["holding_s"]))

    for w in s["watchdog"]:
        print(describe_spell(w))


def run(args: argparse.Namespace) -> int:
    if not args.sim:
        from evservo.commands.servo_real import run_real

        given = sim_options_given(args)
        if given:
            raise ValueError(f"{_only(given)} with --sim (the simulated bench), not with --robot")
        return run_real(args)
    given = [f"--{name.replace('_', '-')}" for name in REAL_ONLY if getattr(args, name) not in (None, False)]
    if given:
        raise ValueError(f"{_only(given)} with --robot (the real loop), not with --sim")
    return run_with_report(args, Path("runs") / "servo")


#: Options of the real loop only (``--sim`` refuses them).
def _only(options: list[str]) -> str:
    return f"{', '.join(options)} only appl{'ies' if len(options) == 1 else 'y'}"


REAL_ONLY = ("camera", "model", "config", "init_pose", "desired_pose", "settle", "stiffness", "rate", "dry_run",
             "replay_speed", "stale_after", "max_jump", "max_jump_rad", "realtime")  # fmt: skip


def add_parser(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("servo", help="closed-loop servoing of a moving object")
    mode = s.add_mutually_exclusive_group(required=True)
    mode.add_argument("--sim", action="store_true", help="the simulated dual-arm bench")
    mode.add_argument(
        "--robot",
        metavar="ur:HOST|franka:HOST|sim",
        help="the real loop on a UR (ur-rtde) or Franka (franky) arm, or on a kinematic stand-in arm (sim)",
    )
    add_episode_arguments(s, speed_mps=0.4)
    from dataclasses import fields

    from evservo.commands.servo_real import add_real_loop_arguments
    from evservo.realloop import RealLoopConfig

    real = {f.name: f.default for f in fields(RealLoopConfig)}
    r = s.add_argument_group("real loop (--robot)")
    r.add_argument("--camera", metavar="prophesee[:SERIAL]|dv[:SERIAL]|FILE",
                   help="live camera, or an event file replayed at real time")  # fmt: skip
    r.add_argument("--model", help="object: built-in name (box, drill, football) or mesh path (default: config's)")
    r.add_argument("--config", metavar="RIG.yaml", help="rig config: camera intrinsics, hand-eye T_e_c, limits")
    r.add_argument(
        "--init-pose",
        metavar="x,y,z,qx,qy,qz,qw|search",
        help="object in camera at start, or 'search': start lost, the arm holding still until the tracker has "
        "found the object (default: the config's, else a simulated recording's ground truth, else search)",
    )
    add_real_loop_arguments(r)
    r.add_argument(
        "--replay-speed",
        type=float,
        help=f"replay FILE this many times faster than real time (default {real['speed']})",
    )
    r.add_argument("--dry-run", action="store_true", help="run everything but never move the arm (commands logged)")
    r.add_argument("--realtime", choices=("enforce", "ignore"),
                   help="franka: libfranka's realtime check (default enforce; ignore for franky-sim)")  # fmt: skip
    s.set_defaults(func=run)
