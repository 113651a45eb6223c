"""The threaded tracker's states under hostile use: fork, absurd times, concurrent start/stop,
failed thread spawns, reads before the first update, live counters."""

import os
import subprocess
import sys
import threading
import time
import warnings

import numpy as np
import pytest

import evservo
from conftest import box_start_pose
from evservo.events import EVENT_CD
from evservo.tracking import model_point_set


@pytest.fixture(scope="module")
def still_box(camera):
    """The box at rest: its edge pixels (in random order) and the pose."""
    T = box_start_pose(0.6)
    dense = model_point_set(camera, "box", T, n_points=30000, seed=3)
    uv = camera.project(dense @ T[:3, :3].T + T[:3, 3])
    px = np.unique(np.floor(uv + 0.5).astype(np.int64), axis=0)
    px = px[(px[:, 0] >= 0) & (px[:, 0] < camera.width) & (px[:, 1] >= 0) & (px[:, 1] < camera.height)]
    return T, px[np.random.default_rng(0).permutation(len(px))]


def batch(px: np.ndarray, t0: int, span_us: int = 1000) -> np.ndarray:
    ev = np.zeros(len(px), dtype=EVENT_CD)
    ev["x"], ev["y"], ev["p"] = px[:, 0], px[:, 1], 1
    ev["t"] = t0 + np.arange(len(px)) * span_us // len(px)
    return ev


def wait_for(cond, timeout_s: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.001)
    return True


def test_not_locked_before_the_first_update(camera, still_box):
    T, px = still_box
    trk = evservo.Tracker(camera, "box", T)
    est = trk.latest()
    assert est.lost and est.seq == 0 and est.inlier_fraction == 0.0
    est = trk.update(batch(px, 0))
    assert not est.lost and est.inlier_fraction > 0.5
    trk.reset_pose(T)
    assert trk.latest().lost, "a pose set by hand is not yet confirmed by events"


def test_absurd_times_are_refused_and_a_reset_restarts_the_time_line(camera, still_box):
    T, px = still_box
    trk = evservo.Tracker(camera, "box", T)
    with trk:
        trk.start()
        bad = batch(px, 0)
        bad["t"][-1] = 2**63 - 1
        with pytest.raises(ValueError, match="corrupt"):
            trk.push(bad)
        trk.push(batch(px, 1000))  # the refused batch left no trace in the time line
        with pytest.raises(ValueError, match="backwards"):
            trk.push(batch(px, 0))
        trk.reset_events()
        trk.push(batch(px, 0))
        assert wait_for(lambda: trk.latest().t_us == 999 and trk.stats()["lm_steps"] > 0)
    assert trk.stats()["events_offered"] == 2 * len(px)


def test_stats_are_live_while_the_thread_runs(camera, still_box):
    T, px = still_box
    trk = evservo.Tracker(camera, "box", T, ingest_core_share=None)
    with trk:
        trk.start()
        for k in range(5):
            trk.push(batch(px, 1000 * k))
        assert wait_for(lambda: trk.stats()["search_steps"] >= 4)
        s = trk.stats()
        assert s["lm_steps"] >= 1 and s["search_seconds"] > 0
        assert s["events_offered"] == s["events_ingested"] == 5 * len(px)
        assert wait_for(lambda: trk.latest().t_us == 4999)
        assert not trk.latest().lost


def test_latency_is_booked_for_every_batch_and_bounds_each_pose(camera, still_box):
    T, px = still_box
    trk = evservo.Tracker(camera, "box", T, ingest_core_share=None)
    assert trk.latency()["oldest_n"] == trk.latency()["batch_n"] == 0 and trk.latency()["batch_p99_s"] is None
    with trk:
        trk.start()
        pushed = []
        for k in range(20):
            pushed.append(time.perf_counter())
            trk.push(batch(px, 1000 * k))
            time.sleep(0.002)
        assert wait_for(lambda: trk.latest().t_us == 19_999)
        waited = time.perf_counter() - pushed[0]
        lat = trk.latency()
        est = trk.latest()
    # Every batch is booked once under the oldest stamp and once at its own latency, which lies
    # between the newest stamp's and the bound; at most one sample per batch newest.
    assert lat["oldest_n"] == lat["batch_n"] == 20 and 1 <= lat["newest_n"] <= 20
    assert 0 < lat["oldest_p50_s"] <= lat["oldest_p99_s"] <= lat["oldest_max_s"] <= waited
    assert 0 < lat["batch_p50_s"] <= lat["batch_p99_s"] <= lat["batch_max_s"] <= lat["oldest_max_s"]
    assert lat["batch_p50_s"] <= lat["oldest_p50_s"]
    assert lat["newest_max_s"] <= lat["batch_max_s"]
    # A pose's oldest batch is no newer than its newest one.
    if est.oldest_latency_s is not None:
        assert est.oldest_pushed_ns <= est.pushed_ns and est.oldest_latency_s >= est.latency_s


def test_latest_and_push_race_start_and_stop_without_borrow_errors(camera, still_box):
    T, px = still_box
    trk = evservo.Tracker(camera, "box", T)
    errors: list[BaseException] = []
    done = threading.Event()

    def producer() -> None:
        t = 0
        while not done.is_set():
            try:
                trk.latest()
                trk.stats()
                trk.push(batch(px[:500], t))
                t += 1000
            except RuntimeError as e:
                if "call start() first" not in str(e):  # pushing while stopped is a clear error
                    errors.append(e)
            except BaseException as e:  # any other failure is the defect
                errors.append(e)

    th = threading.Thread(target=producer)
    th.start()
    try:
        for _ in range(40):
            trk.start()
            time.sleep(0.002)
            trk.latest()
            trk.stop()
    finally:
        done.set()
        th.join()
    assert not errors, errors[:3]
    assert trk.stats()["events_offered"] > 0


def test_fork_with_a_running_thread_leaves_a_usable_child(camera, still_box):
    T, px = still_box
    trk = evservo.Tracker(camera, "box", T)
    trk.start()
    trk.push(batch(px, 0))
    assert wait_for(lambda: trk.latest().seq > 0)
    pid = os.fork()
    if pid == 0:  # the child: report through the exit code, never return into pytest
        code = 1
        try:
            assert not trk.running, "the thread does not exist here"
            try:
                trk.push(batch(px, 1000))
                code = 2
            except RuntimeError as e:
                assert "fork" in str(e)
                trk.stop()  # recovers a synchronous tracker at the last pose
                trk.start()
                trk.push(batch(px, 2000))
                seq = trk.latest().seq
                assert wait_for(lambda: trk.latest().seq > seq, 10.0)
                trk.stop()
                code = 0
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0
    assert trk.running
    trk.push(batch(px, 1000))
    trk.stop()


CHILD_SPAWN_FAILS = """
import resource, sys
import numpy as np
import evservo
sys.path.insert(0, {tests!r})
from conftest import box_start_pose
trk = evservo.Tracker(evservo.Camera.imx636(), "box", box_start_pose(0.6))
vm = next(int(l.split()[1]) * 1024 for l in open("/proc/self/status") if l.startswith("VmSize"))
soft, hard = resource.getrlimit(resource.RLIMIT_AS)
resource.setrlimit(resource.RLIMIT_AS, (vm + (1 << 20), hard))
try:
    trk.start()
    print("started")
except RuntimeError as e:
    print("failed:", e)
resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
print("running", trk.running, "lost", trk.latest().lost)
trk.start()
print("running", trk.running)
trk.stop()
"""


def test_a_failed_thread_spawn_leaves_the_tracker_usable():
    code = CHILD_SPAWN_FAILS.format(tests=os.path.dirname(__file__))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("failed:") and "could not start the tracker thread" in lines[0], out.stdout
    assert lines[1:] == ["running False lost True", "running True"], out.stdout


def test_start_pins_the_solver_and_asks_for_real_time_priority(camera, still_box):
    T, px = still_box
    trk = evservo.Tracker(camera, "box", T)
    with pytest.raises(ValueError, match="unknown priority"):
        trk.start(priority="urgent")
    with pytest.raises(ValueError, match="not among"):
        trk.start(cpu=100_000)
    assert not trk.running
    cpu = min(os.sched_getaffinity(0))
    with trk:
        assert trk.start(cpu=cpu) == "normal"
        assert os.sched_getaffinity(trk._core.solver_thread_id) == {cpu}
        trk.push(batch(px, 0))
        assert wait_for(lambda: trk.latest().seq >= 5)
    with trk, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = trk.start(priority="high")
        tid = trk._core.solver_thread_id
        if got == "high":
            assert os.sched_getscheduler(tid) == os.SCHED_FIFO
        else:  # refused by the OS: said so, and the thread runs normally
            assert any("SCHED_FIFO" in str(w.message) for w in caught)
            assert os.sched_getscheduler(tid) == os.SCHED_OTHER
        trk.push(batch(px, 1000))
        assert wait_for(lambda: trk.latest().t_us == 1999)


def test_a_normal_solver_started_from_a_real_time_thread_runs_normally(camera, still_box):
    # Threads inherit their creator's policy: a caller at SCHED_FIFO (libfranka raises the thread
    # that connects) would otherwise get a solver spinning at real-time priority.
    T, _ = still_box
    trk = evservo.Tracker(camera, "box", T)
    seen: list[tuple[str, int]] = []

    def from_real_time() -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        except PermissionError:
            seen.append(("refused", -1))
            return
        with trk:
            seen.append((trk.start(), os.sched_getscheduler(trk._core.solver_thread_id)))

    th = threading.Thread(target=from_real_time)  # not the test's own thread: its policy stays
    th.start()
    th.join()
    if seen == [("refused", -1)]:
        pytest.skip("the OS does not permit SCHED_FIFO here")
    assert seen == [("normal", os.SCHED_OTHER)]


def test_anti_flicker_drops_a_mains_lamp_and_tracking_holds(camera, still_box):
    """A 100 Hz lamp lights a band across the box (every lit pixel fires an ON and an OFF burst each
    10 ms); the box's edges fire every 1 ms. With the filter, the lamp's events are dropped once
    their rhythm shows and the pose stays on the box."""
    T, px = still_box
    rng = np.random.default_rng(5)
    lo, hi = px.min(axis=0), px.max(axis=0)
    lamp = np.stack(
        [rng.integers(lo[0], hi[0], 4000), rng.integers((lo[1] + hi[1]) // 2 - 20, (lo[1] + hi[1]) // 2 + 20, 4000)], 1
    )
    # Lit pixels that are also edge pixels fire off the lamp's rhythm and rightly pass: keep them apart.
    W = camera.width
    lamp = np.unique(lamp[:, 1] * W + lamp[:, 0])
    lamp = lamp[~np.isin(lamp, px[:, 1] * W + px[:, 0])]
    lamp = np.stack([lamp % W, lamp // W], 1)
    phase = rng.integers(0, 10_000, len(lamp))
    trk = evservo.Tracker(camera, "box", T, anti_flicker_hz=(100, 120))
    lamp_events = 0
    for k in range(300):
        t0 = 1000 * k
        edge = batch(px, t0)
        # Lamp bursts whose ON (OFF) time falls in this millisecond.
        fires = [(lamp[(phase + off) % 10_000 // 1000 == k % 10], p) for p, off in ((1, 0), (0, 5000))]
        parts = [edge]
        for where, p in fires:
            ev = np.zeros(len(where), dtype=EVENT_CD)
            ev["x"], ev["y"], ev["p"] = where[:, 0], where[:, 1], p
            ev["t"] = t0 + rng.integers(0, 1000, len(where))
            parts.append(ev)
        ev = np.concatenate(parts)
        ev = ev[np.argsort(ev["t"], kind="stable")]
        lamp_events += len(ev) - len(edge)
        est = trk.update(ev)
    s = trk.stats()
    # Each lamp pixel passes its first periods (≈ 3 of 30), the edges all their events.
    assert s["events_dropped"] > 0.85 * lamp_events, (s, lamp_events)
    assert not est.lost
    assert np.linalg.norm(est.T_c_o[:3, 3] - T[:3, 3]) < 2e-3
