"""The rerun viewer: a tracking run written to an .rrd and read back with rerun's own CLI
(``rerun rrd print``) holds one frame per 33 ms of sensor time, every stream the viewer promises,
and the same tracking errors as poses.csv. Without rerun-sdk (an optional extra, not in CI), the
options fail with an install hint."""

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
    pytest.importorskip("rerun", reason="rerun-sdk is an optional extra (pip install 'evservo[viewer]')")
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


def test_the_real_loop_refuses_the_viewer(tmp_path, capsys):
    args = ["servo", "--robot", "sim", "--camera", "x.raw", "--viewer-save", str(tmp_path / "r.rrd")]
    assert main(args) == 2
    assert "not yet to the real loop" in capsys.readouterr().err
