"""``evservo demo``: one closed-loop servoing episode on the simulated bench, with the paper's row."""

from __future__ import annotations

import argparse
from pathlib import Path

from evservo.commands import servo


def run(args: argparse.Namespace) -> int:
    """The box at Z = 0.9 m translating at 0.3 m/s, EDFT⁺ on events from the model's edges, the
    tracker's measured compute time charged to the simulated clock; prints the summary next to the
    paper's Table I row and where the Fig. 5 plot went."""
    return servo.run_with_report(args, Path("runs") / "demo")


def add_parser(sub: argparse._SubParsersAction) -> None:
    d = sub.add_parser("demo", help="servo the simulated arm to a moving box (closed loop)")
    servo.add_episode_arguments(d, duration_s=12.0)
    d.set_defaults(func=run)
