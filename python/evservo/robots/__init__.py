"""Robot arms behind one protocol: simulated (MuJoCo) here; hardware drivers plug in the same way."""

from evservo.robots.base import Arm, shift_twist
from evservo.robots.follow import PoseFollower
from evservo.robots.ik import solve_joint_velocities
from evservo.robots.limits import PANDA, UR5E, JointLimits
from evservo.robots.sim_arm import SimArm

__all__ = [
    "PANDA",
    "UR5E",
    "Arm",
    "JointLimits",
    "PoseFollower",
    "SimArm",
    "shift_twist",
    "solve_joint_velocities",
]
