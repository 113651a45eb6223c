"""The one camera-file format, read by ``evservo track --camera``, ``servo --config`` (its ``camera:``
section) and written by ``evservo calib``.

Layout (YAML or JSON; every key required unless marked optional; unknown keys are errors, so a typo
cannot silently drop a coefficient)::

    width: 1280                    # pixels, 1..65535
    height: 720
    fx: 1163.59                    # pixels; or instead of fx, fy, cx, cy:  K: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    fy: 1173.48
    cx: 658.823
    cy: 339.619
    distortion: [-0.2819, 0.0, 0.0, 0.0, 0.0]   # optional, OpenCV order k1, k2, p1, p2[, k3]

Two other dialects are recognised by their keys and read into the same camera:

* **OpenCV** ``cv::FileStorage`` YAML (``%YAML:1.0``, ``image_width``, ``image_height``,
  ``camera_matrix`` and ``distortion_coefficients`` as ``!!opencv-matrix``), as OpenCV's calibration
  tools write it; other keys of theirs (reprojection error, flags, …) are ignored;
* **ROS** ``camera_info`` YAML (``image_width``, ``image_height``, ``camera_matrix``/``distortion_coefficients``
  with ``rows``, ``cols``, ``data``, ``distortion_model: plumb_bob``); its rectification and
  projection matrices are ignored (evservo undistorts with ``K`` and the coefficients).

Distortion models other than OpenCV's 5-coefficient radial–tangential one (``plumb_bob``) are refused.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from evservo._evcore import Camera

__all__ = ["CameraFileError", "camera_from_mapping", "camera_to_mapping", "load_camera_file"]

NATIVE_KEYS = frozenset({"width", "height", "fx", "fy", "cx", "cy", "K", "distortion"})
# Keys of the OpenCV and ROS dialects that carry nothing evservo uses.
_FOREIGN_IGNORED = frozenset({
    "camera_name", "rectification_matrix", "projection_matrix", "avg_reprojection_error", "calibration_time",
    "nr_of_frames", "nframes", "flags", "flag", "board_width", "board_height", "square_size", "fix_aspect_ratio",
    "per_view_reprojection_errors", "extrinsic_parameters", "image_points", "grid_points", "aspectRatio",
})  # fmt: skip
_MODELS = ("plumb_bob", "radtan", "radial-tangential")


class CameraFileError(ValueError):
    """A camera description is malformed (says where and which key)."""


def _whole(where: str) -> str:
    """The name of the whole description from a key prefix (``"camera file c.yaml: "``)."""
    return where.rstrip(".: ") or "camera"


def _matrix(v: Any, where: str, key: str) -> np.ndarray:
    """A matrix given as nested lists, a flat list, or a mapping with ``data`` (OpenCV/ROS)."""
    if isinstance(v, dict):
        if "data" not in v:
            raise CameraFileError(f"{where}{key}: needs 'data'")
        v = v["data"]
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise CameraFileError(f"{where}{key}: must be numbers, got {v!r}") from None
    if not np.all(np.isfinite(a)):
        raise CameraFileError(f"{where}{key}: must be finite, got {v!r}")
    return a


def _number(d: dict, where: str, key: str) -> float:
    if key not in d:
        raise CameraFileError(f"{where}{key}: missing")
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
        raise CameraFileError(f"{where}{key}: must be a finite number, got {v!r}")
    return float(v)


def _size(d: dict, where: str, key: str) -> int:
    v = _number(d, where, key)
    if v != int(v) or not 1 <= v <= 65535:
        raise CameraFileError(f"{where}{key}: must be a whole number of pixels in 1..65535, got {d[key]!r}")
    return int(v)


def camera_from_mapping(d: object, where: str = "") -> Camera:
    """The :class:`~evservo.Camera` a parsed camera description holds (any of the three dialects in
    the module docstring); ``where`` prefixes each key in errors (e.g. ``"rig config r.yaml: camera."``)."""
    if not isinstance(d, dict):
        raise CameraFileError(f"{_whole(where)}: must be a mapping, got {type(d).__name__}")
    foreign = "camera_matrix" in d or "image_width" in d
    if foreign:
        unknown = sorted(set(d) - {"image_width", "image_height", "camera_matrix", "distortion_coefficients",
                                   "distortion_model"} - _FOREIGN_IGNORED)  # fmt: skip
        if unknown:
            raise CameraFileError(f"{_whole(where)}: unknown key(s) {unknown} in an OpenCV/ROS camera description")
        width, height = _size(d, where, "image_width"), _size(d, where, "image_height")
        if "camera_matrix" not in d:
            raise CameraFileError(f"{where}camera_matrix: missing")
        K = _matrix(d["camera_matrix"], where, "camera_matrix")
        model = d.get("distortion_model")
        if model is not None and str(model).lower() not in _MODELS:
            raise CameraFileError(f"{where}distortion_model: {model!r} is not supported (want plumb_bob)")
        dist = _matrix(d.get("distortion_coefficients", []), where, "distortion_coefficients").ravel()
    else:
        unknown = sorted(set(d) - NATIVE_KEYS)
        if unknown:
            raise CameraFileError(f"{_whole(where)}: unknown key(s) {unknown} (allowed: {sorted(NATIVE_KEYS)})")
        width, height = _size(d, where, "width"), _size(d, where, "height")
        if "K" in d:
            if any(k in d for k in ("fx", "fy", "cx", "cy")):
                raise CameraFileError(f"{_whole(where)}: give either K or fx, fy, cx, cy, not both")
            K = _matrix(d["K"], where, "K")
        else:
            fx, fy, cx, cy = (_number(d, where, k) for k in ("fx", "fy", "cx", "cy"))
            K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        dist = _matrix(d.get("distortion") if d.get("distortion") is not None else [], where, "distortion").ravel()
    key = "camera_matrix" if foreign else "K"
    if K.size != 9:
        raise CameraFileError(f"{where}{key}: must be 3×3, got {K.size} values")
    K = K.reshape(3, 3)
    if K[0, 1] != 0 or K[1, 0] != 0 or np.any(K[2] != [0, 0, 1]):
        raise CameraFileError(f"{where}{key}: must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)")
    if len(dist) > 5:
        if np.any(dist[5:] != 0):
            raise CameraFileError(f"{where}distortion: at most 5 coefficients (k1 k2 p1 p2 k3), got {len(dist)}")
        dist = dist[:5]
    if len(dist) not in (0, 4, 5):
        raise CameraFileError(f"{where}distortion: needs 4 or 5 coefficients (k1 k2 p1 p2[ k3]), got {len(dist)}")
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    coeffs = tuple(float(v) for v in np.pad(dist, (0, 5 - len(dist))))
    try:
        return Camera(width, height, float(fx), float(fy), float(cx), float(cy), coeffs)
    except (ValueError, TypeError) as err:
        raise CameraFileError(f"{_whole(where)}: {err}") from None


def camera_to_mapping(camera: Camera) -> dict[str, Any]:
    """The native layout of ``camera`` (what :func:`load_camera_file` reads back to the same camera)."""
    return {
        "width": int(camera.width), "height": int(camera.height), "fx": float(camera.fx), "fy": float(camera.fy),
        "cx": float(camera.cx), "cy": float(camera.cy), "distortion": [float(v) for v in camera.dist],
    }  # fmt: skip


def _opencv_yaml(text: str) -> str:
    """cv::FileStorage YAML as plain YAML: its ``%YAML:1.0`` directive and ``!!opencv-matrix`` tags
    are not standard YAML."""
    text = re.sub(r"^%YAML[:\s].*$", "", text, count=1, flags=re.MULTILINE)
    return text.replace("!!opencv-matrix", "")


def load_camera_file(path: str | os.PathLike) -> Camera:
    """Read a camera file (YAML ``.yaml``/``.yml``, otherwise JSON; layout in the module docstring).
    Raises ``FileNotFoundError`` for a missing file, :class:`CameraFileError` naming the file otherwise."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"no such camera file: {p}")
    if not p.is_file():
        raise CameraFileError(f"camera file {p} is not a regular file")
    try:
        text = p.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise CameraFileError(f"camera file {p}: cannot read it: {err}") from None
    try:
        if p.suffix.lower() in (".yaml", ".yml"):
            import yaml

            d = yaml.safe_load(_opencv_yaml(text))
        else:
            d = json.loads(text)
    except Exception as err:  # any parse error means a bad file for the user
        raise CameraFileError(f"camera file {p}: cannot parse it: {err}") from None
    return camera_from_mapping(d, f"camera file {p}: ")
