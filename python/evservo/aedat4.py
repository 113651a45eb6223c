"""AEDAT4 event files (iniVation DV), read through the maintained ``aedat`` package.

An AEDAT4 file is the magic line ``#!AER-DAT4.0\\r\\n``, a little-endian u32 length and an IOHeader
flatbuffer of that length (compression, position of the trailing file data table, and an XML
description of the streams), then packets: an i32 stream id, a u32 size and that many bytes of a
(possibly LZ4/zstd-compressed) flatbuffer. Polarity events live in the streams whose type
identifier is ``EVTS``; their sensor size is the stream's ``info`` node's ``sizeX``/``sizeY``.

``aedat`` reads the IOHeader without verifying it and panics (pyo3's ``PanicException``, a
``BaseException``) or worse on a corrupt one, so this module checks the magic, the IOHeader
flatbuffer, the description and the packet chain itself before handing the file over, and turns
any error or panic of the decoder into :class:`evservo.io.DecodeError`. Events come from the first
event stream (lowest id), as EVENT_CD arrays: ``on`` becomes ``p`` in {0, 1}, ``t`` i64 µs.
"""

from __future__ import annotations

import os
import struct
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evservo._evcore import DecodeError

__all__ = ["MAGIC", "Aedat4Info", "iter_blocks", "read_header"]

MAGIC = b"#!AER-DAT4.0\r\n"
#: The IOHeader's compression enum (ioheader.fbs): none, LZ4, LZ4 high, zstd, zstd high.
COMPRESSIONS = ("none", "lz4", "lz4-high", "zstd", "zstd-high")
#: Stream types the decoder knows; any other makes ``aedat`` refuse the file.
STREAM_TYPES = ("EVTS", "FRME", "IMUS", "TRIG")

_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_I32 = struct.Struct("<i")
_I64 = struct.Struct("<q")
_PACKET = struct.Struct("<iI")


@dataclass(frozen=True)
class Aedat4Info:
    """What the header says: the event stream used and the layout of the file."""

    width: int
    height: int
    #: Id of the event stream read (the lowest EVTS id).
    stream_id: int
    #: Every stream id in the description, with its type identifier.
    streams: dict[int, str]
    compression: str
    #: Byte offset of the first packet.
    data_start: int
    #: Byte offset of the file data table, or -1 when the file has none.
    data_table: int
    n_packets: int


class _Flatbuffer:
    """Bounds-checked reads of one flatbuffer table (the subset the IOHeader needs)."""

    def __init__(self, buf: bytes, where: str) -> None:
        self.buf, self.where = buf, where

    def fail(self, what: str) -> DecodeError:
        return DecodeError(f"{self.where}: corrupt AEDAT4 IOHeader: {what}")

    def read(self, st: struct.Struct, pos: int, what: str):
        if pos < 0 or pos + st.size > len(self.buf):
            raise self.fail(f"{what} at byte {pos} lies outside the {len(self.buf)}-byte header")
        return st.unpack_from(self.buf, pos)[0]

    def root_fields(self, n_fields: int) -> tuple[int, list[int | None]]:
        """(table position, absolute position of each field or None when absent)."""
        table = self.read(_U32, 0, "root table offset")
        soffset = self.read(_I32, table, "root table")
        vtable = table - soffset
        vt_size = self.read(_U16, vtable, "vtable")
        table_size = self.read(_U16, vtable + 2, "vtable")
        if vt_size < 4 or vt_size % 2 or vtable + vt_size > len(self.buf):
            raise self.fail(f"vtable of {vt_size} bytes at byte {vtable} does not fit")
        if table_size < 4 or table + table_size > len(self.buf):
            raise self.fail(f"table of {table_size} bytes at byte {table} does not fit")
        fields: list[int | None] = []
        for i in range(n_fields):
            slot = 4 + 2 * i
            offset = self.read(_U16, vtable + slot, "vtable entry") if slot < vt_size else 0
            if offset and offset >= table_size:
                raise self.fail(f"field {i} at offset {offset} lies outside its {table_size}-byte table")
            fields.append(table + offset if offset else None)
        return table, fields

    def string(self, pos: int, what: str) -> str:
        start = pos + self.read(_U32, pos, what)
        length = self.read(_U32, start, what)
        if start + 4 + length > len(self.buf):
            raise self.fail(f"{what} of {length} bytes at byte {start} runs past the header")
        try:
            return self.buf[start + 4 : start + 4 + length].decode("utf-8")
        except UnicodeDecodeError as e:
            raise self.fail(f"{what} is not UTF-8: {e}") from e


def _streams_from_description(p: Path, xml: str) -> tuple[dict[int, str], dict[int, tuple[int, int]]]:
    """Stream id → type identifier, and event/frame stream id → (width, height)."""

    def fail(what: str) -> DecodeError:
        return DecodeError(f"{p}: corrupt AEDAT4 stream description: {what}")

    try:
        root = ET.fromstring(xml)
    except ET.ParseError as e:
        raise fail(f"not XML ({e})") from e
    if root.tag != "dv":
        raise fail(f"root element is <{root.tag}>, expected <dv>")
    out_info = next((n for n in root.findall("node") if n.get("name") == "outInfo"), None)
    if out_info is None:
        raise fail("no outInfo node")
    types: dict[int, str] = {}
    sizes: dict[int, tuple[int, int]] = {}
    for node in out_info.findall("node"):
        name = node.get("name", "")
        if not name.isdigit():
            raise fail(f"stream node name {name!r} is not a stream id")
        sid = int(name)
        if sid >= 2**31 or sid in types:
            raise fail(f"stream id {sid} is out of range or repeated")
        kind = next((a.text for a in node.findall("attr") if a.get("key") == "typeIdentifier"), None)
        if kind not in STREAM_TYPES:
            raise fail(f"stream {sid} has type {kind!r} (supported: {', '.join(STREAM_TYPES)})")
        types[sid] = kind
        if kind in ("EVTS", "FRME"):
            info = next((n for n in node.findall("node") if n.get("name") == "info"), None)
            attrs = {} if info is None else {a.get("key"): (a.text or "") for a in info.findall("attr")}
            size_x, size_y = attrs.get("sizeX", ""), attrs.get("sizeY", "")
            # Plain digits only: the decoder parses them as u16 and rejects anything else.
            if not (size_x.isascii() and size_x.isdigit() and size_y.isascii() and size_y.isdigit()):
                raise fail(f"stream {sid} ({kind}) has no valid sizeX/sizeY (got {size_x!r}, {size_y!r})")
            w, h = int(size_x), int(size_y)
            if not (0 < w < 65536 and 0 < h < 65536):
                raise fail(f"stream {sid} has sensor size {w}x{h}")
            sizes[sid] = (w, h)
    if not types:
        raise fail("no streams")
    return types, sizes


def read_header(path: str | os.PathLike) -> Aedat4Info:
    """Validates an AEDAT4 file's framing (magic, IOHeader, description, packet chain) without
    decoding packets; raises :class:`DecodeError` saying what is wrong."""
    p = Path(path)
    size = p.stat().st_size
    with open(p, "rb") as f:
        magic = f.read(len(MAGIC))
        if magic != MAGIC:
            raise DecodeError(f"{p}: not an AEDAT4 file: it starts with {magic[:16]!r}, expected {MAGIC!r}")
        raw_len = f.read(4)
        if len(raw_len) < 4:
            raise DecodeError(f"{p}: truncated AEDAT4 file: it ends inside the IOHeader length")
        (header_len,) = _U32.unpack(raw_len)
        data_start = len(MAGIC) + 4 + header_len
        if data_start > size:
            raise DecodeError(
                f"{p}: truncated or corrupt AEDAT4 file: the IOHeader claims {header_len} bytes, "
                f"the file has {size - len(MAGIC) - 4} after its length"
            )
        fb = _Flatbuffer(f.read(header_len), str(p))
        _, (compression_at, table_at, description_at) = fb.root_fields(3)
        compression = 0 if compression_at is None else fb.read(_I32, compression_at, "compression")
        if not 0 <= compression < len(COMPRESSIONS):
            raise fb.fail(f"unknown compression {compression}")
        data_table = -1 if table_at is None else fb.read(_I64, table_at, "file data position")
        if data_table > size:
            raise DecodeError(
                f"{p}: truncated AEDAT4 file: its header places the file data table at byte {data_table}, "
                f"the file has {size} bytes"
            )
        if data_table != -1 and data_table < data_start:
            raise fb.fail(f"file data table position {data_table} lies before the first packet (byte {data_start})")
        if description_at is None:
            raise fb.fail("no stream description")
        types, sizes = _streams_from_description(p, fb.string(description_at, "stream description"))
        event_ids = sorted(sid for sid, kind in types.items() if kind == "EVTS")
        if not event_ids:
            raise DecodeError(f"{p}: the AEDAT4 file has no event (EVTS) stream; streams: {types}")

        if data_table != -1 and compression == 0:
            # The table (a size-prefixed flatbuffer indexing the packets) is not read, but a file
            # cut inside it is still a truncated file. (Compressed files compress it too.)
            f.seek(data_table)
            prefix = f.read(4)
            table_len = _U32.unpack(prefix)[0] if len(prefix) == 4 else None
            if table_len is None or data_table + 4 + table_len > size:
                raise DecodeError(
                    f"{p}: truncated AEDAT4 file: it ends inside the file data table at byte {data_table}"
                )
        # The packet chain must tile the file up to the data table (or its end) exactly.
        end = size if data_table == -1 else data_table
        pos, n_packets = data_start, 0
        while pos < end:
            f.seek(pos)
            head = f.read(_PACKET.size)
            if pos + _PACKET.size > end or len(head) < _PACKET.size:
                raise DecodeError(f"{p}: truncated AEDAT4 file: it ends inside the header of packet {n_packets}")
            sid, length = _PACKET.unpack(head)
            if sid not in types:
                raise DecodeError(f"{p}: corrupt AEDAT4 packet {n_packets} at byte {pos}: unknown stream id {sid}")
            if pos + _PACKET.size + length > end:
                raise DecodeError(
                    f"{p}: truncated AEDAT4 file: packet {n_packets} at byte {pos} needs {length} bytes, "
                    f"{end - pos - _PACKET.size} remain"
                )
            pos += _PACKET.size + length
            n_packets += 1
    width, height = sizes[event_ids[0]]
    return Aedat4Info(
        width=width, height=height, stream_id=event_ids[0], streams=types,
        compression=COMPRESSIONS[compression], data_start=data_start, data_table=data_table, n_packets=n_packets,
    )  # fmt: skip


def _is_panic(e: BaseException) -> bool:
    # pyo3 creates PanicException at run time (module ``pyo3_runtime``); it is not importable.
    return type(e).__name__ == "PanicException"


def iter_blocks(path: str | os.PathLike, info: Aedat4Info | None = None) -> Iterator[np.ndarray]:
    """The event stream's packets as EVENT_CD arrays, in file order. Validates the file first
    (unless ``info`` from :func:`read_header` is given) and checks every event lies on the sensor."""
    from evservo.io import EVENT_CD

    p = Path(path)
    info = read_header(p) if info is None else info
    try:
        import aedat
    except ImportError as e:
        raise ImportError(f"reading {p} needs the aedat package: pip install aedat==2.3.0") from e

    def failed(e: BaseException) -> DecodeError:
        return DecodeError(f"{p}: corrupt AEDAT4 data ({type(e).__name__} in the aedat decoder: {e})")

    def guarded(call):
        # The decoder's errors, and its Rust panics (BaseException subclasses), become DecodeError;
        # KeyboardInterrupt and the like pass through.
        try:
            return call()
        except Exception as e:
            raise failed(e) from e
        except BaseException as e:
            if not _is_panic(e):
                raise
            raise failed(e) from e

    packets = guarded(lambda: iter(aedat.Decoder(p)))
    index = 0
    while True:
        packet = guarded(lambda: next(packets, None))
        if packet is None:
            return
        index += 1
        if packet.get("stream_id") != info.stream_id or "events" not in packet:
            continue
        ev = packet["events"]
        if len(ev):
            if int(ev["x"].max()) >= info.width or int(ev["y"].max()) >= info.height:
                raise DecodeError(
                    f"{p}: corrupt AEDAT4 packet {index - 1}: an event lies outside the "
                    f"{info.width}x{info.height} sensor"
                )
            if int(ev["t"].max()) >= 2**63:
                raise DecodeError(f"{p}: corrupt AEDAT4 packet {index - 1}: a timestamp is beyond 2^63 µs")
        out = np.empty(len(ev), dtype=EVENT_CD)
        out["x"] = ev["x"]
        out["y"] = ev["y"]
        out["p"] = ev["on"]
        out["t"] = ev["t"]
        yield out
