"""The files calibration writes: the camera file and the rig file's ``camera`` and ``hand_eye`` sections.

* camera file (``evservo calib intrinsics --out cam.yaml``): the project's one camera-file layout
  (:mod:`evservo.camera_file`, its native keys ``width``, ``height``, ``fx``, ``fy``, ``cx``, ``cy``,
  ``distortion`` k1 k2 p1 p2 k3), read by ``track --camera``, ``calib hand-eye --camera`` and, as its
  ``camera:`` section, ``servo --config``.
* rig file (``evservo calib hand-eye --out rig.yaml``): an existing rig config keeps its other
  sections and gets ``camera`` and ``hand_eye`` (``translation`` [m], ``quaternion`` [x, y, z, w]:
  ``T_e_c``) replaced; a new one holds only those two and needs a ``limits`` section, chosen by a
  person, before ``evservo servo --robot`` accepts it.

Files are written whole to a temporary name and renamed, so a failure never leaves half a file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from evservo import _evcore
from evservo.camera_file import camera_to_mapping
from evservo.outputs import write_text_atomic

__all__ = ["hand_eye_section", "merge_rig_file", "write_camera_file"]


def hand_eye_section(T_e_c: np.ndarray) -> dict:
    """The ``hand_eye`` mapping of a rig config: translation (m) and unit quaternion (x, y, z, w)."""
    q = Rotation.from_matrix(T_e_c[:3, :3]).as_quat()
    return dict(translation=[float(v) for v in T_e_c[:3, 3]], quaternion=[float(v) for v in q])


def _write_yaml(path: Path, data: dict, header: str) -> None:
    if not path.parent.is_dir():
        raise FileNotFoundError(f"output directory does not exist: {path.parent}")
    write_text_atomic(path, header + yaml.safe_dump(data, sort_keys=False, default_flow_style=None))


def write_camera_file(path: str | Path, camera: _evcore.Camera, note: str = "") -> None:
    """Write a camera file (see the module docstring); ``note`` becomes a comment line at the top."""
    header = "# Camera intrinsics (evservo calib intrinsics); pixels, OpenCV distortion k1 k2 p1 p2 k3.\n"
    if note:
        header += f"# {note}\n"
    _write_yaml(Path(path), camera_to_mapping(camera), header)


def merge_rig_file(path: str | Path, camera: _evcore.Camera, T_e_c: np.ndarray, note: str = "") -> bool:
    """Put ``camera`` and ``T_e_c`` into the rig file at ``path`` (see the module docstring); True when
    the file existed (its other sections are kept; comments are not)."""
    p = Path(path)
    data: dict = {}
    existed = p.is_file()
    if existed:
        try:
            loaded = yaml.safe_load(p.read_text())
        except yaml.YAMLError as err:
            raise ValueError(f"{p}: not valid YAML, not merging into it: {err}") from err
        if loaded is not None and not isinstance(loaded, dict):
            raise ValueError(f"{p}: a rig config must be a mapping of sections, not merging into it")
        data = dict(loaded or {})
    data["hand_eye"] = hand_eye_section(T_e_c)
    data["camera"] = camera_to_mapping(camera)
    header = "# Rig config; hand_eye and camera written by evservo calib hand-eye.\n"
    if note:
        header += f"# {note}\n"
    if "limits" not in data:
        header += "# Add a limits section (max_lin_vel, max_ang_vel, max_lin_acc, max_ang_acc) before servoing.\n"
    _write_yaml(p, data, header)
    return existed
