"""What a simulated arm can deliver now: the camera twist nearest a wanted one within the joint limits.

The controller asks for a camera twist; the arm's own resolved-rate QP (:mod:`evservo.robots.ik`) then
realises what its joint velocity, acceleration, jerk and position limits allow, weighting all components
alike. Where the limits bite, that silently drops part of the command, and a controller integrating
its own commands believes it moves faster than it does. :class:`ReachableTwist` lets the controller
ask first, with its own priorities (a weight on each component of the twist), and command only what
the arm can do.
"""

from __future__ import annotations

import numpy as np

from evservo.robots.ik import solve_joint_velocities
from evservo.robots.sim_arm import SimArm


class ReachableTwist:
    """Camera twists the :class:`SimArm` ``arm`` can realise over the next period from its current joint
    positions and velocities (a camera at the arm's ``T_e_c``).

    Call with the wanted camera twist ``v_c_w`` (world frame; m/s, rad/s), a 6×6 weight ``W`` (world
    frame, symmetric positive definite) and the period ``dt_s`` (s) it will be held for; returns
    ``v_c_w`` itself when the joint limits let it through, else ``J q̇*`` with ``q̇*`` the joint velocities
    minimising ``‖J q̇ − v_c_w‖²_W`` within the limits. :attr:`saturated` says which it was last time.
    ``tol``: the relative shortfall (W-norm) still counted as delivered: the arm's own QP, regularised,
    realises about 1 % less than asked anyway.
    """

    def __init__(self, arm: SimArm, tol: float = 0.01) -> None:
        self.arm = arm
        self.tol = float(tol)
        self.saturated = False

    def camera_jacobian(self) -> np.ndarray:
        """6×n Jacobian of the camera frame (rows: linear velocity of its origin, angular; world)."""
        J = self.arm.jacobian()
        lever = self.arm.T_w_c()[:3, 3] - self.arm.T_w_e()[:3, 3]
        # v_c = v_e + ω × lever = v_e − lever × ω
        K = np.array([[0.0, -lever[2], lever[1]], [lever[2], 0.0, -lever[0]], [-lever[1], lever[0], 0.0]])
        return np.vstack([J[:3] - K @ J[3:], J[3:]])

    def __call__(self, v_c_w: np.ndarray, W: np.ndarray, dt_s: float) -> np.ndarray:
        arm = self.arm
        J = self.camera_jacobian()
        qd = solve_joint_velocities(J, v_c_w, arm.joint_positions(), arm.qd, dt_s, arm.limits, damping=1e-9,
                                    weights=W, qdd=arm.qdd)  # fmt: skip
        residual = J @ qd - v_c_w
        self.saturated = float(residual @ W @ residual) > self.tol**2 * max(float(v_c_w @ W @ v_c_w), 1e-12)
        return J @ qd if self.saturated else np.asarray(v_c_w, dtype=float)
