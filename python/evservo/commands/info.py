"""``evservo info``: versions and defaults."""

from __future__ import annotations

import argparse


def run(_args: argparse.Namespace) -> int:
    import evservo

    cam = evservo.Camera.imx636()
    print(f"evservo {evservo.__version__}")
    print(f"default camera: {cam}")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    i = sub.add_parser("info", help="versions and defaults")
    i.set_defaults(func=run)
