"""Make an arm's end effector follow a Cartesian pose trajectory by resolved-rate control."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from evservo import geometry
from evservo.robots.base import Arm

PoseTrajectory = Callable[[float], np.ndarray]


def _vee_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of a small rotation (radians); exact enough below ~0.5 rad, as used here for the
    per-period pose error and for differences over 2 ms."""
    w = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s = math.sqrt(w @ w)  # np.linalg.norm's own arithmetic, without its wrappers (3 calls per 2 ms command)
    return w if s < 1e-12 else w * (np.arcsin(min(s, 1.0)) / s)


class PoseFollower:
    """Track ``T_w_x(t)`` with the frame x rigidly attached to the arm's end effector at ``T_e_x``.

    Each call of :meth:`command` (every ``period_s``; 500 Hz by default, the UR5e's RTDE rate) sends the
    twist ``v_ff(t + period) + gain · e`` where ``v_ff`` is the trajectory's velocity (central
    difference) and ``e`` the pose error of the end effector (translation m, rotation vector rad, world
    frame). ``gain`` (1/s) corrects the drift the limits and the discretisation leave.
    """

    def __init__(
        self,
        arm: Arm,
        trajectory: PoseTrajectory,
        T_e_x: np.ndarray | None = None,
        period_s: float = 0.002,
        gain: float = 50.0,
    ) -> None:
        if not (period_s > 0 and gain >= 0):
            raise ValueError("period_s must be > 0 and gain >= 0")
        self.arm, self.trajectory = arm, trajectory
        self.T_x_e = geometry.inv(geometry.as_pose(np.eye(4) if T_e_x is None else T_e_x, "T_e_x"))
        self.period_s, self.gain = float(period_s), float(gain)

    def target(self, t_s: float) -> np.ndarray:
        """Desired end-effector pose at ``t_s`` (seconds)."""
        return self.trajectory(t_s) @ self.T_x_e

    def command(self, t_s: float) -> np.ndarray:
        """Command the arm for the period starting at ``t_s`` (seconds); returns the twist sent."""
        h = 0.5 * self.period_s
        t_mid = t_s + h  # aim at the middle of the period the command is held for
        A, B = self.target(t_mid - h), self.target(t_mid + h)
        v_ff = np.concatenate([(B[:3, 3] - A[:3, 3]) / (2 * h), _vee_log(B[:3, :3] @ A[:3, :3].T) / (2 * h)])
        T, T_star = self.arm.T_w_e(), self.target(t_s)
        e = np.concatenate([T_star[:3, 3] - T[:3, 3], _vee_log(T_star[:3, :3] @ T[:3, :3].T)])
        v = v_ff + self.gain * e
        self.arm.command_twist(v, self.period_s)
        return v
