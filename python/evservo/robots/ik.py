"""Resolved-rate inverse kinematics as a small bound-constrained QP (DAQP).

For a requested end-effector twist ``v`` (world frame, m/s and rad/s) and the 6×n Jacobian ``J`` of the
same frame (``v = J q̇``), find the joint velocities ``q̇`` that minimise

    ‖J q̇ − v‖²_W + λ‖q̇‖² + μ‖q̇ − g (q_rest − q)‖²

subject to, per joint, the velocity limit, the acceleration limit over the command period
(``|q̇ − q̇_now| ≤ q̈_max·dt``), the jerk limit when the current joint acceleration is known (the
acceleration over the period, ``(q̇ − q̇_now)/dt``, differs from ``q̈_now`` by at most ``q⃛_max·dt``)
and a position limit expressed as a braking bound (the joint can still stop at its acceleration limit
before reaching the end of its range). λ damps singularities; the small
posture term (μ, towards ``q_rest``) uses the redundancy of a 7-joint arm and keeps the joints away from
their limits. ``W`` (identity by default) weighs the twist's components against each other where the
limits do not let all of them through. All constraints are boxes, which DAQP handles natively.
"""

from __future__ import annotations

import ctypes

import daqp
import numpy as np

from evservo.robots.limits import JointLimits


def clamp(x: np.ndarray, lo: np.ndarray | float, hi: np.ndarray | float) -> np.ndarray:
    """``np.clip(x, lo, hi)`` (the same ``min(max(x, lo), hi)``) without its ~4 µs of Python wrappers:
    the arms' IK and integration clamp several small vectors per 1 kHz tick."""
    return np.minimum(np.maximum(x, lo), hi)


def joint_velocity_bounds(
    q: np.ndarray, qd: np.ndarray, dt_s: float, limits: JointLimits, qdd: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Bounds on the next joint velocities (rad/s), held for ``dt_s`` from joint positions ``q`` (rad)
    and velocities ``qd`` (rad/s); ``qdd``, the joint accelerations now (rad/s²), adds the jerk limit.

    Where the acceleration (and jerk) window cannot reach the band allowed by the position and velocity
    limits (after a disturbance, e.g. a joint set by hand, or a joint arriving at its velocity limit
    faster than its jerk limit lets the acceleration fall), safety wins: the bound is the nearest edge of
    that band, even if it takes more than the acceleration or jerk limit to get there.
    """
    d_hi = np.maximum(limits.q_max - q, 0.0)
    d_lo = np.maximum(q - limits.q_min, 0.0)
    a = limits.qdd_max
    pv_hi = np.minimum(limits.qd_max, np.minimum(np.sqrt(2.0 * a * d_hi), d_hi / dt_s))
    pv_lo = -np.minimum(limits.qd_max, np.minimum(np.sqrt(2.0 * a * d_lo), d_lo / dt_s))
    w_lo, w_hi = qd - a * dt_s, qd + a * dt_s
    if qdd is not None:
        # The acceleration can move by at most q⃛_max·dt from where it is; the window stays non-empty
        # because q̈ within ±q̈_max puts q̇ + q̈·dt inside the acceleration window.
        a_now = clamp(qdd, -a, a)
        w_lo = np.maximum(w_lo, qd + (a_now - limits.qddd_max * dt_s) * dt_s)
        w_hi = np.minimum(w_hi, qd + (a_now + limits.qddd_max * dt_s) * dt_s)
    lb = np.maximum(pv_lo, w_lo)
    ub = np.minimum(pv_hi, w_hi)
    above = lb > ub
    if above.any():
        # The window lies entirely above or below the safe band: clamp to its nearest edge.
        lb = np.where(above, np.where(w_lo > pv_hi, pv_hi, pv_lo), lb)
        ub = np.where(above, lb, ub)
    return lb, ub


def solve_joint_velocities(
    J: np.ndarray,
    v: np.ndarray,
    q: np.ndarray,
    qd: np.ndarray,
    dt_s: float,
    limits: JointLimits,
    q_rest: np.ndarray | None = None,
    damping: float = 1e-4,
    posture_weight: float = 1e-3,
    posture_gain: float = 1.0,
    weights: np.ndarray | None = None,
    qdd: np.ndarray | None = None,
) -> np.ndarray:
    """Joint velocities (rad/s) realising twist ``v`` (6,) as closely as the limits allow.

    ``J``: 6×n Jacobian (rows: linear then angular, world frame). ``q``, ``qd``: current joint positions
    (rad) and velocities (rad/s). ``dt_s``: period over which the result is held (s). ``q_rest``: posture
    to drift towards in the null space (rad; none: no posture term). ``weights``: 6×6 symmetric positive
    definite ``W`` of the twist residual (units of the twist's rows; none: identity). ``qdd``: joint
    accelerations now (rad/s²); given, the jerk limit applies too (see :func:`joint_velocity_bounds`).
    """
    n = limits.n
    if J.shape != (6, n):
        raise ValueError(f"J must be 6x{n}")
    lb, ub = joint_velocity_bounds(q, qd, dt_s, limits, qdd)
    JW = J.T if weights is None else J.T @ weights
    P = JW @ J
    diag = P.reshape(-1)[:: n + 1]  # a view (P is a fresh contiguous array): the regularisers add in place
    diag += damping
    c = -JW @ v
    if q_rest is not None:
        diag += posture_weight
        c -= posture_weight * posture_gain * (q_rest - q)
    if (lb == ub).all():
        return lb
    # DAQP directly, box constraints only, no general rows (what qpsolvers' wrapper hands it, without its
    # ~10 µs of problem checks and repacking per call: this runs for both arms at up to 1 kHz).
    no_rows, sense = np.zeros((0, n)), np.zeros(n, dtype=ctypes.c_int)
    x, _, exitflag, _ = daqp.solve(P, c, no_rows, ub.copy(), lb.copy(), sense)
    if exitflag <= 0:
        raise RuntimeError("joint-velocity QP failed")
    # The solver's own tolerance can leave the bounds by ~1e-12; the limits are hard.
    return clamp(x, lb, ub)
