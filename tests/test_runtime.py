"""The run layer and the base it stands on: one camera-file format (and the OpenCV and ROS dialects it
reads), input resolution, the watchdog record, and the import boundaries a hardware rig relies on."""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest

import evservo
from evservo import cli
from evservo.camera_file import CameraFileError, camera_to_mapping, load_camera_file
from evservo.runtime.inputs import parse_object_pose, resolve_camera
from evservo.runtime.watchdog import spells_from_flags

DIST = (-0.2819, 0.031, 0.0012, -0.0007, 0.004)


def _same(cam, width, height, fx, fy, cx, cy, dist):
    assert (cam.width, cam.height) == (width, height)
    np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], [fx, fy, cx, cy])
    np.testing.assert_allclose(cam.dist, dist)


def test_native_file_round_trips(tmp_path):
    import yaml

    cam = evservo.Camera(1280, 720, 1163.59, 1173.48, 658.823, 339.619, DIST)
    p = tmp_path / "cam.yaml"
    p.write_text(yaml.safe_dump(camera_to_mapping(cam)))
    _same(load_camera_file(p), 1280, 720, 1163.59, 1173.48, 658.823, 339.619, DIST)
    j = tmp_path / "cam.json"
    j.write_text('{"width": 640, "height": 480, "K": [[500, 0, 320], [0, 510, 240], [0, 0, 1]]}')
    _same(load_camera_file(j), 640, 480, 500, 510, 320, 240, (0, 0, 0, 0, 0))


def test_reads_what_opencv_filestorage_writes(tmp_path):
    """The external oracle: cv2.FileStorage writes the calibration the way OpenCV's tools do."""
    K = np.array([[812.5, 0.0, 401.2], [0.0, 815.25, 299.8], [0.0, 0.0, 1.0]])
    p = tmp_path / "opencv.yaml"
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 800)
    fs.write("image_height", 600)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", np.array(DIST).reshape(1, 5))
    fs.write("avg_reprojection_error", 0.21)
    fs.release()
    text = p.read_text()
    assert text.startswith("%YAML") and "!!opencv-matrix" in text
    _same(load_camera_file(p), 800, 600, 812.5, 815.25, 401.2, 299.8, DIST)
    # OpenCV 4 and older files start with the non-standard "%YAML:1.0" directive.
    old = tmp_path / "opencv4.yml"
    old.write_text("%YAML:1.0\n---\n" + text.split("---\n", 1)[1])
    _same(load_camera_file(old), 800, 600, 812.5, 815.25, 401.2, 299.8, DIST)


def test_reads_ros_camera_info_yaml(tmp_path):
    p = tmp_path / "camera_info.yaml"
    p.write_text(
        "image_width: 1280\nimage_height: 720\ncamera_name: evk4\n"
        "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [1163.59, 0, 658.823, 0, 1173.48, 339.619, 0, 0, 1]\n"
        "distortion_model: plumb_bob\n"
        "distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [-0.2819, 0.031, 0.0012, -0.0007, 0.004]\n"
        "rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
        "projection_matrix:\n  rows: 3\n  cols: 4\n"
        "  data: [1163.59, 0, 658.823, 0, 0, 1173.48, 339.619, 0, 0, 0, 1, 0]\n"
    )
    _same(load_camera_file(p), 1280, 720, 1163.59, 1173.48, 658.823, 339.619, DIST)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("width: -640\nheight: 480\nfx: 1\nfy: 1\ncx: 0\ncy: 0\n", r"width: must be a whole number of pixels"),
        ("width: 640\nheight: 480\nfx: 1\nfy: 1\ncx: 0\ncy: 0\nk1: 0.1\n", r"unknown key\(s\) \['k1'\]"),
        ("width: 640\nheight: 480\nfx: 1\nfy: 1\ncx: 0\n", r"cy: missing"),
        ("width: 640\nheight: 480\nfx: 1\nfy: 1\ncx: 0\ncy: 0\ndistortion: [1, 2, 3]\n", r"needs 4 or 5"),
        ("width: 640\nheight: 480\nK: [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]\n", r"no skew"),
        ("image_width: 640\nimage_height: 480\ncamera_matrix: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
         "distortion_model: equidistant\n", r"equidistant.*not supported"),
        ("- just\n- a list\n", r"must be a mapping"),
        ("width: [\n", r"cannot parse"),
    ],
)  # fmt: skip
def test_bad_camera_files_say_where(tmp_path, text, message):
    p = tmp_path / "cam.yaml"
    p.write_text(text)
    with pytest.raises(CameraFileError, match=message) as err:
        load_camera_file(p)
    assert str(p) in str(err.value)


def test_camera_file_that_is_a_directory_or_missing(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such camera file"):
        load_camera_file(tmp_path / "missing.yaml")
    with pytest.raises(CameraFileError, match="not a regular file"):
        load_camera_file(tmp_path)


def test_resolve_camera_falls_back_to_the_imx636_once_and_says_so():
    notes: list[str] = []
    cam = resolve_camera("rec.raw", (1280, 720), None, None, "give --camera FILE", notes)
    assert (cam.fx, cam.width) == (evservo.Camera.imx636().fx, 1280)
    assert len(notes) == 1 and "IMX636" in notes[0]
    with pytest.raises(ValueError, match="640x480 and describes no camera: give --camera FILE"):
        resolve_camera("rec.raw", (640, 480), None, None, "give --camera FILE")
    given = evservo.Camera(640, 480, 500, 500, 320, 240, (0, 0, 0, 0, 0))
    with pytest.raises(ValueError, match=r"camera is 640x480 but rec\.raw is 1280x720"):
        resolve_camera("rec.raw", (1280, 720), given, None, "")


def test_object_pose_must_be_in_front_of_the_camera():
    T = parse_object_pose("0.1,0,0.6,0,0,0,1")
    np.testing.assert_allclose(T[:3, 3], [0.1, 0, 0.6])
    with pytest.raises(ValueError, match="--desired-pose: the object must be in front"):
        parse_object_pose("0,0,-0.6,0,0,0,1", "--desired-pose")
    with pytest.raises(ValueError, match="7 finite numbers"):
        parse_object_pose("0,0,nan,0,0,0,1")


def test_watchdog_spells_from_a_per_cycle_record():
    t = np.arange(10) * 0.01
    braking = np.array([0, 0, 1, 1, 1, 0, 0, 1, 1, 1], bool)
    est_t = np.array([0, 0.01, 0.01, 0.01, 0.01, 0.05, 0.06, 0.06, 0.06, 0.06])
    v = np.ones((10, 6))
    v[4] = 0
    spells = spells_from_flags(t, braking, est_t, v)
    assert [(s.start_s, s.last_pose_s, s.zero_s, s.end_s) for s in spells] == [
        (0.02, 0.01, 0.04, 0.05),
        (0.07, 0.06, None, None),
    ]


def test_sim_only_options_are_refused_with_robot(tmp_path, capsys):
    code = cli.main(["servo", "--robot", "sim", "--camera", str(tmp_path / "x.raw"), "--speed", "0.3"])
    assert code == 2
    assert "--speed only applies with --sim" in capsys.readouterr().err
    code = cli.main(["servo", "--robot", "sim", "--camera", "x.raw", "--object", "box", "--events", "render"])
    assert code == 2
    assert "--object, --events only apply with --sim" in capsys.readouterr().err


def test_a_hardware_rig_loads_no_simulator():
    """The real loop, the robots and the controller import no MuJoCo, no QP solver and no sim module."""
    code = (
        "import sys, evservo.realloop, evservo.robots, evservo.control, evservo.runtime.track\n"
        "from evservo.robots import UrArm, FrankaArm, KinematicArm, load_rig_config\n"
        "bad = [m for m in ('mujoco', 'qpsolvers', 'daqp', 'evservo.sim.scene', 'evservo.sim.episode',"
        " 'evservo.robots.ik', 'evservo.robots.sim_arm') if m in sys.modules]\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_the_command_line_starts_without_the_mesh_library_or_the_simulator():
    """``evservo --help`` and argument errors need no trimesh (about 2 s to import), no MuJoCo and no
    simulated scene: the parser takes the episode's options from :mod:`evservo.sim.episode_config`."""
    code = (
        "import sys, evservo, evservo.cli\nevservo.cli.build_parser()\n"
        "heavy = ('trimesh', 'mujoco', 'evservo.sim.episode', 'evservo.sim.scene')\n"
        "print(','.join(m for m in heavy if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
