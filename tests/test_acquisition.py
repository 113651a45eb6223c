"""Starting without a pose (issue 12 items 3-4): the global search over the template bank finds the
drill and the textured box in simulated recordings, locks within 300 ms with the pose right, and a
wrong model never locks. ``evservo track --init-pose search`` starts lost even on a recording with
ground truth, so the error after the lock can be checked against it."""

import json

import numpy as np
import pytest

from evservo.cli import main
from evservo.outputs import read_json


def _record(path, obj: str, scale: str, seconds: float):
    """A simulated recording of ``obj`` at Z = 0.7 m on a 0.1 m/s translation."""
    args = ["sim", "record", "--object", obj, "--trajectory", "trans", "--speed", "0.1", "--distance", "0.7",
            "--duration", str(seconds), "--scale", scale, "--quiet", "--out", str(path)]  # fmt: skip
    assert main(args) == 0
    return path


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    d = tmp_path_factory.mktemp("acq")
    shots = (("drill", "drill", "0.5"), ("box", "box", "0.5"), ("drill-1280", "drill", "1.0"))
    return {name: _record(d / f"{name}.h5", obj, scale, 0.3) for name, obj, scale in shots}


def _track(path, out, model, seconds):
    args = ["track", str(path), "--model", model, "--init-pose", "search", "--max-seconds", str(seconds), "--quiet"]
    assert main([*args, "--out", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    lost = np.genfromtxt(out / "poses.csv", delimiter=",", names=True)["lost"].astype(bool)
    return s, lost


@pytest.mark.parametrize("name", ["drill", "box", "drill-1280"])
def test_track_from_no_pose_locks_within_300_ms_and_is_right(recordings, tmp_path, name):
    """Measured (Z = 0.7 m, 0.1 m/s; 640x360 unless named 1280): drill locks after 46 ms, <= 7.1 mm /
    2 deg after; box after 3 ms, <= 3.4 mm / 1.2 deg; drill at 1280x720 after 8 ms, <= 3.9 mm / 0.5 deg."""
    s, lost = _track(recordings[name], tmp_path / "o", name.split("-")[0], 0.3)
    assert s["started_lost"] and lost[0], s
    assert s["first_lock_s"] is not None and s["first_lock_s"] <= 0.3, s
    # Once locked it stays locked, and every locked pose is right (issue 12: never a wrong lock).
    first = int(np.argmin(lost))
    assert not lost[first:].any(), np.flatnonzero(lost[first:])[:5]
    assert s["gt_locked_pos_max_mm"] <= 10.0 and s["gt_locked_rot_max_deg"] <= 5.0, s


def test_a_wrong_model_never_locks(recordings, tmp_path):
    """The drill searched for in a box recording: every update stays lost."""
    s, lost = _track(recordings["box"], tmp_path / "o", "drill", 0.15)
    assert s["first_lock_s"] is None and lost.all(), s


REALTIME_RECORDING_S = 1.0


def test_servo_from_a_search_locks_while_streaming_and_never_trusts_a_wrong_pose(unloaded_cpus, tmp_path):
    """`evservo servo --robot sim --init-pose search`: the real loop with the threaded tracker, the
    recording replayed at real time. The tracker's global searches share its thread with the local
    steps, so it must lock while events stream in and, scored against the recording's truth, never hand
    the loop a wrong pose as trusted. How soon it locks in wall time measures the machine as much as the
    code (a pass costs ~100 ms of CPU, and a lock takes a pass that finds and one that confirms): that is
    a speed figure, reported by the robustness suite's start-without-pose rows, not a bound here; the
    300 ms bound in sensor time is ``test_track_from_no_pose_locks_within_300_ms_and_is_right``'s.
    Measured at load 6.5 on 2 cores: locked 56-276 ms in, in 8 runs of 9 (592 ms in one). A 0.3 s
    recording left no time for the confirming pass when the first pass missed (main passed 5 runs in 6
    quiet, 2 in 6 at load 6-8). At load 15-27 it never locked: skipped then, see ``unloaded_cpus``."""
    # Recorded here, after ``unloaded_cpus``, so that a skip does not pay for it.
    recording = _record(tmp_path / "drill.h5", "drill", "0.5", REALTIME_RECORDING_S)
    out = tmp_path / "o"
    args = ["servo", "--robot", "sim", "--camera", str(recording), "--init-pose", "search",
            "--settle", "0.05", "--stale-after", "1.0", "--out", str(out)]  # fmt: skip
    assert main(args) == 0
    s = read_json(out / "summary.json")  # a run that never locked writes relock_ms as "Infinity"
    assert s["config"]["search"] and s["tracker_steps"]["global"] >= 1, s["tracker_steps"]
    loss = s["loss"]
    # Locked before the recording ended.
    assert loss["relock_ms"] is not None and loss["relock_ms"] < REALTIME_RECORDING_S * 1e3, loss
    assert loss["right_samples"] > 0 and loss["confident_wrong_ms"] == 0.0, loss


def _pose_error(P: np.ndarray, G: np.ndarray) -> tuple[float, float]:
    """Position (mm) and attitude (deg) error of pose P against G (4x4 each)."""
    cos = (np.trace(P[:3, :3].T @ G[:3, :3]) - 1) / 2
    return float(np.linalg.norm(P[:3, 3] - G[:3, 3]) * 1e3), float(np.degrees(np.arccos(np.clip(cos, -1, 1))))


def test_an_object_that_moved_30_mm_during_a_dropout_is_not_trusted_at_its_old_place(tmp_path):
    """The drill at Z = 0.6 m on a 0.3 m/s translation, tracked from its true pose with a template bank;
    every event from 100 to 210 ms is lost (the stream time goes on, so the tracker reads a dropout) while
    the drill moves 31 mm. Once the events are back the drill must be found where it is, never trusted
    where it was (issue 12, round 14: the first global pass of a loss now looks near the held pose). Every
    trusted pose after the dropout is within 10 mm / 5 deg of the truth, and the pose is trusted again
    within 100 ms. Measured (synchronous updates): trusted again 5 ms after the events resumed, the local
    steps having pulled the pose 32 mm onto the fresh events before any pass was due; <= 1.6 mm off after."""
    from evservo.io import read_events
    from evservo.sim.record import gt_at, load_recording
    from evservo.tracking import Tracker

    path = tmp_path / "drill.h5"
    args = ["sim", "record", "--object", "drill", "--trajectory", "trans", "--speed", "0.3", "--distance", "0.6",
            "--duration", "0.4", "--scale", "0.5", "--quiet", "--out", str(path)]  # fmt: skip
    assert main(args) == 0
    rec, ev = load_recording(path), read_events(path)
    t0 = int(ev["t"][0])
    gap = (t0 + 100_000, t0 + 210_000)

    def truth(t_us: int) -> np.ndarray:
        return gt_at(rec.gt_t_us, rec.gt_T, np.array([t_us]))[0]

    moved_mm, _ = _pose_error(truth(gap[0]), truth(gap[1]))
    assert moved_mm >= 30.0, moved_mm
    tracker = Tracker(rec.camera, rec.object, truth(t0), reacquire=True)
    newest, held, trusted_again = None, None, None
    for end in range(t0 + 1000, int(ev["t"][-1]), 1000):
        sl = ev[(ev["t"] >= end - 1000) & (ev["t"] < end)]
        if gap[0] <= end - 1000 < gap[1]:
            sl = sl[:0]
        est = tracker.update_slice(sl, end, newest)
        newest = int(sl["t"][-1]) if len(sl) else newest
        if end <= gap[0]:
            held = None if est.lost else np.asarray(est.T_c_o)
            continue
        assert held is not None, "locked when the dropout began"
        if end <= gap[1] or est.lost:
            continue
        trusted_again = trusted_again or end
        pos_mm, rot_deg = _pose_error(np.asarray(est.T_c_o), truth(end - 1))
        from_held_mm, _ = _pose_error(np.asarray(est.T_c_o), held)
        assert pos_mm <= 10.0 and rot_deg <= 5.0, (end - t0, pos_mm, rot_deg, from_held_mm)
    assert trusted_again is not None and trusted_again - gap[1] <= 100_000, trusted_again


def test_a_box_moving_back_into_a_quiet_view_explains_its_fresh_events_enough_to_be_taken():
    """Leave-return's mechanism without the loop (issue 12, round 16): a still camera sees only the edges
    source's background noise for 2 s (the object out of view), which the front-end keeps active, then the
    box slides back in along x at 0.5 m/s (Z = 0.6 m). Refined from its true pose on a global search's
    field, the box must score the acquisition bar (0.5) and 1.15x every candidate elsewhere (the tracker's
    rule for taking it). Main counted every pixel the front-end held in an 8x8 block that fired within the
    search's 10 ms as an event to explain, the noise of 2 s included: explained 0.58-0.64, acquisition
    0.27-0.32. Measured here (only the pixels fired within the 10 ms): at 2.60 and 2.65 s explained
    0.81-0.82, acquisition 0.53, no candidate elsewhere above 0.00. Later, as the box nears the middle,
    the truth reads 0.48-0.51 (explained 0.80-0.86; support - chance itself falls to 0.48-0.51 as chance
    rises to 0.44-0.48), at the bar rather than over it."""
    from scipy.spatial.transform import Rotation

    from evservo import _evcore
    from evservo.sim.sources import edge_source
    from evservo.tracking import Tracker

    camera = _evcore.Camera.imx636()
    z_m, speed_mps, quiet_s = 0.6, 0.5, 2.0
    out_x_m = z_m * (camera.width / 2) / camera.fx + 0.2  # the box's centre 0.2 m beyond the view's edge

    def truth(t_s: float) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec([0.35, -0.45, 0.1]).as_matrix()
        T[:3, 3] = [max(0.0, out_x_m - speed_mps * max(0.0, t_s - quiet_s)), 0.0, z_m]
        return T

    source = edge_source(camera, "box", truth(1e9), 0, 1)
    tracker = Tracker(camera, "box", None)
    t_ms = 0
    for probe_ms in (2600, 2650):
        while t_ms < probe_ms:
            t_ms += 1
            tracker.ingest(source.events_until(t_ms * 1000, truth(t_ms / 1000)))
        G = truth(t_ms / 1000)
        *others, found = tracker._core._global_candidates(extra=G[None])
        pos_mm, rot_deg = _pose_error(np.asarray(found["T_c_o"]), G)
        assert pos_mm <= 10.0 and rot_deg <= 5.0, (probe_ms, pos_mm, rot_deg)
        assert found["visible"] >= 0.9, (probe_ms, found["visible"])  # the box back in view
        assert found["explained"] >= 0.75, (probe_ms, found["explained"])
        elsewhere = [c["acquisition"] for c in others if not _same_place(np.asarray(c["T_c_o"]), G)]
        assert found["acquisition"] >= 0.5, (probe_ms, found)
        assert found["acquisition"] >= 1.15 * max(elsewhere), (probe_ms, found["acquisition"], max(elsewhere))


def _same_place(P: np.ndarray, G: np.ndarray) -> bool:
    """The tracker's `same_place`: within 20 mm and 5 deg."""
    pos_mm, rot_deg = _pose_error(P, G)
    return pos_mm < 20.0 and rot_deg < 5.0
