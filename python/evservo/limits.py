"""Limits on the camera's Cartesian motion, shared by the controller and the arms' safety gates."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CartesianLimits:
    """Limits on the camera's motion: norms of the linear (m/s, m/s²) and angular (rad/s, rad/s²) parts.

    Defaults are about half of the Panda's Cartesian limits (Franka FCI: 1.7 m/s, 2.5 rad/s, 13 m/s²,
    25 rad/s²), leaving headroom for the joint-space QP that follows and for the arm's other limits.
    """

    max_lin_vel: float = 0.8
    max_ang_vel: float = 1.5
    max_lin_acc: float = 4.0
    max_ang_acc: float = 8.0

    def __post_init__(self) -> None:
        for name in ("max_lin_vel", "max_ang_vel", "max_lin_acc", "max_ang_acc"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v}")
