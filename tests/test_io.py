"""evservo.io against real Prophesee recordings (digests from independent decoders) and round trips."""

import hashlib
from pathlib import Path

import h5py
import hdf5plugin
import numpy as np
import pytest

from conftest import SAMPLES
from evservo import io
from evservo._evcore import DecodeError, RawReader, RawSlices

# From shared/event-samples/README.md: SHA3-224 over t as u64, x u16, y u16, on as bool.
EXPECTED = {
    "prophesee_gen41_evt3_1280x720.raw": dict(
        format="EVT3", width=1280, height=720, n=219_596, t_first=11_718_656, t_last=11_727_457, on=115_532,
        t="40fc435b407b3a72c52fd24338151caa33e59cfc7fa4f2eddee0f857",
        x="c88bf5a9cd91ad9dc2782e11659e2bd6cfcd97ae77f4db347ede4d3f",
        y="2581d0ac206d0b7d9e58a51baf0601c0f7460559b44246fd4aec9b15",
        p="9966c54546959e2c31e538e9f5c851bfcd059fbf7e913b296775c621",
    ),
    "prophesee_gen3_evt2_640x480_a.raw": dict(
        format="EVT2", width=640, height=480, n=521_252, t_first=913_716_224, t_last=913_812_095, on=185_861,
        t="9855ba39c1baea316ae623b72466e420df60a7510248391856eb4eaf",
        x="93fc6cff19b483fd48ca53345c6c1cf05123681d7b7272a1717e9303",
        y="07cfaef58e5fa71ce9910ed5b88fb7e9fcf71e4a8654cc2c4666f1ae",
        p="d2b5e9c4047f4c431937b24cd46c8b504e055372b0ded1df77f0ffa1",
    ),
    "prophesee_gen3_evt2_640x480_b.raw": dict(
        format="EVT2", width=640, height=480, n=539_481, t_first=1_317_888, t_last=1_367_888, on=367_855,
        t="88cd1934f5fac4a512fa8c5a54785afd9059bb2edffdc0a7d258c96d",
        x="a59ce9d8a440e327400618b09b067e0721ff69301a20df082c7ad8ac",
        y="e8caba01c078762fc5a6cc823ef5c91548d80dfd33cc80787e6e8231",
        p="ba98b38db72347c528b25aa16650556c0e7613d4278bcd34db30f818",
    ),
}  # fmt: skip
EVT3_FILE = "prophesee_gen41_evt3_1280x720.raw"


def sample(name: str) -> Path:
    path = SAMPLES / name
    if not path.is_file():
        pytest.skip(f"sample recording {path} not found (set EVSERVO_SAMPLES)")
    return path


def sha3(a: np.ndarray) -> str:
    return hashlib.sha3_224(np.ascontiguousarray(a).tobytes()).hexdigest()


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_recordings_decode_to_reference_digests(name):
    e = EXPECTED[name]
    ev = io.read_events(sample(name))
    assert ev.dtype == io.EVENT_CD
    assert len(ev) == e["n"]
    assert (int(ev["t"][0]), int(ev["t"][-1])) == (e["t_first"], e["t_last"])
    assert int((ev["p"] == 1).sum()) == e["on"]
    assert sha3(ev["t"].astype("<u8")) == e["t"]
    assert sha3(ev["x"].astype("<u2")) == e["x"]
    assert sha3(ev["y"].astype("<u2")) == e["y"]
    assert sha3((ev["p"] != 0).astype(np.bool_)) == e["p"]
    assert io.info(sample(name)) == dict(
        format=e["format"], width=e["width"], height=e["height"], n_events=e["n"],
        t_first_us=e["t_first"], t_last_us=e["t_last"], geometry_inferred=False,
    )  # fmt: skip


def test_evt3_matches_evt3_package():
    evt3 = pytest.importorskip("evt3", reason="optional oracle evt3==0.4.1 not installed")
    path = sample(EVT3_FILE)
    ref = evt3.decode_file(str(path))
    ev = io.read_events(path)
    np.testing.assert_array_equal(ev["x"], ref.x)
    np.testing.assert_array_equal(ev["y"], ref.y)
    np.testing.assert_array_equal(ev["t"], np.asarray(ref.t).astype(np.int64))
    np.testing.assert_array_equal(ev["p"] != 0, np.asarray(ref.p) != 0)


@pytest.mark.parametrize("name", [EVT3_FILE, "prophesee_gen3_evt2_640x480_b.raw"])
def test_raw_slices_concatenate_to_the_stream(name):
    path = sample(name)
    whole = io.read_events(path)
    by_time = list(io.open_events(path, delta_t_us=5_000))
    t0 = int(whole["t"][0]) // 5_000 * 5_000
    for k, s in enumerate(by_time):
        assert s.dtype == io.EVENT_CD
        # Slice k holds stream events up to its end on the 5 ms grid.
        if len(s):
            assert int(s["t"][-1]) < t0 + (k + 1) * 5_000
    span_slices = (int(whole["t"][-1]) - t0) // 5_000 + 1
    assert len(by_time) == span_slices
    np.testing.assert_array_equal(np.concatenate(by_time), whole)
    by_count = list(io.open_events(path, n_events=70_000))
    assert [len(s) for s in by_count[:-1]] == [70_000] * (len(by_count) - 1)
    assert 0 < len(by_count[-1]) <= 70_000
    np.testing.assert_array_equal(np.concatenate(by_count), whole)
    # The default is 10 ms slices, as OpenEB's EventsIterator.
    assert len(list(io.open_events(path))) == (int(whole["t"][-1]) - t0 // 10_000 * 10_000) // 10_000 + 1


@pytest.mark.parametrize("name", [EVT3_FILE, "prophesee_gen3_evt2_640x480_a.raw"])
def test_raw_slices_are_those_of_the_decoded_array(name):
    """The RAW slices come from Rust in runs (views into one array per ~1 MiB of the file); the
    array path cuts the same stream in numpy: every slice must match, empty ones included (1 µs
    slices of sample a: 95 872 of them, more than one run holds)."""
    path = sample(name)
    whole = io.read_events(path)
    for dt in (1, 300, 10_000):
        got, want = list(io.open_events(path, delta_t_us=dt)), list(io._array_time_slices(whole, dt))
        assert len(got) == len(want), dt
        for a, b in zip(got, want, strict=True):
            assert a.dtype == io.EVENT_CD and a.flags.c_contiguous
            np.testing.assert_array_equal(a, b)
    by_count = list(io.open_events(path, n_events=1_000))
    assert len(by_count) == -(-len(whole) // 1_000)
    for i, s in enumerate(by_count):
        np.testing.assert_array_equal(s, whole[i * 1_000 : (i + 1) * 1_000])


def test_raw_slices_need_exactly_one_rule():
    path = sample(EVT3_FILE)
    for kwargs in ({}, {"delta_t_us": 10, "n_events": 10}):
        with pytest.raises(ValueError, match="exactly one"):
            RawSlices(path, **kwargs)
    with pytest.raises(ValueError, match="delta_t_us must be >= 1"):
        RawSlices(path, delta_t_us=0)


def synthetic_events() -> np.ndarray:
    rng = np.random.default_rng(7)
    n = 5_000
    ev = np.empty(n, dtype=io.EVENT_CD)
    ev["x"] = rng.integers(0, 320, n)
    ev["y"] = rng.integers(0, 240, n)
    ev["p"] = rng.integers(0, 2, n)
    ev["t"] = 1_000_000 + np.cumsum(rng.integers(0, 20, n))
    ev["t"][100] = ev["t"][99] - 11  # a step back in time survives round trips and slicing
    return ev


@pytest.mark.parametrize("suffix", [".npz", ".h5", ".hdf5", ".npy"])
def test_write_read_round_trip_is_identical(tmp_path, suffix):
    ev = synthetic_events()
    path = tmp_path / f"events{suffix}"
    io.write_events(path, ev, 320, 240)
    back = io.read_events(path)
    assert back.dtype == io.EVENT_CD
    np.testing.assert_array_equal(back, ev)
    meta = io.info(path)
    inferred = suffix == ".npy"
    size = (int(ev["x"].max()) + 1, int(ev["y"].max()) + 1) if inferred else (320, 240)
    assert (meta["width"], meta["height"], meta["geometry_inferred"]) == (*size, inferred)
    assert (meta["n_events"], meta["t_first_us"], meta["t_last_us"]) == (
        5_000,
        int(ev["t"][0]),
        int(ev["t"][-1]),
    )
    slices = list(io.open_events(path, delta_t_us=1_000))
    np.testing.assert_array_equal(np.concatenate(slices), ev)
    assert sum(len(s) for s in io.open_events(path, n_events=999)) == 5_000


def test_our_hdf5_layout_is_documented_shape(tmp_path):
    ev = synthetic_events()
    path = tmp_path / "ours.h5"
    io.write_events(path, ev, 320, 240)
    with h5py.File(path, "r") as f:
        g = f["events"]
        assert (g.attrs["width"], g.attrs["height"]) == (320, 240)
        assert {n: g[n].dtype.str for n in "xypt"} == {"x": "<u2", "y": "<u2", "p": "<i2", "t": "<i8"}
        # Blosc (hdf5plugin's filter 32001) with zstd, as io.H5_COMPRESSION says.
        assert all(str(hdf5plugin.BLOSC_ID) in g[n]._filters for n in "xypt")


def test_hdf5_is_blosc_zstd_compressed_and_smaller_than_raw(tmp_path):
    ev = io.read_events(sample(EVT3_FILE))
    path = tmp_path / "rec.h5"
    io.write_events(path, ev, 1280, 720)
    with h5py.File(path, "r") as f:
        for n in "xypt":
            ds = f["events"][n]
            plist = ds.id.get_create_plist()
            filters = {plist.get_filter(i)[0]: plist.get_filter(i)[2] for i in range(plist.get_nfilters())}
            assert hdf5plugin.BLOSC_ID in filters, filters
            # Blosc's options: (..., clevel, shuffle, compressor); compressor 5 is zstd.
            assert filters[hdf5plugin.BLOSC_ID][-1] == 5
            assert ds.id.get_storage_size() < ds.size * ds.dtype.itemsize
    raw_bytes = len(ev) * sum(ev.dtype[n].itemsize for n in "xypt")
    assert path.stat().st_size < 0.3 * raw_bytes
    np.testing.assert_array_equal(io.read_events(path), ev)


def test_h5_compression_setting_is_used_by_every_writer(tmp_path, monkeypatch):
    ev = synthetic_events()
    monkeypatch.setattr(io, "H5_COMPRESSION", {"compression": "gzip", "compression_opts": 4})
    io.write_events(tmp_path / "gzip.h5", ev, 320, 240)
    monkeypatch.setattr(io, "H5_COMPRESSION", {})
    io.write_events(tmp_path / "plain.h5", ev, 320, 240)
    with h5py.File(tmp_path / "gzip.h5", "r") as f, h5py.File(tmp_path / "plain.h5", "r") as g:
        assert f["events/t"].compression == "gzip"
        assert g["events/t"].compression is None and not g["events/t"]._filters
    for name in ("gzip.h5", "plain.h5"):
        np.testing.assert_array_equal(io.read_events(tmp_path / name), ev)
    # The simulator's recording writer takes the same setting.
    from evservo.sim.record import _EventWriter

    monkeypatch.setattr(io, "H5_COMPRESSION", hdf5plugin.Blosc(cname="lz4", clevel=1))
    with h5py.File(tmp_path / "rec.h5", "w") as f:
        w = _EventWriter(f, 320, 240)
        w.append(ev)
        w.flush()
        assert str(hdf5plugin.BLOSC_ID) in f["events/t"]._filters
    np.testing.assert_array_equal(io.read_events(tmp_path / "rec.h5"), ev)


@pytest.mark.parametrize(
    "codec",
    [
        hdf5plugin.Blosc(cname="blosclz", clevel=9, shuffle=hdf5plugin.Blosc.SHUFFLE),
        hdf5plugin.Blosc(cname="lz4hc"),
        hdf5plugin.Zstd(clevel=3),
        hdf5plugin.LZ4(),
        hdf5plugin.Bitshuffle(),
    ],
    ids=["blosc-blosclz", "blosc-lz4hc", "zstd", "lz4", "bitshuffle"],
)
def test_third_party_plugin_compressed_hdf5_reads(tmp_path, codec):
    """A Metavision-layout file another tool compressed with an hdf5plugin filter."""
    ev = synthetic_events()
    path = tmp_path / "third_party.hdf5"
    with h5py.File(path, "w") as f:
        f.attrs["geometry"] = "320x240"
        f.create_group("CD").create_dataset("events", data=ev, chunks=(1024,), **codec)
    np.testing.assert_array_equal(io.read_events(path), ev)


def test_round_trip_of_a_real_recording(tmp_path):
    ev = io.read_events(sample(EVT3_FILE))
    for suffix in (".npz", ".h5"):
        path = tmp_path / f"rec{suffix}"
        io.write_events(path, ev, 1280, 720)
        np.testing.assert_array_equal(io.read_events(path), ev)


def test_metavision_hdf5_is_read(tmp_path):
    ev = synthetic_events()
    path = tmp_path / "mv.hdf5"
    with h5py.File(path, "w") as f:
        f.attrs["geometry"] = "320x240"
        f.create_group("CD").create_dataset("events", data=ev, chunks=(1024,), compression="gzip")
    np.testing.assert_array_equal(io.read_events(path), ev)
    assert io.info(path)["format"] == "metavision-hdf5"
    assert (io.info(path)["width"], io.info(path)["height"]) == (320, 240)


def test_ecf_compressed_metavision_hdf5_names_the_codec(tmp_path):
    if h5py.h5z.filter_avail(io.ECF_FILTER_ID):
        pytest.skip("the ECF plugin is installed here, so the file would be readable")
    path = tmp_path / "ecf.hdf5"
    with h5py.File(path, "w") as f:
        ds = f.create_group("CD")
        ds.create_dataset(
            "events", data=synthetic_events(), chunks=(1024,), compression=0x8ECF, allow_unknown_filter=True
        )
    with pytest.raises(DecodeError, match="0x8ECF"):
        io.read_events(path)


def test_missing_files_and_unknown_extensions(tmp_path):
    with pytest.raises(FileNotFoundError):
        io.read_events(tmp_path / "absent.raw")
    with pytest.raises(FileNotFoundError):
        RawReader(tmp_path / "absent.raw")
    (tmp_path / "events.csv").write_text("x,y\n")
    with pytest.raises(ValueError, match="unsupported event file extension"):
        io.read_events(tmp_path / "events.csv")
    with pytest.raises(ValueError, match="only one"):
        io.open_events(tmp_path / "events.csv", delta_t_us=10, n_events=10)
    with pytest.raises(ValueError, match="cannot write"):
        io.write_events(tmp_path / "out.raw", synthetic_events(), 320, 240)
    with pytest.raises(ValueError, match="beyond"):
        io.write_events(tmp_path / "out.npz", synthetic_events(), 100, 240)


def test_truncated_raw_raises_decode_error(tmp_path):
    data = sample(EVT3_FILE).read_bytes()
    cut = tmp_path / "cut.raw"
    cut.write_bytes(data[:-1])  # inside the last 16-bit word
    with pytest.raises(DecodeError, match="truncated"):
        io.read_events(cut)
    cut.write_bytes(data[:20])  # inside the first header line: no format line survives
    with pytest.raises(DecodeError, match="names no event format"):
        io.read_events(cut)
    cut.write_bytes(data[:100])  # the format line survives, the plugin line with the geometry does not
    with pytest.raises(DecodeError, match="no sensor geometry"):
        io.read_events(cut)


def test_corrupt_raw_raises_decode_error(tmp_path):
    bad = tmp_path / "garbage.raw"
    bad.write_bytes(np.random.default_rng(1).integers(0, 256, 10_000, dtype=np.uint8).tobytes())
    with pytest.raises(DecodeError):
        io.read_events(bad)
    # A valid header over random words: coordinates beyond 64x32 are reported, not clipped.
    bad.write_bytes(b"% evt 3.0\n% geometry 64x32\n% end\n" + b"\x01\x80" + b"\xff\x2f" * 100)
    with pytest.raises(DecodeError, match="outside the 64x32 sensor"):
        io.read_events(bad)


def test_corrupt_npz_and_h5_raise_decode_error(tmp_path):
    ev = synthetic_events()
    for suffix in (".npz", ".h5", ".npy"):
        good = tmp_path / f"good{suffix}"
        io.write_events(good, ev, 320, 240)
        bad = tmp_path / f"bad{suffix}"
        bad.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
        with pytest.raises(DecodeError):
            io.read_events(bad)


def test_raw_reader_binding():
    r = RawReader(sample(EVT3_FILE))
    assert (r.format, r.width, r.height) == ("EVT3", 1280, 720)
    first = r.read_n_events(10)
    assert first.dtype == io.EVENT_CD and first.flags.c_contiguous
    assert len(first) == 10
    assert r.peek_t() == int(io.read_events(sample(EVT3_FILE))["t"][10])
    rest = r.read_until(2**62)
    assert len(rest) == 219_596 - 10
    assert r.peek_t() is None
    assert r.read_n_events(10) is None
    assert r.read_until(2**62) is None
    assert len(r.read_all()) == 0
