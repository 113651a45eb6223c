"""The ``evservo`` command line: event-camera 6-DoF tracking and visual servoing."""

from __future__ import annotations

import argparse
import sys

from evservo.commands import bench, demo, info, ros, servo, sim, track

# Each module registers its own subcommand; add new ones here.
COMMANDS = (bench, demo, info, ros, servo, sim, track)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="evservo", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    for module in COMMANDS:
        module.add_parser(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
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
