"""Joint limits of the real arms, used by the simulated ones so that what works in simulation is
feasible on hardware."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evservo.limits import CartesianLimits


@dataclass(frozen=True)
class JointLimits:
    """Per-joint limits: positions (rad), velocities (rad/s), accelerations (rad/s²), jerks (rad/s³)."""

    q_min: np.ndarray
    q_max: np.ndarray
    qd_max: np.ndarray
    qdd_max: np.ndarray
    qddd_max: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.q_min)
        for name in ("q_min", "q_max", "qd_max", "qdd_max", "qddd_max"):
            a = np.asarray(getattr(self, name), dtype=float)
            # An arm whose interface imposes no jerk limit has an infinite one.
            ok = np.all(~np.isnan(a)) if name == "qddd_max" else np.all(np.isfinite(a))
            if a.shape != (n,) or not ok:
                raise ValueError(f"{name} must be a ({n},) array of finite numbers (jerks may be inf)")
            object.__setattr__(self, name, a)
        if np.any(self.q_min >= self.q_max) or min(self.qd_max.min(), self.qdd_max.min(), self.qddd_max.min()) <= 0:
            raise ValueError("need q_min < q_max and positive velocity, acceleration and jerk limits")

    @property
    def n(self) -> int:
        """Number of joints."""
        return len(self.q_min)


# Franka Emika Panda, from Franka's "Robot and interface specifications" (the constants libfranka's
# rate limiter uses): positions, kMaxJointVelocity, kMaxJointAcceleration, kMaxJointJerk.
PANDA = JointLimits(
    q_min=np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973]),
    q_max=np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973]),
    qd_max=np.array([2.1750, 2.1750, 2.1750, 2.1750, 2.6100, 2.6100, 2.6100]),
    qdd_max=np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0]),
    qddd_max=np.array([7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0]),
)

# Universal Robots UR5e, from the UR5e data sheet / user manual: ±360° on every joint, 180°/s on every
# joint. The elbow is restricted to ±180° as in UR's ROS description (self-collision). UR publishes no
# joint acceleration limit; 8 rad/s² is our conservative assumption, not a vendor figure. Nor a jerk
# limit: its joint interfaces (speedj, servoj) take an acceleration only, so the model imposes none.
UR5E = JointLimits(
    q_min=np.array([-2 * np.pi, -2 * np.pi, -np.pi, -2 * np.pi, -2 * np.pi, -2 * np.pi]),
    q_max=np.array([2 * np.pi, 2 * np.pi, np.pi, 2 * np.pi, 2 * np.pi, 2 * np.pi]),
    qd_max=np.full(6, np.pi),
    qdd_max=np.full(6, 8.0),
    qddd_max=np.full(6, np.inf),
)

# The Panda's Cartesian limits of the end effector (Franka FCI): 1.7 m/s, 2.5 rad/s, 13 m/s², 25 rad/s².
# The controller may use them in full only when it also checks each command against the joint limits
# (evservo.robots.reach); CartesianLimits' defaults are half of them for a controller that does not.
PANDA_CARTESIAN = CartesianLimits(max_lin_vel=1.7, max_ang_vel=2.5, max_lin_acc=13.0, max_ang_acc=25.0)
