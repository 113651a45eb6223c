"""Event files: read, slice and write change-detection events as ``EVENT_CD`` arrays.

Events are numpy structured arrays of dtype :data:`EVENT_CD`, the layout of OpenEB's ``EventCD``:
``x`` u16 and ``y`` u16 (sensor pixels), ``p`` i16 (0 = OFF, 1 = ON), ``t`` i64 (µs).

Formats, chosen by file extension:

``.raw``
    Prophesee RAW, EVT 2.0 or EVT 3.0, decoded by the Rust core (``evservo._evcore.RawReader``)
    with the GIL released. Geometry comes from the header; a ``% t0`` header line (faery writes
    times relative to it) is added back to every timestamp. Read only.
``.aedat4``
    iniVation AEDAT4 (DV), read through the ``aedat`` package after :mod:`evservo.aedat4` has
    checked the file's header, stream description and packet framing. Events of the first event
    stream; the sensor size from its description; ``on`` becomes ``p``. Read only.
``.npz`` (ours)
    ``events``: an EVENT_CD array; ``width``, ``height``: 0-d integer arrays. Written compressed.
``.npy``
    A bare EVENT_CD array. The sensor size is not stored: readers infer it as max(x)+1 by
    max(y)+1 and :func:`info` reports ``geometry_inferred=True``.
``.h5`` / ``.hdf5``, our layout
    Group ``/events`` with 1-D datasets ``x`` (u16), ``y`` (u16), ``p`` (i16), ``t`` (i64, µs), all
    chunked and compressed as :data:`H5_COMPRESSION` says (Blosc + zstd through ``hdf5plugin`` by
    default; files written with gzip or uncompressed read too), and integer attributes ``width``
    and ``height`` on ``/events``.
``.h5`` / ``.hdf5``, Metavision layout (read only)
    Compound dataset ``/CD/events`` with fields x, y, p, t. Geometry from the root attribute
    ``geometry`` ("WxH") or ``width``/``height``, else inferred as for ``.npy``. Files compressed
    with Prophesee's ECF codec (HDF5 filter 0x8ECF) need the hdf5-ecf plugin on
    ``HDF5_PLUGIN_PATH``, which ships only with Prophesee's own packages (not PyPI, not Debian);
    without it reading raises :class:`DecodeError` naming the codec. Files compressed with any
    filter ``hdf5plugin`` provides (Blosc, Blosc2, Zstd, LZ4, Bitshuffle, ...) read.

ROS 2 bags: a rosbag2 directory or a bare ``.mcap`` file
    ``event_camera_msgs/EventPacket`` (``evt3``, ``mono``), ``dvs_msgs/EventArray`` or
    ``prophesee_event_msgs/EventArray`` messages, through :mod:`evservo.bags` (see there for
    times and geometry). ``topic=`` picks the event topic when there are several;
    :func:`info` lists the topics. Written as EventPacket ``evt3`` (exact round trip).

Not read: CSV, Prophesee DAT, ES (faery writes these).

Bad input raises ``FileNotFoundError`` (missing file), :class:`DecodeError` (a ``ValueError``;
corrupt or truncated content) or ``ValueError`` (unsupported extension or arguments).
"""

from __future__ import annotations

import os
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path

import h5py
import hdf5plugin
import numpy as np

from evservo import aedat4, bags
from evservo._evcore import DecodeError, RawReader, RawSlices
from evservo.events import EVENT_CD, from_columns, lossless_column
from evservo.input_files import require_regular_file
from evservo.outputs import atomic_path

__all__ = ["EVENT_CD", "DecodeError", "info", "open_events", "read_events", "write_events"]


#: HDF5 filter id of Prophesee's ECF codec used by Metavision HDF5 files.
ECF_FILTER_ID = 0x8ECF

#: How the HDF5 files evservo writes (:func:`write_events` and the recordings of
#: :mod:`evservo.sim.record`) compress their event columns: keyword arguments for h5py's
#: ``create_dataset``, set once here for every writer. The default is Blosc with zstd level 5 and
#: bit-shuffle (HDF5 filter 32001 from ``hdf5plugin``): on the real EVT3 recording 14 % of the raw
#: column size, smaller than gzip's 17 %, and about twice as fast to read and write. Importing this
#: module imports ``hdf5plugin``, which registers its filters (Blosc, Blosc2, Zstd, LZ4,
#: Bitshuffle, ...) with HDF5, so such files from other tools read too. Other programs need
#: ``hdf5plugin`` (or the Blosc plugin on ``HDF5_PLUGIN_PATH``) to read these files; set
#: ``{"compression": "gzip"}`` for files any HDF5 reader opens, or ``{}`` for no compression.
H5_COMPRESSION: Mapping[str, object] = hdf5plugin.Blosc(cname="zstd", clevel=5, shuffle=hdf5plugin.Blosc.BITSHUFFLE)


def h5_compression_options() -> dict[str, object]:
    """:data:`H5_COMPRESSION` as a plain dict of ``create_dataset`` keyword arguments, read at
    call time so that changing the module attribute affects every later write."""
    return dict(H5_COMPRESSION or {})


_RAW_BLOCK_EVENTS = 1 << 20
#: Events per HDF5 chunk in files written by :func:`write_events` (1 MB of ``t``).
_H5_CHUNK_EVENTS = 1 << 17
_H5_SUFFIXES = (".h5", ".hdf5")
_AEDAT_SUFFIX = ".aedat4"
_SUFFIXES = (".raw", _AEDAT_SUFFIX, ".npz", ".npy", *_H5_SUFFIXES)


#: What :func:`_checked_path` calls a ROS bag (directory or ``.mcap`` file) in place of a suffix.
_BAG = "rosbag2"


def _checked_path(path: str | os.PathLike, topic: str | None = None) -> tuple[Path, str]:
    p = Path(path)
    if bags.is_bag(p):
        return p, _BAG
    if topic is not None:
        raise ValueError(f"topic= applies to ROS bags only, not {p}")
    suffix = p.suffix.lower()
    if suffix not in _SUFFIXES:
        raise ValueError(f"unsupported event file extension {suffix!r} for {p} (supported: {', '.join(_SUFFIXES)})")
    return require_regular_file(p, "event file"), suffix


def _as_cd(events: np.ndarray) -> np.ndarray:
    """Any structured array with fields x, y, p, t as an EVENT_CD array (copied if needed)."""
    names = getattr(events.dtype, "names", None) or ()
    missing = [n for n in EVENT_CD.names if n not in names]
    if events.ndim != 1 or missing:
        raise ValueError(f"events must be a 1-D structured array with fields x, y, p, t (missing: {missing})")
    if events.dtype == EVENT_CD:
        return events
    out = np.empty(len(events), dtype=EVENT_CD)
    for name in EVENT_CD.names:
        out[name] = lossless_column(name, events[name])
    return out


def _inferred_geometry(events: np.ndarray) -> tuple[int, int]:
    if len(events) == 0:
        return 0, 0
    return int(events["x"].max()) + 1, int(events["y"].max()) + 1


#: Largest sensor side a file may declare: x and y are u16 pixel indices.
MAX_SENSOR_SIDE = 1 << 16


def _stored_geometry(p: Path, width: object, height: object) -> tuple[int, int]:
    """A file's declared sensor size as ints, refused unless both are whole numbers in
    1..:data:`MAX_SENSOR_SIDE` (a negative or huge size would otherwise flow into allocations)."""

    def side(v: object) -> int | None:
        v = v.item() if isinstance(v, np.ndarray | np.generic) and np.ndim(v) == 0 else v
        if isinstance(v, bytes | str):
            text = v.decode() if isinstance(v, bytes) else v
            return int(text) if text.strip().isdigit() else None
        if isinstance(v, float) and v.is_integer():
            return int(v)
        return v if isinstance(v, int) and not isinstance(v, bool) else None

    w, h = side(width), side(height)
    if w is None or h is None or not (1 <= w <= MAX_SENSOR_SIDE and 1 <= h <= MAX_SENSOR_SIDE):
        raise DecodeError(f"{p}: sensor size must be whole numbers in 1..{MAX_SENSOR_SIDE}, got {width}x{height}")
    return w, h


def _h5_columns(p: Path, g: h5py.Group, sl: slice = slice(None)) -> dict[str, np.ndarray]:
    """The four event columns of our HDF5 layout (the slice ``sl`` of each), refused when their
    lengths differ instead of being broadcast."""
    lengths = {n: len(g[n]) for n in EVENT_CD.names}
    if len(set(lengths.values())) != 1:
        raise DecodeError(f"{p}: event columns differ in length: {lengths}")
    return {n: g[n][sl] for n in EVENT_CD.names}


def _load_npz(p: Path) -> tuple[np.ndarray, int, int]:
    try:
        with np.load(p, allow_pickle=False) as z:
            events, width, height = z["events"], z["width"], z["height"]
    except (KeyError, ValueError, OSError, EOFError, zipfile.BadZipFile) as e:
        raise DecodeError(f"{p}: corrupt or not an evservo .npz (events, width, height): {e}") from e
    return _decoded_cd(p, events), *_stored_geometry(p, width, height)


def _decoded_cd(p: Path, events: np.ndarray) -> np.ndarray:
    try:
        return _as_cd(events)
    except ValueError as e:
        raise DecodeError(f"{p}: {e}") from e


def _load_npy(p: Path) -> np.ndarray:
    try:
        events = np.load(p, allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise DecodeError(f"{p}: corrupt .npy: {e}") from e
    return _decoded_cd(p, events)


def _check_ecf(p: Path, ds: h5py.Dataset) -> None:
    plist = ds.id.get_create_plist()
    for i in range(plist.get_nfilters()):
        if plist.get_filter(i)[0] == ECF_FILTER_ID and not h5py.h5z.filter_avail(ECF_FILTER_ID):
            raise DecodeError(
                f"{p}: {ds.name} is compressed with Prophesee's ECF codec (HDF5 filter 0x8ECF), which is not "
                "available: install the hdf5-ecf plugin (e.g. Ubuntu package hdf5-plugin-ecf) and point "
                "HDF5_PLUGIN_PATH at it"
            )


def _load_h5(p: Path) -> tuple[np.ndarray, int, int, bool, str]:
    """(events, width, height, geometry_inferred, layout name)."""
    try:
        f = h5py.File(p, "r")
    except OSError as e:
        raise DecodeError(f"{p}: not a readable HDF5 file: {e}") from e
    try:
        with f:
            if "events" in f and isinstance(f["events"], h5py.Group):
                g = f["events"]
                events = from_columns(_h5_columns(p, g))
                return events, *_stored_geometry(p, g.attrs["width"], g.attrs["height"]), False, "hdf5"
            if "CD/events" in f:
                ds = f["CD/events"]
                _check_ecf(p, ds)
                events = _decoded_cd(p, ds[()])
                geometry = f.attrs.get("geometry")
                if isinstance(geometry, bytes):
                    geometry = geometry.decode()
                if isinstance(geometry, str) and "x" in geometry:
                    w, h = geometry.split("x", 1)
                    return events, *_stored_geometry(p, w, h), False, "metavision-hdf5"
                if "width" in f.attrs and "height" in f.attrs:
                    return events, *_stored_geometry(p, f.attrs["width"], f.attrs["height"]), False, "metavision-hdf5"
                return events, *_inferred_geometry(events), True, "metavision-hdf5"
    except DecodeError:
        raise
    except (KeyError, OSError, ValueError, TypeError) as e:
        raise DecodeError(f"{p}: unreadable event HDF5: {e}") from e
    raise DecodeError(f"{p}: HDF5 file has neither /events (evservo) nor /CD/events (Metavision)")


def _load_array(p: Path, suffix: str) -> tuple[np.ndarray, int, int, bool, str]:
    if suffix == ".npz":
        return (*_load_npz(p), False, "npz")
    if suffix == ".npy":
        events = _load_npy(p)
        return events, *_inferred_geometry(events), True, "npy"
    return _load_h5(p)


def _raw_slices(p: Path, delta_t_us: int | None, n_events: int | None) -> Iterator[np.ndarray]:
    """Slices cut in Rust and handed over a run at a time (one array per ~1 MiB of the file): each
    slice is a view into its run, so crossing to Python costs one array per run, not per slice."""
    for events, ends in RawSlices(p, delta_t_us=delta_t_us, n_events=n_events):
        start = 0
        for stop in ends:
            yield events[start:stop]
            start = stop


def _is_our_h5(p: Path) -> bool:
    try:
        with h5py.File(p, "r") as f:
            return "events" in f and isinstance(f["events"], h5py.Group)
    except OSError as e:
        raise DecodeError(f"{p}: not a readable HDF5 file: {e}") from e


def _h5_blocks(p: Path, n: int) -> Iterator[np.ndarray]:
    """Our HDF5 layout read ``n`` events at a time, so long recordings never sit in memory whole."""
    try:
        with h5py.File(p, "r") as f:
            g = f["events"]
            total = len(g["t"])
            for start in range(0, total, n):
                yield from_columns(_h5_columns(p, g, slice(start, start + n)))
    except DecodeError:
        raise
    except (KeyError, OSError, ValueError, TypeError) as e:
        raise DecodeError(f"{p}: unreadable event HDF5: {e}") from e


def _block_time_slices(blocks: Iterator[np.ndarray], delta_t_us: int) -> Iterator[np.ndarray]:
    """The slices of :func:`_array_time_slices` over a stream of blocks (same boundaries, same
    stream-order rule), carrying partial slices across block edges."""
    end, carry, t_max = None, [], None
    for block in blocks:
        if len(block) == 0:
            continue
        if end is None:
            end = (int(block["t"][0]) // delta_t_us + 1) * delta_t_us
        running = np.maximum.accumulate(block["t"])
        if t_max is not None:
            running = np.maximum(running, t_max)
        t_max = int(running[-1])
        start = 0
        while True:
            stop = int(np.searchsorted(running, end, side="left"))
            if stop == len(block):
                carry.append(block[start:])
                break
            yield np.concatenate([*carry, block[start:stop]], dtype=EVENT_CD)
            carry, start = [], stop
            end += delta_t_us
    if carry:
        yield np.concatenate(carry, dtype=EVENT_CD)


def _rechunked(blocks: Iterator[np.ndarray], n: int) -> Iterator[np.ndarray]:
    """Blocks of any sizes regrouped into slices of exactly ``n`` events (the last one shorter)."""
    pending, count = [], 0
    for block in blocks:
        while len(block):
            take = min(n - count, len(block))
            pending.append(block[:take])
            count += take
            block = block[take:]
            if count == n:
                yield np.concatenate(pending, dtype=EVENT_CD)
                pending, count = [], 0
    if count:
        yield np.concatenate(pending, dtype=EVENT_CD)


def _array_time_slices(events: np.ndarray, delta_t_us: int) -> Iterator[np.ndarray]:
    if len(events) == 0:
        return
    # The running maximum turns "first event at or after the boundary, in stream order" into a
    # sorted search, also where time steps back; stream order is kept, as in the RAW reader.
    running = np.maximum.accumulate(events["t"])
    start = 0
    end = (int(events["t"][0]) // delta_t_us + 1) * delta_t_us
    while start < len(events):
        stop = int(np.searchsorted(running, end, side="left"))
        yield events[start:stop]
        start = stop
        end += delta_t_us


def open_events(
    path: str | os.PathLike, delta_t_us: int | None = None, n_events: int | None = None, topic: str | None = None
) -> Iterator[np.ndarray]:
    """Iterate over an event file in EVENT_CD slices, like OpenEB's ``EventsIterator``.

    Give at most one of ``delta_t_us`` (time slices, default 10 000 µs) and ``n_events`` (slices
    of that many events, the last one shorter). Time slices lie on a grid of multiples of
    ``delta_t_us`` starting with the one holding the first event; each slice ends before the first
    event at or after its end, in stream order, and slices without events inside the recording
    are yielded empty. The slices concatenate to :func:`read_events`. ``topic`` picks the event
    topic of a ROS bag. Slices of a RAW file are views into runs of decoded events (about 1 MiB of
    the file each), so a slice kept after the iteration moved on keeps its run's memory (copy it
    to release that).
    """
    if delta_t_us is not None and n_events is not None:
        raise ValueError("give only one of delta_t_us and n_events")
    if n_events is not None:
        if n_events < 1:
            raise ValueError(f"n_events must be >= 1, got {n_events}")
    else:
        delta_t_us = 10_000 if delta_t_us is None else delta_t_us
        if delta_t_us < 1:
            raise ValueError(f"delta_t_us must be >= 1, got {delta_t_us}")
    p, suffix = _checked_path(path, topic)
    if suffix == _BAG:
        blocks = bags.event_blocks(p, topic)[1]
        if n_events is not None:
            return _rechunked(blocks, n_events)
        return _block_time_slices(blocks, delta_t_us)
    if suffix == ".raw":
        return _raw_slices(p, delta_t_us, n_events)
    if suffix in _H5_SUFFIXES and _is_our_h5(p):
        if n_events is not None:
            return _h5_blocks(p, n_events)
        return _block_time_slices(_h5_blocks(p, _RAW_BLOCK_EVENTS), delta_t_us)
    if suffix == _AEDAT_SUFFIX:
        # The header and packet chain are checked here, before the first slice is asked for.
        blocks = aedat4.iter_blocks(p, aedat4.read_header(p))
        if n_events is not None:
            return _rechunked(blocks, n_events)
        return _block_time_slices(blocks, delta_t_us)
    events = _load_array(p, suffix)[0]
    if n_events is not None:
        return (events[i : i + n_events] for i in range(0, len(events), n_events))
    return _array_time_slices(events, delta_t_us)


def read_events(path: str | os.PathLike, topic: str | None = None) -> np.ndarray:
    """All events of a file as one EVENT_CD array, in stream order (``topic``: see :func:`open_events`)."""
    p, suffix = _checked_path(path, topic)
    if suffix == _BAG:
        blocks = list(bags.event_blocks(p, topic)[1])
        return np.concatenate(blocks, dtype=EVENT_CD) if blocks else np.empty(0, dtype=EVENT_CD)
    if suffix == ".raw":
        return RawReader(p).read_all()
    if suffix == _AEDAT_SUFFIX:
        blocks = list(aedat4.iter_blocks(p))
        return np.concatenate(blocks, dtype=EVENT_CD) if blocks else np.empty(0, dtype=EVENT_CD)
    return _load_array(p, suffix)[0]


def info(path: str | os.PathLike, topic: str | None = None) -> dict:
    """Format, sensor size and extent of an event file (RAW and AEDAT4 files are decoded once to count).

    Keys: ``format`` ("EVT2", "EVT3", "aedat4", "npz", "npy", "hdf5" or "metavision-hdf5"),
    ``width``, ``height`` (pixels), ``n_events``, ``t_first_us``, ``t_last_us`` (None when empty) and
    ``geometry_inferred`` (True when the size was taken as max+1 of the coordinates).
    ROS bags (format "rosbag2", decoded once to count) also report the event ``topic`` read,
    its message ``type`` and ``encoding``, and ``topics`` (every topic's type and message count).
    """
    p, suffix = _checked_path(path, topic)
    if suffix == _BAG:
        return _bag_info(p, topic)
    if suffix == ".raw":
        reader = RawReader(p)
        n, t_first, t_last = 0, None, None
        while (block := reader.read_n_events(_RAW_BLOCK_EVENTS)) is not None:
            if len(block):
                t_first = int(block["t"][0]) if t_first is None else t_first
                t_last = int(block["t"][-1])
                n += len(block)
        return dict(
            format=reader.format, width=reader.width, height=reader.height, n_events=n,
            t_first_us=t_first, t_last_us=t_last, geometry_inferred=False,
        )  # fmt: skip
    if suffix in _H5_SUFFIXES and _is_our_h5(p):
        return _h5_info(p)
    if suffix == _AEDAT_SUFFIX:
        header = aedat4.read_header(p)
        n, t_first, t_last = 0, None, None
        for block in aedat4.iter_blocks(p, header):
            if len(block):
                t_first = int(block["t"][0]) if t_first is None else t_first
                t_last = int(block["t"][-1])
                n += len(block)
        return dict(
            format="aedat4", width=header.width, height=header.height, n_events=n,
            t_first_us=t_first, t_last_us=t_last, geometry_inferred=False,
        )  # fmt: skip
    events, width, height, inferred, layout = _load_array(p, suffix)
    empty = len(events) == 0
    return dict(
        format=layout, width=width, height=height, n_events=len(events),
        t_first_us=None if empty else int(events["t"][0]), t_last_us=None if empty else int(events["t"][-1]),
        geometry_inferred=inferred,
    )  # fmt: skip


def _bag_info(p: Path, topic: str | None) -> dict:
    meta, blocks = bags.event_blocks(p, topic)
    n, t_first, t_last = 0, None, None
    for cols in blocks:
        if len(cols["t"]):
            t_first = int(cols["t"][0]) if t_first is None else t_first
            t_last = int(cols["t"][-1])
            n += len(cols["t"])
    return dict(
        format=_BAG, width=meta["width"], height=meta["height"], n_events=n, t_first_us=t_first,
        t_last_us=t_last, geometry_inferred=False, topic=meta["topic"], type=meta["type"],
        encoding=meta["encoding"], topics=meta["topics"],
    )  # fmt: skip


#: Root attribute of a simulated recording (:mod:`evservo.sim.record`): 0 while it is written, 1 as
#: its last write. Recordings from before it existed lack it and count as complete.
RECORDING_COMPLETE_ATTR = "evservo_complete"


def check_complete_recording(p: Path, f: h5py.File) -> None:
    """Raise :class:`DecodeError` for a simulated recording whose writer stopped before its last write."""
    if f.attrs.get("evservo_recording", 0) and not f.attrs.get(RECORDING_COMPLETE_ATTR, 1):
        raise DecodeError(f"{p} is an incomplete recording (its `evservo sim record` was interrupted): record it again")


def _h5_info(p: Path) -> dict:
    """:func:`info` of our HDF5 layout from the dataset shapes and end points; a simulated recording
    (:mod:`evservo.sim.record`) also reports ``object``, ``trajectory``, ``duration_s`` and ``has_gt``."""
    try:
        with h5py.File(p, "r") as f:
            g = f["events"]
            t = g["t"]
            n = len(t)
            _h5_columns(p, g, slice(0, 0))
            width, height = _stored_geometry(p, g.attrs["width"], g.attrs["height"])
            out = dict(
                format="hdf5", width=width, height=height, n_events=n,
                t_first_us=int(t[0]) if n else None, t_last_us=int(t[n - 1]) if n else None, geometry_inferred=False,
            )  # fmt: skip
            check_complete_recording(p, f)
            if f.attrs.get("evservo_recording", 0):
                out.update(
                    object=str(f.attrs["object"]), trajectory=str(f.attrs["trajectory"]),
                    duration_s=float(f.attrs["duration_s"]), has_gt="gt/T_c_o" in f,
                )  # fmt: skip
            return out
    except DecodeError:
        raise
    except (KeyError, OSError, ValueError, TypeError) as e:
        raise DecodeError(f"{p}: unreadable event HDF5: {e}") from e


def write_events(
    path: str | os.PathLike, events: np.ndarray, width: int, height: int, topic: str = bags.DEFAULT_TOPIC
) -> None:
    """Write events to ``.npz``, ``.npy`` or ``.h5``/``.hdf5`` (our layouts, see the module doc), or
    to a ROS 2 bag on ``topic``: a bare ``.mcap`` file, or a new rosbag2 directory when ``path``
    has no suffix (see :func:`evservo.bags.write`).

    Every event must lie on the ``width`` x ``height`` sensor. ``.npy`` does not store the size.
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in (".npz", ".npy", *_H5_SUFFIXES, ".mcap", ""):
        raise ValueError(
            f"cannot write {suffix!r} event files (supported: .npz, .npy, .h5, .hdf5, .mcap, a rosbag2 directory)"
        )
    events = _as_cd(np.asarray(events))
    if not (1 <= width <= MAX_SENSOR_SIDE and 1 <= height <= MAX_SENSOR_SIDE):
        raise ValueError(f"sensor size must be in 1..{MAX_SENSOR_SIDE} per side, got {width}x{height}")
    if len(events) and (int(events["x"].max()) >= width or int(events["y"].max()) >= height):
        raise ValueError(f"events reach beyond the {width}x{height} sensor")
    if suffix in (".mcap", ""):
        # Written into a temporary directory beside the target, moved into place when complete.
        bags.write(p, events, width, height, topic)
        return
    if p.is_dir():
        raise ValueError(f"{p} is a directory; give an event file name")
    # To a temporary file beside it, renamed when complete: an interrupted write keeps the old file.
    with atomic_path(p) as tmp:
        _write_to(tmp, suffix, events, width, height)


def _write_to(p: Path, suffix: str, events: np.ndarray, width: int, height: int) -> None:
    if suffix == ".npz":
        with p.open("wb") as fh:  # a file object: numpy would append ".npz" to a name lacking it
            np.savez_compressed(fh, events=events, width=np.int64(width), height=np.int64(height))
    elif suffix == ".npy":
        with p.open("wb") as fh:
            np.save(fh, events)
    else:
        with h5py.File(p, "w") as f:
            g = f.create_group("events")
            g.attrs["width"] = int(width)
            g.attrs["height"] = int(height)
            # HDF5 cannot chunk (hence compress) an empty dataset.
            options = h5_compression_options() if len(events) else {}
            if options:
                options.setdefault("chunks", (min(len(events), _H5_CHUNK_EVENTS),))
            for name in EVENT_CD.names:
                g.create_dataset(name, data=events[name], **options)
