"""Robot arms behind one protocol: simulated (MuJoCo), and real UR (ur-rtde) and Franka (franky) arms
behind a :class:`SafetyGate`.

Names load on first use: a hardware rig that uses :class:`UrArm` never imports MuJoCo (``SimArm``) or
the IK's QP solver (``solve_joint_velocities``), and the drivers import their client packages only
when constructed."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

# name -> module that defines it
_WHERE = {
    "Arm": "base", "shift_twist": "base", "GatedArm": "gated", "RigConfig": "config", "RigConfigError": "config",
    "load_rig_config": "config", "PoseFollower": "follow", "FrankaArm": "franka",
    "solve_joint_velocities": "ik", "KinematicArm": "kinematic", "PANDA": "limits", "UR5E": "limits",
    "JointLimits": "limits", "GateRecord": "safety", "SafetyGate": "safety", "Workspace": "safety",
    "SimArm": "sim_arm", "UrArm": "ur", "RobotSpec": "open", "open_arm": "open", "parse_robot": "open",
    "TwistSink": "twist_sink",
}  # fmt: skip

__all__ = [
    "PANDA",
    "UR5E",
    "Arm",
    "FrankaArm",
    "GateRecord",
    "GatedArm",
    "JointLimits",
    "KinematicArm",
    "PoseFollower",
    "RigConfig",
    "RigConfigError",
    "RobotSpec",
    "SafetyGate",
    "SimArm",
    "TwistSink",
    "UrArm",
    "Workspace",
    "load_rig_config",
    "open_arm",
    "parse_robot",
    "shift_twist",
    "solve_joint_velocities",
]

if TYPE_CHECKING:
    from evservo.robots.base import Arm, shift_twist
    from evservo.robots.config import RigConfig, RigConfigError, load_rig_config
    from evservo.robots.follow import PoseFollower
    from evservo.robots.franka import FrankaArm
    from evservo.robots.gated import GatedArm
    from evservo.robots.ik import solve_joint_velocities
    from evservo.robots.kinematic import KinematicArm
    from evservo.robots.limits import PANDA, UR5E, JointLimits
    from evservo.robots.open import RobotSpec, open_arm, parse_robot
    from evservo.robots.safety import GateRecord, SafetyGate, Workspace
    from evservo.robots.sim_arm import SimArm
    from evservo.robots.twist_sink import TwistSink
    from evservo.robots.ur import UrArm


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module 'evservo.robots' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"evservo.robots.{_WHERE[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
