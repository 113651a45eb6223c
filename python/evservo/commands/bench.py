"""``evservo bench``: end-to-end benchmark suites with reports."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

SUITES = ("latency",)


def run(args: argparse.Namespace) -> int:
    from evservo.bench import latency

    samples = Path(os.environ.get("EVSERVO_SAMPLES", Path(__file__).resolve().parents[4] / "shared/event-samples"))
    latency.run(Path(args.out), quick=args.quick, samples=samples)
    print(f"wrote {Path(args.out) / 'latency.md'} and latency.json")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    b = sub.add_parser("bench", help="benchmark suites (latency)")
    b.add_argument("--suite", choices=SUITES, default="latency")
    b.add_argument("--out", default="out/bench", help="output directory")
    b.add_argument("--quick", action="store_true", help="short runs (for tests)")
    b.set_defaults(func=run)
