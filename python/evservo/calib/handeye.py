"""Hand-eye calibration: the camera on the flange (``T_e_c``) from board views and arm poses.

The board stays fixed in the robot base while the arm carries the camera to each view. Inputs:

* ``poses.csv``, header ``t_s,x_m,y_m,z_m,qx,qy,qz,qw``: the flange in the robot base (``T_b_e``)
  at each still moment, on the recording's clock (seconds).
* the views of :func:`evservo.calib.views.scan_recording` and the camera's intrinsics.

Steps: each view's board pose ``T_c_board`` by PnP on its corners; views matched to poses by time
(one view per pose, each within ``max_dt_s``); OpenCV's ``calibrateHandEye`` with every method it has
(Tsai, Park, Horaud, Andreff, Daniilidis), their spread reported as the largest pairwise rotation and
translation difference; then a joint refinement of ``T_e_c`` and the board in the base ``T_b_board``
minimising the corners' reprojection error over all views (Levenberg–Marquardt, from the Park
solution), which uses every corner rather than one pose per view.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from evservo import _evcore, geometry
from evservo.calib.board import Board
from evservo.calib.views import View
from evservo.outputs import atomic_path

__all__ = [
    "HAND_EYE_METHODS",
    "MIN_POSES",
    "POSES_HEADER",
    "HandEyeResult",
    "board_poses",
    "calibrate_hand_eye",
    "match_views",
    "read_poses",
    "write_poses",
]

POSES_HEADER = ("t_s", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw")

#: OpenCV's hand-eye methods, by name.
HAND_EYE_METHODS = {
    "tsai": cv2.CALIB_HAND_EYE_TSAI,
    "park": cv2.CALIB_HAND_EYE_PARK,
    "horaud": cv2.CALIB_HAND_EYE_HORAUD,
    "andreff": cv2.CALIB_HAND_EYE_ANDREFF,
    "daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS,
}

#: Fewest poses: hand-eye needs at least two motions about non-parallel axes; a few more average noise.
MIN_POSES = 5


def read_poses(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(t_s (N,), T_b_e (N, 4, 4)) from a poses CSV (see the module docstring)."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such poses file: {p}")
    with p.open(newline="") as f:
        rows = list(csv.reader(f))
    if not rows or tuple(c.strip() for c in rows[0]) != POSES_HEADER:
        raise ValueError(f"{p}: the header must be {','.join(POSES_HEADER)}")
    times, poses = [], []
    for n, row in enumerate(rows[1:], start=2):
        if not row:
            continue
        try:
            v = [float(c) for c in row]
        except ValueError:
            raise ValueError(f"{p}:{n}: not a number in {row}") from None
        if len(v) != 8 or not np.all(np.isfinite(v)):
            raise ValueError(f"{p}:{n}: need 8 finite numbers, got {row}")
        if abs(np.linalg.norm(v[4:]) - 1.0) > 1e-3:
            raise ValueError(f"{p}:{n}: qx, qy, qz, qw must be a unit quaternion (norm {np.linalg.norm(v[4:]):.6f})")
        times.append(v[0])
        poses.append(geometry.pose_from_xyz_quat(*v[1:]))
    if not times:
        raise ValueError(f"{p}: no poses")
    t = np.array(times)
    if np.any(np.diff(t) <= 0):
        raise ValueError(f"{p}: t_s must increase from row to row")
    return t, np.array(poses)


def write_poses(path: str | Path, t_s: np.ndarray, T_b_e: np.ndarray) -> None:
    """Write a poses CSV (the inverse of :func:`read_poses`), atomically."""
    with atomic_path(path) as tmp, tmp.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(POSES_HEADER)
        for t, T in zip(t_s, T_b_e, strict=True):
            q = Rotation.from_matrix(T[:3, :3]).as_quat()
            w.writerow([f"{t:.6f}", *(f"{v:.9f}" for v in T[:3, 3]), *(f"{v:.9f}" for v in q)])


def match_views(views: list[View], t_s: np.ndarray, max_dt_s: float = 0.5) -> list[int]:
    """For each pose time, the index of its view: one view per pose and the same number of each, each
    pose within ``max_dt_s`` of its view's blinks. Raises ``ValueError`` saying what does not match."""
    if len(views) != len(t_s):
        raise ValueError(
            f"the poses file has {len(t_s)} pose(s) but the recording shows the whole board in {len(views)} still "
            "view(s); each pose must belong to one view (drop the poses of views where the board was not found whole)"
        )
    out = []
    for k, t in enumerate(t_s):
        t_us = t * 1e6
        gaps = [max(v.t_start_us - t_us, t_us - v.t_end_us, 0.0) for v in views]
        i = int(np.argmin(gaps))
        if gaps[i] > max_dt_s * 1e6:
            raise ValueError(
                f"pose {k + 1} at t = {t:.3f} s is {gaps[i] * 1e-6:.3f} s from the nearest view (allowed "
                f"{max_dt_s} s): are the poses on the recording's clock?"
            )
        if i in out:
            raise ValueError(
                f"poses {out.index(i) + 1} and {k + 1} both fall on the view at {views[i].t_mid_us * 1e-6:.3f} s: "
                "the poses' times do not match the views' (are the poses on the recording's clock?)"
            )
        out.append(i)
    return out


def board_poses(views: list[View], board: Board, camera: _evcore.Camera) -> np.ndarray:
    """``T_c_board`` (N, 4, 4) of each view by PnP (IPPE for a plane, then Levenberg–Marquardt)."""
    K, dist = camera.k, np.array(camera.dist, float)
    obj = board.object_points().astype(np.float64)
    out = []
    for v in views:
        img = v.corners.astype(np.float64)
        ok, rvec, tvec = cv2.solvePnP(obj, img, K, dist, flags=cv2.SOLVEPNP_IPPE)
        if not ok:
            raise ValueError(f"PnP failed for the view at {v.t_mid_us * 1e-6:.3f} s")
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, dist, rvec, tvec)
        T = np.eye(4)
        T[:3, :3] = cv2.Rodrigues(rvec)[0]
        T[:3, 3] = tvec.ravel()
        out.append(T)
    return np.array(out)


@dataclass
class HandEyeResult:
    """``T_e_c`` (4×4, metres) after the joint refinement; ``T_b_board`` (the board in the base);
    ``methods``: each OpenCV method's ``T_e_c``; their spread (degrees, millimetres); the refined
    reprojection RMS over all corners (px); how many views were used."""

    T_e_c: np.ndarray
    T_b_board: np.ndarray
    methods: dict[str, np.ndarray]
    rot_spread_deg: float
    trans_spread_mm: float
    rms_px: float
    views_used: int

    def summary(self) -> dict:
        """The ``--json`` record: T_e_c (4×4 list), rot_spread_deg, trans_spread_mm, views_used (plus rms_px)."""
        return dict(
            T_e_c=self.T_e_c.tolist(), rot_spread_deg=self.rot_spread_deg, trans_spread_mm=self.trans_spread_mm,
            views_used=self.views_used, rms_px=self.rms_px,
        )  # fmt: skip


def _spread(poses: list[np.ndarray]) -> tuple[float, float]:
    rot = max(geometry.rotation_error_rad(a, b) for a in poses for b in poses)
    trans = max(geometry.translation_error_m(a, b) for a in poses for b in poses)
    return float(np.degrees(rot)), float(trans * 1e3)


def _to_pose(x: np.ndarray) -> np.ndarray:
    return geometry.pose(x[3:], x[:3])


def _to_params(T: np.ndarray) -> np.ndarray:
    return np.r_[Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3]]


def _refine(
    T_e_c: np.ndarray, T_b_e: np.ndarray, views: list[View], board: Board, camera: _evcore.Camera, T_b_board: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    K, dist = camera.k, np.array(camera.dist, float)
    obj = board.object_points().astype(np.float64)
    seen = np.concatenate([v.corners.astype(np.float64).ravel() for v in views])
    T_e_b = np.array([geometry.inv(T) for T in T_b_e])

    def residuals(x: np.ndarray) -> np.ndarray:
        T_c_e = geometry.inv(_to_pose(x[:6]))
        T_bb = _to_pose(x[6:])
        proj = []
        for T in T_e_b:
            T_c_board = T_c_e @ T @ T_bb
            rvec = cv2.Rodrigues(T_c_board[:3, :3])[0]
            proj.append(cv2.projectPoints(obj, rvec, T_c_board[:3, 3], K, dist)[0].ravel())
        return np.concatenate(proj) - seen

    fit = least_squares(residuals, np.r_[_to_params(T_e_c), _to_params(T_b_board)], method="lm", x_scale="jac")
    rms = float(np.sqrt(np.mean(fit.fun.reshape(-1, 2) ** 2) * 2))
    return _to_pose(fit.x[:6]), _to_pose(fit.x[6:]), rms


def calibrate_hand_eye(
    views: list[View], T_b_e: np.ndarray, board: Board, camera: _evcore.Camera, min_poses: int = MIN_POSES
) -> HandEyeResult:
    """Solve ``T_e_c`` from views and their flange poses ``T_b_e`` (same order, already matched)."""
    if not board.oriented:
        raise ValueError(
            f"a {board} board looks the same turned half a turn, so its pose is ambiguous; hand-eye needs a board with "
            "one even and one odd count of inner corners (e.g. 9x6)"
        )
    if len(views) < min_poses:
        raise ValueError(f"hand-eye needs at least {min_poses} views with poses, got {len(views)}")
    if not hasattr(cv2, "calibrateHandEye"):
        raise RuntimeError(
            f"this OpenCV ({cv2.__version__}) has no calibrateHandEye; install the pinned opencv-python-headless "
            "(requirements.txt)"
        )
    T_c_board = board_poses(views, board, camera)
    methods = {}
    for name, flag in HAND_EYE_METHODS.items():
        R, t = cv2.calibrateHandEye(
            T_b_e[:, :3, :3], T_b_e[:, :3, 3], T_c_board[:, :3, :3], T_c_board[:, :3, 3], method=flag
        )
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, np.ravel(t)
        if np.all(np.isfinite(T)) and abs(np.linalg.det(R) - 1.0) < 1e-6:
            methods[name] = T
    if "park" not in methods:
        raise ValueError(
            "OpenCV's hand-eye solvers failed: are the poses varied enough (rotations about different axes)?"
        )
    rot_spread, trans_spread = _spread(list(methods.values()))
    start = methods["park"]
    # The board in the base from each view with the starting T_e_c; their mean starts the refinement.
    T_b_board_k = T_b_e @ start @ T_c_board
    T_b_board = np.eye(4)
    T_b_board[:3, :3] = Rotation.from_matrix(T_b_board_k[:, :3, :3]).mean().as_matrix()
    T_b_board[:3, 3] = T_b_board_k[:, :3, 3].mean(axis=0)
    T_e_c, T_b_board, rms = _refine(start, T_b_e, views, board, camera, T_b_board)
    return HandEyeResult(T_e_c, T_b_board, methods, rot_spread, trans_spread, rms, len(views))
