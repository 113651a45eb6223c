"""ROS 2 nodes over loopback (after ``make ros``), every node a process of its own.

* ``ros play`` publishes a simulated recording as EventPacket (evt3), ``ros track`` tracks it with the
  intrinsics from a CameraInfo the peer (tests/ros_peer.py) publishes; the poses it publishes on
  PoseStamped and /tf equal those ``evservo track`` writes for the same recording (and, with rerun
  installed, its ``--viewer-save`` recording holds one frame per 33 ms of sensor time).
* ``ros servo`` servos on the played recording and publishes TwistStamped to a fake arm controller
  (the peer): one twist per control cycle at the control rate, each as the loop's log says it sent
  it; when the recording ends the watchdog brakes and stops the arm, and Ctrl-C stops it: in both
  the last twist is zero and the node exits with its code.

The test process never loads rclpy. Each test runs in its own random ROS_DOMAIN_ID restricted to
this machine, every process has a hard timeout and is killed (its whole process group) however the
test ends. Skipped, with the reason, where ROS 2 support is not installed (``make ros``; CI installs
it: ``make test ROS=1``).
"""

import contextlib
import importlib.util
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from evservo import geometry
from evservo.cli import main
from evservo.sim.record import load_recording

#: Beyond the per-process timeouts below: no ROS test outlives this (s), whatever it waits on.
pytestmark = pytest.mark.timeout(300)

PEER = Path(__file__).with_name("ros_peer.py")
#: Longest any ROS process of these tests may live (s).
PROCESS_TIMEOUT_S = 120


def _need_ros() -> None:
    missing = [m for m in ("rclpy", "event_camera_msgs", "tf2_msgs") if importlib.util.find_spec(m) is None]
    if missing:
        failed = Path(sys.prefix) / ".ros-failed"
        why = f": `make ros` failed: {failed.read_text().strip()}" if failed.is_file() else " (make ros)"
        pytest.skip(f"ROS 2 support not installed, {', '.join(missing)} missing{why}")


@pytest.fixture
def ros_env(tmp_path):
    """The environment of the test's ROS processes: its own domain, this machine only, over UDP (no
    shared-memory segments left behind by a killed node), logs in the test's directory. Fast DDS
    takes domains 0-232 (its ports)."""
    return dict(
        os.environ, ROS_DOMAIN_ID=str(random.randint(1, 232)), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
        FASTDDS_BUILTIN_TRANSPORTS="UDPv4", ROS_LOG_DIR=str(tmp_path / "roslog"), PYTHONUNBUFFERED="1",
    )  # fmt: skip


@pytest.fixture
def ns():
    """A topic namespace of the test's own: other ROS tests on this machine (other checkouts) that
    drew the same domain still cannot cross-talk, except on /tf."""
    return f"/t{random.getrandbits(48):012x}"


class _Procs:
    """Processes started in their own process groups, their output in files (a pipe nobody reads
    could block them), killed with their children on exit.

    The tests start one ROS process only once the one before has its node: with Fast DDS over UDP
    alone, two participants created at the same instant on one host were seen (4 of 6 runs) to leave
    one of them deaf to a third participant started before both, for good. Even one after another, a
    new participant stays cut off from the ones before it in about 1 % of starts (4 of 326 runs of
    the play/track exchange on one machine; in one, the peer started first and a participant created
    after the cut-off one both missed it, while one started after it found it; in another, the peer
    saw the node's name but none of their topics matched). So each node a test starts must show up
    in the peer started before it, their shared topics matched (``start_seen``), else it is started
    again, once: that is the middleware's discovery, not the node's behaviour under test."""

    def __init__(self, env: dict, logs: Path) -> None:
        self.env, self.logs, self.procs = env, logs, []
        logs.mkdir(exist_ok=True)

    def start(self, *args: str) -> subprocess.Popen:
        k = len(self.procs)
        with open(self.logs / f"{k}.out", "w") as out, open(self.logs / f"{k}.err", "w") as err:
            p = subprocess.Popen([sys.executable, *args], env=self.env, stdout=out, stderr=err, text=True,
                                 start_new_session=True)  # fmt: skip
        p.k = k
        self.procs.append(p)
        return p

    def evservo(self, *args: str) -> subprocess.Popen:
        return self.start("-m", "evservo.cli", *args)

    def start_seen(self, witness: subprocess.Popen, sign: str, *args: str, timeout_s: float = 15) -> subprocess.Popen:
        """``evservo ARGS``, once the already running ``witness`` (a tests/ros_peer.py) prints ``sign``
        (``sees NODE``, or ``matched``: its topics matched the new node's) within ``timeout_s``, or
        once the process ended (a player can be done before the peer's graph shows it); a start still
        running unnoticed is killed and made once more."""
        for attempt in range(2):
            p = self.evservo(*args)
            if self._printed(witness, sign, timeout_s, until_exit=p):
                return p
            self._kill(p)
            p.wait()
            print(f"no {sign!r} from the peer within {timeout_s} s of starting {args[:2]} (attempt {attempt + 1})")
        pytest.fail(f"the peer never printed {sign!r} for {' '.join(args)}\n{self.output(witness)}")

    def _printed(
        self, p: subprocess.Popen, text: str, timeout_s: float, until_exit: subprocess.Popen | None = None
    ) -> bool:
        """Whether ``p`` printed ``text`` within ``timeout_s`` (or ``until_exit`` ended first)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if text in "".join(self.output(p)) or (until_exit is not None and until_exit.poll() is not None):
                return True
            if p.poll() is not None:
                return False
            time.sleep(0.02)
        return False

    def output(self, p: subprocess.Popen) -> tuple[str, str]:
        return (self.logs / f"{p.k}.out").read_text(), (self.logs / f"{p.k}.err").read_text()

    def wait(self, p: subprocess.Popen, timeout_s: float = PROCESS_TIMEOUT_S) -> tuple[str, str]:
        """Its output once it exited; killed (and the test failed) if it is not done in ``timeout_s``."""
        try:
            p.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self._kill(p)
            p.wait()
            out, err = self.output(p)
            pytest.fail(f"{' '.join(p.args)} did not end within {timeout_s} s\n{out}\n{err}")
        return self.output(p)

    def wait_line(self, p: subprocess.Popen, text: str, timeout_s: float = 60) -> None:
        """Wait until ``p`` printed (to stdout or stderr) a line containing ``text`` (fails after
        ``timeout_s``)."""
        if not self._printed(p, text, timeout_s):
            out, err = self.output(p)
            pytest.fail(f"no {text!r} from {' '.join(p.args)} within {timeout_s} s:\n{out}\n{err}")

    def _kill(self, p: subprocess.Popen) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(p.pid, signal.SIGKILL)

    def __enter__(self) -> "_Procs":
        return self

    def __exit__(self, *exc: object) -> None:
        for p in self.procs:
            if p.poll() is None:
                self._kill(p)
            p.wait()


def _record(tmp_path_factory, seconds: float) -> Path:
    out = tmp_path_factory.mktemp("rec") / "small.h5"
    assert main(["sim", "record", "--duration", str(seconds), "--scale", "0.25", "--quiet", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def small_rec(tmp_path_factory):
    return _record(tmp_path_factory, 0.2)


@pytest.fixture(scope="module")
def servo_rec(tmp_path_factory):
    """Long enough to settle and servo for 0.4 s (box, translating)."""
    return _record(tmp_path_factory, 0.6)


def _pose_text(T: np.ndarray) -> str:
    from scipy.spatial.transform import Rotation

    return ",".join(repr(float(v)) for v in [*T[:3, 3], *Rotation.from_matrix(T[:3, :3]).as_quat()])


def _with_gap(path: Path, out: Path, gap_us: tuple[int, int]) -> Path:
    """A copy of the recording ``path`` with every event of ``gap_us`` cut (ground truth kept)."""
    import shutil

    import h5py

    shutil.copy(path, out)
    with h5py.File(out, "r+") as f:
        g = f["events"]
        keep = (g["t"][:] < gap_us[0]) | (g["t"][:] >= gap_us[1])
        for name in ("x", "y", "p", "t"):
            kept = g[name][:][keep]
            g[name].resize((len(kept),))
            g[name][:] = kept
    return out


@pytest.mark.parametrize("gap", [False, True], ids=["whole", "gap"])
def test_play_and_track_nodes_match_the_offline_tracker(small_rec, tmp_path, ros_env, ns, gap):
    """``gap``: the events of 80–160 ms cut; the node, like ``evservo track``, advances the tracker's
    stream time over the empty slices, so both flag ``lost`` 20 ms into the gap, update for update."""
    _need_ros()
    rec = load_recording(small_rec)
    if gap:
        small_rec = _with_gap(small_rec, tmp_path / "gap.h5", (80_000, 160_000))
    init = _pose_text(rec.gt_T[0])
    assert main(["track", str(small_rec), "--init-pose", init, "--quiet", "--out", str(tmp_path / "offline")]) == 0
    offline = np.genfromtxt(tmp_path / "offline" / "poses.csv", delimiter=",", names=True)
    if gap:
        t, lost = offline["t_us"], offline["lost"].astype(bool)
        assert 80_000 < t[lost & (t >= 80_000)][0] <= 130_000 and lost[(t >= 130_000) & (t <= 160_000)].all()

    cam = rec.camera
    got = tmp_path / "peer.json"
    intrinsics = [str(v) for v in (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, *cam.dist)]
    with _Procs(ros_env, tmp_path / "logs") as procs:
        peer = procs.start(str(PEER), str(got), "track", *intrinsics, "--idle-exit", "4", "--ns", ns)
        procs.wait_line(peer, "ready")
        # With rerun installed, the node's viewer records too (one frame per 33 ms of sensor time).
        rrd = tmp_path / "track.rrd" if importlib.util.find_spec("rerun") else None
        viewer = ["--viewer-save", str(rrd)] if rrd else []
        topics = ["--events-topic", f"{ns}/events", "--camera-info-topic", f"{ns}/camera_info",
                  "--pose-topic", f"{ns}/pose", "--status-topic", f"{ns}/status"]  # fmt: skip
        # One participant after another, each seen by the peer (see _Procs).
        track = procs.start_seen(peer, "matched", "ros", "track", "--model", rec.object, "--init-pose", init,
                                 "--idle-exit", "2", *topics, *viewer)  # fmt: skip
        procs.wait_line(track, "listening on")
        play = procs.start_seen(peer, "sees evservo_play", "ros", "play", str(small_rec), "--topic", f"{ns}/events",
                                "--wait", "60")  # fmt: skip
        _, err_p = procs.wait(play)
        out_t, err_t = procs.wait(track)
        procs.wait(peer)
    assert play.returncode == 0, f"play: {err_p}\ntrack: {err_t}"
    assert track.returncode == 0, err_t
    assert peer.returncode == 0
    assert f"{len(offline)} poses" in out_t
    seen = json.loads(got.read_text())
    poses, tfs, status = seen["poses"], seen["tfs"], seen["status"]
    assert len(poses) == len(tfs) == len(status) == len(offline)
    xyz = np.array(poses)
    np.testing.assert_allclose(xyz[:, 0], offline["x_m"], atol=1e-6)  # poses.csv keeps 6 decimals
    np.testing.assert_allclose(xyz[:, 1], offline["y_m"], atol=1e-6)
    np.testing.assert_allclose(xyz[:, 2], offline["z_m"], atol=1e-6)
    np.testing.assert_array_equal(np.array([t[2] for t in tfs]), xyz)
    assert {(t[0], t[1]) for t in tfs} == {("camera", "object")}
    assert [s["t_us"] for s in status] == offline["t_us"].astype(int).tolist()
    assert [s["lost"] for s in status] == offline["lost"].astype(bool).tolist()
    np.testing.assert_allclose([s["confidence"] for s in status], offline["confidence"], atol=1e-6)
    if rrd is not None:
        from test_viewer import _rows_per_entity, _rrd_print

        frames = len(np.unique(offline["t_us"].astype(np.int64) // 33_333))
        rows = _rows_per_entity(_rrd_print(rrd, "-v"))
        for entity in ("/camera/events", "/camera/sstar", "/field/distance", "/world/object", "/tracking/lost"):
            assert rows.get(entity) == frames, (entity, rows)


def test_track_node_without_intrinsics_waits_for_them_and_ends_with_a_clear_error(small_rec, tmp_path, ros_env, ns):
    """Packets but no CameraInfo (and no --camera): the node says what it waits for, does not take
    the idle exit while the packets wait, and a Ctrl-C ends it with an error naming the topic (it
    used to wait forever for the intrinsics after the idle exit)."""
    _need_ros()
    rec = load_recording(small_rec)
    topics = ["--events-topic", f"{ns}/events", "--camera-info-topic", f"{ns}/camera_info",
              "--pose-topic", f"{ns}/pose", "--status-topic", f"{ns}/status"]  # fmt: skip
    with _Procs(ros_env, tmp_path / "logs") as procs:
        # A witness only (it publishes no CameraInfo): it sees each node come up (see _Procs).
        peer = procs.start(str(PEER), str(tmp_path / "peer.json"), "twist", f"{ns}/unused")
        procs.wait_line(peer, "ready")
        track = procs.start_seen(peer, "sees evservo_track", "ros", "track", "--model", rec.object, "--init-pose",
                                 _pose_text(rec.gt_T[0]), "--idle-exit", "0.5", *topics)  # fmt: skip
        procs.wait_line(track, "listening on")
        play = procs.start_seen(peer, "sees evservo_play", "ros", "play", str(small_rec), "--topic", f"{ns}/events",
                                "--wait", "60")  # fmt: skip
        procs.wait(play)
        procs.wait_line(track, "wait for a sensor_msgs/CameraInfo")
        time.sleep(1.0)  # twice the idle exit: the node must still be waiting
        assert track.poll() is None, procs.output(track)
        track.send_signal(signal.SIGINT)
        out, err = procs.wait(track, timeout_s=30)
    assert play.returncode == 0
    assert track.returncode == 2, out + err
    assert f"no sensor_msgs/CameraInfo on {ns}/camera_info" in err and "Traceback" not in err, err


def _rig(tmp_path: Path, camera) -> Path:
    """A rig whose intrinsics are the recording's, the camera on the flange, generous limits."""
    path = tmp_path / "rig.yaml"
    path.write_text(
        "hand_eye: {translation: [0.0, 0.0, 0.1], quaternion: [0.0, 0.0, 0.0, 1.0]}\n"
        f"camera: {{width: {camera.width}, height: {camera.height}, fx: {camera.fx}, fy: {camera.fy}, "
        f"cx: {camera.cx}, cy: {camera.cy}, distortion: {list(camera.dist)}}}\n"
        "limits: {max_lin_vel: 1.0, max_ang_vel: 2.0, max_lin_acc: 10.0, max_ang_acc: 20.0}\n"
    )
    return path


def _servo(
    procs: _Procs, ns: str, rec_path: Path, tmp_path: Path, *extra: str, peer_args: tuple[str, ...] = ()
) -> tuple[subprocess.Popen, subprocess.Popen]:
    """Start the fake arm, then ``ros servo`` at 100 Hz, then ``ros play``; returns (servo, peer).

    The fake arm does not carry the recording's camera: the loop dead-reckons the camera from its own
    twists, so the object's world pose moves by the camera's made-up motion, and across a loaded
    machine's gaps between poses (up to the 0.5 s watchdog) the jump gate's prediction of it is
    meaningless. The gate is opened (1 m, and 4 rad: any turn) so that these runs end by the watchdog
    the tests are about.
    """
    rec = load_recording(rec_path)
    peer = procs.start(str(PEER), str(tmp_path / "twists.json"), "twist", f"{ns}/twist", "--idle-exit", "3",
                       *peer_args)  # fmt: skip
    procs.wait_line(peer, "ready")
    servo = procs.start_seen(
        peer, "matched", "ros", "servo", "--config", str(_rig(tmp_path, rec.camera)), "--model", rec.object,
        "--init-pose", _pose_text(rec.gt_T[0]), "--twist-topic", f"{ns}/twist", "--ee-frame", "flange",
        "--events-topic", f"{ns}/events",
        "--rate", "100", "--settle", "0.1", "--start-timeout", "60", "--stale-after", "0.5", "--max-jump", "1",
        "--max-jump-rad", "4",
        "--out", str(tmp_path / "out"), *extra,
    )  # fmt: skip
    procs.wait_line(servo, "for the first events")  # subscribed and matched the arm: the player waits for it
    procs.start_seen(peer, "sees evservo_play", "ros", "play", str(rec_path), "--topic", f"{ns}/events", "--wait", "60")
    return servo, peer


def _twists(tmp_path: Path) -> tuple[np.ndarray, np.ndarray, set[str]]:
    rows = json.loads((tmp_path / "twists.json").read_text())["twists"]
    return np.array([r[1] for r in rows]), np.array([r[3] for r in rows]), {r[2] for r in rows}


def _log(tmp_path: Path) -> np.ndarray:
    return np.genfromtxt(tmp_path / "out" / "log.csv", delimiter=",", names=True, dtype=None, encoding=None)


def _cycle_twists(twists: np.ndarray, log: np.ndarray) -> np.ndarray:
    """Indices of the twists the loop's cycles sent (the rows of log.csv, in order, matched by the
    norms of their linear and angular parts, which the end-effector axes keep). Every other twist
    must be a stop (zero): the gate's own watchdog halts the arm when two cycles are more than its
    0.05 s apart, as happens on a loaded machine."""
    v, w = np.linalg.norm(twists[:, :3], axis=1), np.rad2deg(np.linalg.norm(twists[:, 3:], axis=1))
    idx = []
    for i in range(len(twists)):
        k = len(idx)
        # log.csv keeps 6 significant digits.
        if (
            k < len(log)
            and np.isclose(v[i], log["v_sent_mps"][k], rtol=1e-5, atol=1e-9)
            and np.isclose(w[i], log["w_sent_dps"][k], rtol=1e-5, atol=1e-9)
        ):
            idx.append(i)
        else:
            assert not np.any(twists[i]), f"twist {i} is neither cycle {k}'s (as logged) nor a stop: {twists[i]}"
    assert len(idx) == len(log), f"only {len(idx)} of the {len(log)} cycles' twists were published"
    return np.array(idx)


def test_servo_node_publishes_a_twist_per_cycle_and_a_zero_twist_when_the_events_stop(servo_rec, tmp_path, ros_env, ns):
    _need_ros()
    with _Procs(ros_env, tmp_path / "logs") as procs:
        servo, peer = _servo(procs, ns, servo_rec, tmp_path, "--duration", "5")
        out, err = procs.wait(servo)
        procs.wait(peer)
    # The recording ends long before the 5 s: no fresh pose for 0.5 s (a loaded machine delays poses by
    # up to 0.1 s), the watchdog brakes and stops the arm.
    assert servo.returncode == 1, out + err
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["ended"].startswith("watchdog: no fresh pose"), summary["ended"]
    stamps, twists, frames = _twists(tmp_path)
    assert frames == {"flange"}
    gate = summary["gate"]
    # Every twist the gate let through and every stop reached the arm, in order: one per cycle, then the
    # loop's stop (counted in the summary) and the stop of closing the arm (after it), zeros last.
    assert gate["commands"] == summary["control_cycles"]
    assert len(twists) == gate["commands"] + gate["halts"] + 1
    assert gate["commands"] >= 10  # servoed for a while before the recording ran out (0.4 s at most)
    n = summary["control_cycles"]
    log = _log(tmp_path)
    assert len(log) == n  # logged every cycle at 100 Hz
    cyc = _cycle_twists(twists, log)  # each cycle's twist is the one the loop logged as sent, in order
    assert not np.any(twists[cyc[-1] + 1 :])  # the stops
    assert not np.any(twists[-1])
    assert np.any(twists[cyc])  # the arm did move
    # At the control rate: the loop ran on a 10 ms grid (cycles it could not make in time on this loaded
    # machine are counted as missed, never made up), and each twist went out in its cycle.
    assert (n + summary["missed_cycles"]) / log["t_s"][-1] == pytest.approx(100, rel=0.1)
    assert np.median(np.abs(np.diff(stamps[cyc]) - np.diff(log["t_s"]))) < 0.001


def test_servo_node_without_a_twist_subscriber_says_so_and_sends_nothing(servo_rec, tmp_path, ros_env, ns):
    """Nobody subscribes to the twist topic (no controller running): the node does not start the loop
    (twists before discovery would be lost), exits 2 naming the topic, and writes no run."""
    _need_ros()
    rec = load_recording(servo_rec)
    with _Procs(ros_env, tmp_path / "logs") as procs:
        servo = procs.evservo(
            "ros", "servo", "--config", str(_rig(tmp_path, rec.camera)), "--model", rec.object,
            "--init-pose", _pose_text(rec.gt_T[0]), "--twist-topic", f"{ns}/twist", "--events-topic", f"{ns}/events",
            "--start-timeout", "1", "--out", str(tmp_path / "out"),
        )  # fmt: skip
        out, err = procs.wait(servo, timeout_s=60)
    assert servo.returncode == 2, out + err
    assert f"no subscriber on {ns}/twist within 1 s" in err and "Traceback" not in err, err
    assert not (tmp_path / "out" / "summary.json").exists()


def test_servo_node_stops_the_arm_on_ctrl_c(servo_rec, tmp_path, ros_env, ns):
    _need_ros()
    with _Procs(ros_env, tmp_path / "logs") as procs:
        # Long enough that the Ctrl-C lands while servoing however late a loaded machine reads the line.
        servo, peer = _servo(procs, ns, servo_rec, tmp_path, "--duration", "60")
        procs.wait_line(servo, "servoing for")
        time.sleep(0.2)
        servo.send_signal(signal.SIGINT)
        out, err = procs.wait(servo, timeout_s=30)
        procs.wait(peer)
    assert servo.returncode == 130, out + err
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["interrupted"] and summary["ended"] == "interrupted (Ctrl-C)"
    _, twists, _ = _twists(tmp_path)
    # Every twist is a logged cycle or a stop (a Ctrl-C waits for the cycle's log row).
    assert len(twists) == summary["control_cycles"] + summary["gate"]["halts"] + 1
    assert np.any(twists[:-1]) and not np.any(twists[-1])


def test_servo_node_twists_are_in_the_arm_pose_axes_and_a_lost_pose_topic_stops_it(servo_rec, tmp_path, ros_env, ns):
    """With ``--ee-pose-topic`` the twists are the gated base-frame twists in the published pose's
    axes; when the pose stops coming (0.2 s after the first twist; a pose 0.4 s old is lost, which
    a loaded machine's delays never reach) the link counts as lost: the run stops with an error and
    a zero twist."""
    _need_ros()
    T_w_e = geometry.pose((0.4, 0.1, 0.5), (2.9, 0.3, -0.4))
    pose = _pose_text(T_w_e)
    peer_args = ("--ee-pose-topic", f"{ns}/ee_pose", "--ee-pose", pose, "--pose-after-twist", "0.2")
    with _Procs(ros_env, tmp_path / "logs") as procs:
        servo, peer = _servo(
            procs, ns, servo_rec, tmp_path, "--duration", "5", "--ee-pose-topic", f"{ns}/ee_pose", "--ee-pose-timeout",
            "0.4", peer_args=peer_args,
        )  # fmt: skip
        out, err = procs.wait(servo)
        procs.wait(peer)
    assert servo.returncode == 1, out + err
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert f"end-effector pose on {ns}/ee_pose is" in (summary["error"] or ""), summary["ended"]
    _, twists, _ = _twists(tmp_path)
    log = _log(tmp_path)
    assert len(log) == summary["control_cycles"] >= 10, summary
    cyc = _cycle_twists(twists, log)
    assert np.any(twists[cyc]) and not np.any(twists[cyc[-1] + 1 :])
    for part, cols, unit in ((slice(0, 3), ("vx_mps", "vy_mps", "vz_mps"), 1.0),
                             (slice(3, 6), ("wx_dps", "wy_dps", "wz_dps"), np.pi / 180)):  # fmt: skip
        sent_w = np.column_stack([log[f"sent_{c}"] for c in cols]) * unit
        # R^T v row by row; log.csv keeps 6 significant digits (<= 5e-6 relative) of each base-frame
        # component, and a row of R^T sums to at most sqrt(3) in magnitude.
        tol = np.sqrt(3) * 5e-6 * np.abs(sent_w).max(axis=1, keepdims=True)
        assert np.all(np.abs(twists[cyc, part] - sent_w @ T_w_e[:3, :3]) <= tol)


def test_ros_commands_without_ros_say_how_to_install(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "rclpy", None)
    assert main(["ros", "play", "x.raw"]) == 2
    assert "make ros" in capsys.readouterr().err
    assert main(["ros", "servo", "--config", "rig.yaml"]) == 2
    assert "make ros" in capsys.readouterr().err
