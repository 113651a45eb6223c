"""ROS 2 nodes over loopback (after ``make ros``): ``evservo ros play`` publishes a simulated
recording as EventPacket (evt3) in one process, ``evservo ros track`` tracks it in another with the
intrinsics from a CameraInfo this test publishes; the poses it publishes on PoseStamped and /tf equal
those ``evservo track`` writes for the same recording. Each run uses its own random ROS_DOMAIN_ID,
restricted to this machine. Skipped, with the reason, where ROS 2 support is not installed."""

import json
import os
import random
import subprocess
import sys
import time

import numpy as np
import pytest

from evservo.cli import main
from evservo.sim.record import load_recording


def _need_ros() -> None:
    pytest.importorskip("rclpy", reason="ROS 2 support not installed (make ros)")
    pytest.importorskip("event_camera_msgs.msg", reason="event_camera_msgs not generated (make ros)")
    pytest.importorskip("tf2_msgs.msg", reason="tf2_msgs not generated (make ros)")


@pytest.fixture(scope="module")
def small_rec(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec") / "small.h5"
    assert main(["sim", "record", "--duration", "0.2", "--scale", "0.25", "--quiet", "--out", str(out)]) == 0
    return out


def _pose_text(T: np.ndarray) -> str:
    from scipy.spatial.transform import Rotation

    return ",".join(repr(float(v)) for v in [*T[:3, 3], *Rotation.from_matrix(T[:3, :3]).as_quat()])


def test_play_and_track_nodes_match_the_offline_tracker(small_rec, tmp_path, monkeypatch):
    _need_ros()
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import CameraInfo
    from std_msgs.msg import String
    from tf2_msgs.msg import TFMessage

    from evservo.ros.nodes import _qos

    rec = load_recording(small_rec)
    init = _pose_text(rec.gt_T[0])
    assert main(["track", str(small_rec), "--init-pose", init, "--quiet", "--out", str(tmp_path / "offline")]) == 0
    offline = np.genfromtxt(tmp_path / "offline" / "poses.csv", delimiter=",", names=True)

    # Its own domain, this machine only, over UDP (no shared-memory segments left behind by a killed node).
    ros_env = dict(ROS_DOMAIN_ID=str(random.randint(1, 100)), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
                   FASTDDS_BUILTIN_TRANSPORTS="UDPv4")  # fmt: skip
    for k, v in ros_env.items():
        monkeypatch.setenv(k, v)
    env = dict(os.environ)
    rclpy.init()
    node = rclpy.create_node("evservo_test")
    poses, tfs, status = [], [], []
    node.create_subscription(PoseStamped, "/evservo/pose", poses.append, _qos())
    node.create_subscription(TFMessage, "/tf", tfs.append, _qos())
    node.create_subscription(String, "/evservo/status", lambda m: status.append(json.loads(m.data)), _qos())
    info_pub = node.create_publisher(CameraInfo, "/event_camera/camera_info", 10)
    cam = rec.camera
    info = CameraInfo(width=cam.width, height=cam.height, distortion_model="plumb_bob")
    info.k = [cam.fx, 0.0, cam.cx, 0.0, cam.fy, cam.cy, 0.0, 0.0, 1.0]
    info.d = [float(v) for v in cam.dist]
    cli = [sys.executable, "-m", "evservo.cli", "ros"]
    track = subprocess.Popen([*cli, "track", "--model", rec.object, "--init-pose", init, "--idle-exit", "2"],
                             env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    play = subprocess.Popen([*cli, "play", str(small_rec), "--wait", "60"], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while track.poll() is None and time.monotonic() < deadline:
            info_pub.publish(info)
            rclpy.spin_once(node, timeout_sec=0.05)
        end = time.monotonic() + 3
        while time.monotonic() < end and len(poses) < len(offline):
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        for p in (track, play):
            if p.poll() is None:
                p.kill()
        node.destroy_node()
        rclpy.shutdown()
    out_t, err_t = track.communicate()
    _, err_p = play.communicate()
    assert play.returncode == 0, f"play: {err_p}\ntrack: {err_t}"
    assert track.returncode == 0, err_t
    assert f"{len(offline)} poses" in out_t
    assert len(poses) == len(tfs) == len(status) == len(offline)
    xyz = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in poses])
    np.testing.assert_allclose(xyz[:, 0], offline["x_m"], atol=1e-6)  # poses.csv keeps 6 decimals
    np.testing.assert_allclose(xyz[:, 1], offline["y_m"], atol=1e-6)
    np.testing.assert_allclose(xyz[:, 2], offline["z_m"], atol=1e-6)
    tf_xyz = np.array([[t.transforms[0].transform.translation.x, t.transforms[0].transform.translation.z] for t in tfs])
    np.testing.assert_array_equal(tf_xyz, xyz[:, [0, 2]])
    assert {(t.transforms[0].header.frame_id, t.transforms[0].child_frame_id) for t in tfs} == {("camera", "object")}
    assert [s["t_us"] for s in status] == offline["t_us"].astype(int).tolist()
    assert [s["lost"] for s in status] == offline["lost"].astype(bool).tolist()


def test_ros_commands_without_ros_say_how_to_install(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "rclpy", None)
    assert main(["ros", "play", "x.raw"]) == 2
    assert "make ros" in capsys.readouterr().err
