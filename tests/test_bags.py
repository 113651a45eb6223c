"""ROS 2 bags in evservo.io: bags written by rosbags (the drivers' message layouts) read back
exactly; bags evservo writes read back exactly and, through the independent mcap-ros2-support
reader and the evt3 package's EVT 3.0 decoder, hold the events written."""

import itertools
from pathlib import Path

import numpy as np
import pytest

from conftest import SAMPLES
from evservo import bags, io
from evservo._evcore import DecodeError, Evt3Decoder, Evt3Encoder

rosbag2 = pytest.importorskip("rosbags.rosbag2", reason="rosbags (requirements.txt) not installed")

EVT3_FILE = SAMPLES / "prophesee_gen41_evt3_1280x720.raw"
PERIOD_US = 1 << 24


def evt3_sample() -> tuple[bytes, np.ndarray]:
    """The real EVT 3.0 recording: its data bytes (header stripped) and its events."""
    if not EVT3_FILE.is_file():
        pytest.skip(f"sample recording {EVT3_FILE} not found (set EVSERVO_SAMPLES)")
    raw = EVT3_FILE.read_bytes()
    pos = 0
    while raw.startswith(b"%", pos):
        pos = raw.index(b"\n", pos) + 1
    return raw[pos:], io.read_events(EVT3_FILE)


def synthetic_events(n: int = 5000, seed: int = 0) -> np.ndarray:
    """Events on 640x480 over ~40 s (two 2^24 µs counter wraps), with same-time row bursts
    (vectors) and small steps back in time."""
    rng = np.random.default_rng(seed)
    ev = np.zeros(n, dtype=io.EVENT_CD)
    ev["x"] = rng.integers(0, 640, n)
    ev["y"] = rng.integers(0, 480, n)
    ev["p"] = rng.integers(0, 2, n)
    dt = rng.integers(0, 16_000, n)
    dt[rng.random(n) < 0.3] = 0
    ev["t"] = 7 + np.cumsum(dt)
    back = np.flatnonzero(rng.random(n) < 0.02)
    ev["t"][back] = np.maximum(ev["t"][back] - 500, ev["t"][back] // PERIOD_US * PERIOD_US)
    burst = slice(n // 2, n // 2 + 12)
    ev["t"][burst], ev["y"][burst], ev["p"][burst] = ev["t"][n // 2], 9, 1
    ev["x"][burst] = 200 + np.arange(12)
    return ev


def _store():
    return bags._typestore()


def write_bag(path: Path, topics: dict[str, tuple[str, list]], storage: str = "mcap") -> None:
    """A rosbag2 directory written by rosbags: ``{topic: (msgtype, [message, ...])}``, log time
    1 ms apart in message order."""
    store = _store()
    plugin = rosbag2.StoragePlugin.MCAP if storage == "mcap" else rosbag2.StoragePlugin.SQLITE3
    with rosbag2.Writer(path, version=9, storage_plugin=plugin) as w:
        for topic, (msgtype, msgs) in topics.items():
            con = w.add_connection(topic, msgtype, typestore=store)
            for k, m in enumerate(msgs):
                w.write(con, 1_000_000 * (k + 1), store.serialize_cdr(m, msgtype))


def _header(t_us: int = 0):
    store = _store()
    stamp = store.types["builtin_interfaces/msg/Time"](sec=t_us // 1_000_000, nanosec=t_us % 1_000_000 * 1000)
    return store.types["std_msgs/msg/Header"](stamp=stamp, frame_id="cam")


def packet(data: bytes, encoding: str, width: int, height: int, time_base: int = 0, seq: int = 0, big=False):
    return _store().types[bags.EVENT_PACKET](
        header=_header(), height=height, width=width, seq=seq, time_base=time_base, encoding=encoding,
        is_bigendian=big, events=np.frombuffer(data, dtype=np.uint8),
    )  # fmt: skip


def evt3_packets(data: bytes, cuts: np.ndarray, width: int, height: int) -> list:
    edges = [0, *sorted(int(c) for c in cuts), len(data)]
    return [packet(data[a:b], "evt3", width, height, seq=k) for k, (a, b) in enumerate(itertools.pairwise(edges))]


@pytest.mark.parametrize("unit", [2, 1], ids=["word-cuts", "byte-cuts"])
def test_driver_evt3_packets_cut_anywhere_decode_like_the_raw_file(tmp_path, unit):
    data, ref = evt3_sample()
    rng = np.random.default_rng(unit)
    # 300 packets cut at random word (or byte) boundaries: the decoder state crosses every cut.
    cuts = np.unique(rng.integers(1, len(data) // unit, 300) * unit)
    write_bag(tmp_path / "bag", {"/event_camera/events": (bags.EVENT_PACKET, evt3_packets(data, cuts, 1280, 720))})
    ev = io.read_events(tmp_path / "bag")
    assert ev.dtype == io.EVENT_CD and len(ev) == 219_596
    np.testing.assert_array_equal(ev, ref)
    # The bare MCAP file inside the directory reads the same.
    np.testing.assert_array_equal(io.read_events(tmp_path / "bag" / "bag.mcap"), ref)


def test_mono_packets_decode_exactly(tmp_path):
    ev = synthetic_events(3000)
    ev = ev[np.argsort(ev["t"], kind="stable")]
    time_base_ns = 1_700_000_000_123_456_000
    msgs = []
    for k, chunk in enumerate(np.array_split(ev, 7)):
        base = time_base_ns + int(chunk["t"][0]) * 1000
        dt = (chunk["t"] * 1000 + time_base_ns - base).astype(np.uint64)
        words = (
            (chunk["p"].astype(np.uint64) << 63) | (chunk["y"].astype(np.uint64) << 48)
            | (chunk["x"].astype(np.uint64) << 32) | dt
        )  # fmt: skip
        big = k % 2 == 1  # both byte orders
        msgs.append(packet(words.astype(">u8" if big else "<u8").tobytes(), "mono", 640, 480, base, k, big))
    write_bag(tmp_path / "bag", {"/dvs/events": (bags.EVENT_PACKET, msgs)})
    back = io.read_events(tmp_path / "bag")
    np.testing.assert_array_equal(back[["x", "y", "p"]], ev[["x", "y", "p"]])
    np.testing.assert_array_equal(back["t"], ev["t"] + time_base_ns // 1000)
    assert io.info(tmp_path / "bag")["encoding"] == "mono"


@pytest.mark.parametrize("package", ["dvs_msgs", "prophesee_event_msgs"])
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_event_arrays_decode_exactly(tmp_path, package, storage):
    store = _store()
    Event, Time = store.types[f"{package}/msg/Event"], store.types["builtin_interfaces/msg/Time"]
    EventArray = store.types[f"{package}/msg/EventArray"]
    ev = synthetic_events(600)
    ev["t"] += 1_700_000_000_000_000  # ROS time, µs since the epoch
    msgs = [
        EventArray(header=_header(), height=260, width=346, events=[
            Event(x=int(e["x"]) % 346, y=int(e["y"]) % 260, polarity=bool(e["p"]),
                  ts=Time(sec=int(e["t"]) // 1_000_000, nanosec=int(e["t"]) % 1_000_000 * 1000 + 999))
            for e in chunk
        ])
        for chunk in np.array_split(ev, 5)
    ]  # fmt: skip
    write_bag(tmp_path / "bag", {"/dvs/events": (f"{package}/msg/EventArray", msgs)}, storage)
    back = io.read_events(tmp_path / "bag")
    np.testing.assert_array_equal(back["x"], ev["x"] % 346)
    np.testing.assert_array_equal(back["y"], ev["y"] % 260)
    np.testing.assert_array_equal(back["p"], ev["p"])
    np.testing.assert_array_equal(back["t"], ev["t"])
    meta = io.info(tmp_path / "bag")
    assert (meta["width"], meta["height"], meta["n_events"], meta["type"]) == (
        346,
        260,
        600,
        f"{package}/msg/EventArray",
    )


def _oracle_packets(path: Path) -> list:
    """The bag's messages as decoded by mcap-ros2-support from the schemas stored in the file."""
    reader = pytest.importorskip("mcap_ros2.reader", reason="oracle mcap-ros2-support not installed")
    return list(reader.read_ros2_messages(str(path)))


@pytest.mark.parametrize("target", ["run.mcap", "run_bag"])
def test_written_bag_round_trips_and_the_oracle_agrees(tmp_path, target):
    evt3 = pytest.importorskip("evt3", reason="oracle evt3==0.4.1 not installed")
    _, ref = evt3_sample()
    path = tmp_path / target
    io.write_events(path, ref, 1280, 720)
    np.testing.assert_array_equal(io.read_events(path), ref)
    mcap_file = path if path.suffix == ".mcap" else path / f"{target}.mcap"
    msgs = _oracle_packets(mcap_file)
    assert {m.channel.topic for m in msgs} == {bags.DEFAULT_TOPIC}
    assert {m.schema.name for m in msgs} == {bags.EVENT_PACKET}
    assert [m.ros_msg.seq for m in msgs] == list(range(len(msgs)))
    assert {(m.ros_msg.encoding, m.ros_msg.width, m.ros_msg.height) for m in msgs} == {("evt3", 1280, 720)}
    # Events from 11 718 656 to 11 727 457 µs: one packet per millisecond of the grid, 11718..11727.
    assert len(msgs) == 10
    stream = b"".join(bytes(m.ros_msg.events) for m in msgs)
    other = evt3.decode_bytes(stream, 1280, 720)
    np.testing.assert_array_equal(np.asarray(other.x), ref["x"])
    np.testing.assert_array_equal(np.asarray(other.y), ref["y"])
    np.testing.assert_array_equal(np.asarray(other.t).astype(np.int64), ref["t"])
    np.testing.assert_array_equal(np.asarray(other.p) != 0, ref["p"] != 0)
    # The header stamp is each packet's first event time.
    first = msgs[0].ros_msg.header.stamp
    assert first.sec * 1_000_000 + first.nanosec // 1000 == int(ref["t"][0])


def test_written_bag_with_wraps_round_trips_through_slices(tmp_path):
    ev = synthetic_events(20_000, seed=3)
    assert int(ev["t"].max()) > 2 * PERIOD_US
    io.write_events(tmp_path / "w.mcap", ev, 640, 480)
    np.testing.assert_array_equal(io.read_events(tmp_path / "w.mcap"), ev)
    by_time = list(io.open_events(tmp_path / "w.mcap", delta_t_us=250_000))
    np.testing.assert_array_equal(np.concatenate(by_time), ev)
    t0 = int(ev["t"][0]) // 250_000 * 250_000
    assert len(by_time) == (int(ev["t"].max()) - t0) // 250_000 + 1
    by_count = list(io.open_events(tmp_path / "w.mcap", n_events=3000))
    assert [len(s) for s in by_count] == [3000] * 6 + [2000]
    np.testing.assert_array_equal(np.concatenate(by_count), ev)
    meta = io.info(tmp_path / "w.mcap")
    assert (meta["n_events"], meta["t_first_us"], meta["t_last_us"]) == (20_000, int(ev["t"][0]), int(ev["t"][-1]))


def test_empty_written_bag_keeps_its_geometry(tmp_path):
    io.write_events(tmp_path / "e.mcap", np.empty(0, dtype=io.EVENT_CD), 320, 240)
    assert len(io.read_events(tmp_path / "e.mcap")) == 0
    meta = io.info(tmp_path / "e.mcap")
    assert (meta["width"], meta["height"], meta["n_events"], meta["t_first_us"]) == (320, 240, 0, None)


def test_unencodable_events_raise_before_anything_is_written(tmp_path):
    ev = synthetic_events(200)
    ev["t"][10] = ev["t"][9] + PERIOD_US
    ev["t"][11] = ev["t"][9]  # a step back into the previous counter period
    with pytest.raises(ValueError, match="earlier 2\\^24"):
        io.write_events(tmp_path / "x.mcap", ev, 640, 480)
    epoch = synthetic_events(200)
    epoch["t"] += 1_700_000_000_000_000
    with pytest.raises(ValueError, match="relative"):
        io.write_events(tmp_path / "x.mcap", epoch, 640, 480)
    assert list(tmp_path.iterdir()) == []
    io.write_events(tmp_path / "d", synthetic_events(200), 640, 480)
    with pytest.raises(FileExistsError):
        io.write_events(tmp_path / "d", synthetic_events(200), 640, 480)


def test_topics_are_listed_and_chosen(tmp_path):
    data, ref = evt3_sample()
    ev = synthetic_events(400)
    store = _store()
    String = store.types["std_msgs/msg/String"]
    enc = Evt3Encoder(640, 480)
    second = enc.encode(ev)
    write_bag(tmp_path / "bag", {
        "/cam_a/events": (bags.EVENT_PACKET, evt3_packets(data, np.array([1000, 5000]), 1280, 720)),
        "/cam_b/events": (bags.EVENT_PACKET, evt3_packets(second, np.array([64]), 640, 480)),
        "/chatter": ("std_msgs/msg/String", [String(data="hi")] * 3),
    })  # fmt: skip
    with pytest.raises(ValueError, match=r"several event topics.*/cam_a/events, /cam_b/events"):
        io.read_events(tmp_path / "bag")
    np.testing.assert_array_equal(io.read_events(tmp_path / "bag", topic="/cam_a/events"), ref)
    np.testing.assert_array_equal(io.read_events(tmp_path / "bag", topic="/cam_b/events"), ev)
    meta = io.info(tmp_path / "bag", topic="/cam_b/events")
    assert (meta["width"], meta["height"], meta["n_events"]) == (640, 480, 400)
    assert meta["topics"] == {
        "/cam_a/events": {"type": bags.EVENT_PACKET, "messages": 3},
        "/cam_b/events": {"type": bags.EVENT_PACKET, "messages": 2},
        "/chatter": {"type": "std_msgs/msg/String", "messages": 3},
    }
    assert bags.topics(tmp_path / "bag") == meta["topics"]
    with pytest.raises(ValueError, match="not events"):
        io.read_events(tmp_path / "bag", topic="/chatter")
    with pytest.raises(ValueError, match=r"no topic '/nope'.*/chatter \(std_msgs/msg/String\)"):
        io.open_events(tmp_path / "bag", topic="/nope")  # raised on opening, not on the first slice
    with pytest.raises(ValueError, match="ROS bags only"):
        io.read_events(EVT3_FILE, topic="/cam_a/events")


def test_bad_bags_raise_clear_errors(tmp_path):
    with pytest.raises(FileNotFoundError):
        io.read_events(tmp_path / "missing.mcap")
    (tmp_path / "plain_dir").mkdir()
    with pytest.raises(DecodeError, match=r"no metadata\.yaml"):
        io.info(tmp_path / "plain_dir")
    (tmp_path / "junk.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(range(200)))
    with pytest.raises(DecodeError, match="unreadable ROS bag"):
        io.read_events(tmp_path / "junk.mcap")
    write_bag(tmp_path / "odd", {"/e": (bags.EVENT_PACKET, [packet(b"\x00" * 12, "mono", 640, 480)])})
    with pytest.raises(DecodeError, match="whole number of 8-byte events"):
        io.read_events(tmp_path / "odd")
    write_bag(tmp_path / "enc", {"/e": (bags.EVENT_PACKET, [packet(b"", "evt2", 640, 480)])})
    with pytest.raises(DecodeError, match="'evt2' is not supported"):
        io.read_events(tmp_path / "enc")
    # An EVT3 event beyond the declared 640x480 sensor.
    off = Evt3Encoder(1280, 720).encode(np.array([(900, 5, 1, 10)], dtype=io.EVENT_CD))
    write_bag(tmp_path / "off", {"/e": (bags.EVENT_PACKET, [packet(off, "evt3", 640, 480)])})
    with pytest.raises(DecodeError, match="outside the 640x480 sensor"):
        io.read_events(tmp_path / "off")


def test_streaming_codec_bindings_carry_state_across_calls():
    ev = synthetic_events(2000, seed=5)
    enc = Evt3Encoder(640, 480)
    parts = [enc.encode(np.ascontiguousarray(c)) for c in np.array_split(ev, 4)]
    data = b"".join(parts)
    dec = Evt3Decoder(640, 480)
    chunks = [dec.decode(data[:1]), dec.decode(data[1:777]), dec.decode(data[777:])]
    assert dec.pending_bytes == 0
    assert all(c.dtype == io.EVENT_CD for c in chunks)
    np.testing.assert_array_equal(np.concatenate(chunks), ev)
    with pytest.raises(ValueError, match="polarity 3"):
        enc.encode(np.array([(1, 1, 3, ev["t"][-1])], dtype=io.EVENT_CD))


def test_tracking_a_bag_equals_tracking_the_raw_file(tmp_path):
    from evservo.cli import main

    _, ref = evt3_sample()
    io.write_events(tmp_path / "bag", ref, 1280, 720)
    common = ["--model", "box", "--init-pose", "0,0,0.6,0,0,0,1", "--max-seconds", "0.004", "--quiet"]
    assert main(["track", str(EVT3_FILE), *common, "--out", str(tmp_path / "raw")]) == 0
    assert main(["track", str(tmp_path / "bag"), *common, "--out", str(tmp_path / "bagout")]) == 0
    raw = (tmp_path / "raw" / "poses.csv").read_text()
    assert raw.count("\n") == 6  # header + 5 updates (1 ms slices over 4 ms of the grid)
    assert (tmp_path / "bagout" / "poses.csv").read_text() == raw


def test_track_picks_a_bag_topic(tmp_path, capsys):
    from evservo.cli import main

    data, _ = evt3_sample()
    packets = evt3_packets(data, np.array([4096]), 1280, 720)
    write_bag(tmp_path / "bag", {"/a/events": (bags.EVENT_PACKET, packets), "/b/events": (bags.EVENT_PACKET, packets)})
    common = ["--model", "box", "--init-pose", "0,0,0.6,0,0,0,1", "--max-seconds", "0.002", "--quiet"]
    assert main(["track", str(tmp_path / "bag"), *common, "--out", str(tmp_path / "o1")]) == 2
    assert "several event topics" in capsys.readouterr().err
    assert main(["track", str(tmp_path / "bag"), *common, "--topic", "/b/events", "--out", str(tmp_path / "o2")]) == 0
    assert (tmp_path / "o2" / "poses.csv").read_text().count("\n") == 4  # header + 3 updates


@pytest.mark.parametrize("little_endian", [True, False])
def test_event_array_cdr_parsing_handles_every_alignment(tmp_path, little_endian):
    """Event arrays are parsed from their CDR bytes (little-endian) or through rosbags (big-endian):
    frame ids of every length mod 4 and arrays of 0, 1, 2 and 7 events decode exactly."""
    store = _store()
    Event, Time = store.types["dvs_msgs/msg/Event"], store.types["builtin_interfaces/msg/Time"]
    EventArray = store.types["dvs_msgs/msg/EventArray"]
    rng = np.random.default_rng(7)
    msgs, expected = [], []
    for frame_id in ["", "a", "ab", "abc", "abcd"]:
        for n in [0, 1, 2, 7]:
            x, y = rng.integers(0, 346, n), rng.integers(0, 260, n)
            p, sec, nsec = rng.integers(0, 2, n), rng.integers(0, 2**31 - 1, n), rng.integers(0, 10**9, n)
            events = [Event(x=int(a), y=int(b), polarity=bool(c), ts=Time(sec=int(s), nanosec=int(q)))
                      for a, b, c, s, q in zip(x, y, p, sec, nsec, strict=True)]  # fmt: skip
            stamp = Time(sec=1, nanosec=2)
            msg = EventArray(header=store.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id),
                             height=260, width=346, events=events)  # fmt: skip
            msgs.append(msg)
            expected.append(np.rec.fromarrays([x, y, p, sec * 1_000_000 + nsec // 1000], names="x,y,p,t"))
    with rosbag2.Writer(tmp_path / "bag", version=9, storage_plugin=rosbag2.StoragePlugin.MCAP) as w:
        con = w.add_connection("/dvs/events", "dvs_msgs/msg/EventArray", typestore=store)
        for k, m in enumerate(msgs):
            w.write(con, k + 1, store.serialize_cdr(m, "dvs_msgs/msg/EventArray", little_endian=little_endian))
    back = io.read_events(tmp_path / "bag")
    want = np.concatenate(expected)
    for f in "xypt":
        np.testing.assert_array_equal(back[f], want[f].astype(back[f].dtype))
