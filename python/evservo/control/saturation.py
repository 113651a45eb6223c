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


def image_motion_matrix(T_w_c: np.ndarray, p_o_w: np.ndarray, radius_m: float) -> np.ndarray:
    """7×6 matrix ``A`` turning a camera twist relative to the object's motion (world frame; m/s,
    rad/s) into the rates (rad/s) at which the object moves in the image: rows 0–2 the bearing of its
    centre ``p_o_w`` (translation across the line of sight over the depth, and pan/tilt), row 3 its
    apparent size (translation along the line of sight; ``radius_m`` is the object's radius), rows 4–6
    its appearance (any relative rotation moves the object's outline, ``radius_m`` from the centre, by
    ``radius_m/Z`` per rad). Built in the camera frame and returned for world-frame twists."""
    R = T_w_c[:3, :3]
    p = R.T @ (np.asarray(p_o_w, dtype=float) - T_w_c[:3, 3])
    Z = float(np.linalg.norm(p))
    u = p / Z
    ux = np.array([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]])
    A = np.zeros((7, 6))
    A[:3, :3] = (np.eye(3) - np.outer(u, u)) / Z
    A[:3, 3:] = -ux
    A[3, :3] = (radius_m / Z**2) * u
    A[4:, 3:] = (radius_m / Z) * np.eye(3)
    return A @ np.block([[R.T, np.zeros((3, 3))], [np.zeros((3, 3)), R.T]])


def limit_image_rate(v_w: np.ndarray, v_ref_w: np.ndarray, A: np.ndarray, max_rate: float) -> np.ndarray:
    """``v_w`` with its part relative to the object's motion ``v_ref_w`` scaled down so that the image
    moves no faster than ``max_rate`` (rad/s, the norm of ``A (v_w − v_ref_w)``, see
    :func:`image_motion_matrix`): a camera that fell behind catches up no faster than the tracker
    can follow."""
    d = v_w - v_ref_w
    rate = float(np.linalg.norm(A @ d))
    return v_w if rate <= max_rate else v_ref_w + d * (max_rate / rate)


def image_priority_weights(A: np.ndarray, depth_m: float, pose_weight: float = 0.01) -> np.ndarray:
    """6×6 weight on camera-twist errors (world frame) when the arm cannot deliver all of a twist: the
    image motion ``‖A Δv‖²`` (:func:`image_motion_matrix`; keeps the object where it is in the image
    and its apparent speed low), plus ``pose_weight`` times the plain twist error (translation over
    ``depth_m``, rotation in rad/s) so that the viewpoint and the distance are still matched as
    nearly as the remaining freedom allows."""
    reg = np.diag(np.r_[np.full(3, 1.0 / depth_m**2), np.ones(3)])
    return A.T @ A + pose_weight * reg
