"""Rig config files: hand–eye, intrinsics, limits, workspace; errors that say what and where."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

from evservo import geometry
from evservo.robots.config import RigConfigError, load_rig_config

GOOD = """
hand_eye:
  translation: [0.0, 0.05, 0.1]
  quaternion: [0.0, 0.0, 0.7071067811865476, 0.7071067811865476]
camera:
  width: 1280
  height: 720
  fx: 1163.59
  fy: 1173.48
  cx: 658.823
  cy: 339.619
  distortion: [-0.2819, 0.0, 0.0, 0.0]
limits:
  max_lin_vel: 0.25
  max_ang_vel: 0.5
  max_lin_acc: 1.0
  max_ang_acc: 2.0
workspace:
  lo: [0.2, -0.4, 0.05]
  hi: [0.7, 0.4, 0.6]
"""


def write(tmp_path, text: str):
    p = tmp_path / "rig.yaml"
    p.write_text(textwrap.dedent(text))
    return p


def test_loads_a_complete_rig(tmp_path):
    rig = load_rig_config(write(tmp_path, GOOD))
    np.testing.assert_allclose(rig.T_e_c, geometry.pose((0.0, 0.05, 0.1), (0.0, 0.0, np.pi / 2)), atol=1e-12)
    cam = rig.camera
    assert (cam.width, cam.height) == (1280, 720)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (1163.59, 1173.48, 658.823, 339.619)
    np.testing.assert_allclose(cam.dist, [-0.2819, 0, 0, 0, 0])  # k3 padded
    assert rig.limits.max_lin_vel == 0.25 and rig.limits.max_ang_acc == 2.0
    assert rig.workspace is not None and rig.workspace.contains([0.5, 0.0, 0.3])


def test_matrix_and_K_forms(tmp_path):
    T = geometry.pose((0.01, 0.02, 0.03), (0.1, -0.2, 0.3))
    K = "  K: [[500, 0, 320], [0, 510, 240], [0, 0, 1]]\n"
    text = (
        GOOD.replace("  translation: [0.0, 0.05, 0.1]\n", f"  matrix: {T.tolist()}\n")
        .replace("  quaternion: [0.0, 0.0, 0.7071067811865476, 0.7071067811865476]\n", "")
        .replace("  fx: 1163.59\n  fy: 1173.48\n  cx: 658.823\n  cy: 339.619\n", K)
        .replace("workspace:\n  lo: [0.2, -0.4, 0.05]\n  hi: [0.7, 0.4, 0.6]\n", "")
    )
    rig = load_rig_config(write(tmp_path, text))
    np.testing.assert_allclose(rig.T_e_c, T, atol=1e-12)
    assert (rig.camera.fx, rig.camera.fy, rig.camera.cx, rig.camera.cy) == (500, 510, 320, 240)
    assert rig.workspace is None


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (("limits:", "limitz:"), "unknown section"),
        (("  max_ang_acc: 2.0\n", ""), r"limits\.max_ang_acc: missing"),
        (("max_lin_vel: 0.25", "max_lin_vel: -1"), r"limits: max_lin_vel must be finite and > 0"),
        (("max_lin_vel: 0.25", "max_lin_vel: fast"), r"limits\.max_lin_vel: must be a finite number"),
        (("quaternion: [0.0, 0.0, 0.7071067811865476, 0.7071067811865476]", "quaternion: [0, 0, 1, 1]"),
         "unit quaternion"),
        (("quaternion:", "quaterion:"), r"hand_eye: unknown key\(s\) \['quaterion'\]"),
        (("translation: [0.0, 0.05, 0.1]", "translation: [0.0, 0.05]"), r"hand_eye\.translation: .*shape 3"),
        (("  width: 1280\n", ""), r"camera\.width: missing"),
        (("fx: 1163.59", "fx: -1163.59"), "focal lengths must be finite and positive"),
        (("distortion: [-0.2819, 0.0, 0.0, 0.0]", "distortion: [1, 2, 3]"), r"camera\.distortion"),
        (("hi: [0.7, 0.4, 0.6]", "hi: [0.1, 0.4, 0.6]"), "workspace: .*lo < hi"),
    ],
)  # fmt: skip
def test_bad_fields_are_named(tmp_path, edit, message):
    old, new = edit
    assert old in GOOD
    p = write(tmp_path, GOOD.replace(old, new))
    with pytest.raises(RigConfigError, match=message) as err:
        load_rig_config(p)
    assert str(p) in str(err.value)


def test_missing_section_file_and_bad_yaml(tmp_path):
    with pytest.raises(RigConfigError, match="hand_eye: missing section"):
        load_rig_config(write(tmp_path, "camera:" + GOOD.split("camera:")[1]))
    with pytest.raises(FileNotFoundError, match="no such rig config"):
        load_rig_config(tmp_path / "nope.yaml")
    with pytest.raises(RigConfigError, match="not valid YAML"):
        load_rig_config(write(tmp_path, "hand_eye: [unclosed\n"))


def test_object_section_is_optional_and_read(tmp_path):
    rig = load_rig_config(write(tmp_path, GOOD))
    assert rig.model is None and rig.init_pose is None and rig.desired_pose is None
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "part.obj").write_text("v 0 0 0\n")
    text = GOOD + (
        "object:\n  model: meshes/part.obj\n  init_pose: [0.01, 0.0, 0.6, 0.0, 0.0, 0.0, 1.0]\n"
        "  desired_pose: [0.0, 0.0, 0.5, 0.0, 0.0, 0.7071067811865476, 0.7071067811865476]\n"
    )
    rig = load_rig_config(write(tmp_path, text))
    assert rig.model == str(tmp_path / "meshes" / "part.obj")  # relative to the config file
    np.testing.assert_allclose(rig.init_pose, geometry.pose((0.01, 0.0, 0.6)), atol=1e-12)
    np.testing.assert_allclose(rig.desired_pose, geometry.pose((0.0, 0.0, 0.5), (0.0, 0.0, np.pi / 2)), atol=1e-12)
    assert load_rig_config(write(tmp_path, GOOD + "object:\n  model: box\n")).model == "box"


@pytest.mark.parametrize(
    ("section", "message"),
    [
        ("object:\n  init_pose: [0, 0, 0.6]\n", r"object\.init_pose: .*shape 7"),
        ("object:\n  init_pose: [0, 0, 0.6, 0, 0, 1, 1]\n", r"object\.init_pose: .*unit quaternion"),
        ("object:\n  desired_pose: [0, 0, -0.6, 0, 0, 0, 1]\n", r"object\.desired_pose: .*in front of the camera"),
        ("object:\n  model: 3\n", r"object\.model"),
        ("object:\n  pose: [0, 0, 0.6, 0, 0, 0, 1]\n", r"object: unknown key\(s\) \['pose'\]"),
    ],
)
def test_bad_object_section_is_named(tmp_path, section, message):
    with pytest.raises(RigConfigError, match=message):
        load_rig_config(write(tmp_path, GOOD + section))


def test_the_example_rig_config_loads():
    from pathlib import Path

    rig = load_rig_config(Path(__file__).resolve().parents[1] / "examples" / "rig.yaml")
    assert (rig.camera.width, rig.camera.height) == (1280, 720) and rig.workspace is not None
    assert rig.model == "box" and rig.init_pose is not None and rig.desired_pose is None
