"""No lost work: bad outputs fail before the run, Ctrl-C leaves partial outputs marked interrupted (exit
130) and never an earlier run's summary, writers replace files atomically, and an interrupted
recording is refused instead of misread."""

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from evservo import io
from evservo.cli import main
from evservo.control import Pbvs
from evservo.interrupt import StopOnInterrupt
from evservo.outputs import OutputError, atomic_path, check_out_file, prepare_out_dir, read_json
from evservo.tracking import Tracker


@pytest.fixture(scope="module")
def small_rec(tmp_path_factory):
    """A 0.3 s quarter-scale (320x180) recording of the box."""
    out = tmp_path_factory.mktemp("rec") / "small.h5"
    args = ["sim", "record", "--duration", "0.3", "--scale", "0.25", "--quiet", "--out", str(out)]
    assert main(args) == 0
    return out


@pytest.mark.parametrize(
    "args",
    [
        ["track", "{rec}", "--quiet", "--out", "{file}"],
        ["servo", "--sim", "--duration", "0.5", "--out", "{file}"],
        ["servo", "--robot", "sim", "--camera", "{rec}", "--duration", "0.5", "--out", "{file}"],
        ["bench", "--suite", "paper", "--quick", "--out", "{file}"],
        ["bench", "--suite", "latency", "--quick", "--out", "{file}/sub"],
        ["bench", "--suite", "latency", "--quick", "--out", "{dir}/b", "--results", "{dir}"],
        ["sim", "record", "--duration", "0.3", "--out", "{dir}"],
        ["sim", "record", "--duration", "0.3", "--out", "{file}/x.h5"],
    ],
)
def test_an_unusable_out_fails_at_once_with_exit_2(args, small_rec, tmp_path, capsys, monkeypatch):
    import evservo.sim.episode
    import evservo.sim.record

    def must_not_run(*_a, **_k):
        raise AssertionError("the run started although --out is unusable")

    monkeypatch.setattr(evservo.sim.episode, "run_episode", must_not_run)
    monkeypatch.setattr(evservo.sim.record, "_EventWriter", must_not_run)
    monkeypatch.setattr("evservo.robots.kinematic.KinematicArm", must_not_run)
    monkeypatch.setattr("evservo.tracking.Tracker.__init__", must_not_run)
    file = tmp_path / "taken"
    file.write_text("precious\n")
    started = time.perf_counter()
    code = main([a.format(rec=small_rec, file=file, dir=tmp_path) for a in args])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith(("evservo: error: --out", "evservo: error: --results")) and "Traceback" not in err
    assert time.perf_counter() - started < 5.0
    assert file.read_text() == "precious\n"


def test_out_checks_name_the_problem(tmp_path):
    f = tmp_path / "f"
    f.write_text("x")
    with pytest.raises(OutputError, match="exists and is not a directory"):
        prepare_out_dir(f)
    with pytest.raises(OutputError, match="is a file, not a directory"):
        prepare_out_dir(f / "a" / "b")
    with pytest.raises(OutputError, match="is a directory"):
        check_out_file(tmp_path, (".h5",))
    with pytest.raises(OutputError, match=r"want a \.h5 file name"):
        check_out_file(tmp_path / "x.txt", (".h5",))
    # A missing directory is fine and is not created by the check (bad inputs leave nothing behind).
    assert prepare_out_dir(tmp_path / "new" / "dir") == tmp_path / "new" / "dir"
    assert not (tmp_path / "new").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_an_unwritable_out_is_refused(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(OutputError, match="not writable"):
            prepare_out_dir(ro / "out")
    finally:
        ro.chmod(0o700)


def test_summaries_are_strict_json_and_read_back_with_their_non_finite_figures(tmp_path):
    """A run that never re-locked has an infinite re-lock time and no lag (NaN): its summary.json must
    still be JSON that any parser takes (bare Infinity/NaN are not), and read back as those floats."""
    from evservo.runtime.report import write_summary

    summary = {"loss": {"relock_ms": float("inf"), "detection_ms": None}, "lag_s": np.float64("nan"),
               "cw": [np.float32(2.5), -np.inf], "n": np.int64(3), "name": "x"}  # fmt: skip
    path = write_summary(tmp_path / "summary.json", summary)

    def refuse(constant: str) -> None:
        raise ValueError(f"not strict JSON: {constant}")

    json.loads(path.read_text(), parse_constant=refuse)
    back = read_json(path)
    assert back["loss"] == {"relock_ms": float("inf"), "detection_ms": None}
    assert np.isnan(back["lag_s"]) and back["cw"] == [2.5, float("-inf")] and back["n"] == 3 and back["name"] == "x"


def _interrupt_on_call(monkeypatch, owner: object, name: str, n: int) -> None:
    """Wrap ``owner.name`` so that its ``n``-th call sends this process SIGINT, as Ctrl-C would."""
    original = getattr(owner, name)
    calls = [0]

    def wrapped(*a, **k):
        calls[0] += 1
        if calls[0] == n:
            os.kill(os.getpid(), signal.SIGINT)
        return original(*a, **k)

    monkeypatch.setattr(owner, name, wrapped)


def test_ctrl_c_in_track_writes_a_partial_summary_and_exits_130(small_rec, tmp_path, capsys, monkeypatch):
    out = tmp_path / "t"
    out.mkdir()
    (out / "summary.json").write_text('{"stale": true}')
    (out / "overlay.png").write_text("stale")
    _interrupt_on_call(monkeypatch, Tracker, "update", 50)
    assert main(["track", str(small_rec), "--quiet", "--out", str(out)]) == 130
    assert "interrupted" in capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    # The SIGINT arrived during update 50; that update completes and the loop stops before the next.
    assert s["interrupted"] is True and s["n_updates"] == 50
    assert len(np.loadtxt(out / "poses.csv", delimiter=",", skiprows=1)) == 50
    assert (out / "overlay.png").read_bytes()[:4] == b"\x89PNG"
    assert s["gt_track_pos_rms_mm"] is not None  # scored over the part that ran


def test_a_track_that_stops_early_leaves_no_stale_summary(small_rec, tmp_path, monkeypatch):
    out = tmp_path / "t"
    out.mkdir()
    (out / "summary.json").write_text('{"stale": true}')

    def dies(*_a, **_k):
        raise KeyboardInterrupt  # a second Ctrl-C in the middle of an update

    monkeypatch.setattr("evservo.tracking.Tracker.update", dies)
    assert main(["track", str(small_rec), "--quiet", "--out", str(out)]) == 130
    assert not (out / "summary.json").exists()


def test_ctrl_c_in_servo_sim_writes_a_partial_summary_and_exits_130(tmp_path, capsys, monkeypatch):
    out = tmp_path / "s"
    out.mkdir()
    (out / "summary.json").write_text('{"stale": true}')
    # Pbvs.update runs every control period (2 ms): the 100th call is at t = 198 ms.
    _interrupt_on_call(monkeypatch, Pbvs, "update", 100)
    assert main(["servo", "--sim", "--duration", "2", "--out", str(out)]) == 130
    assert "interrupted" in capsys.readouterr().err
    s = json.loads((out / "summary.json").read_text())
    assert s["interrupted"] is True and not s["completed"] and s["ended"] == "interrupted (Ctrl-C)"
    assert s["simulated_s"] == pytest.approx(0.199)
    assert len((out / "log.csv").read_text().splitlines()) > 10


@pytest.mark.parametrize("when", ["stopping", "writing"])
def test_ctrl_c_after_the_real_loop_ended_still_stops_everything_and_writes_the_outputs(
    small_rec, tmp_path, capsys, monkeypatch, when
):
    """A Ctrl-C that lands once servoing is over (on a loaded machine a user's Ctrl-C can arrive while
    the loop stops the camera pump, or while the figure is drawn) asks for what is already happening:
    the stop completes, the outputs are written, the exit code says Ctrl-C."""
    from evservo import realloop

    owner, name = (realloop._CameraPump, "halt") if when == "stopping" else (realloop, "summarize")
    _interrupt_on_call(monkeypatch, owner, name, 1)
    threads = {t.ident for t in threading.enumerate()}
    out = tmp_path / "o"
    args = ["servo", "--robot", "sim", "--camera", str(small_rec), "--settle", "0.05", "--out", str(out)]
    assert main(args) == 130
    s = read_json(out / "summary.json")
    assert s["completed"] and s["control_cycles"] > 0 and s["interrupted"] == (when == "stopping")
    assert (out / "motion.png").read_bytes()[:4] == b"\x89PNG" and (out / "log.csv").is_file()
    assert "Traceback" not in capsys.readouterr().err
    # The tracker and camera threads ended with the run.
    assert {t.ident for t in threading.enumerate() if t.is_alive()} <= threads


def test_a_second_ctrl_c_raises_at_once():
    with StopOnInterrupt() as stop:
        os.kill(os.getpid(), signal.SIGINT)
        assert stop.requested
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def _children(pid: int) -> set[int]:
    out = set()
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            if ppid == pid:
                out.add(int(d.name))
    return out


def test_ctrl_c_stops_the_parallel_paper_suite(tmp_path):
    """Ctrl-C goes to the whole process group (parent and workers): one is enough, the workers end,
    and no interrupted episode is saved as finished."""
    cmd = [sys.executable, "-m", "evservo.cli", "bench", "--suite", "paper", "--quick", "--jobs", "2",
           "--out", str(tmp_path)]  # fmt: skip
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 60
        while len(_children(proc.pid)) < 2 and time.monotonic() < deadline:
            time.sleep(0.2)
        workers = _children(proc.pid)
        assert len(workers) >= 2, "the pool did not start"
        time.sleep(4.0)  # the workers are inside their first episodes
        os.killpg(proc.pid, signal.SIGINT)
        code = proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    err = proc.stderr.read().decode()
    assert code == 130, err
    assert "Traceback" not in err
    time.sleep(0.5)
    assert not [w for w in workers if Path(f"/proc/{w}").exists() and "Z" not in _state(w)], "workers live on"
    for summary in (tmp_path / "episodes").glob("*/summary.json"):
        assert json.loads(summary.read_text())["completed"] in (True, False)
        assert not json.loads(summary.read_text())["interrupted"]


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "gone"


def test_write_events_replaces_atomically(tmp_path, monkeypatch):
    ev = np.zeros(3, dtype=io.EVENT_CD)
    ev["t"] = [1, 2, 3]
    for name in ("a.npz", "a.npy", "a.h5"):
        path = tmp_path / name
        io.write_events(path, ev, 4, 4)
        before = path.read_bytes()

        def dies(p, *_a):
            Path(p).write_bytes(b"half")
            raise KeyboardInterrupt

        monkeypatch.setattr(io, "_write_to", dies)
        with pytest.raises(KeyboardInterrupt):
            io.write_events(path, np.concatenate([ev, ev]), 4, 4)
        monkeypatch.undo()
        assert path.read_bytes() == before
        assert len(io.read_events(path)) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5", "a.npy", "a.npz"]  # no temporary left
    (tmp_path / "d.h5").mkdir()
    with pytest.raises(ValueError, match="is a directory"):
        io.write_events(tmp_path / "d.h5", ev, 4, 4)


def test_an_interrupted_sim_record_keeps_the_previous_file(small_rec, tmp_path, monkeypatch):
    import evservo.sim.record as record

    out = tmp_path / "r.h5"
    out.write_bytes(small_rec.read_bytes())
    calls = [0]
    original = record.substep_times

    def interrupted(*a, **k):
        calls[0] += 1
        if calls[0] == 20:
            raise KeyboardInterrupt
        return original(*a, **k)

    monkeypatch.setattr(record, "substep_times", interrupted)
    assert main(["sim", "record", "--duration", "0.3", "--scale", "0.25", "--quiet", "--out", str(out)]) == 130
    assert out.read_bytes() == small_rec.read_bytes()
    assert [p.name for p in tmp_path.iterdir()] == ["r.h5"]


def test_an_incomplete_recording_is_refused(small_rec, tmp_path, capsys):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(small_rec.read_bytes())
    with h5py.File(bad, "a") as f:
        assert f.attrs["evservo_complete"] == 1
        f.attrs["evservo_complete"] = 0
    assert main(["track", str(bad), "--quiet", "--out", str(tmp_path / "t")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("evservo: error:") and "incomplete recording" in err
    with pytest.raises(io.DecodeError, match="incomplete recording"):
        io.info(bad)


def test_atomic_path_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "x.txt"
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("partial")
        raise RuntimeError("writer failed")
    assert list(tmp_path.iterdir()) == []
    with atomic_path(target) as tmp:
        tmp.write_text("whole")
    assert target.read_text() == "whole" and oct(target.stat().st_mode & 0o777) != "0o600"
