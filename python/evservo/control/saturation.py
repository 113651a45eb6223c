"""Keeping the commanded camera twist within Cartesian limits, and braking to rest (pure functions).

The limits apply to the norms of the linear and angular parts separately; the acceleration limit is
applied over the control period ``period_s`` the twist is held for.
"""

from __future__ import annotations

import numpy as np

from evservo.limits import CartesianLimits


def clip_norm(x: np.ndarray, limit: float) -> np.ndarray:
    """``x`` scaled down to norm ``limit`` if longer."""
    n = float(np.linalg.norm(x))
    return x if n <= limit else x * (limit / n)


def saturate(
    v_w: np.ndarray, a_w: np.ndarray, limits: CartesianLimits, period_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """The twist to hold next (world frame) from the twist now ``v_w`` and the wanted acceleration
    ``a_w``, and the acceleration actually applied. Clips the acceleration, then the velocity:
    projecting onto the velocity ball cannot raise the acceleration (projection onto a convex set
    holding ``v_w`` is non-expansive)."""
    L, h = limits, period_s
    a = np.concatenate([clip_norm(a_w[:3], L.max_lin_acc), clip_norm(a_w[3:], L.max_ang_acc)])
    v_new = v_w + a * h
    v_new = np.concatenate([clip_norm(v_new[:3], L.max_lin_vel), clip_norm(v_new[3:], L.max_ang_vel)])
    return v_new, (v_new - v_w) / h


def brake(v_w: np.ndarray, limits: CartesianLimits, period_s: float) -> np.ndarray:
    """The twist one period nearer to rest at the acceleration limit, reaching exactly zero."""
    L, h = limits, period_s
    lin = v_w[:3] - clip_norm(v_w[:3], L.max_lin_acc * h)
    ang = v_w[3:] - clip_norm(v_w[3:], L.max_ang_acc * h)
    return np.concatenate([clip_norm(lin, L.max_lin_vel), clip_norm(ang, L.max_ang_vel)])
