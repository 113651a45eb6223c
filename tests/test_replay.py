"""Rust-side file replay (``Tracker.replay``): the same events reach ingest as through the Python
push path, and bad files, stopped trackers and stop requests end it cleanly."""

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
