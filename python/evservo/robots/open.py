"""Opening the arm a command line names: ``ur:HOST``, ``franka:HOST`` or ``sim`` (the kinematic
stand-in), with the rig's hand–eye, limits and workspace."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from evservo.robots.config import RigConfig
from evservo.robots.gated import GatedArm

ROBOT_KINDS = ("ur", "franka", "sim")


@dataclass(frozen=True)
class RobotSpec:
    """A parsed ``--robot``: ``kind`` is ``ur``, ``franka`` or ``sim``; ``host`` the controller's
    address (None for ``sim``)."""

    kind: str
    host: str | None


def parse_robot(spec: str) -> RobotSpec:
    """``ur:HOST``, ``franka:HOST`` or ``sim``; ``ValueError`` saying what is wanted otherwise."""
    kind, _, host = spec.partition(":")
    kind = kind.strip().lower()
    if kind not in ROBOT_KINDS:
        raise ValueError(f"--robot {spec!r}: want ur:HOST, franka:HOST or sim")
    if kind == "sim":
        if host:
            raise ValueError(f"--robot {spec!r}: 'sim' takes no host")
        return RobotSpec("sim", None)
    if not host.strip():
        raise ValueError(f"--robot {spec!r}: give the controller's address, e.g. {kind}:192.168.1.10")
    return RobotSpec(kind, host.strip())


def open_arm(
    spec: RobotSpec, rig: RigConfig | None, dry_run: bool, realtime: Literal["enforce", "ignore"] = "enforce"
) -> GatedArm:
    """Connect to the arm of ``spec`` (its driver package is imported only now) behind its safety gate.
    ``realtime`` applies to a Franka (libfranka's realtime check). Raises ``ImportError`` for a
    missing driver package and ``ConnectionError`` for an unreachable controller."""
    T_e_c = rig.T_e_c if rig else None
    limits = rig.limits if rig else None
    workspace = rig.workspace if rig else None
    if spec.kind == "sim":
        from evservo.robots.kinematic import KinematicArm

        return KinematicArm(T_e_c=T_e_c, limits=limits, workspace=workspace, dry_run=dry_run)
    assert spec.host is not None
    if spec.kind == "ur":
        from evservo.robots.ur import UrArm

        return UrArm(spec.host, T_e_c=T_e_c, limits=limits, workspace=workspace, dry_run=dry_run)
    from evservo.robots.franka import FrankaArm

    return FrankaArm(spec.host, T_e_c=T_e_c, limits=limits, workspace=workspace, dry_run=dry_run, realtime=realtime)
