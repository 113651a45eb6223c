"""Rust-side file replay (``Tracker.replay``): the same events reach ingest as through the Python
push path, and bad files, stopped trackers and stop requests end it cleanly."""

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import SAMPLES
from evservo import Camera, geometry, io
from evservo._evcore import DecodeError
from evservo.events import clamp_time
from evservo.tracking import Tracker

EVT3 = SAMPLES / "prophesee_gen41_evt3_1280x720.raw"
pytestmark = pytest.mark.skipif(not EVT3.exists(), reason="event samples unavailable")


def _tracker() -> Tracker:
    # Every event ingested (no thinning), so the front-end's content depends on the events alone.
    T0 = geometry.pose((0.0, 0.0, 0.6), (0.0, 0.0, 0.0))
    return Tracker(Camera.imx636(), "box", T0, ingest_core_share=None)


def test_replay_ingests_exactly_what_the_python_push_path_does():
    py = _tracker()
    py.start()
    t_max, clamped = None, 0
    for ev in io.open_events(EVT3, delta_t_us=500):
        ev, n, t_max = clamp_time(ev, t_max)
        clamped += n
        if len(ev):
            py.push(ev)
    py.stop()

    rs = _tracker()
    rs.start()
    with rs.replay(EVT3, batch_us=500, speed=None) as replay:
        assert replay.wait(timeout=60.0)
        stats = replay.stats()
    rs.stop()
    assert not replay.running
    assert stats["events"] == rs.stats()["events_offered"] == py.stats()["events_offered"] == 219_596
    assert stats["clamped"] == clamped  # (the clamp itself: evcore replay unit tests)
    assert stats["end_us"] == (11_727_457 // 500 + 1) * 500
    mask_py, mask_rs = py.active_mask(), rs.active_mask()
    assert mask_py.sum() > 1000
    np.testing.assert_array_equal(mask_rs, mask_py)


def _copy(tmp_path: Path, name: str, edit) -> Path:
    data = edit(EVT3.read_bytes())
    out = tmp_path / name
    out.write_bytes(data)
    return out


def test_corrupt_files_raise_decode_errors(tmp_path):
    trk = _tracker()
    trk.start()
    try:
        # Cut inside a word: the stream ends with a stray byte.
        cut = _copy(tmp_path, "cut.raw", lambda b: b[:-1])
        with trk.replay(cut, speed=None) as replay, pytest.raises(DecodeError, match="truncated"):
            replay.wait(timeout=60.0)
        # A header claiming a smaller sensor: events fall off it.
        narrow = _copy(tmp_path, "narrow.raw", lambda b: b.replace(b"% evt 3.0", b"% evt 3.0\n% geometry 640x480", 1))
        trk.reset_events()
        with trk.replay(narrow, speed=None) as replay, pytest.raises(DecodeError, match="outside"):
            replay.wait(timeout=60.0)
        with pytest.raises(DecodeError):
            trk.replay(_copy(tmp_path, "nohead.raw", lambda b: b"% evt 3.0\n% end\n" + b[-64:]))
        with pytest.raises(FileNotFoundError):
            trk.replay(tmp_path / "missing.raw")
        with pytest.raises(ValueError, match="speed"):
            trk.replay(EVT3, speed=0.0)
        with pytest.raises(ValueError, match="batch_us"):
            trk.replay(EVT3, batch_us=0)
    finally:
        trk.stop()


def test_replay_needs_a_running_tracker_and_stops_on_request():
    trk = _tracker()
    with pytest.raises(RuntimeError, match="start"):
        trk.replay(EVT3)
    trk.start()
    # 1/1000 of real time: the 8.8 ms recording would take 8.8 s.
    replay = trk.replay(EVT3, speed=0.001)
    assert not replay.wait(timeout=0.05)
    replay.stop()
    assert not replay.running
    assert replay.stats()["events"] < 219_596
    assert replay.wait(timeout=0.0)  # ended by the request, no error
    # A tracker stopped under a running replay ends the replay with an error, not a crash.
    replay = trk.replay(EVT3, speed=0.001)
    trk.stop()
    with pytest.raises(RuntimeError, match="stopped"):
        replay.wait(timeout=30.0)


def _update_per_slice(batch_us: int) -> tuple[Tracker, list]:
    """The Python path of ``evservo track``: one ``update`` per clamped slice, empty ones too."""
    trk, t_max, out = _tracker(), None, []
    end = (11_718_656 // batch_us + 1) * batch_us
    for ev in io.open_events(EVT3, delta_t_us=batch_us):
        ev, _, t_max = clamp_time(ev, t_max)
        out.append((end, len(ev), trk.update(ev)))
        end += batch_us
    return trk, out


def test_update_replay_gives_exactly_the_poses_of_update_per_slice():
    py, expected = _update_per_slice(500)
    rs = _tracker()
    with rs.replay(EVT3, batch_us=500, speed=None, mode="update", snapshots_at=[0, len(expected) - 1]) as replay:
        assert replay.wait(timeout=120.0)
        got, snaps, stats = replay.updates(), replay.snapshots(), replay.stats()
    assert len(got) == len(expected) == stats["slices"] == 18
    assert sum(n for _, n, _ in got) == 219_596 and stats["update_seconds"] > 0
    for (end, n, est), (end_py, n_py, est_py) in zip(got, expected, strict=True):
        assert (end, n, est.seq, est.lost) == (end_py, n_py, est_py.seq, est_py.lost)
        np.testing.assert_array_equal(est.T_c_o, est_py.T_c_o)
    # The estimate moved off the start pose: the comparison is not between two untouched poses.
    assert not np.array_equal(got[-1][2].T_c_o, _tracker().latest().T_c_o)
    assert [s[0] for s in snaps] == [expected[0][0], expected[-1][0]]
    field, origin = py.field()
    np.testing.assert_array_equal(snaps[-1][1], field)
    assert snaps[-1][2] == origin
    np.testing.assert_array_equal(snaps[-1][3], py.projected_points())
    # Cut after the slice holding until_us, as `track --max-seconds` does.
    rs = _tracker()
    with rs.replay(EVT3, batch_us=500, speed=None, mode="update", until_us=11_720_000) as replay:
        assert replay.wait(timeout=120.0)
        assert [u[0] for u in replay.updates()] == [e[0] for e in expected if e[0] - 500 <= 11_720_000]


def test_update_replay_needs_a_stopped_tracker_and_reports_corrupt_files(tmp_path):
    trk = _tracker()
    trk.start()
    with pytest.raises(RuntimeError, match="stop"):
        trk.replay(EVT3, mode="update")
    trk.stop()
    with pytest.raises(ValueError, match="mode"):
        trk.replay(EVT3, mode="pull")
    cut = _copy(tmp_path, "cut.raw", lambda b: b[:-1])
    with trk.replay(cut, speed=None, mode="update") as replay, pytest.raises(DecodeError, match="truncated"):
        replay.wait(timeout=120.0)
    assert replay.updates(), "the slices before the bad word were tracked"


def _track(tmp_path: Path, *extra: str) -> list[str]:
    """``evservo track`` arguments for the EVT3 sample with the box at 0.6 m, output in tmp_path/t."""
    return ["track", str(EVT3), "--model", "box", "--init-pose", "0,0,0.6,0,0,0,1", *extra,
            "--out", str(tmp_path / "t")]  # fmt: skip


def test_track_on_a_raw_file_uses_the_rust_replay_with_the_python_path_s_poses(tmp_path, capsys, monkeypatch):
    from evservo.cli import main

    calls = []
    original = Tracker.replay
    monkeypatch.setattr(Tracker, "replay", lambda self, *a, **k: calls.append(k) or original(self, *a, **k))
    assert main(_track(tmp_path, "--batch-us", "500")) == 0
    assert [c["mode"] for c in calls] == ["update"]
    err = capsys.readouterr().err
    assert "edft+" in err and "batch" in err  # the progress bar
    poses = np.loadtxt(tmp_path / "t" / "poses.csv", delimiter=",", skiprows=1)
    _, expected = _update_per_slice(500)
    assert poses.shape == (18, 10)
    np.testing.assert_array_equal(poses[:, 0], [e[0] for e in expected])
    np.testing.assert_allclose(poses[:, 1:4], [e[2].T_c_o[:3, 3] for e in expected], atol=1e-6)
    np.testing.assert_array_equal(poses[:, 8], [e[2].lost for e in expected])
    np.testing.assert_allclose(poses[:, 9], [e[2].confidence for e in expected], atol=1e-6)


def test_ctrl_c_in_a_replayed_track_keeps_what_was_tracked(tmp_path, capsys, monkeypatch):
    import os
    import signal
    import threading

    from evservo.cli import main

    original = Tracker.replay

    def replay_then_ctrl_c(self, *a, **k):
        replay = original(self, *a, **k)
        threading.Timer(0.5, os.kill, (os.getpid(), signal.SIGINT)).start()
        return replay

    monkeypatch.setattr(Tracker, "replay", replay_then_ctrl_c)
    # 1 µs slices: 8802 updates, far more than run in 0.5 s.
    assert main(_track(tmp_path, "--batch-us", "1", "--quiet")) == 130
    assert "interrupted" in capsys.readouterr().err
    s = json.loads((tmp_path / "t" / "summary.json").read_text())
    assert s["interrupted"] is True and 0 < s["n_updates"] < 8802
    assert len(np.loadtxt(tmp_path / "t" / "poses.csv", delimiter=",", skiprows=1)) == s["n_updates"]


def test_track_on_a_corrupt_raw_file_exits_2_with_a_message(tmp_path, capsys):
    from evservo.cli import main

    cut = _copy(tmp_path, "cut.raw", lambda b: b[:-1])
    args = _track(tmp_path, "--quiet")
    args[1] = str(cut)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.splitlines()[-1].startswith("evservo: error:") and "Traceback" not in err
