"""Camera intrinsics and distortion from board views (OpenCV's ``calibrateCamera``).

Distortion models (OpenCV order k1, k2, p1, p2, k3; what a model does not estimate stays 0):
``k1`` (one radial term), ``k1k2`` (two radial terms, the default), ``full`` (all five).

Outlier views: after each solve, views whose reprojection RMS exceeds ``max(3 × median, median +
0.5 px)`` are dropped and the camera is solved again, until none is dropped (never below
``min_views``).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from evservo import _evcore
from evservo.calib.board import Board
from evservo.calib.views import View

__all__ = ["DISTORTION_MODELS", "MIN_VIEWS", "IntrinsicsResult", "calibrate_intrinsics"]

DISTORTION_MODELS = {
    "k1": cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST,
    "k1k2": cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST,
    "full": 0,
}

#: Fewest good views a calibration accepts: below this the focal length and distortion trade off.
MIN_VIEWS = 6


@dataclass
class IntrinsicsResult:
    """A calibration: the camera, the overall reprojection RMS (px) over the views used, each view's
    RMS (px, NaN for a rejected view) and which views were used / rejected (indices into the input)."""

    camera: _evcore.Camera
    rms_px: float
    view_rms_px: list[float]
    used: list[int]
    rejected: list[int]
    model: str

    def summary(self) -> dict:
        """The ``--json`` record: fx, fy, cx, cy, dist [k1, k2, p1, p2, k3], rms_px, views_used."""
        c = self.camera
        return dict(
            fx=c.fx, fy=c.fy, cx=c.cx, cy=c.cy, dist=[float(v) for v in c.dist], rms_px=self.rms_px,
            views_used=len(self.used),
        )  # fmt: skip


def _solve(views: list[View], board: Board, size: tuple[int, int], flags: int):
    obj = [board.object_points()] * len(views)
    img = [v.corners.reshape(-1, 1, 2) for v in views]
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    rms, K, dist, _, _, _, _, per_view = cv2.calibrateCameraExtended(
        obj, img, size, None, None, flags=flags, criteria=criteria
    )
    return float(rms), K, dist.ravel(), per_view.ravel()


def calibrate_intrinsics(
    views: list[View], board: Board, width: int, height: int, model: str = "k1k2", min_views: int = MIN_VIEWS
) -> IntrinsicsResult:
    """Calibrate from ``views`` of ``board`` on a ``width`` × ``height`` sensor (see the module docstring).
    Raises ``ValueError`` with fewer than ``min_views`` views (before or after outlier rejection)."""
    if model not in DISTORTION_MODELS:
        raise ValueError(f"unknown distortion model {model!r} (choose from {', '.join(DISTORTION_MODELS)})")
    if len(views) < min_views:
        raise ValueError(
            f"only {len(views)} view(s) show the whole {board} board; a calibration needs at least {min_views}: "
            "record more views, from different angles and covering the image corners"
        )
    used = list(range(len(views)))
    while True:
        rms, K, dist, per_view = _solve([views[i] for i in used], board, (width, height), DISTORTION_MODELS[model])
        med = float(np.median(per_view))
        bad = per_view > max(3.0 * med, med + 0.5)
        if not bad.any():
            break
        keep = [i for i, b in zip(used, bad, strict=True) if not b]
        if len(keep) < min_views:
            raise ValueError(
                f"{len(used) - len(keep)} of {len(used)} views do not fit the others (reprojection RMS "
                f"{', '.join(f'{e:.2f}' for e in per_view[bad])} px against a median {med:.2f} px) and fewer than "
                f"{min_views} remain"
            )
        used = keep
    view_rms = [float("nan")] * len(views)
    for i, e in zip(used, per_view, strict=True):
        view_rms[i] = float(e)
    d = np.zeros(5)
    d[: min(5, len(dist))] = dist[:5]
    camera = _evcore.Camera(width, height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], tuple(float(v) for v in d))
    rejected = sorted(set(range(len(views))) - set(used))
    return IntrinsicsResult(camera, rms, view_rms, used, rejected, model)
