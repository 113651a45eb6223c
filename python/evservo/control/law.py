"""The paper's control law, Eq. (5)–(6), with a feed-forward reference (pure functions).

Eq. (5): the camera target ``T_w_ctgt = T_w_o · inv(T_c_o_des)``. Eq. (6): the second-order law
``ë* = −k e − 2√k ė`` with the error taken as target − current in the world, ``ė = v_ref − v_c`` where
``v_ref`` is the target's velocity when it is fed forward (mc_rtc's ``refVel``; zero in the paper's
literal law), plus the target's acceleration ``a_ref`` (mc_rtc's ``refAccel``).

A *twist in the world frame* of a frame x is ``(v, ω)``: the linear velocity of x's origin (m/s) and
its angular velocity (rad/s), both in world coordinates.
"""

from __future__ import annotations

import numpy as np

from evservo import geometry


def camera_target(T_w_o: np.ndarray, T_c_o_des: np.ndarray) -> np.ndarray:
    """Eq. (5): where the camera must be for the object to sit at ``T_c_o_des`` (4×4, world)."""
    return T_w_o @ geometry.inv(T_c_o_des)


def pose_error(T_w_c: np.ndarray, T_w_ctgt: np.ndarray) -> np.ndarray:
    """The paper's error: translation (m) and angle-axis (rad) of ``inv(T_w_c) · T_w_ctgt``, both in
    the current camera frame."""
    T = geometry.inv(T_w_c) @ T_w_ctgt
    return np.concatenate([T[:3, 3], geometry.rotvec(T[:3, :3])])


def world_error(T_w_c: np.ndarray, T_w_ctgt: np.ndarray) -> np.ndarray:
    """Target − current in the world frame: translation (m) and rotation vector of
    ``R_tgt · R_cᵀ`` (rad)."""
    return np.concatenate([T_w_ctgt[:3, 3] - T_w_c[:3, 3], geometry.rotvec(T_w_ctgt[:3, :3] @ T_w_c[:3, :3].T)])


def rigid_reference(
    T_w_o: np.ndarray, T_w_ctgt: np.ndarray, twist_o_w: np.ndarray, accel_o_w: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """Twist and acceleration (world frame) of the camera target, which moves rigidly with the object:
    the same ω, the lever arm from the object's origin to the target's. ``accel_o_w`` None: no
    acceleration reference (zeros)."""
    lever = T_w_ctgt[:3, 3] - T_w_o[:3, 3]
    w = twist_o_w[3:]
    v_ref = np.concatenate([twist_o_w[:3] + np.cross(w, lever), w])
    if accel_o_w is None:
        return v_ref, np.zeros(6)
    a_ref = np.concatenate(
        [accel_o_w[:3] + np.cross(accel_o_w[3:], lever) + np.cross(w, np.cross(w, lever)), accel_o_w[3:]]
    )
    return v_ref, a_ref


def acceleration(k: float, e_w: np.ndarray, v_c_w: np.ndarray, v_ref_w: np.ndarray, a_ref_w: np.ndarray) -> np.ndarray:
    """Eq. (6) with critical damping ``2√k``: the camera acceleration (world frame; m/s², rad/s²)."""
    return a_ref_w + k * e_w + 2.0 * np.sqrt(k) * (v_ref_w - v_c_w)
