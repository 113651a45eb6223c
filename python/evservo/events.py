"""The event record layout shared by every reader, writer and the tracker: OpenEB's ``EventCD``
(x u16, y u16, p i16, t i64 µs; 16 bytes with padding before t). The dtype comes from the Rust
core, where the record is defined once (``evcore::EventCd``), so arrays of it cross into Rust as
one buffer without a copy."""

import numpy as np

from evservo import _evcore

EVENT_CD: np.dtype = _evcore.EVENT_CD


def as_event_cd(events: np.ndarray) -> np.ndarray:
    """``events`` as a 1-D C-contiguous EVENT_CD array: returned as it is when it already is one (no
    copy); any other structured array with fields x, y, p, t is converted (a copy) where no value
    changes (see :func:`lossless_column`)."""
    dtype = getattr(events, "dtype", None)
    if dtype == EVENT_CD and events.ndim == 1:
        return np.ascontiguousarray(events)
    names = getattr(dtype, "names", None) or ()
    missing = [f for f in EVENT_CD.names if f not in names]
    if missing or np.ndim(events) != 1:
        raise ValueError(f"events must be a 1-D structured array with fields x, y, p, t; missing {missing}")
    out = np.empty(len(events), dtype=EVENT_CD)
    for name in EVENT_CD.names:
        out[name] = lossless_column(name, events[name])  # NaN, fractions, out-of-range values refused
    return out


def from_columns(columns: dict[str, np.ndarray]) -> np.ndarray:
    """An EVENT_CD array from columns ``x``, ``y``, ``p``, ``t`` (µs) of equal length, converted
    only where no value changes (see :func:`lossless_column`)."""
    n = {name: len(columns[name]) for name in EVENT_CD.names}
    if len(set(n.values())) != 1:
        raise ValueError(f"event columns differ in length: {n}")
    out = np.empty(n["t"], dtype=EVENT_CD)
    for name in EVENT_CD.names:
        out[name] = lossless_column(name, columns[name])
    return out


def lossless_column(name: str, values: np.ndarray) -> np.ndarray:
    """Field ``name`` of :data:`EVENT_CD` from ``values`` (any numeric array), converted only when no
    value changes: ``ValueError`` for NaN, infinite or fractional values and for values outside the
    field's integer range (``p`` = 70000 or ``x`` = -1 would otherwise wrap, NaN would become 0)."""
    dtype = EVENT_CD[name]
    v = np.asarray(values)
    if v.dtype == dtype:
        return v
    if v.dtype.kind == "f":
        if not np.all(np.isfinite(v)):
            raise ValueError(f"event field {name} holds NaN or infinite values")
        if np.any(v != np.trunc(v)):
            raise ValueError(f"event field {name} holds fractional values")
    elif v.dtype.kind not in "iub":
        raise ValueError(f"event field {name} must be numeric, got dtype {v.dtype}")
    lim = np.iinfo(dtype)
    if v.size and (v.min() < lim.min or v.max() > lim.max):
        raise ValueError(f"event field {name} has values outside {lim.min}..{lim.max} (range {v.min()}..{v.max()})")
    return v.astype(dtype)


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
