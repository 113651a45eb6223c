"""Rig configuration: what ties a real camera to a real arm, read from one YAML file.

Layout (every section and key below is required unless marked optional; unknown keys are errors, so a
typo cannot silently drop a limit)::

    hand_eye:                      # T_e_c: camera optical frame in the end-effector frame
      translation: [0.0, 0.05, 0.1]        # metres
      quaternion: [0.0, 0.0, 0.0, 1.0]     # x, y, z, w (unit; normalised on load)
      # or instead of both:  matrix: [[r11, r12, r13, tx], ..., [0, 0, 0, 1]]
    camera:                        # the camera-file layout of evservo.camera_file (its OpenCV and ROS
      width: 1280                  # camera_info dialects too)
      height: 720
      fx: 1163.59                  # pixels; or instead of fx, fy, cx, cy:  K: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
      fy: 1173.48
      cx: 658.823
      cy: 339.619
      distortion: [-0.2819, 0.0, 0.0, 0.0, 0.0]   # optional, OpenCV order k1, k2, p1, p2[, k3]
    limits:                        # end-effector Cartesian limits (see evservo.control.CartesianLimits)
      max_lin_vel: 0.25            # m/s
      max_ang_vel: 0.5             # rad/s
      max_lin_acc: 1.0             # m/s²
      max_ang_acc: 2.0             # rad/s²
    workspace:                     # optional: box for the end-effector origin, robot base frame, metres
      lo: [0.2, -0.4, 0.05]
      hi: [0.7, 0.4, 0.6]
    object:                        # optional: defaults for `evservo servo --robot ...` (options override)
      model: box                   # built-in name or mesh path (relative paths: from this file's folder)
      init_pose: [0.0, 0.0, 0.6, 0.0, 0.0, 0.0, 1.0]     # T_c_o at start: x, y, z (m), qx, qy, qz, qw
      desired_pose: [0.0, 0.0, 0.6, 0.0, 0.0, 0.0, 1.0]  # T_c_o to servo to (default: the pose at start)

:func:`load_rig_config` raises :class:`RigConfigError` (a ``ValueError``) naming the file and the
offending key; a missing file raises ``FileNotFoundError``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from evservo import geometry
from evservo._evcore import Camera
from evservo.camera_file import CameraFileError, camera_from_mapping
from evservo.limits import CartesianLimits
from evservo.robots.safety import Workspace

__all__ = ["RigConfig", "RigConfigError", "load_rig_config"]


class RigConfigError(ValueError):
    """A rig config file is malformed: a section or key is missing, unknown or of the wrong kind."""


@dataclass(frozen=True)
class RigConfig:
    """A loaded rig: ``T_e_c`` (4×4, metres), the camera model, the end-effector limits and,
    optionally, the workspace box; ``path`` is where it was read from. From the optional ``object``
    section: ``model`` (name or resolved path), ``init_pose`` and ``desired_pose`` (``T_c_o``, 4×4),
    each None when not given."""

    T_e_c: np.ndarray
    camera: Camera
    limits: CartesianLimits
    workspace: Workspace | None
    path: Path
    model: str | None = None
    init_pose: np.ndarray | None = None
    desired_pose: np.ndarray | None = None


class _Reader:
    """Pulls typed values out of nested mappings, with errors that say where."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, where: str, msg: str) -> RigConfigError:
        return RigConfigError(f"rig config {self.path}: {where}: {msg}")

    def section(self, data: dict, key: str, allowed: set[str], optional: bool = False) -> dict | None:
        if key not in data or data[key] is None:
            if optional:
                return None
            raise self.fail(key, "missing section")
        sec = data[key]
        if not isinstance(sec, dict):
            raise self.fail(key, f"must be a mapping, got {type(sec).__name__}")
        unknown = sorted(set(sec) - allowed)
        if unknown:
            raise self.fail(key, f"unknown key(s) {unknown} (allowed: {sorted(allowed)})")
        return sec

    def number(self, sec: dict, where: str, key: str) -> float:
        if key not in sec:
            raise self.fail(f"{where}.{key}", "missing")
        v = sec[key]
        if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
            raise self.fail(f"{where}.{key}", f"must be a finite number, got {v!r}")
        return float(v)

    def array(self, sec: dict, where: str, key: str, shapes: tuple[tuple[int, ...], ...]) -> np.ndarray:
        if key not in sec:
            raise self.fail(f"{where}.{key}", "missing")
        try:
            a = np.asarray(sec[key], dtype=float)
        except (TypeError, ValueError):
            a = None
        if a is None or a.shape not in shapes or not np.all(np.isfinite(a)):
            want = " or ".join("×".join(map(str, s)) for s in shapes)
            raise self.fail(f"{where}.{key}", f"must be finite numbers of shape {want}, got {sec[key]!r}")
        return a


def _hand_eye(r: _Reader, data: dict) -> np.ndarray:
    sec = r.section(data, "hand_eye", {"translation", "quaternion", "matrix"})
    assert sec is not None
    if "matrix" in sec:
        if "translation" in sec or "quaternion" in sec:
            raise r.fail("hand_eye", "give either matrix or translation + quaternion, not both")
        M = r.array(sec, "hand_eye", "matrix", ((4, 4),))
        try:
            return geometry.as_pose(M, "hand_eye.matrix")
        except ValueError as err:
            raise r.fail("hand_eye.matrix", str(err)) from err
    t = r.array(sec, "hand_eye", "translation", ((3,),))
    q = r.array(sec, "hand_eye", "quaternion", ((4,),))
    if abs(np.linalg.norm(q) - 1.0) > 1e-3:
        raise r.fail("hand_eye.quaternion", f"must be a unit quaternion (x, y, z, w), norm is {np.linalg.norm(q):.6f}")
    return geometry.pose_from_xyz_quat(*t, *q)


def _camera(r: _Reader, data: dict) -> Camera:
    if data.get("camera") is None:
        raise r.fail("camera", "missing section")
    try:
        return camera_from_mapping(data["camera"], f"rig config {r.path}: camera.")
    except CameraFileError as err:
        raise RigConfigError(str(err)) from None


def _limits(r: _Reader, data: dict) -> CartesianLimits:
    names = ("max_lin_vel", "max_ang_vel", "max_lin_acc", "max_ang_acc")
    sec = r.section(data, "limits", set(names))
    assert sec is not None
    values = {k: r.number(sec, "limits", k) for k in names}
    try:
        return CartesianLimits(**values)
    except ValueError as err:
        raise r.fail("limits", str(err)) from err


def _workspace(r: _Reader, data: dict) -> Workspace | None:
    sec = r.section(data, "workspace", {"lo", "hi"}, optional=True)
    if sec is None:
        return None
    lo, hi = r.array(sec, "workspace", "lo", ((3,),)), r.array(sec, "workspace", "hi", ((3,),))
    try:
        return Workspace(lo, hi)
    except ValueError as err:
        raise r.fail("workspace", str(err)) from err


def _object(r: _Reader, data: dict) -> tuple[str | None, np.ndarray | None, np.ndarray | None]:
    sec = r.section(data, "object", {"model", "init_pose", "desired_pose"}, optional=True)
    if sec is None:
        return None, None, None
    model = sec.get("model")
    if model is not None:
        if not isinstance(model, str) or not model:
            raise r.fail("object.model", f"must be a built-in name or a mesh path, got {model!r}")
        candidate = r.path.parent / model
        if ("/" in model or "." in model) and not Path(model).is_absolute() and candidate.exists():
            model = str(candidate)
    poses = []
    for key in ("init_pose", "desired_pose"):
        if sec.get(key) is None:
            poses.append(None)
            continue
        v = r.array(sec, "object", key, ((7,),))
        if abs(np.linalg.norm(v[3:]) - 1.0) > 1e-3:
            norm = np.linalg.norm(v[3:])
            raise r.fail(f"object.{key}", f"must be x, y, z, qx, qy, qz, qw with a unit quaternion; norm is {norm:.6f}")
        if v[2] <= 0:
            raise r.fail(f"object.{key}", f"the object must be in front of the camera (z > 0), got z = {v[2]}")
        poses.append(geometry.pose_from_xyz_quat(*v))
    return model, poses[0], poses[1]


def load_rig_config(path: str | os.PathLike) -> RigConfig:
    """Read and validate a rig config YAML file (layout in the module docstring)."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such rig config: {p}")
    r = _Reader(p)
    try:
        data: Any = yaml.safe_load(p.read_text())
    except yaml.YAMLError as err:
        raise RigConfigError(f"rig config {p}: not valid YAML: {err}") from err
    if not isinstance(data, dict):
        raise RigConfigError(f"rig config {p}: top level must be a mapping of sections")
    unknown = sorted(set(data) - {"hand_eye", "camera", "limits", "workspace", "object"})
    if unknown:
        raise RigConfigError(f"rig config {p}: unknown section(s) {unknown}")
    return RigConfig(_hand_eye(r, data), _camera(r, data), _limits(r, data), _workspace(r, data), p, *_object(r, data))
