"""The real loop (evservo.realloop, `evservo servo --robot …`): a simulated recording replayed at real time
through the threaded tracker and PBVS into a kinematic stand-in arm, the UR loopback RTDE peer and
franky-sim; watchdog stops, Ctrl-C, dry run, and bad command lines.

Replays run at half speed on a 320×180 recording so that a loaded two-core machine keeps up."""

from __future__ import annotations

import json
import math
import os
import signal
import sys
import threading
import time
import weakref
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evservo import io
from evservo.cameras import ReplaySource
from evservo.cli import main
from evservo.control.hold import COAST_S
from evservo.limits import CartesianLimits
from evservo.realloop import RealLoopConfig, run_real_loop, summarize, write_outputs
from evservo.robots.kinematic import KinematicArm
from evservo.sim.record import RecordConfig, load_recording, record
from evservo.tracking import Tracker

SPEED = 0.5  # replay speed: the 0.6 s recording plays in 1.2 s
SUMMARY_NUMBERS = ("servo_pos_rms_mm", "servo_rot_rms_deg", "tracker_rate_hz", "pose_age_mean_ms", "servo_s",
                   "camera_rot_mean_deg", "cycle_time_mean_ms", "wall_s")  # fmt: skip
GENTLE = CartesianLimits(max_lin_vel=0.05, max_ang_vel=0.2, max_lin_acc=0.5, max_ang_acc=1.0)


@pytest.fixture(scope="module")
def rec_path(tmp_path_factory):
    """0.6 s of the box translating at 0.2 m/s, 0.6 m away, on a 320×180 sensor (~0.5 M events)."""
    out = tmp_path_factory.mktemp("realloop") / "rec.h5"
    record(out, RecordConfig(trajectory="trans", speed_mps=0.2, duration_s=0.6, scale=0.25, seed=1), progress=False)
    return out


@pytest.fixture(scope="module")
def rec(rec_path):
    return load_recording(rec_path)


def rig_yaml(tmp_path, rec, extra: str = "") -> str:
    c = rec.camera
    p = tmp_path / "rig.yaml"
    p.write_text(
        f"hand_eye:\n  translation: [0.0, 0.0, 0.05]\n  quaternion: [0.0, 0.0, 0.0, 1.0]\n"
        f"camera:\n  width: {c.width}\n  height: {c.height}\n  fx: {c.fx}\n  fy: {c.fy}\n  cx: {c.cx}\n  cy: {c.cy}\n"
        f"  distortion: {list(c.dist)}\n"
        "limits:\n  max_lin_vel: 0.1\n  max_ang_vel: 0.3\n  max_lin_acc: 1.0\n  max_ang_acc: 2.0\n" + extra
    )
    return str(p)


def parts(rec_path, rec, **cfg):
    """A replay source, a tracker at the recording's start pose and a loop config. The stale limit is
    loose (1 s) so that a loaded machine starving the tracker thread does not end a test that is about
    something else; the watchdog tests set their own."""
    source = ReplaySource(rec_path, speed=SPEED)
    tracker = Tracker(rec.camera, rec.object, rec.gt_T[0])
    options = dict(settle_s=0.1, duration_s=5.0, speed=SPEED, stale_after_s=1.0, rate_hz=250.0)
    return source, tracker, RealLoopConfig(**{**options, **cfg})


class AfterServoStart:
    """A progress callback that runs ``action`` ``delay_s`` after servoing starts (on a timer thread);
    use as a context manager so that a timer still pending when the loop has ended is cancelled."""

    def __init__(self, delay_s: float, action) -> None:
        self.timer = threading.Timer(delay_s, action)

    def __call__(self, msg: str) -> None:
        if msg.startswith("servoing"):
            self.timer.start()

    def __enter__(self) -> AfterServoStart:
        return self

    def __exit__(self, *exc: object) -> None:
        self.timer.cancel()


def check_summary(s: dict) -> None:
    for key in (*SUMMARY_NUMBERS, "completed", "ended", "watchdog", "tracker_steps", "events", "missed_cycles",
                "control_cycles", "gate", "config"):  # fmt: skip
        assert key in s, key
    for key in SUMMARY_NUMBERS:
        assert isinstance(s[key], float) and math.isfinite(s[key]), (key, s[key])
    assert isinstance(s["missed_cycles"], int) and s["missed_cycles"] >= 0
    json.dumps(s)


# -- (a) a recording through the real loop into the kinematic arm ---------------------------------


def test_replay_through_the_kinematic_arm(rec_path, rec, tmp_path, capsys):
    out = tmp_path / "out"
    args = ["servo", "--robot", "sim", "--camera", str(rec_path), "--settle", "0.1", "--duration", "5",
            "--replay-speed", str(SPEED), "--stale-after", "1.0", "--rate", "250", "--out", str(out)]  # fmt: skip
    assert main(args) == 0, capsys.readouterr()
    s = json.loads((out / "summary.json").read_text())
    check_summary(s)
    assert s["completed"] and s["ended"] == "end of recording" and s["watchdog"] == []
    assert s["events"] == io.info(rec_path)["n_events"]
    # Tracking held against the recording's ground truth (synchronous tracking gets ~2 mm / 0.5°).
    assert s["gt_track_pos_rms_mm"] < 10.0 and s["gt_track_rot_rms_deg"] < 3.0, s
    # The object moved in the recording and the arm followed it (open loop: a recording cannot see the arm).
    assert s["camera_travel_max_m"] > 0.005 and s["gate"]["commands"] == s["control_cycles"] > 100
    assert s["servo_s"] > 0.8  # 1.2 s of replay, less the settle
    log = np.genfromtxt(out / "log.csv", delimiter=",", names=True, dtype=None, encoding=None)
    assert len(log) > 50 and np.all(np.diff(log["t_s"]) > 0)
    assert log["v_cmd_mps"][-1] == 0.0  # braked to rest at the end
    assert (out / "motion.png").stat().st_size > 10_000
    assert "ended normally" in capsys.readouterr().out


def test_rig_config_object_section_supplies_model_and_poses(rec_path, rec, tmp_path):
    T0 = rec.gt_T[0]
    q = Rotation.from_matrix(T0[:3, :3]).as_quat()
    pose = [float(v) for v in (*T0[:3, 3], *q)]
    cfg = rig_yaml(tmp_path, rec, f"object:\n  model: box\n  init_pose: {pose}\n  desired_pose: {pose}\n")
    out = tmp_path / "out"
    args = ["servo", "--robot", "sim", "--camera", str(rec_path), "--config", cfg, "--settle", "0.1",
            "--duration", "0.3", "--replay-speed", str(SPEED), "--stale-after", "1.0", "--out", str(out)]  # fmt: skip
    assert main(args) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["completed"] and s["ended"] == "duration" and s["model"] == "box"
    np.testing.assert_allclose(s["T_c_o_des"], T0, atol=1e-9)
    np.testing.assert_allclose(s["T_c_o_init"], T0, atol=1e-9)


def test_init_pose_search_starts_lost_even_with_ground_truth_and_holds_the_arm(rec_path, tmp_path, capsys):
    """``--init-pose search`` on a simulated recording (whose ground truth would otherwise give the
    start pose): the tracker starts lost and runs global searches, the arm is held still until it
    locks, and the summary does not report errors of the search's placeholder pose as servoing."""
    out = tmp_path / "out"
    args = ["servo", "--robot", "sim", "--camera", str(rec_path), "--init-pose", "search", "--settle", "0.1",
            "--duration", "0.3", "--replay-speed", str(SPEED), "--stale-after", "1.0", "--out", str(out)]  # fmt: skip
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "note: --init-pose search: the tracker searches" in printed
    s = json.loads((out / "summary.json").read_text())
    assert s["config"]["search"] and s["T_c_o_init"] is None
    assert s["tracker_steps"]["global"] >= 1, s["tracker_steps"]
    log = np.genfromtxt(out / "log.csv", delimiter=",", names=True, dtype=None, encoding=None)
    # It may have locked during the settle time already (the 0.1 s box locks in a few ms); any cycle
    # still searching must hold the arm (the loop's side, with a faked loss, is tested above).
    searching = log["state"] == "searching"
    assert np.all(log["v_cmd_mps"][searching] == 0.0) and np.all(log["w_cmd_dps"][searching] == 0.0)
    assert "loss: detection delay" in printed
    if s["lost_fraction"] == 1.0:
        assert "the tracker never locked on the object" in printed and "servo error" not in printed
    else:
        assert "servo error (estimate vs desired)" in printed


# -- (b) the UR loopback peer: commands stream, the link dies, the loop stops ----------------------


def test_ur_peer_streams_then_link_loss_stops_with_zero_velocity(rec_path, rec):
    pytest.importorskip("rtde_receive", reason="needs ur-rtde")
    from rtde_peer import Peer, make_arm

    peer = Peer()
    try:
        arm, ctl = make_arm(peer, limits=GENTLE, state_timeout_s=0.5)
        source, tracker, cfg = parts(rec_path, rec)
        with arm:
            with AfterServoStart(0.4, peer.proc.kill) as kill:
                r = run_real_loop(arm, source, tracker, cfg, progress=kill)
            assert not r.completed and r.error is not None
            assert peer.host in r.error and "lost" in r.error
            np.testing.assert_array_equal(arm.gate.last_sent, np.zeros(6))
        names = ctl.names()
        assert names.count("speedL") > 20  # commands streamed before the link died
        # After the last speedL came a speedStop (zero velocity), and nothing moved the arm again.
        last_speed_l = len(names) - 1 - names[::-1].index("speedL")
        assert "speedStop" in names[last_speed_l:]
        assert names[-1] == "disconnect"
        s = summarize(r)
        assert s["ended"].startswith("error:") and not s["completed"]
    finally:
        peer.close()


def test_ur_dry_run_never_opens_the_control_interface(rec_path, rec):
    pytest.importorskip("rtde_receive", reason="needs ur-rtde")
    from evservo.robots.ur import UrArm
    from rtde_peer import Peer

    peer = Peer()
    try:
        source, tracker, cfg = parts(rec_path, rec, duration_s=0.4, dry_run=True)
        with UrArm(peer.host, dry_run=True, limits=GENTLE, state_timeout_s=0.5) as arm:
            r = run_real_loop(arm, source, tracker, cfg)
            assert sum(h.kind == "command" for h in arm.gate.history) > 20
        assert r.completed and summarize(r)["dry_run"]
        seen = peer.log()
        assert seen["connections"] == 1 and seen["received"] == ["V", "v", "O", "S"]  # receive only
    finally:
        peer.close()


# -- (c) franky-sim -------------------------------------------------------------------------------


# franky's own planner (Ruckig), rarely, cannot plan a velocity motion from the state the simulator
# reports: "Motion planner failed with error code -110" ended one CI run in about 25, and none of 40 runs
# here, also at load 10. That failure is franky's, not ours; what is ours is stopping the arm cleanly when
# the arm refuses, which the test checks before it tries once more.
FRANKY_PLANNER_FAILED = "Motion planner failed"


@pytest.fixture
def franka_sim():
    """A franky-sim server (one MuJoCo FR3 on loopback) and evservo's FrankaArm class."""
    pytest.importorskip("franky", reason="needs franky-control")
    pytest.importorskip("franky_sim", reason="needs franky-sim (requirements-hw.txt)")
    from evservo.robots.franka import FrankaArm
    from franka_sim import Sim

    sim = Sim()
    try:
        yield sim.host, FrankaArm
    finally:
        sim.close()


def assert_connects_again_at_rest(FrankaArm, host: str) -> None:
    """The last arm released the robot (franky-sim serves one client at a time) and left it at rest."""
    with FrankaArm(host, realtime="ignore") as again:
        a = again.T_w_e()[:3, 3]
        time.sleep(0.2)
        assert np.linalg.norm(again.T_w_e()[:3, 3] - a) < 1e-3


def test_franka_sim_connect_stream_and_clean_shutdown(rec_path, rec, franka_sim):
    host, FrankaArm = franka_sim
    for attempt in (1, 2):
        source, tracker, cfg = parts(rec_path, rec, duration_s=0.5)
        with FrankaArm(host, realtime="ignore", limits=GENTLE) as arm:
            p0 = arm.T_w_e()[:3, 3]
            r = run_real_loop(arm, source, tracker, cfg)
            assert arm.gate.history[-1].kind == "halt"
            if attempt == 1 and r.error is not None and FRANKY_PLANNER_FAILED in r.error:
                assert not r.completed and r.ended == f"error: {r.error}"
                continue
            assert r.completed and r.error is None, r.ended
            assert sum(h.kind == "command" for h in arm.gate.history) > 20
            moved = np.linalg.norm(arm.T_w_e()[:3, 3] - p0)
        break
    assert 1e-4 < moved < 0.05
    assert_connects_again_at_rest(FrankaArm, host)


class RefusesOneMotion:
    """A franky robot whose ``n``-th motion franky's planner refuses, as it did in CI."""

    def __init__(self, *args, n: int = 40, **kwargs) -> None:
        import franky

        self.robot, self.moves_left = franky.Robot(*args, **kwargs), n

    def __getattr__(self, name: str):
        return getattr(self.robot, name)

    def move(self, motion, asynchronous: bool = False):
        self.moves_left -= 1
        if self.moves_left == 0:
            raise RuntimeError("Motion planner failed with error code -110")
        return self.robot.move(motion, asynchronous=asynchronous)


def test_franka_sim_a_refused_motion_stops_the_loop_and_the_robot_can_be_connected_again(rec_path, rec, franka_sim):
    host, FrankaArm = franka_sim
    robots = []

    def connect(*args, **kwargs) -> RefusesOneMotion:
        robots.append(RefusesOneMotion(*args, **kwargs))
        return robots[-1]

    source, tracker, cfg = parts(rec_path, rec, duration_s=0.5)
    with FrankaArm(host, realtime="ignore", limits=GENTLE, robot_factory=connect) as arm:
        r = run_real_loop(arm, source, tracker, cfg)
        assert r.ended == "error: Motion planner failed with error code -110" and not r.completed
        assert arm.gate.history[-1].kind == "halt"
    # Nothing that outlived the loop (a log record, a traceback) may still hold the first connection:
    # connecting again would wait for it forever.
    first = weakref.ref(robots.pop())
    assert first() is None, "the refused motion's connection outlived the arm"
    assert_connects_again_at_rest(FrankaArm, host)


# -- (d) injected faults: a pose jump, a stale pose, a lost object ----------------------------------


class FaultyTracker:
    """A real tracker whose published poses go wrong ``after_s`` after :meth:`arm_fault` is called."""

    def __init__(self, tracker: Tracker, fault: str, lasting_s: float = math.inf) -> None:
        self.trk, self.fault, self.t_fault, self.lasting_s = tracker, fault, math.inf, lasting_s
        self.frozen = None

    def arm_fault(self, after_s: float) -> None:
        self.t_fault = time.monotonic() + after_s

    def latest(self):
        est = self.trk.latest()
        if not self.t_fault <= time.monotonic() < self.t_fault + self.lasting_s:
            return est
        fields = {k: getattr(est, k) for k in ("T_c_o", "t_us", "seq", "lost", "inlier_fraction")}
        if self.fault == "jump":
            T = est.T_c_o.copy()
            T[:3, 3] += [0.2, 0.0, 0.0]  # 20 cm in one pose
            fields["T_c_o"] = T
        elif self.fault == "stale":
            self.frozen = self.frozen or fields  # the tracker stops publishing
            fields = self.frozen
        elif self.fault == "lost":
            fields["lost"] = True
        return SimpleNamespace(**fields)

    def __getattr__(self, name):
        return getattr(self.trk, name)


@pytest.mark.parametrize(("fault", "reason"), [("jump", "pose jump"), ("stale", "no fresh pose")])
def test_injected_fault_stops_by_watchdog(rec_path, rec, tmp_path, fault, reason):
    source, tracker, cfg = parts(rec_path, rec, stale_after_s=0.1)
    faulty = FaultyTracker(tracker, fault)
    with KinematicArm(limits=GENTLE) as arm:
        r = run_real_loop(
            arm, source, faulty, cfg, progress=lambda m: faulty.arm_fault(0.2) if m.startswith("servoing") else None
        )
        np.testing.assert_array_equal(arm.twist_w(), np.zeros(6))  # left stopped
        assert arm.gate.history[-1].kind == "halt"
    s = summarize(r)
    write_outputs(r, tmp_path, s)
    check_summary(s)
    assert not s["completed"] and s["ended"].startswith("watchdog") and reason in s["ended"]
    [w] = s["watchdog"]
    assert reason in w["reason"] and w["end_s"] is None
    assert 0.15 < w["start_s"] < 0.2 + cfg.stale_after_s + 0.25  # when the fault hit (+ the stale time)
    assert w["zero_s"] is not None and w["zero_s"] >= w["start_s"] and w["last_pose_s"] <= w["start_s"]
    assert s["servo_s"] < 1.0  # did not run on to the end of the recording
    log = (tmp_path / "log.csv").read_text()
    assert ",stopped" in log and (",rejected" in log or ",stale" in log)


def test_a_lost_object_holds_the_arm_still_then_servoing_resumes(rec_path, rec, tmp_path):
    """The tracker flags the object lost for 0.3 s: the arm follows the predicted motion for the coast
    (LossHold's, from the newest trusted pose), then brakes to rest within the gate's limits and stays
    there with the desired pose kept (no watchdog stop), then servoing resumes to the end."""
    source, tracker, cfg = parts(rec_path, rec, stale_after_s=0.1)
    faulty = FaultyTracker(tracker, "lost", lasting_s=0.3)
    with KinematicArm(limits=GENTLE) as arm:
        r = run_real_loop(
            arm, source, faulty, cfg, progress=lambda m: faulty.arm_fault(0.2) if m.startswith("servoing") else None
        )
        limits = arm.gate.limits
    s = summarize(r, gt=(rec.gt_t_us, rec.gt_T))
    write_outputs(r, tmp_path, s)
    check_summary(s)
    assert s["completed"] and s["ended"] == "end of recording" and not s["watchdog"], s["ended"]
    lost = np.flatnonzero(r.lost)
    assert len(lost) and 0.15 < r.t_s[lost[0]] < 0.35 and r.t_s[lost[-1]] - r.t_s[lost[0]] > 0.2
    speed = np.linalg.norm(r.v_cmd_w[:, :3], axis=1)
    dv = np.abs(np.diff(speed))[lost[0] : lost[-1]]  # braking while lost: within the acceleration limit
    assert dv.max() <= limits.max_lin_acc / cfg.rate_hz * (1 + 1e-6)
    braking = r.t_s[lost[0]] + COAST_S
    rest = r.lost & (r.t_s >= braking + limits.max_lin_vel / limits.max_lin_acc + 0.02)
    assert rest.sum() > 10 and np.all(speed[rest] == 0.0)
    assert {r.state[i] for i in lost if r.t_s[i] < braking} <= {"ok", "holding"}  # "ok": coasting
    assert {r.state[i] for i in lost if r.t_s[i] > braking + 1.0 / cfg.rate_hz} == {"holding"}
    # Servoing resumed after the spell (ramped in), on the desired pose captured at servo start.
    after = r.t_s > r.t_s[lost[-1]] + 0.1
    assert after.any() and "ok" in {r.state[i] for i in np.flatnonzero(after)}
    assert np.any(speed[after] > 0)
    assert s["holding_s"] >= 0.5 and s["lost_fraction"] > 0.1  # the 0.3 s spell, then the 0.3 s ramp
    np.testing.assert_allclose(s["T_c_o_des"], r.T_c_o_est[0], atol=0.05)


class EventsStop:
    """A replayed camera whose events stop from ``cut_us[0]`` to ``cut_us[1]`` of sensor time while its
    clock runs on: the slices keep coming, empty, with the source's ``stream_time_us`` (``clock``) or
    without it (a source that cannot tell, as before). Notes the host time of the first empty slice."""

    def __init__(self, source, cut_us: tuple[int, int], clock: bool) -> None:
        self.source, self.cut_us, self.clock = source, cut_us, clock
        self.width, self.height = source.width, source.height
        self.cut_at: float | None = None

    @property
    def stream_time_us(self):
        return self.source.stream_time_us if self.clock else None

    def __iter__(self):
        for ev in self.source:
            t = ev["t"]
            ev = ev[(t < self.cut_us[0]) | (t >= self.cut_us[1])]
            if not len(ev) and self.cut_at is None and self.source.stream_time_us >= self.cut_us[0]:
                self.cut_at = time.monotonic()
            yield ev


@pytest.mark.parametrize("clock", [True, False])
def test_events_stopping_while_the_camera_clock_runs_reads_lost_before_the_watchdog(rec_path, rec, clock):
    """Issue 12: the camera's events stop for 0.2 s of sensor time while its slices go on, empty. With
    the source's clock handed on (``stream_time_us`` → ``Tracker.advance_time``) the loop sees the
    tracker's ``lost`` (measured 18.1–22.3 ms of sensor time after the first empty slice, ≈ 40 ms of
    host time at half speed; 20 runs) and holds, with no watchdog spell; a source that cannot tell its time leaves
    only the stale-pose watchdog, which stops the loop (the behaviour before)."""
    # The gap lasts 0.4 s of host time: the 0.25 s stale limit stops the loop unless something flags the
    # object lost (looser than the CLI's 50 ms so that a loaded machine starving the tracker thread a
    # moment before the gap does not end the test early).
    source, tracker, cfg = parts(rec_path, rec, stale_after_s=0.25)
    gap = EventsStop(source, (300_000, 500_000), clock)
    cycles: list[tuple[float, float]] = []
    with KinematicArm(limits=GENTLE) as arm:
        r = run_real_loop(arm, gap, tracker, cfg, on_cycle=lambda t, *_: cycles.append((t, time.monotonic())))
    s = summarize(r)
    assert gap.cut_at is not None and cycles
    cut_s = gap.cut_at - (cycles[0][1] - cycles[0][0])  # the first empty slice, in seconds since servo start
    assert 0.2 < cut_s < 1.0, cut_s  # while servoing
    lost_at = r.t_s[r.lost & (r.t_s >= cut_s)]
    if clock:
        assert s["completed"] and not s["watchdog"], (s["ended"], s["watchdog"])
        assert len(lost_at) and not r.lost[r.t_s < cut_s - 0.02].any(), (cut_s, r.t_s[r.lost][:5])
        delay_sensor_s = (lost_at[0] - cut_s) * SPEED
        print(f"lost {delay_sensor_s * 1e3:.1f} ms of sensor time after the events stopped")
        assert 0.015 < delay_sensor_s < 0.05, delay_sensor_s
        through = (r.t_s >= lost_at[0]) & (r.t_s < cut_s + 0.2 / SPEED)
        assert np.all(r.lost[through]), r.t_s[through & ~r.lost]  # lost through the gap
    else:
        assert not len(lost_at) and not s["completed"] and "no fresh pose" in s["ended"], s["ended"]
        assert s["watchdog"][0]["start_s"] > cut_s, (s["watchdog"], cut_s)  # stopped by the gap


def test_the_live_view_tap_keeps_the_batches_and_passes_the_source_clock_on(rec_path):
    """With ``--viewer`` the camera thread iterates the viewer's tap: it must still see the source's
    ``stream_time_us`` (else events stopping would again reach the loop only as a stale pose)."""
    from evservo.runtime.live_view import LiveView

    source = ReplaySource(rec_path, speed=100.0)
    live = LiveView(viewer=None, tracker=None)
    tapped = live.tap(source)
    assert tapped.stream_time_us is None  # nothing yielded yet
    first = next(iter(tapped))
    assert tapped.stream_time_us == source.stream_time_us and tapped.stream_time_us >= int(first["t"][-1])
    assert live._events[-1] is first


def test_starting_from_a_search_holds_still_until_locked_then_captures_the_desired_pose(rec_path, rec):
    """With ``search`` the loop starts while the tracker is lost (here: flagged lost for its first 0.5 s)
    and holds the arm still; once the tracker locks the tracked pose becomes the desired one."""
    source, tracker, cfg = parts(rec_path, rec, search=True)
    faulty = FaultyTracker(tracker, "lost", lasting_s=cfg.settle_s + 0.4)
    with KinematicArm(limits=GENTLE) as arm:
        r = run_real_loop(
            arm, source, faulty, cfg, progress=lambda m: faulty.arm_fault(0.0) if m.startswith("settling") else None
        )
    s = summarize(r)
    assert s["completed"] and not s["watchdog"], s["ended"]
    searching = np.array([st == "searching" for st in r.state])
    assert searching[0] and searching.sum() > 10
    speed = np.linalg.norm(r.v_cmd_w, axis=1)
    assert np.all(speed[searching] == 0.0), "the arm must not move before the tracker has locked"
    locked = int(np.argmax(~searching))
    assert locked > 0 and not r.lost[locked] and "ok" in r.state[locked:]
    # The desired pose is the tracked pose at the lock (as the paper takes it at servo start).
    np.testing.assert_allclose(r.T_c_o_des, r.T_c_o_est[locked], atol=0.01)
    assert np.any(speed[locked:] > 0)


class CtrlCArm(KinematicArm):
    """A kinematic arm whose ``after``-th command meets a Ctrl-C: the KeyboardInterrupt surfaces in the
    control loop's thread at a known cycle (``_thread.interrupt_main`` from a timer, tried first, is
    delivered at the interpreter's discretion and let a full-suite run reach the end of the replay)."""

    def __init__(self, after: int, **kw) -> None:
        super().__init__(**kw)
        self.after = after

    def _send(self, v: np.ndarray, dt_s: float) -> None:
        if self.commands == self.after:
            self.commands += 1
            raise KeyboardInterrupt
        super()._send(v, dt_s)


def test_ctrl_c_stops_the_arm_and_the_threads(rec_path, rec):
    source, tracker, cfg = parts(rec_path, rec)
    with CtrlCArm(after=round(0.3 * cfg.rate_hz), limits=GENTLE) as arm:
        r = run_real_loop(arm, source, tracker, cfg)
        np.testing.assert_array_equal(arm.twist_w(), np.zeros(6))
        assert arm.gate.history[-1].kind == "halt"
    assert r.interrupted and not r.completed and "interrupted" in r.ended, (r.ended, r.watchdog)
    assert not tracker.running and 0.2 < r.servo_s < 1.0


class SignalledArm(KinematicArm):
    """A kinematic arm that, right after its ``after``-th twist reached it, gets a real SIGINT: the
    Ctrl-C lands between a cycle's command and its log row."""

    def __init__(self, after: int, **kw) -> None:
        super().__init__(**kw)
        self.after = after

    def _send(self, v: np.ndarray, dt_s: float) -> None:
        super()._send(v, dt_s)
        if self.commands == self.after:
            os.kill(os.getpid(), signal.SIGINT)


def test_a_ctrl_c_after_a_command_still_logs_that_cycle(rec_path, rec):
    """Every twist that reached the arm has its row in the log, even when the Ctrl-C arrives between
    the command and the row (it used to leave the last twist unlogged)."""
    source, tracker, cfg = parts(rec_path, rec)
    with SignalledArm(after=round(0.3 * cfg.rate_hz), limits=GENTLE) as arm:
        r = run_real_loop(arm, source, tracker, cfg)
        sent = arm.commands
    assert r.interrupted and "interrupted" in r.ended, r.ended
    assert sent == round(0.3 * cfg.rate_hz) == len(r.t_s) == len(r.state)
    assert summarize(r)["control_cycles"] == sent


class RacedArm(KinematicArm):
    """A kinematic arm whose gate watchdog halts it right after its ``after``-th command returned, as
    the gate's thread can on a loaded machine, before the loop has written the cycle's row."""

    def __init__(self, after: int, **kw) -> None:
        super().__init__(**kw)
        self.after = after

    def command_twist(self, v_e_w: np.ndarray, dt_s: float) -> np.ndarray:
        sent = super().command_twist(v_e_w, dt_s)
        if self.commands == self.after:
            self.gate.stop("watchdog: no fresh command")
        return sent


def test_the_log_holds_the_twist_each_cycle_sent_even_when_the_gate_halts_meanwhile(rec_path, rec):
    """A cycle's ``v_sent_w`` is the twist the gate sent in that cycle (it read the gate's twist in
    force after the send, which a halt in between turned into zeros)."""
    source, tracker, cfg = parts(rec_path, rec, duration_s=0.5)
    with RacedArm(after=20, limits=GENTLE) as arm:
        r = run_real_loop(arm, source, tracker, cfg)
        sent = [h.sent for h in arm.gate.history if h.kind == "command"]
    assert len(sent) == len(r.t_s) > 20 and np.any(sent[19])
    np.testing.assert_array_equal(r.v_sent_w, sent)


# -- (e) dry run ---------------------------------------------------------------------------------


def test_dry_run_logs_but_never_moves(rec_path, rec):
    source, tracker, cfg = parts(rec_path, rec, duration_s=0.5, dry_run=True)
    with KinematicArm(limits=GENTLE, dry_run=True) as arm:
        T0 = arm.T_w_e()
        r = run_real_loop(arm, source, tracker, cfg)
        assert arm.commands == 0 and arm.halts == 0  # nothing reached the arm
        np.testing.assert_array_equal(arm.T_w_e(), T0)
        logged = [h for h in arm.gate.history if h.kind == "command"]
    assert r.completed and len(logged) > 50 and any(np.any(h.sent) for h in logged)
    s = summarize(r)
    assert s["dry_run"] and s["gate"]["dry_run"] and s["camera_travel_max_m"] == 0.0


# -- (f) bad command lines ---------------------------------------------------------------------------


def _unused_host() -> str:
    import random

    return f"127.{random.randint(1, 254)}.{random.randint(1, 254)}.1"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--robot", "abb:10.0.0.2", "--camera", "{rec}"], "want ur:HOST"),
        (["--robot", "ur", "--camera", "{rec}", "--config", "{rig}"], "controller's address"),
        (["--robot", "sim:host", "--camera", "{rec}"], "takes no host"),
        (["--robot", "ur:10.0.0.2", "--camera", "{rec}"], "needs --config"),
        (["--robot", "sim"], "needs --camera"),
        (["--robot", "sim", "--camera", "{d}/missing.h5"], "no such event file"),
        (["--robot", "sim", "--camera", "{rec}", "--config", "{d}/missing.yaml"], "no such rig config"),
        (["--robot", "sim", "--camera", "{rec}", "--config", "{d}/bad.yaml"], "camera: missing section"),
        (["--robot", "sim", "--camera", "{rec}", "--config", "{d}/big.yaml"], "1280x720"),
        (["--robot", "sim", "--camera", "{rec}", "--model", "{d}/missing.obj"], "missing.obj"),
        (["--robot", "sim", "--camera", "{rec}", "--init-pose", "1,2,3"], "--init-pose"),
        (["--robot", "sim", "--camera", "{rec}", "--desired-pose", "0,0,-1,0,0,0,1"], "in front of the camera"),
        (["--robot", "sim", "--camera", "{rec}", "--rate", "0"], "rate_hz"),
        (["--robot", "sim", "--camera", "dv", "--replay-speed", "2"], "files only"),
        (["--robot", "sim", "--camera", "dv"], "iniVation"),
        (["--robot", "ur:{host}", "--camera", "{rec}", "--config", "{rig}"], "cannot connect to the UR controller"),
        (
            ["--robot", "franka:{host}", "--camera", "{rec}", "--config", "{rig}", "--realtime", "ignore"],
            "cannot connect to the Franka robot",
        ),
        (["--robot", "sim", "--camera", "{rec}", "--realtime", "ignore"], "franka"),
        (["--sim", "--camera", "{rec}"], "--camera only applies with --robot"),
    ],
)
def test_bad_input_exits_non_zero_with_a_message(args, message, rec_path, rec, tmp_path, capsys):
    (tmp_path / "bad.yaml").write_text("hand_eye: {translation: [0, 0, 0], quaternion: [0, 0, 0, 1]}\n")
    (tmp_path / "big.yaml").write_text(
        "hand_eye: {translation: [0, 0, 0], quaternion: [0, 0, 0, 1]}\n"
        "camera: {width: 1280, height: 720, fx: 1000, fy: 1000, cx: 640, cy: 360}\n"
        "limits: {max_lin_vel: 0.1, max_ang_vel: 0.3, max_lin_acc: 1.0, max_ang_acc: 2.0}\n"
    )
    if "ur:{host}" in args:
        pytest.importorskip("rtde_receive", reason="needs ur-rtde")
    if "franka:{host}" in args:
        pytest.importorskip("franky", reason="needs franky-control")
    fill = dict(rec=rec_path, d=tmp_path, rig=rig_yaml(tmp_path, rec), host=_unused_host())
    code = main(["servo", *(a.format(**fill) for a in args), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code != 0
    assert err.startswith("evservo: error:") and message in err and "Traceback" not in err, err


@pytest.mark.parametrize(("camera", "module", "message"), [("prophesee", "metavision_core", "OpenEB"),
                                                           ("dv", "dv_processing", "dv-processing")])  # fmt: skip
def test_missing_camera_sdk_is_named(camera, module, message, rec_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, module, None)  # the import fails, installed or not
    assert main(["servo", "--robot", "sim", "--camera", camera]) == 2
    err = capsys.readouterr().err
    assert err.startswith("evservo: error:") and message in err and "Traceback" not in err


@pytest.mark.parametrize(("robot", "module", "message"), [("ur:10.0.0.2", "rtde_receive", "ur-rtde"),
                                                          ("franka:10.0.0.2", "franky", "franky-control")])  # fmt: skip
def test_missing_robot_sdk_is_named(robot, module, message, rec_path, rec, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, module, None)
    args = ["servo", "--robot", robot, "--camera", str(rec_path), "--config", rig_yaml(tmp_path, rec)]
    assert main([*args, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("evservo: error:") and message in err and "Traceback" not in err


def test_kinematic_arm_integrates_the_twist_it_holds():
    t = [0.0]
    arm = KinematicArm(limits=CartesianLimits(max_lin_acc=100.0, max_ang_acc=100.0), clock=lambda: t[0])
    with arm:
        T0 = arm.T_w_e()
        arm.command_twist(np.array([0.1, 0.0, -0.05, 0.0, 0.0, 0.5]), 0.01)
        t[0] = 0.2
        T = arm.T_w_e()
        np.testing.assert_allclose(T[:3, 3] - T0[:3, 3], [0.02, 0.0, -0.01], atol=1e-12)
        np.testing.assert_allclose(T[:3, :3], Rotation.from_rotvec([0, 0, 0.1]).as_matrix() @ T0[:3, :3], atol=1e-12)
        arm.stop()
        t[0] = 1.0
        np.testing.assert_allclose(arm.T_w_e(), T, atol=1e-12)  # stopped: stays put
        assert arm.commands == 1 and arm.halts == 1
    # The gate's limits act: 1 m/s asked, 0.1 m/s held.
    with KinematicArm(limits=CartesianLimits(max_lin_vel=0.1, max_lin_acc=100.0), clock=lambda: t[0]) as arm:
        arm.command_twist(np.array([1.0, 0, 0, 0, 0, 0]), 0.01)
        np.testing.assert_allclose(arm.twist_w(), [0.1, 0, 0, 0, 0, 0])


class ShiftedClock:
    """A source whose sensor clock starts far from zero, as a live camera's does."""

    def __init__(self, source, shift_us: int) -> None:
        self.source, self.shift_us = source, shift_us
        self.width, self.height = source.width, source.height

    def __iter__(self):
        for ev in self.source:
            ev = ev.copy()
            ev["t"] += self.shift_us
            yield ev


def test_sensor_clock_is_mapped_to_host_time(rec_path, rec):
    source, tracker, cfg = parts(rec_path, rec, duration_s=0.5)
    with KinematicArm(limits=GENTLE) as arm:
        r = run_real_loop(arm, ShiftedClock(source, 7_123_456_789), tracker, cfg)
    s = summarize(r)
    assert s["completed"], s["ended"]
    # Ages are event latency plus tracking time (a few ms), not the clock shift.
    assert 0.0 <= s["pose_age_mean_ms"] < 100.0 and s["pose_age_max_ms"] < cfg.stale_after_s * 1e3
    assert np.all(np.diff(r.est_t_s) >= 0) and np.all(r.est_t_s <= r.t_s)


def test_a_tracker_that_cannot_lock_on_stops_before_moving(rec_path, rec):
    from evservo.realloop import TrackingError

    source, tracker, cfg = parts(rec_path, rec)
    faulty = FaultyTracker(tracker, "lost")
    faulty.arm_fault(0.0)  # every pose flagged lost from the start
    with KinematicArm(limits=GENTLE) as arm, pytest.raises(TrackingError, match="lost the object while settling"):
        run_real_loop(arm, source, faulty, cfg)
    assert arm.commands == 0 and not tracker.running


def test_a_file_shorter_than_the_settle_time_is_refused(tmp_path, capsys):
    from conftest import SAMPLES

    raw = SAMPLES / "prophesee_gen41_evt3_1280x720.raw"  # 9 ms of a real scene
    if not raw.exists():
        pytest.skip(f"{raw} not found (set EVSERVO_SAMPLES)")
    args = ["servo", "--robot", "sim", "--camera", str(raw), "--model", "box", "--init-pose", "0,0,0.6,0,0,0,1",
            "--out", str(tmp_path)]  # fmt: skip
    assert main(args) == 2
    out, err = capsys.readouterr()
    assert "IMX636 intrinsics" in out  # a 1280x720 file without --config, as `evservo track` does
    assert err.startswith("evservo: error:") and "ended during the settle time" in err and "Traceback" not in err
    assert not (tmp_path / "summary.json").exists()


def test_cli_watchdog_stop_exits_1_and_still_writes_the_summary(rec_path, tmp_path, capsys):
    args = ["servo", "--robot", "sim", "--camera", str(rec_path), "--settle", "0.1", "--replay-speed", str(SPEED),
            "--stale-after", "0.0005", "--out", str(tmp_path)]  # fmt: skip
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err.startswith("evservo: error: servoing stopped (arm stopped): watchdog") and "Traceback" not in err
    s = json.loads((tmp_path / "summary.json").read_text())
    assert not s["completed"] and len(s["watchdog"]) == 1 and s["watchdog"][0]["zero_s"] is not None


def test_cli_jump_gate_options_reach_the_watchdog(rec_path, tmp_path, capsys):
    """``--max-jump``: a gate of 10 µm refuses the first pose after the start (the box moves far more
    than that between two poses), which stops the run like any other watchdog."""
    args = ["servo", "--robot", "sim", "--camera", str(rec_path), "--settle", "0.1", "--replay-speed", str(SPEED),
            "--stale-after", "1.0", "--max-jump", "1e-5", "--out", str(tmp_path)]  # fmt: skip
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "watchdog: pose jump: jump of" in err and "Traceback" not in err
    s = json.loads((tmp_path / "summary.json").read_text())
    assert not s["completed"] and s["ended"].startswith("watchdog: pose jump")
