"""Live event sources: replay pacing, the iniVation no-camera path, missing driver packages."""

from __future__ import annotations

import sys
import time
import types

import numpy as np
import pytest

from evservo import io
from evservo.cameras import (
    CameraNotFoundError,
    EventSource,
    InivationCamera,
    PropheseeCamera,
    ReplaySource,
    dv_store_to_cd,
    open_camera,
)
from evservo.io import EVENT_CD


@pytest.fixture
def recording(tmp_path):
    """1 s of events, one every 100 µs, starting at t = 5 003 000 µs, on a 64×48 sensor."""
    n = 10_000
    ev = np.zeros(n, dtype=EVENT_CD)
    ev["t"] = 5_003_000 + 100 * np.arange(n)
    ev["x"] = np.arange(n) % 64
    ev["y"] = np.arange(n) % 48
    ev["p"] = np.arange(n) % 2
    path = tmp_path / "rec.npz"
    io.write_events(path, ev, 64, 48)
    return path, ev


def test_replay_paces_batches_against_the_wall_clock(recording):
    path, ev = recording
    src = ReplaySource(path, speed=10.0, delta_t_us=10_000)
    assert isinstance(src, EventSource) and (src.width, src.height) == (64, 48)
    got, times = [], []
    start = time.monotonic()
    for batch in src:
        times.append(time.monotonic() - start)
        got.append(batch)
    total = time.monotonic() - start
    # The recording lasts 1 s: at ×10 it plays in ~0.1 s (generous bounds for a loaded machine).
    assert 0.09 <= total < 0.6
    np.testing.assert_array_equal(np.concatenate(got), ev)
    # Each batch comes out no earlier than the (scaled) recording time of its end.
    ends_us = np.array([(int(b["t"][-1]) // 10_000 + 1) * 10_000 for b in got])
    due_s = (ends_us - int(ev["t"][0])) * 1e-6 / 10.0
    assert np.all(np.array(times) >= due_s - 0.005)
    assert np.median(np.array(times) - due_s) < 0.02


def test_replay_of_a_slow_consumer_falls_behind_without_dropping(recording):
    path, ev = recording
    src = ReplaySource(path, speed=100.0, delta_t_us=5_000)  # a batch due every 50 µs of wall time
    n = 0
    for batch in src:
        n += len(batch)
        time.sleep(0.001)
    assert n == len(ev) and src.lag_s > 0.0


def test_replay_rejects_bad_arguments(recording, tmp_path):
    path, _ = recording
    with pytest.raises(ValueError, match="speed"):
        ReplaySource(path, speed=0.0)
    with pytest.raises(ValueError, match="delta_t_us"):
        ReplaySource(path, delta_t_us=0)
    with pytest.raises(FileNotFoundError):
        ReplaySource(tmp_path / "missing.npz")


def test_missing_driver_packages_are_named(monkeypatch):
    # A None entry in sys.modules makes the import fail, whether or not the package is installed.
    monkeypatch.setitem(sys.modules, "metavision_core", None)
    monkeypatch.setitem(sys.modules, "metavision_core.event_io", None)
    monkeypatch.setitem(sys.modules, "dv_processing", None)
    with pytest.raises(ImportError, match="metavision_core"):
        PropheseeCamera()
    with pytest.raises(ImportError, match="dv-processing"):
        open_camera("inivation")
    with pytest.raises(ValueError, match="unknown camera kind"):
        open_camera("kinect")


def test_inivation_without_a_camera_says_so():
    pytest.importorskip("dv_processing", reason="needs dv-processing")
    with pytest.raises(CameraNotFoundError, match="no iniVation camera"):
        InivationCamera()


def test_dv_event_store_converts_to_event_cd():
    dv = pytest.importorskip("dv_processing", reason="needs dv-processing")
    store = dv.EventStore()
    store.push_back(1000, 3, 4, True)
    store.push_back(1500, 639, 479, False)
    out = dv_store_to_cd(store)
    assert out.dtype == EVENT_CD
    assert out.tolist() == [(3, 4, 1, 1000), (639, 479, 0, 1500)]


def test_prophesee_adapter_against_a_stand_in_of_openeb(monkeypatch):
    """OpenEB is not installable here; a stand-in with the documented EventsIterator interface checks
    how the adapter calls it (live camera by serial, delta_t slices) and reads (height, width)."""
    calls = {}
    # OpenEB's EventCD, field for field (x u2, y u2, p i2, t i8), but packed: converted on the way.
    packed = np.dtype([("x", "<u2"), ("y", "<u2"), ("p", "<i2"), ("t", "<i8")])

    class EventsIterator:
        def __init__(self, input_path, mode, delta_t):
            calls.update(input_path=input_path, mode=mode, delta_t=delta_t)

        def get_size(self):
            return (720, 1280)

        def __iter__(self):
            yield np.array([(1, 2, 1, 10), (3, 4, 0, 20)], dtype=packed)
            yield np.zeros(0, dtype=EVENT_CD)

    event_io = types.ModuleType("metavision_core.event_io")
    event_io.EventsIterator = EventsIterator
    monkeypatch.setitem(sys.modules, "metavision_core", types.ModuleType("metavision_core"))
    monkeypatch.setitem(sys.modules, "metavision_core.event_io", event_io)
    with PropheseeCamera(serial="00ca0009", delta_t_us=2000) as cam:
        assert calls == {"input_path": "00ca0009", "mode": "delta_t", "delta_t": 2000}
        assert (cam.width, cam.height) == (1280, 720)
        batches = list(cam)
    assert all(b.dtype == EVENT_CD for b in batches)
    assert batches[0].tolist() == [(1, 2, 1, 10), (3, 4, 0, 20)] and len(batches[1]) == 0


def test_open_source_names_live_cameras_and_files(recording, monkeypatch, tmp_path):
    from evservo.cameras import open_source

    path, _ = recording
    src = open_source(str(path), speed=4.0)
    assert isinstance(src, ReplaySource) and src.speed == 4.0 and (src.width, src.height) == (64, 48)
    with pytest.raises(FileNotFoundError, match="prophesee"):
        open_source(str(tmp_path / "missing.raw"))
    with pytest.raises(ValueError, match="files only"):
        open_source("dv", speed=2.0)
    monkeypatch.setitem(sys.modules, "metavision_core", None)
    monkeypatch.setitem(sys.modules, "metavision_core.event_io", None)
    with pytest.raises(ImportError, match="metavision_core"):
        open_source("prophesee:00ca0009")
    opened = []
    monkeypatch.setattr("evservo.cameras.open_camera", lambda kind, serial=None: opened.append((kind, serial)))
    open_source("dv:DXA000123")
    open_source("Prophesee")
    assert opened == [("inivation", "DXA000123"), ("prophesee", None)]
