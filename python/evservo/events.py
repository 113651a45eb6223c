"""The event record layout shared by every reader, writer and the tracker: OpenEB's ``EventCD``
(x u16, y u16, p i16, t i64 µs; 16 bytes with padding before t)."""

import numpy as np

EVENT_CD = np.dtype(
    {"names": ["x", "y", "p", "t"], "formats": ["<u2", "<u2", "<i2", "<i8"], "offsets": [0, 2, 4, 8], "itemsize": 16}
)


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
