"""The rerun viewer: a tracking run written to an .rrd and read back with rerun's own CLI
(``rerun rrd print``) holds one frame per 33 ms of sensor time, every stream the viewer promises,
and the same tracking errors as poses.csv; so does a run of the real loop. Without rerun-sdk (an
optional extra; CI installs it: make test VIEWER=1), the options fail with an install hint."""

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from evservo import viewer
from evservo.cli import main


@pytest.fixture(scope="module")
def small_rec(tmp_path_factory):
    """A 0.2 s quarter-scale (320x180) recording of the box."""
    out = tmp_path_factory.mktemp("rec") / "small.h5"
    assert main(["sim", "record", "--duration", "0.2", "--scale", "0.25", "--quiet", "--out", str(out)]) == 0
    return out


def _need_rerun() -> None:
    failed = Path(sys.prefix) / ".viewer-failed"
    why = f"; `make viewer` failed: {failed.read_text().strip()}" if failed.is_file() else ""
    pytest.importorskip("rerun", reason=f"rerun-sdk is an optional extra (pip install 'evservo[viewer]'){why}")


def _rrd_print(path: Path, verbosity: str) -> str:
    rerun = Path(sys.executable).parent / "rerun"
    res = subprocess.run(
        [str(rerun), "rrd", "print", verbosity, str(path)], capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 0, res.stderr
    return res.stdout


def _rows_per_entity(summary: str) -> dict[str, int]:
    rows: dict[str, int] = {}
    for n, entity in re.findall(r"with (\d+) rows .*? - (/\S+) - data columns", summary):
        rows[entity] = rows.get(entity, 0) + int(n)
    return rows


def _scalars(dump: str, entity: str) -> dict[float, float]:
    """``{sensor time (s): value}`` of a Scalars entity in ``rerun rrd print -vvv`` output."""
    out = {}
    for block in dump.split("Chunk(")[1:]:
        if f"entity_path: {entity} " not in block:
            continue
        for t, v in re.findall(r"┆\s*(P\S+)\s*┆\s*\[([^\]]+)\]", block):
            out[0.0 if t == "P0D" else float(t.removeprefix("PT").removesuffix("S"))] = float(v)
    return out


def test_tracking_run_reads_back_from_the_rrd(small_rec, tmp_path):
    _need_rerun()
    rrd = tmp_path / "run.rrd"
    assert main(["track", str(small_rec), "--quiet", "--out", str(tmp_path / "o"), "--viewer-save", str(rrd)]) == 0
    poses = np.genfromtxt(tmp_path / "o" / "poses.csv", delimiter=",", names=True)
    # One frame at the first update and at the first update of every later 33 333 µs bin.
    frames = len(np.unique(poses["t_us"].astype(np.int64) // viewer.DEFAULT_PERIOD_US))
    assert frames >= 6
    rows = _rows_per_entity(_rrd_print(rrd, "-v"))
    streams = ("/camera/events", "/camera/sstar", "/field/distance", "/field/sstar", "/world/object",
               "/world/object_true", "/errors/track_pos_mm", "/errors/track_rot_deg", "/tracking/lost")  # fmt: skip
    for entity in streams:
        assert rows.get(entity) == frames, (entity, rows)
    assert rows["/world/camera"] == frames + 1  # the pinhole, static, plus one pose per frame
    logged = _scalars(_rrd_print(rrd, "-vvv"), "/errors/track_pos_mm")
    assert len(logged) == frames
    by_time = {round(t * 1e-6, 6): e for t, e in zip(poses["t_us"], poses["pos_err_mm"], strict=True)}
    for t_s, err_mm in logged.items():
        assert err_mm == pytest.approx(by_time[round(t_s, 6)], abs=1e-4)  # poses.csv keeps 4 decimals


def test_without_rerun_the_options_fail_with_an_install_hint(small_rec, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun now raises ImportError
    with pytest.raises(ValueError, match=r"pip install 'evservo\[viewer\]'"):
        viewer.open_viewer("rerun", None)
    assert viewer.open_viewer(None, None) is None
    assert main(["track", str(small_rec), "--quiet", "--out", str(tmp_path / "o"), "--viewer", "rerun"]) == 2
    assert "pip install 'evservo[viewer]'" in capsys.readouterr().err


def test_viewer_options_are_checked(tmp_path):
    with pytest.raises(ValueError, match=r"\.rrd file name"):
        viewer.open_viewer(None, tmp_path / "run.txt")
    with pytest.raises(ValueError, match="unknown viewer"):
        viewer.open_viewer("foxglove", tmp_path / "run.rrd")


def _translations(dump: str, entity: str) -> dict[float, np.ndarray]:
    """``{sensor time (s): translation}`` of a Transform3D entity in ``rerun rrd print -vvv`` output."""
    out = {}
    for block in dump.split("Chunk(")[1:]:
        if f"entity_path: {entity} " not in block:
            continue
        for t, xyz in re.findall(r"┆\s*(P\S+)\s*┆[^\n]*┆\s*\[\[([^\]]+)\]\]\s*│", block):
            out[0.0 if t == "P0D" else float(t.removeprefix("PT").removesuffix("S"))] = np.array(
                [float(v) for v in xyz.split(",")]
            )
    return out


def test_real_loop_run_reads_back_from_the_rrd(tmp_path):
    """``servo --robot sim`` on a replayed recording with ``--viewer-save``: the viewer thread logs
    whole frames (no distance field: the threaded tracker keeps it), the plotted servo error is the
    distance between the logged object and desired-object frames, and it is the recording's truth's
    within the tracking error."""
    _need_rerun()
    from evservo.sim.record import gt_at, load_recording

    rec_path = tmp_path / "rec.h5"
    assert main(["sim", "record", "--duration", "0.6", "--scale", "0.25", "--quiet", "--out", str(rec_path)]) == 0
    rrd, out = tmp_path / "run.rrd", tmp_path / "o"
    args = ["servo", "--robot", "sim", "--camera", str(rec_path), "--settle", "0.1", "--duration", "5", "--rate",
            "100", "--stale-after", "0.5", "--out", str(out), "--viewer-save", str(rrd)]  # fmt: skip
    # 0: the recording ended; 1: the loop's watchdog stopped it (on a loaded machine the tracker may
    # jump): either way the viewer recorded the servoing there was.
    assert main(args) in (0, 1)
    assert json.loads((out / "summary.json").read_text())["control_cycles"] > 0
    rows = _rows_per_entity(_rrd_print(rrd, "-v"))
    frames = rows.get("/errors/servo_pos_mm", 0)
    assert frames >= 1, rows
    for entity in ("/camera/events", "/camera/sstar", "/world/object", "/world/object_desired", "/tracking/lost"):
        assert rows.get(entity) == frames, (entity, rows)
    assert rows["/world/camera"] == frames + 1  # the pinhole, static, plus one pose per frame
    assert "/field/distance" not in rows
    dump = _rrd_print(rrd, "-vvv")
    errors = _scalars(dump, "/errors/servo_pos_mm")
    obj, des = _translations(dump, "/world/object"), _translations(dump, "/world/object_desired")
    assert len(errors) == len(obj) == len(des) == frames
    rec = load_recording(rec_path)
    T_des = np.array(json.loads((out / "summary.json").read_text())["T_c_o_des"])
    for t_s, err_mm in errors.items():
        assert err_mm == pytest.approx(np.linalg.norm(obj[t_s] - des[t_s]) * 1e3, abs=1e-3)  # float32 frames
        truth_mm = np.linalg.norm(gt_at(rec.gt_t_us, rec.gt_T, np.array([round(t_s * 1e6)]))[0][:3, 3] - T_des[:3, 3])
        assert err_mm == pytest.approx(truth_mm * 1e3, abs=25.0)  # the tracker's error on this recording: ~4-15 mm
