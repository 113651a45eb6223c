"""4×4 pose helpers and error metrics.

Convention: ``T_a_b`` is the pose of frame b expressed in frame a (so ``T_c_o`` is the object in the
camera optical frame), a 4×4 float64 homogeneous matrix, translations in metres.
"""

from __future__ import annotations

import numpy as np

_EYE3 = np.eye(3)
_BOTTOM_ROW = np.array([0.0, 0.0, 0.0, 1.0])


def _det3(R: np.ndarray) -> float:
    """Determinant of a 3×3 matrix by cofactors (np.linalg.det's LU costs ~10× more at this size)."""
    (a, b, c), (d, e, f), (g, h, i) = R.tolist()
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def as_pose(T: object, name: str = "pose") -> np.ndarray:
    """Return ``T`` as a validated 4×4 float64 rigid transform; raise ``ValueError`` otherwise."""
    # Array methods and constants rather than np.all/np.linalg.det/list operands: the controller
    # validates poses every cycle, where those wrappers were most of the cost.
    M = np.asarray(T, dtype=np.float64)
    if M.shape != (4, 4):
        raise ValueError(f"{name} must be a 4x4 matrix, got shape {M.shape}")
    if not np.isfinite(M).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    R = M[:3, :3]
    if abs(R.T @ R - _EYE3).max() > 1e-6 or _det3(R) <= 0:
        raise ValueError(f"{name} rotation block is not a rotation matrix")
    if abs(M[3] - _BOTTOM_ROW).max() > 1e-9:
        raise ValueError(f"{name} bottom row must be (0, 0, 0, 1)")
    return np.ascontiguousarray(M)


def pose(translation_m: object = (0.0, 0.0, 0.0), rotvec_rad: object = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Pose from a translation (metres) and a rotation vector (radians)."""
    T = np.eye(4)
    T[:3, :3] = rotmat(np.asarray(rotvec_rad, dtype=float))
    T[:3, 3] = np.asarray(translation_m, dtype=float)
    return T


def pose_from_xyz_quat(x: float, y: float, z: float, qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """Pose from a translation (metres) and a unit quaternion (x, y, z, w)."""
    q = np.array([qx, qy, qz, qw], dtype=float)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < 1e-9:
        raise ValueError("quaternion must be finite and non-zero")
    qx, qy, qz, qw = q / n
    T = np.eye(4)
    T[:3, :3] = [
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ]
    T[:3, 3] = [x, y, z]
    return T


def inv(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform."""
    out = np.eye(4)
    R = T[:3, :3]
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def interpolate(T_a: np.ndarray, T_b: np.ndarray, s: float) -> np.ndarray:
    """The pose a fraction ``s`` of the way from ``T_a`` to ``T_b``: translation linear, rotation along the
    geodesic (slerp). ``T_a``, ``T_b``: 4×4 poses, or (N, 4, 4) stacks interpolated pose by pose."""
    # Imported here: scipy takes about a second to import, which every command (even --help) paid
    # when this module, which `import evservo` loads, imported it at the top.
    from scipy.spatial.transform import Rotation

    R_a = T_a[..., :3, :3]
    d = Rotation.from_matrix(np.swapaxes(R_a, -1, -2) @ T_b[..., :3, :3]).as_rotvec()
    T = np.zeros(np.broadcast_shapes(np.shape(T_a), np.shape(T_b)))
    T[..., :3, :3] = R_a @ Rotation.from_rotvec(s * d).as_matrix()
    T[..., :3, 3] = (1.0 - s) * T_a[..., :3, 3] + s * T_b[..., :3, 3]
    T[..., 3, 3] = 1.0
    return T


def translation_error_m(T_a: np.ndarray, T_b: np.ndarray) -> float:
    """Euclidean distance between the translations of two poses (metres)."""
    return float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]))


def rotation_error_rad(T_a: np.ndarray, T_b: np.ndarray) -> float:
    """Geodesic angle between the rotations of two poses (radians)."""
    R = T_a[:3, :3].T @ T_b[:3, :3]
    c = (R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0  # np.trace's order; scalar clamp, no np.clip wrappers
    return float(np.arccos(min(max(c, -1.0), 1.0)))


def pose_errors(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation distance (m) and geodesic angle (rad) between pose stacks ``A`` and ``B`` (N, 4, 4)."""
    pos = np.linalg.norm(A[:, :3, 3] - B[:, :3, 3], axis=1)
    tr = np.einsum("nji,nji->n", A[:, :3, :3], B[:, :3, :3])  # trace(Aᵀ B)
    return pos, np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))


def rotation_from_first_rad(T: np.ndarray) -> np.ndarray:
    """Geodesic angle (rad) of each orientation in the stack ``T`` (N, 4, 4) from the first one."""
    if not len(T):
        return np.zeros(0)
    tr = np.einsum("ji,nji->n", T[0, :3, :3], T[:, :3, :3])
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))


def rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector (axis × angle, radians, angle in [0, π]) of a 3×3 rotation matrix.

    Closed form rather than scipy's ``Rotation`` because the controller runs it several times per
    control period and scipy's object construction dominates at that size.
    """
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])  # 2 sin θ · axis
    c = float(np.clip((R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0, -1.0, 1.0))
    s = 0.5 * float(np.linalg.norm(w))
    theta = float(np.arctan2(s, c))
    if theta < 1e-6:
        return 0.5 * w * (1.0 + theta * theta / 6.0)
    if theta < np.pi - 1e-4:
        return w * (theta / (2.0 * s))
    # Near π the antisymmetric part vanishes; the axis comes from the symmetric part (1−c)·u uᵀ.
    S = (0.5 * (R + R.T) - c * np.eye(3)) / (1.0 - c)
    i = int(np.argmax(np.diag(S)))
    u = S[:, i] / np.sqrt(S[i, i])
    if float(u @ w) < 0:
        u = -u
    return theta * u


def rotmat(w: np.ndarray) -> np.ndarray:
    """3×3 rotation matrix of a rotation vector (radians), by Rodrigues' formula."""
    theta = float(np.linalg.norm(w))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if theta < 1e-8:
        return np.eye(3) + K + 0.5 * (K @ K)
    return np.eye(3) + (np.sin(theta) / theta) * K + ((1.0 - np.cos(theta)) / theta**2) * (K @ K)


def advance(T_w_x: np.ndarray, twist_w: np.ndarray, dt_s: float) -> np.ndarray:
    """Pose of frame x after ``dt_s`` seconds (negative: before) at the constant world-frame twist
    ``twist_w`` = (linear velocity of x's origin m/s, angular velocity rad/s): the origin moves along a
    straight line and the frame turns about a fixed world axis through it."""
    T = np.eye(4)
    T[:3, :3] = rotmat(twist_w[3:] * dt_s) @ T_w_x[:3, :3]
    T[:3, 3] = T_w_x[:3, 3] + twist_w[:3] * dt_s
    return T
