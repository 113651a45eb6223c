"""``evservo demo``: one closed-loop servoing episode on the simulated bench with our controller, the same
episode with the paper's literal law, and the paper's row."""

from __future__ import annotations

import argparse
from pathlib import Path

from evservo.commands import servo


def run(args: argparse.Namespace) -> int:
    """The box at Z = 0.9 m translating at 0.3 m/s, EDFT⁺ on events from the model's edges, the
    tracker's measured compute time charged to the simulated clock, servoed by our controller
    (feed-forward within the arm's limits), then the same episode with the paper's literal law; prints
    one line for each next to the paper's Table I row, and where the Fig. 5 plots went.
    ``--paper-law`` runs the literal law only."""
    return servo.run_with_report(args, Path("runs") / "demo", compare_paper_law=True)


def add_parser(sub: argparse._SubParsersAction) -> None:
    d = sub.add_parser("demo", help="servo the simulated arm to a moving box (closed loop)")
    servo.add_episode_arguments(d, duration_s=12.0, feedforward=True)
    d.set_defaults(func=run)
