"""Robot arms behind one protocol: simulated (MuJoCo), and real UR (ur-rtde) and Franka (franky) arms
behind a :class:`SafetyGate`. The hardware drivers import their client packages only when constructed."""

from evservo.robots.base import Arm, shift_twist
from evservo.robots.config import RigConfig, RigConfigError, load_rig_config
from evservo.robots.follow import PoseFollower
from evservo.robots.franka import FrankaArm
from evservo.robots.ik import solve_joint_velocities
from evservo.robots.kinematic import KinematicArm
from evservo.robots.limits import PANDA, UR5E, JointLimits
from evservo.robots.safety import GateRecord, SafetyGate, Workspace
from evservo.robots.sim_arm import SimArm
from evservo.robots.ur import UrArm

__all__ = [
    "PANDA",
    "UR5E",
    "Arm",
    "FrankaArm",
    "GateRecord",
    "JointLimits",
    "KinematicArm",
    "PoseFollower",
    "RigConfig",
    "RigConfigError",
    "SafetyGate",
    "SimArm",
    "UrArm",
    "Workspace",
    "load_rig_config",
    "shift_twist",
    "solve_joint_velocities",
]
