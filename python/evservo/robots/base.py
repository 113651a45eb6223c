"""The arm protocol and twist bookkeeping.

Frames: w world, e end effector (flange), c a frame rigidly attached to it (camera: ``T_e_c``, the
hand–eye transform). A twist "in the world frame" of frame x is ``(v, ω)``: the linear velocity of x's
origin (m/s) and the angular velocity (rad/s), both in world coordinates.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Arm(Protocol):
    """A velocity-controlled arm."""

    @property
    def T_e_c(self) -> np.ndarray:
        """Hand–eye transform: the camera (or tool) frame in the end-effector frame, 4×4, metres."""
        ...

    def T_w_e(self) -> np.ndarray:
        """End-effector pose in the world, 4×4, metres."""
        ...

    def joint_positions(self) -> np.ndarray:
        """Joint positions (rad)."""
        ...

    def command_twist(self, v_e_w: np.ndarray, dt_s: float) -> np.ndarray | None:
        """Ask the end effector to move with twist ``v_e_w`` (world frame, (6,)) for the next ``dt_s``
        seconds; the arm resolves it within its joint limits and holds it until the next command.
        Returns the twist sent when the arm limits it on the way (a gated arm), else None."""
        ...

    def stop(self) -> None:
        """Bring the arm to rest within its acceleration limits."""
        ...


def shift_twist(v_a_w: np.ndarray, p_a_w: np.ndarray, p_b_w: np.ndarray) -> np.ndarray:
    """Twist of a frame b rigidly attached to frame a, from a's twist: same ω,
    ``v_b = v_a + ω × (p_b − p_a)``. All vectors in world coordinates (m, m/s, rad/s)."""
    v = np.asarray(v_a_w, dtype=float)
    (wx, wy, wz), (rx, ry, rz) = v[3:], np.asarray(p_b_w, dtype=float) - np.asarray(p_a_w, dtype=float)
    # The cross product written out: np.cross costs ~15 µs on 3-vectors, and this runs every 1 kHz tick.
    out = v.copy()
    out[:3] += (wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx)
    return out
