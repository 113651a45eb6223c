"""Event files written by an independent writer (faery) read back identically through evservo.io,
oracle cross-checks (evt3 for EVT 3.0, aedat for AEDAT4) on the real recording, and corrupt AEDAT4
files ending in DecodeError.

faery writes EVT 2.0 / EVT 3.0 RAW, AEDAT4, CSV, DAT and ES; evservo reads the first three and
refuses the others by name.
"""

import hashlib

import numpy as np
import pytest

from conftest import SAMPLES
from evservo import aedat4, io
from evservo._evcore import DecodeError

faery = pytest.importorskip("faery", reason="faery==0.7.1 (requirements.txt) writes the fixtures")
faery_encoder = pytest.importorskip("faery.file_encoder")

EVT3_FILE = "prophesee_gen41_evt3_1280x720.raw"
WIDTH, HEIGHT = 1280, 720

#: (file suffix, keyword arguments of faery's to_file) for every format both sides support.
WRITERS = {
    "evt2": (".raw", dict(version="evt2")),
    "evt3": (".raw", dict(version="evt3")),
    "evt3-absolute": (".raw", dict(version="evt3", zero_t0=False)),
    "aedat4-lz4": (".aedat4", dict(compression=("lz4", 1))),
    "aedat4-zstd": (".aedat4", dict(compression=("zstd", 3))),
    "aedat4-none": (".aedat4", dict(compression=None)),
}


def random_events(seed: int, n: int = 40_000) -> np.ndarray:
    """faery's dtype (t u64, x u16, y u16, on bool), time-sorted as the formats require.

    Half the events are scattered; the other half come in bursts sharing t and y along runs of x,
    which EVT 3.0 writers pack into vector words. Times start near 2^33 µs and span ~40 s, past the
    24-bit EVT 3.0 time wrap (16.8 s) twice; the sensor's last row and column are included.
    """
    rng = np.random.default_rng(seed)
    ev = np.zeros(n, dtype=faery.EVENTS_DTYPE)
    half = n // 2
    ev["x"][:half] = rng.integers(0, WIDTH, half)
    ev["y"][:half] = rng.integers(0, HEIGHT, half)
    ev["t"][:half] = rng.integers(0, 40_000_000, half)
    bursts = rng.integers(0, 40_000_000, half // 20)
    for k, t in enumerate(bursts):
        sl = slice(half + 20 * k, half + 20 * (k + 1))
        x0 = int(rng.integers(0, WIDTH - 40))
        ev["x"][sl] = np.sort(x0 + rng.choice(40, 20, replace=False))
        ev["y"][sl] = rng.integers(0, HEIGHT)
        ev["t"][sl] = t
    ev["on"] = rng.integers(0, 2, n).astype(bool)
    ev["x"][0], ev["y"][0] = WIDTH - 1, HEIGHT - 1
    ev["t"] += 2**33
    return ev[np.argsort(ev["t"], kind="stable")]


def write_with_faery(events: np.ndarray, path, **kwargs) -> None:
    faery.events_stream_from_array(events, (WIDTH, HEIGHT)).to_file(path, **kwargs)


def assert_identical(ours: np.ndarray, ref: np.ndarray) -> None:
    assert ours.dtype == io.EVENT_CD
    assert len(ours) == len(ref)
    np.testing.assert_array_equal(ours["x"], ref["x"])
    np.testing.assert_array_equal(ours["y"], ref["y"])
    np.testing.assert_array_equal(ours["p"], ref["on"].astype(np.int16))
    np.testing.assert_array_equal(ours["t"], ref["t"].astype(np.int64))


@pytest.mark.parametrize("kind", sorted(WRITERS))
def test_faery_written_files_read_back_identically(tmp_path, kind):
    suffix, kwargs = WRITERS[kind]
    ev = random_events(seed=sorted(WRITERS).index(kind))
    if kwargs.get("zero_t0") is False:
        # Without faery's `% t0` header line only the 24-bit counter and its wraps carry time,
        # so a recording written this way starts near 0 (as a camera's does).
        ev["t"] -= 2**33
    path = tmp_path / f"events{suffix}"
    write_with_faery(ev, path, **kwargs)
    assert_identical(io.read_events(path), ev)
    meta = io.info(path)
    expected_format = {"evt2": "EVT2", "evt3": "EVT3"}.get(kind.split("-")[0], "aedat4")
    assert meta == dict(
        format=expected_format, width=WIDTH, height=HEIGHT, n_events=len(ev),
        t_first_us=int(ev["t"][0]), t_last_us=int(ev["t"][-1]), geometry_inferred=False,
    )  # fmt: skip
    # Streaming slices (by time across the wraps, and by count) concatenate to the same events.
    slices = list(io.open_events(path, delta_t_us=1_000_000))
    assert len(slices) == int(ev["t"][-1]) // 1_000_000 - int(ev["t"][0]) // 1_000_000 + 1
    assert_identical(np.concatenate(slices, dtype=io.EVENT_CD), ev)
    counted = list(io.open_events(path, n_events=7_000))
    assert [len(s) for s in counted] == [7_000] * (len(ev) // 7_000) + [len(ev) % 7_000]


@pytest.mark.parametrize("suffix", [".csv", ".dat", ".es"])
def test_faery_formats_evservo_does_not_read_are_refused_by_name(tmp_path, suffix):
    path = tmp_path / f"events{suffix}"
    write_with_faery(random_events(seed=5, n=2_000), path)
    assert path.stat().st_size > 0
    for read in (io.read_events, io.info, io.open_events):
        with pytest.raises(ValueError, match=rf"unsupported event file extension '\{suffix}'"):
            read(path)


def sample(name: str):
    path = SAMPLES / name
    if not path.is_file():
        pytest.skip(f"sample recording {path} not found (set EVSERVO_SAMPLES)")
    return path


def test_real_evt3_recording_agrees_with_the_oracles_through_faery(tmp_path):
    """The real EVT 3.0 recording: evservo equals the evt3 package on it; its events written by faery
    as EVT 2.0, EVT 3.0 and AEDAT4 read back identically; and aedat reads that AEDAT4 file the same."""
    evt3 = pytest.importorskip("evt3", reason="oracle evt3==0.4.1 (requirements.txt) not installed")
    aedat = pytest.importorskip("aedat", reason="oracle aedat==2.3.0 (requirements.txt) not installed")
    path = sample(EVT3_FILE)
    ours = io.read_events(path)
    ref = evt3.decode_file(str(path))
    src = np.zeros(len(ours), dtype=faery.EVENTS_DTYPE)
    src["t"], src["x"], src["y"] = np.asarray(ref.t), ref.x, ref.y
    src["on"] = np.asarray(ref.p) != 0
    assert_identical(ours, src)
    # The README's digest of t, so the oracle itself is the known-good one.
    assert hashlib.sha3_224(src["t"].astype("<u8").tobytes()).hexdigest().startswith("40fc435b")

    for kind in ("evt2", "evt3", "aedat4-lz4"):
        suffix, kwargs = WRITERS[kind]
        out = tmp_path / f"{kind}{suffix}"
        write_with_faery(src, out, **kwargs)
        assert_identical(io.read_events(out), src)
    packets = [p["events"] for p in aedat.Decoder(tmp_path / "aedat4-lz4.aedat4") if "events" in p]
    assert_identical(io.read_events(tmp_path / "aedat4-lz4.aedat4"), np.concatenate(packets))


# --- corrupt AEDAT4 -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def aedat_bytes(tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("aedat") / "good.aedat4"
    # Several packets, so truncation can fall between and inside them. (faery's own .chunks()
    # never ends after the last chunk, so its encoder gets the packets as a list.)
    ev = random_events(seed=11, n=6_000)
    chunks = [ev[i : i + 1_000] for i in range(0, len(ev), 1_000)]
    faery_encoder.events_to_file(chunks, path, (WIDTH, HEIGHT), compression=None)
    data = path.read_bytes()
    assert aedat4.read_header(path).n_packets >= 6
    return data


def read_bytes_as_aedat4(tmp_path, data: bytes, name: str = "bad.aedat4"):
    path = tmp_path / name
    path.write_bytes(data)
    return io.read_events(path)


def test_aedat4_header_is_parsed(tmp_path, aedat_bytes):
    path = tmp_path / "good.aedat4"
    path.write_bytes(aedat_bytes)
    h = aedat4.read_header(path)
    assert (h.width, h.height, h.stream_id, h.streams, h.compression) == (WIDTH, HEIGHT, 0, {0: "EVTS"}, "none")
    assert len(io.read_events(path)) == 6_000


def test_truncated_aedat4_raises_decode_error(tmp_path, aedat_bytes):
    h_len = int.from_bytes(aedat_bytes[14:18], "little")
    data_start = 18 + h_len
    cuts = {
        "inside the magic": 5,
        "inside the header length": 16,
        "inside the IOHeader": 18 + h_len // 2,
        "inside a packet header": data_start + 4,
        "inside a packet": data_start + 100,
        "inside the last packet": aedat4.read_header(_write(tmp_path / "good.aedat4", aedat_bytes)).data_table - 30,
        "inside the data table": len(aedat_bytes) - 30,
    }
    for where, cut in cuts.items():
        with pytest.raises(DecodeError, match=r"truncated|not an AEDAT4 file") as e:
            read_bytes_as_aedat4(tmp_path, aedat_bytes[:cut])
        assert "bad.aedat4" in str(e.value), where
        # Each entry point fails up front, before any event is handed out.
        with pytest.raises(DecodeError):
            io.info(tmp_path / "bad.aedat4")
        with pytest.raises(DecodeError):
            io.open_events(tmp_path / "bad.aedat4", n_events=10)
    with pytest.raises(DecodeError, match="not an AEDAT4 file"):
        read_bytes_as_aedat4(tmp_path, b"")


def test_wrong_magic_raises_decode_error(tmp_path, aedat_bytes):
    with pytest.raises(DecodeError, match=r"not an AEDAT4 file.*AER-DAT3\.1"):
        read_bytes_as_aedat4(tmp_path, b"#!AER-DAT3.1\r\n" + aedat_bytes[14:])
    with pytest.raises(DecodeError, match="not an AEDAT4 file"):
        read_bytes_as_aedat4(tmp_path, b"% evt 3.0\n" + aedat_bytes)


def test_garbage_header_raises_decode_error(tmp_path, aedat_bytes):
    """aedat reads the IOHeader unverified and panics on these; evservo must say what is wrong."""
    rng = np.random.default_rng(5)
    h_len = int.from_bytes(aedat_bytes[14:18], "little")
    garbage = rng.integers(0, 256, h_len, dtype=np.uint8).tobytes()
    with pytest.raises(DecodeError, match="corrupt AEDAT4"):
        read_bytes_as_aedat4(tmp_path, aedat_bytes[:18] + garbage + aedat_bytes[18 + h_len :])
    root_far_away = (1 << 30).to_bytes(4, "little")
    with pytest.raises(DecodeError, match="corrupt AEDAT4 IOHeader: root table"):
        read_bytes_as_aedat4(tmp_path, aedat_bytes[:18] + root_far_away + aedat_bytes[22:])
    with pytest.raises(DecodeError, match="claims 4294967295 bytes"):
        read_bytes_as_aedat4(tmp_path, aedat_bytes[:14] + b"\xff\xff\xff\xff" + aedat_bytes[18:])


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (b"<dv", b"<xx", "not XML|expected <dv>"),
        (b">EVTS<", b">EVTX<", "type 'EVTX'"),
        (b'"sizeX"', b'"sizeZ"', "no valid sizeX/sizeY"),
        (b'name="outInfo"', b'name="outInfx"', "no outInfo node"),
        (b'<node name="0"', b'<node name="a"', "not a stream id"),
    ],
)
def test_bad_stream_description_raises_decode_error(tmp_path, aedat_bytes, old, new, message):
    assert len(old) == len(new) and old in aedat_bytes
    with pytest.raises(DecodeError, match=message):
        read_bytes_as_aedat4(tmp_path, aedat_bytes.replace(old, new, 1))


def test_corrupt_packets_raise_decode_error(tmp_path, aedat_bytes):
    h = aedat4.read_header(_write(tmp_path / "good.aedat4", aedat_bytes))
    data = bytearray(aedat_bytes)
    data[h.data_start : h.data_start + 4] = (7).to_bytes(4, "little")  # a stream id not described
    with pytest.raises(DecodeError, match="unknown stream id 7"):
        read_bytes_as_aedat4(tmp_path, bytes(data))
    # Event coordinates beyond the described sensor: a 64x32 sensor for 1280x720 events.
    small = aedat_bytes.replace(b">1280<", b">0064<", 1).replace(b">720<", b">032<", 1)
    assert len(small) == len(aedat_bytes)
    with pytest.raises(DecodeError, match="outside the 64x32 sensor"):
        read_bytes_as_aedat4(tmp_path, small)


def _write(path, data: bytes):
    path.write_bytes(data)
    return path


def test_random_corruption_never_escapes_as_anything_but_decode_error(tmp_path, aedat_bytes):
    """Bytes overwritten anywhere (header, description, packet framing, flatbuffers): the result is
    events or a DecodeError, never a panic, a crash or another exception type."""
    rng = np.random.default_rng(3)
    h_len = int.from_bytes(aedat_bytes[14:18], "little")
    hot = [*range(14, 18 + 64), *range(18 + h_len, 18 + h_len + 64)]  # header and first packet
    outcomes = {"ok": 0, "DecodeError": 0}
    for k in range(150):
        data = bytearray(aedat_bytes)
        for _ in range(int(rng.integers(1, 5))):
            at = int(rng.choice(hot)) if k % 2 else int(rng.integers(0, len(data)))
            data[at] = int(rng.integers(0, 256))
        try:
            read_bytes_as_aedat4(tmp_path, bytes(data))
            outcomes["ok"] += 1
        except DecodeError:
            outcomes["DecodeError"] += 1
    assert outcomes["DecodeError"] > 0


def test_a_panic_inside_aedat_becomes_decode_error(tmp_path, aedat_bytes):
    """Past evservo's own header check (skipped here by handing over the good file's header), aedat
    panics on a root table offset beyond its buffer; that PanicException (a BaseException) must come
    out as DecodeError."""
    header = aedat4.read_header(_write(tmp_path / "good.aedat4", aedat_bytes))
    bad = _write(tmp_path / "bad.aedat4", aedat_bytes[:18] + (60_000).to_bytes(4, "little") + aedat_bytes[22:])
    with pytest.raises(DecodeError, match="PanicException in the aedat decoder") as e:
        list(aedat4.iter_blocks(bad, header))
    assert type(e.value.__cause__).__name__ == "PanicException"
