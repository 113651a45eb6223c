"""ROS 2 bags of event-camera messages: rosbag2 directories and bare MCAP files.

:mod:`evservo.io` reads and writes bags through this module; use it directly only to list a
bag's topics. Bags are read and written with ``rosbags`` (pure Python), imported on first use.

Message types read (definitions registered from the ``.msg`` texts below, so no ROS install is
needed):

``event_camera_msgs/msg/EventPacket`` (``metavision_driver``, ``libcaer_driver``)
    ``encoding == "evt3"``: ``events`` holds raw EVT 3.0 words. The packets of a topic are one
    byte stream, decoded by the Rust EVT 3.0 decoder whose state (time base and wraps, row,
    vector base, a partial word) carries from packet to packet, so packets may be cut at any
    byte. Times are sensor times in µs from the stream (``time_base`` is undefined for evt3 and
    ignored). ``encoding == "mono"``: 64-bit words, polarity bit 63, y bits 62..48, x bits
    47..32, ``dt`` bits 31..0 in ns; time = ``(time_base + dt) // 1000`` µs.
``dvs_msgs/msg/EventArray`` and ``prophesee_event_msgs/msg/EventArray``
    ``Event[] events`` with ``x``, ``y``, ``ts`` (``builtin_interfaces/Time``, ROS time) and
    ``polarity``; time = ``ts`` in µs since the epoch.

Sensor size: ``width`` × ``height`` of the topic's first message. A bag holding one event topic
is read without naming it; with several, ``topic=`` picks one, else :func:`event_topic` raises a
``ValueError`` listing them.

Writing (:func:`write`): ``EventPacket`` messages with ``encoding "evt3"``, one per
:data:`PACKET_US` of events, encoded by the Rust EVT 3.0 encoder as one stream, in MCAP
storage. Reading the bag back gives exactly the events written; EVT 3.0 carries times ≥ 0 µs
that never step back across a 2^24 µs counter period (the encoder raises ``ValueError``
otherwise), so absolute (epoch) times must be made relative first.
"""

from __future__ import annotations

import functools
import itertools
import shutil
import tempfile
import types
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from evservo._evcore import DecodeError, Evt3Decoder, Evt3Encoder
from evservo.events import from_columns

__all__ = ["DEFAULT_TOPIC", "EVENT_PACKET", "EVENT_TYPES", "PACKET_US", "event_topic", "is_bag", "topics", "write"]

EVENT_PACKET = "event_camera_msgs/msg/EventPacket"
_DVS_ARRAY = "dvs_msgs/msg/EventArray"
_PROPHESEE_ARRAY = "prophesee_event_msgs/msg/EventArray"
#: Message types :mod:`evservo.io` reads events from.
EVENT_TYPES = (EVENT_PACKET, _DVS_ARRAY, _PROPHESEE_ARRAY)
#: Topic :func:`write` uses unless told otherwise (the drivers' default).
DEFAULT_TOPIC = "/event_camera/events"
#: Time span of the events in one written packet (µs); the drivers publish about 1 ms packets.
PACKET_US = 1000
_MCAP_SUFFIX = ".mcap"

_EVENT_PACKET_MSG = """\
std_msgs/Header header
uint32 height
uint32 width
uint64 seq
uint64 time_base
string encoding
bool is_bigendian
uint8[] events
"""
# dvs_msgs and prophesee_event_msgs share the layout of their Event and EventArray.
_EVENT_MSG = """\
uint16 x
uint16 y
builtin_interfaces/Time ts
bool polarity
"""
_EVENT_ARRAY_MSG = """\
std_msgs/Header header
uint32 height
uint32 width
Event[] events
"""


@functools.cache
def _typestore() -> Any:
    """ROS 2 jazzy's standard types plus the event messages above."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types = get_types_from_msg(_EVENT_PACKET_MSG, EVENT_PACKET)
    for package in ("dvs_msgs", "prophesee_event_msgs"):
        types.update(get_types_from_msg(_EVENT_MSG, f"{package}/msg/Event"))
        types.update(
            get_types_from_msg(_EVENT_ARRAY_MSG.replace("Event[]", f"{package}/Event[]"), f"{package}/msg/EventArray")
        )
    store.register(types)
    return store


def is_bag(path: Path) -> bool:
    """Whether :mod:`evservo.io` treats ``path`` as a bag: a rosbag2 directory or a ``.mcap`` file."""
    # A directory named like an event file (rec.h5/) is a mistake, not a bag: io says so.
    bag_dir = path.is_dir() and ((path / "metadata.yaml").is_file() or not path.suffix)
    return bag_dir or path.suffix.lower() == _MCAP_SUFFIX


def _reader(path: Path) -> Any:
    """An opened rosbags reader; missing paths raise FileNotFoundError, anything unreadable
    DecodeError."""
    from rosbags.rosbag2 import Reader

    if not path.exists():
        raise FileNotFoundError(f"no such bag: {path}")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise DecodeError(f"{path}: a directory but not a rosbag2 bag (no metadata.yaml)")
    try:
        reader = Reader(path)
        reader.open()
    except Exception as e:  # rosbags raises its own errors and whatever its storage readers hit
        raise DecodeError(f"{path}: unreadable ROS bag: {e}") from e
    return reader


def topics(path: str | Path) -> dict[str, dict[str, Any]]:
    """Every topic of the bag: ``{topic: {"type": message type, "messages": count}}``."""
    reader = _reader(Path(path))
    try:
        return _topics(reader)
    finally:
        reader.close()


def _topics(reader: Any) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for c in reader.connections:
        entry = out.setdefault(c.topic, {"type": c.msgtype, "messages": 0})
        entry["messages"] += c.msgcount
    return out


def event_topic(path: str | Path, topic: str | None = None) -> tuple[str, str]:
    """The event topic to read and its message type: ``topic`` if given, else the bag's only
    topic of an :data:`EVENT_TYPES` type. ValueError (listing the topics) when there is none,
    several, or ``topic`` is missing or of another type."""
    reader = _reader(Path(path))
    try:
        return _event_topic(Path(path), _topics(reader), topic)
    finally:
        reader.close()


def _event_topic(path: Path, all_topics: dict[str, dict[str, Any]], topic: str | None) -> tuple[str, str]:
    listing = ", ".join(f"{t} ({v['type']})" for t, v in sorted(all_topics.items())) or "none"
    if topic is not None:
        if topic not in all_topics:
            raise ValueError(f"{path}: no topic {topic!r}; topics: {listing}")
        msgtype = all_topics[topic]["type"]
        if msgtype not in EVENT_TYPES:
            raise ValueError(f"{path}: topic {topic!r} holds {msgtype}, not events ({', '.join(EVENT_TYPES)})")
        return topic, msgtype
    found = [(t, v["type"]) for t, v in sorted(all_topics.items()) if v["type"] in EVENT_TYPES]
    if len(found) == 1:
        return found[0]
    if not found:
        raise ValueError(f"{path}: no event topic ({', '.join(EVENT_TYPES)}); topics: {listing}")
    raise ValueError(f"{path}: several event topics, choose one with topic=: {', '.join(t for t, _ in found)}")


def event_blocks(path: str | Path, topic: str | None = None) -> tuple[dict[str, Any], Iterator[dict[str, np.ndarray]]]:
    """``(meta, blocks)``: the chosen topic's ``meta`` (``topic``, ``type``, ``encoding``,
    ``width``, ``height``, ``topics``) and an iterator over its messages' events as column dicts
    ``x`` (u16), ``y`` (u16), ``p`` (i16, 0/1), ``t`` (i64 µs), in bag order. The topic is chosen
    and its first message read before this returns, so a bad bag or topic raises here."""
    p = Path(path)
    reader = _reader(p)
    try:
        all_topics = _topics(reader)
        name, msgtype = _event_topic(p, all_topics, topic)
        messages = _messages(reader, name)
        first_raw = next(messages, None)
        first = None if first_raw is None else _first_message(p, name, first_raw, msgtype)
    except BaseException:
        reader.close()
        raise
    meta = dict(
        topic=name, type=msgtype, topics=all_topics,
        encoding=_encoding(first) if first is not None else None,
        width=int(first.width) if first is not None else 0, height=int(first.height) if first is not None else 0,
    )  # fmt: skip
    return meta, _blocks(p, reader, first_raw, messages, meta)


def _messages(reader: Any, topic: str) -> Iterator[bytes]:
    """The topic's serialized (CDR) messages in bag order."""
    connections = [c for c in reader.connections if c.topic == topic]
    for _con, _t, raw in reader.messages(connections=connections):
        yield raw


def _first_message(path: Path, topic: str, raw: bytes, msgtype: str) -> Any:
    """What :func:`event_blocks` needs of the first message (``width``, ``height``, ``encoding`` of
    a packet): an event array's geometry is read from its CDR head, not by deserializing every event."""
    if msgtype != EVENT_PACKET and len(raw) >= 16 and raw[1] == 1:
        frame_len = int.from_bytes(raw[12:16], "little")
        pos = 4 + ((12 + frame_len + 3) & ~3)
        if pos + 8 <= len(raw):
            height, width = (int.from_bytes(raw[pos + k : pos + k + 4], "little") for k in (0, 4))
            return types.SimpleNamespace(width=width, height=height)
    return _deserialize(path, topic, raw, msgtype)


def _deserialize(path: Path, topic: str, raw: bytes, msgtype: str) -> Any:
    try:
        return _typestore().deserialize_cdr(raw, msgtype)
    except Exception as e:  # a malformed CDR payload fails anywhere inside rosbags' parser
        raise DecodeError(f"{path}: undecodable {msgtype} message on {topic}: {e}") from e


def _encoding(msg: Any) -> str:
    return str(msg.encoding) if hasattr(msg, "encoding") else "event-array"


def _blocks(
    path: Path, reader: Any, first_raw: bytes | None, messages: Iterator[bytes], meta: dict[str, Any]
) -> Iterator[np.ndarray]:
    try:
        if first_raw is None:
            return
        topic, msgtype = meta["topic"], meta["type"]
        decode = message_decoder(msgtype, meta["encoding"], meta["width"], meta["height"], str(path))
        for raw in itertools.chain([first_raw], messages):
            # Event arrays are parsed straight from their CDR bytes (rosbags would build one Python
            # object per event, ~0.1 Mev/s); anything unusual goes through rosbags.
            cols = _event_array_cdr(path, raw) if msgtype != EVENT_PACKET else None
            yield from_columns(cols) if cols is not None else decode(_deserialize(path, topic, raw, msgtype))
    finally:
        reader.close()


def message_decoder(msgtype: str, encoding: str | None, width: int, height: int, where: str) -> Any:
    """The function turning each message of one event topic, in order, into an EVENT_CD array (for
    ``evt3`` it carries the stream's decoder state). ``msgtype`` one of :data:`EVENT_TYPES`;
    ``encoding``, ``width``, ``height`` those of the topic's first message; ``where`` names the
    source in errors. Messages may come from rosbags or from rclpy."""
    if msgtype != EVENT_PACKET:
        return lambda msg: from_columns(_event_array_columns(msg))
    if encoding == "evt3":
        try:
            stream = Evt3Decoder(width, height)
        except ValueError as e:
            raise DecodeError(f"{where}: {e}") from e
        return lambda msg: stream.decode(_payload(msg))
    if encoding == "mono":
        return lambda msg: from_columns(_mono_columns(where, msg))
    raise DecodeError(f"{where}: EventPacket encoding {encoding!r} is not supported (evt3, mono)")


def _payload(msg: Any) -> bytes:
    return np.asarray(msg.events, dtype=np.uint8).tobytes()


def _mono_columns(where: str, msg: Any) -> dict[str, np.ndarray]:
    data = _payload(msg)
    if len(data) % 8:
        raise DecodeError(f"{where}: mono EventPacket of {len(data)} bytes is not a whole number of 8-byte events")
    words = np.frombuffer(data, dtype=">u8" if msg.is_bigendian else "<u8").astype(np.uint64)
    t_ns = np.int64(msg.time_base) + (words & 0xFFFFFFFF).astype(np.int64)
    return dict(
        x=((words >> 32) & 0xFFFF).astype(np.uint16), y=((words >> 48) & 0x7FFF).astype(np.uint16),
        p=(words >> 63).astype(np.int16), t=t_ns // 1000,
    )  # fmt: skip


#: dvs_msgs / prophesee_event_msgs ``Event`` in little-endian CDR from the second element of an
#: array on: each starts 2 bytes past a 4-byte boundary, so ``ts`` is preceded by 2 bytes of padding
#: and the element (with its trailing pad byte) is 16 bytes.
_CDR_EVENT = np.dtype(
    {"names": ["x", "y", "sec", "nsec", "p"], "formats": ["<u2", "<u2", "<i4", "<u4", "u1"],
     "offsets": [0, 2, 6, 10, 14], "itemsize": 16}
)  # fmt: skip
#: The first element starts on a 4-byte boundary: no padding before ``ts``, 13 bytes (+1 pad).
_CDR_FIRST_EVENT = np.dtype(
    {"names": ["x", "y", "sec", "nsec", "p"], "formats": ["<u2", "<u2", "<i4", "<u4", "u1"],
     "offsets": [0, 2, 4, 8, 12], "itemsize": 13}
)  # fmt: skip


def _event_array_cdr(path: Path, raw: bytes) -> dict[str, np.ndarray] | None:
    """The events of a serialized ``EventArray`` (little-endian CDR) without building messages;
    None for other encodings (the caller falls back to rosbags). Offsets are counted from the end
    of the 4-byte encapsulation header, where CDR alignment starts."""
    if len(raw) < 24 or raw[1] != 1:
        return None
    body = memoryview(raw)[4:]
    frame_len = int.from_bytes(body[8:12], "little")
    pos = (12 + frame_len + 3) & ~3  # header.frame_id, then height and width (uint32)
    pos += 8
    if pos + 4 > len(body):
        raise DecodeError(f"{path}: truncated EventArray message")
    n = int.from_bytes(body[pos : pos + 4], "little")
    pos += 4
    end = pos if n == 0 else pos + 13 + 16 * (n - 1)
    if end > len(body):
        raise DecodeError(f"{path}: EventArray of {n} events in a {len(raw)}-byte message")
    if n == 0:
        return dict(
            x=np.empty(0, np.uint16), y=np.empty(0, np.uint16), p=np.empty(0, np.int16), t=np.empty(0, np.int64)
        )
    data = bytes(body[pos:end]) + b"\0"  # the last element's pad byte may be missing
    first = np.frombuffer(data, dtype=_CDR_FIRST_EVENT, count=1)
    rest = np.frombuffer(data, dtype=_CDR_EVENT, count=n - 1, offset=14)
    ev = np.concatenate([first.astype(_CDR_EVENT), rest])
    return dict(
        x=ev["x"].copy(), y=ev["y"].copy(), p=(ev["p"] != 0).astype(np.int16),
        t=ev["sec"].astype(np.int64) * 1_000_000 + ev["nsec"].astype(np.int64) // 1000,
    )  # fmt: skip


def _event_array_columns(msg: Any) -> dict[str, np.ndarray]:
    ev = msg.events
    n = len(ev)
    sec = np.fromiter((e.ts.sec for e in ev), dtype=np.int64, count=n)
    nsec = np.fromiter((e.ts.nanosec for e in ev), dtype=np.int64, count=n)
    return dict(
        x=np.fromiter((e.x for e in ev), dtype=np.uint16, count=n),
        y=np.fromiter((e.y for e in ev), dtype=np.uint16, count=n),
        p=np.fromiter((e.polarity for e in ev), dtype=np.int16, count=n),
        t=sec * 1_000_000 + nsec // 1000,
    )


def _packet_bounds(t_us: np.ndarray) -> np.ndarray:
    """Start indices of the :data:`PACKET_US` packets of a stream (the running maximum makes the
    cut "first event at or after the boundary, in stream order", as :mod:`evservo.io` slices)."""
    if len(t_us) == 0:
        return np.zeros(1, dtype=np.int64)
    running = np.maximum.accumulate(t_us)
    first = int(t_us[0]) // PACKET_US
    ends = np.arange(first + 1, int(running[-1]) // PACKET_US + 1) * PACKET_US
    starts = np.concatenate([[0], np.searchsorted(running, ends, side="left")])
    return np.unique(starts)


def write(path: str | Path, events: np.ndarray, width: int, height: int, topic: str = DEFAULT_TOPIC) -> None:
    """Write ``events`` (an EVENT_CD array on a ``width`` x ``height`` sensor) as EventPacket
    ``evt3`` messages on ``topic``: a bare MCAP file when ``path`` ends in ``.mcap``, else a new
    rosbag2 directory (MCAP storage; it must not exist yet). Events EVT 3.0 cannot carry exactly
    raise ValueError before anything is written."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    p = Path(path)
    encoder = Evt3Encoder(width, height)
    packets = []
    bounds = _packet_bounds(events["t"])
    for start, stop in zip(bounds, [*bounds[1:], len(events)], strict=True):
        chunk = events[start:stop]
        data = encoder.encode(np.ascontiguousarray(chunk))
        packets.append((int(chunk["t"].max()) if len(chunk) else 0, int(chunk["t"][0]) if len(chunk) else 0, data))
    bare = p.suffix.lower() == _MCAP_SUFFIX
    if not bare and p.exists():
        raise FileExistsError(f"{p} exists: a rosbag2 directory is written new")
    store = _typestore()
    packet_type = store.types[EVENT_PACKET]
    header_type = store.types["std_msgs/msg/Header"]
    time_type = store.types["builtin_interfaces/msg/Time"]
    with tempfile.TemporaryDirectory(dir=p.parent) as tmp:
        bag_dir = Path(tmp) / (p.stem if bare else p.name)
        with Writer(bag_dir, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            conn = writer.add_connection(topic, EVENT_PACKET, typestore=store)
            log_ns = 0
            for seq, (t_max, t_first, data) in enumerate(packets):
                stamp = time_type(sec=t_first // 1_000_000, nanosec=t_first % 1_000_000 * 1000)
                msg = packet_type(
                    header=header_type(stamp=stamp, frame_id="event_camera"), height=height, width=width,
                    seq=seq, time_base=0, encoding="evt3", is_bigendian=False,
                    events=np.frombuffer(data, dtype=np.uint8),
                )  # fmt: skip
                # Bag log times must not decrease, also where event time steps back.
                log_ns = max(log_ns, t_max * 1000)
                writer.write(conn, log_ns, store.serialize_cdr(msg, EVENT_PACKET))
        if bare:
            (bag_dir / f"{bag_dir.name}{_MCAP_SUFFIX}").replace(p)
        else:
            shutil.move(bag_dir, p)
