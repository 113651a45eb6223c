"""Resolving a run's inputs the same way for ``evservo track`` and ``evservo servo --robot``: the
camera geometry of an event source, and a pose given on the command line."""

from __future__ import annotations

import numpy as np

from evservo import _evcore, geometry

#: Sensor size of the paper's camera (Prophesee IMX636), whose intrinsics are the fallback for a
#: file of that size that describes no camera.
IMX636_SIZE = (1280, 720)


def parse_pose(text: str, option: str = "--init-pose") -> np.ndarray:
    """``x,y,z,qx,qy,qz,qw`` (metres, unit quaternion) as a 4×4 pose; errors name ``option``."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"{option} must be 7 numbers x,y,z,qx,qy,qz,qw; got {text!r}") from None
    if len(values) != 7 or not np.all(np.isfinite(values)):
        raise ValueError(f"{option} must be 7 finite numbers x,y,z,qx,qy,qz,qw; got {text!r}")
    return geometry.pose_from_xyz_quat(*values)


def parse_object_pose(text: str, option: str = "--init-pose") -> np.ndarray:
    """A pose of the object in the camera (``T_c_o``, as :func:`parse_pose`) that puts the object in
    front of the camera (z > 0)."""
    T = parse_pose(text, option)
    if T[2, 3] <= 0:
        raise ValueError(f"{option}: the object must be in front of the camera (z > 0), got z = {T[2, 3]}")
    return T


def resolve_camera(
    source: str,
    size: tuple[int, int],
    given: _evcore.Camera | None,
    recorded: _evcore.Camera | None,
    hint: str,
    note: list[str] | None = None,
) -> _evcore.Camera:
    """The camera of event ``source`` whose sensor is ``size`` (width, height): the one ``given`` (a
    camera file or rig config), else the one ``recorded`` with the events (a simulated recording),
    else the IMX636's for a 1280×720 sensor (a line saying so is appended to ``note``). ``hint`` says
    how to give one (``"give --camera FILE"``). Raises ``ValueError`` when none fits."""
    cam = given or recorded
    if cam is None:
        if tuple(size) != IMX636_SIZE:
            raise ValueError(f"{source} is {size[0]}x{size[1]} and describes no camera: {hint} for its intrinsics")
        cam = _evcore.Camera.imx636()
        if note is not None:
            note.append(f"{source} describes no camera: taking the paper's IMX636 intrinsics (1280x720)")
    if (cam.width, cam.height) != tuple(size):
        raise ValueError(f"the camera is {cam.width}x{cam.height} but {source} is {size[0]}x{size[1]}")
    return cam
