"""Bad input ends in one ``evservo: error: …`` line (exit 2) or a clear Python exception: never a
traceback, a silent coercion or a misleading message (issue 10's list, one case each)."""

import os

import h5py
import numpy as np
import pytest
import trimesh

from evservo import geometry, io
from evservo.cli import main
from evservo.tracking import Tracker


@pytest.fixture(scope="module")
def small_rec(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec") / "small.h5"
    assert main(["sim", "record", "--duration", "0.2", "--scale", "0.25", "--quiet", "--out", str(out)]) == 0
    return out


@pytest.fixture()
def files(tmp_path):
    (tmp_path / "dir.csv").mkdir()
    (tmp_path / "dir.h5").mkdir()
    (tmp_path / "loop.h5").symlink_to(tmp_path / "loop.h5")
    os.mkfifo(tmp_path / "fifo.h5")
    (tmp_path / "neg.yaml").write_text("width: -640\nheight: 360\nfx: 300\nfy: 300\ncx: 160\ncy: 90\n")
    return tmp_path


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["servo", "--sim", "--seed", "-1", "--out", "{d}/o"], "seed must be >= 0"),
        (["sim", "record", "--seed", "-1", "--out", "{d}/a.h5"], "seed must be >= 0"),
        (["servo", "--sim", "--rot-rate", "nan", "--out", "{d}/o"], "rot_rate_dps must be finite"),
        (["sim", "record", "--rot-rate", "nan", "--out", "{d}/a.h5"], "rotation rate must be finite"),
        (["servo", "--sim", "--duration", "1e9", "--out", "{d}/o"], "duration must be at most"),
        (["sim", "record", "--duration", "1e9", "--out", "{d}/a.h5"], "duration must be at most"),
        (["servo", "--robot", "sim", "--camera", "{rec}", "--duration", "1e9", "--out", "{d}/o"], "control cycles"),
        (["servo", "--sim", "--trajectory", "{d}/dir.csv", "--out", "{d}/o"], "is a directory"),
        (["sim", "record", "--trajectory", "{d}/dir.csv", "--out", "{d}/a.h5"], "is a directory"),
        (["sim", "record", "--out", "{d}/dir.h5"], "is a directory"),
        (["track", "{rec}", "--camera", "{d}/neg.yaml", "--out", "{d}/o"], "width: must be a whole number of pixels"),
        (["track", "{rec}", "--max-seconds", "-1", "--out", "{d}/o"], "--max-seconds must be"),
        (["track", "{rec}", "--max-seconds", "nan", "--out", "{d}/o"], "--max-seconds must be"),
        (["track", "{d}/dir.h5", "--out", "{d}/o"], "is a directory, not a file"),
        (["track", "{d}/fifo.h5", "--out", "{d}/o"], "not a regular file"),
        (["track", "{d}/loop.h5", "--out", "{d}/o"], "symbolic links"),
        (["servo", "--robot", "sim", "--camera", "{d}/fifo.h5", "--out", "{d}/o"], "not a regular file"),
        (["track", "{rec}", "--init-pose", "0,0,0.001,0,0,0,1", "--out", "{d}/o"], "camera is inside the object"),
    ],
)
def test_bad_input_exits_2_with_one_clear_line(args, message, small_rec, files, capsys):
    code = main([a.format(d=files, rec=small_rec) for a in args])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("evservo: error:") and "Traceback" not in err
    assert message in err, err
    assert "no such" not in err


def test_an_object_filling_the_view_is_called_too_close(camera):
    with pytest.raises(ValueError, match="the object fills the view: it is too close"):
        Tracker(camera, "box", geometry.pose((0, 0, 0.05)))


def test_corrupt_bench_summary_is_named(tmp_path, capsys):
    from evservo.bench.paper import code_version, config_hash, episode_key, plan

    cfg = plan(quick=True)[0][1]
    bad = tmp_path / "episodes" / episode_key(cfg) / "summary.json"
    bad.parent.mkdir(parents=True)
    bad.write_text('{"completed": tru')
    # Stamped as this configuration and code's episode, so the suite takes it as finished.
    (bad.parent / "config_hash").write_text(config_hash(cfg, code_version()))
    assert main(["bench", "--suite", "paper", "--quick", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("evservo: error:") and str(bad) in err and "delete it" in err


def test_bench_cache_outside_the_objects_suite_is_refused(tmp_path, capsys):
    assert main(["bench", "--suite", "latency", "--cache", str(tmp_path / "c"), "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("evservo: error:") and "--cache applies to the objects suite only" in err
    assert not (tmp_path / "c").exists()


def _events(**overrides):
    ev = np.zeros(3, dtype=[("x", "f8"), ("y", "f8"), ("p", "i8"), ("t", "i8")])
    ev["x"], ev["y"], ev["p"], ev["t"] = [1, 2, 3], [1, 1, 1], [0, 1, 1], [10, 20, 30]
    for name, (i, v) in overrides.items():
        ev[name][i] = v
    return ev


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"x": (1, np.nan)}, "x holds NaN"),
        ({"x": (1, 2.5)}, "x holds fractional"),
        ({"x": (0, -1)}, r"x has values outside 0\.\.65535"),
        ({"p": (2, 70000)}, r"p has values outside -32768\.\.32767"),
    ],
)
def test_events_are_never_coerced(overrides, message, tmp_path, camera):
    ev = _events(**overrides)
    with pytest.raises(ValueError, match=message):
        io.write_events(tmp_path / "e.npz", ev, 640, 480)
    trk = Tracker(camera, "box", geometry.pose((0, 0, 0.6), (0.35, -0.45, 0.1)))
    with pytest.raises(ValueError, match=message):
        trk.update(ev)
    assert not (tmp_path / "e.npz").exists()
    # The same values in range convert exactly.
    clean = io.read_events(_written(tmp_path, _events()))
    assert clean.dtype == io.EVENT_CD and list(clean["x"]) == [1, 2, 3] and list(clean["p"]) == [0, 1, 1]


def _written(tmp_path, ev):
    path = tmp_path / "ok.npz"
    io.write_events(path, ev, 640, 480)
    return path


def test_hdf5_columns_of_different_lengths_are_refused(tmp_path):
    path = tmp_path / "ragged.h5"
    with h5py.File(path, "w") as f:
        g = f.create_group("events")
        g.attrs["width"], g.attrs["height"] = 640, 480
        for name, n in (("x", 5), ("y", 5), ("p", 5), ("t", 3)):
            g.create_dataset(name, data=np.zeros(n, io.EVENT_CD[name]))
    for read in (io.read_events, io.info, lambda p: list(io.open_events(p))):
        with pytest.raises(io.DecodeError, match="columns differ in length"):
            read(path)


@pytest.mark.parametrize("size", [(-640, 480), (640, 2**40), (0, 480)])
def test_bad_stored_sensor_sizes_are_refused(size, tmp_path):
    ev = np.zeros(2, io.EVENT_CD)
    h5 = tmp_path / "e.h5"
    with h5py.File(h5, "w") as f:
        g = f.create_group("events")
        g.attrs["width"], g.attrs["height"] = np.int64(size[0]), np.int64(size[1])
        for name in io.EVENT_CD.names:
            g.create_dataset(name, data=ev[name])
    npz = tmp_path / "e.npz"
    np.savez(npz, events=ev, width=np.int64(size[0]), height=np.int64(size[1]))
    for path in (h5, npz):
        for read in (io.info, io.read_events):
            with pytest.raises(io.DecodeError, match=r"sensor size must be whole numbers in 1\.\.65536"):
                read(path)
    with pytest.raises(ValueError, match="sensor size must be in"):
        io.write_events(tmp_path / "w.h5", ev, *size)


def test_binary_stl_with_a_non_utf8_header_loads(tmp_path):
    from evservo.models import load_object

    box = trimesh.creation.box((0.1, 0.2, 0.3))
    data = bytearray(box.export(file_type="stl"))
    data[:80] = bytes(range(176, 256))  # Latin-1 bytes: not UTF-8, as CAD exporters write
    path = tmp_path / "box.stl"
    path.write_bytes(bytes(data))
    mesh = load_object(str(path))
    assert len(mesh.faces) == 12
    np.testing.assert_allclose(mesh.extents, [0.1, 0.2, 0.3], rtol=1e-6)


def test_summary_of_bad_input_is_never_written(small_rec, tmp_path):
    out = tmp_path / "o"
    assert main(["track", str(small_rec), "--max-seconds", "nan", "--out", str(out)]) == 2
    assert not out.exists()


def test_names_are_parsed_once_in_rust(camera):
    from evservo import _evcore
    from evservo.tracking import FRONTENDS, SOLVERS

    assert SOLVERS == ("edft+", "edopts", "edft") == tuple(_evcore.SOLVERS)
    assert FRONTENDS == ("scarf", "fixed-count", "eros") == tuple(_evcore.FRONTENDS)
    T = geometry.pose((0, 0, 0.6), (0.35, -0.45, 0.1))
    for solver in SOLVERS:
        assert Tracker(camera, "box", T, solver=solver).solver == solver
    # One spelling each: the aliases Rust used to take are refused there, not in Python.
    for solver in ("EDFT+", "edftplus", "edopt"):
        with pytest.raises(ValueError, match="unknown solver"):
            Tracker(camera, "box", T, solver=solver)
    for frontend in ("fixed_count", " Fixed-Count ", "SCARF"):
        with pytest.raises(ValueError, match="unknown front-end"):
            Tracker(camera, "box", T, frontend=frontend)


@pytest.mark.parametrize("args", [["track", "x.h5", "--solver", "EDFT+", "--out", "o"],
                                  ["servo", "--sim", "--frontend-typo"]])  # fmt: skip
def test_argument_errors_end_in_one_error_line(args, capsys):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.splitlines()[-1].startswith("evservo: error:") and "Traceback" not in err
