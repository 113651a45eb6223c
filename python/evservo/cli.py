"""The ``evservo`` command line: event-camera 6-DoF tracking and visual servoing."""

from __future__ import annotations

import argparse
import sys
from typing import NoReturn

from evservo.commands import bench, calib, demo, info, ros, servo, sim, track

# Each module registers its own subcommand; add new ones here.
COMMANDS = (bench, calib, demo, info, ros, servo, sim, track)


class UsageError(Exception):
    """A command line argparse rejected (unknown option, invalid choice, wrong type)."""


class _Parser(argparse.ArgumentParser):
    """argparse with its errors raised, so that they end like every other bad input: one
    ``evservo: error: …`` line, exit code 2 (subcommand parsers are of this class too)."""

    def error(self, message: str) -> NoReturn:
        raise UsageError(f"{message} (see {self.prog} --help)")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="evservo", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    for module in COMMANDS:
        module.add_parser(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except UsageError as e:
        print(f"evservo: error: {e}", file=sys.stderr)
        return 2
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError, RuntimeError) as e:
        print(f"evservo: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("evservo: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
