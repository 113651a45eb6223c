"""The event record layout shared by every reader, writer and the tracker: OpenEB's ``EventCD``
(x u16, y u16, p i16, t i64 µs; 16 bytes with padding before t). The dtype comes from the Rust
core, where the record is defined once (``evcore::EventCd``), so arrays of it cross into Rust as
one buffer without a copy."""

import numpy as np

from evservo import _evcore

EVENT_CD: np.dtype = _evcore.EVENT_CD


def as_event_cd(events: np.ndarray) -> np.ndarray:
    """``events`` as a 1-D C-contiguous EVENT_CD array: returned as it is when it already is one (no
    copy); any other structured array with fields x, y, p, t is converted (a copy), its coordinates
    checked to fit u16."""
    dtype = getattr(events, "dtype", None)
    if dtype == EVENT_CD and events.ndim == 1:
        return np.ascontiguousarray(events)
    names = getattr(dtype, "names", None) or ()
    missing = [f for f in EVENT_CD.names if f not in names]
    if missing or np.ndim(events) != 1:
        raise ValueError(f"events must be a 1-D structured array with fields x, y, p, t; missing {missing}")
    for axis in ("x", "y"):
        v = events[axis]
        if v.size and (v.min() < 0 or v.max() > 65535):
            raise ValueError("event coordinates must lie in 0..65535")
    out = np.empty(len(events), dtype=EVENT_CD)
    for name in EVENT_CD.names:
        out[name] = events[name]
    return out


def clamp_time(ev: np.ndarray, t_max: int | None) -> tuple[np.ndarray, int, int | None]:
    """Events whose time steps back below the newest one already seen (``t_max``, µs, or None before
    the first batch) restamped with that newest time: a clamp, never a drop, so a live-like consumer
    sees monotonic time (real streams, e.g. EVT3's repeated TIME_HIGH, can step back). Returns
    (events, how many were changed, new running maximum)."""
    if len(ev) == 0:
        return ev, 0, t_max
    t = ev["t"]
    running = np.maximum.accumulate(t)
    if t_max is not None:
        running = np.maximum(running, t_max)
    n = int(np.count_nonzero(running != t))
    if n:
        ev = ev.copy()
        ev["t"] = running
    return ev, n, int(running[-1])
