"""Starting without a pose (issue 12 items 3-4): the global search over the template bank finds the
drill and the textured box in simulated recordings, locks within 300 ms with the pose right, and a
wrong model never locks. ``evservo track --init-pose search`` starts lost even on a recording with
ground truth, so the error after the lock can be checked against it."""

import json

import numpy as np
import pytest

from evservo.cli import main
from evservo.outputs import read_json


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    d = tmp_path_factory.mktemp("acq")
    out = {}
    for name, obj, scale in (("drill", "drill", "0.5"), ("box", "box", "0.5"), ("drill-1280", "drill", "1.0")):
        out[name] = d / f"{name}.h5"
        args = ["sim", "record", "--object", obj, "--trajectory", "trans", "--speed", "0.1", "--distance", "0.7",
                "--duration", "0.3", "--scale", scale, "--quiet", "--out", str(out[name])]  # fmt: skip
        assert main(args) == 0
    return out


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


def test_servo_from_a_search_locks_within_300_ms_and_never_trusts_a_wrong_pose(recordings, tmp_path, unloaded_cpus):
    """`evservo servo --robot sim --init-pose search`: the real loop with the threaded tracker, the
    recording replayed at real time. The tracker's global searches share its thread with the local
    steps, so it must lock while events stream in (within 300 ms of the start) and, scored against the
    recording's truth, never hand the loop a wrong pose as trusted. Measured at low load: locked 84 ms
    into a 2 s drill recording; 5.2 mm / 0.55 deg RMS after. At load 15-27 on 2 cores it never locked
    (the searches get a fraction of a core): skipped then, see ``unloaded_cpus``."""
    out = tmp_path / "o"
    settle_s = 0.05
    args = ["servo", "--robot", "sim", "--camera", str(recordings["drill"]), "--init-pose", "search",
            "--settle", str(settle_s), "--stale-after", "1.0", "--out", str(out)]  # fmt: skip
    assert main(args) == 0
    s = read_json(out / "summary.json")  # a run that never locked writes relock_ms as "Infinity"
    assert s["config"]["search"] and s["tracker_steps"]["global"] >= 1, s["tracker_steps"]
    loss = s["loss"]
    # The log starts after the settle time, so the lock is due settle_s earlier in it.
    assert loss["relock_ms"] is not None and loss["relock_ms"] <= 300 - settle_s * 1e3, loss
    assert loss["confident_wrong_ms"] == 0.0, loss
