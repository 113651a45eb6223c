"""Splitting an event stream into blinks, and one event image per blink.

A blink of the screen (its lit squares switching on or off together) fires a large part of the
sensor within a millisecond or so: a sharp peak of the event rate over whatever the scene, the
camera's motion and the sensor's noise produce around it. The rate is counted in ``bin_us`` bins;
a bin is *hot* when it holds more than ``peak_factor`` times the local rate (the median of the bins
within ±``local_us``) plus a floor of ``min_rate`` events per pixel per second; a blink is a run of
hot bins grown over neighbours above half that threshold, and no longer than ``max_us`` (a screen
switches within a few milliseconds; a longer run is the camera starting to move). The image of a
blink counts every event (both polarities) of its run per pixel.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import median_filter

__all__ = ["DEFAULT_PARAMS", "Blink", "BlinkParams", "Stream", "blink_windows", "iter_blinks"]

#: A factory of the stream: each call iterates again over time-ordered EVENT_CD slices.
Stream = Callable[[], Iterable[np.ndarray]]


@dataclass(frozen=True)
class BlinkParams:
    """Thresholds of the blink splitter (see the module docstring). Times in µs."""

    bin_us: int = 500
    local_us: int = 50_000
    peak_factor: float = 4.0
    #: Floor of a hot bin, events per pixel per second (0.05 = 46 000 events/s on a 1280×720 sensor).
    min_rate: float = 0.05
    #: Fewest events of a blink, as a fraction of the sensor's pixels.
    min_events_fraction: float = 0.005
    max_us: int = 20_000


DEFAULT_PARAMS = BlinkParams()


@dataclass
class Blink:
    """One blink: events in [t_start_us, t_end_us), their count image ((height, width) uint16)."""

    t_start_us: int
    t_end_us: int
    n_events: int
    image: np.ndarray


def _rate_histogram(stream: Stream, bin_us: int) -> tuple[int, np.ndarray]:
    """(t0_us, counts per bin from t0)."""
    t0: int | None = None
    counts = np.zeros(0, np.int64)
    for ev in stream():
        if not len(ev):
            continue
        if t0 is None:
            t0 = int(ev["t"][0])
        idx = (ev["t"] - t0) // bin_us
        if idx[0] < 0:
            raise ValueError("event times go backwards; a calibration recording must be time-ordered")
        c = np.bincount(idx)
        if len(c) > len(counts):
            counts = np.pad(counts, (0, len(c) - len(counts)))
        counts[: len(c)] += c
    return (0 if t0 is None else t0), counts


def blink_windows(stream: Stream, n_pixels: int, params: BlinkParams = DEFAULT_PARAMS) -> list[tuple[int, int]]:
    """The [start, end) times (µs) of the blinks in the stream (see the module docstring)."""
    t0, counts = _rate_histogram(stream, params.bin_us)
    if not len(counts):
        return []
    half = max(1, params.local_us // params.bin_us)
    local = median_filter(counts.astype(float), size=2 * half + 1, mode="reflect")
    floor = params.min_rate * n_pixels * params.bin_us * 1e-6
    high = params.peak_factor * local + floor
    low = 0.5 * high
    hot = counts > high
    warm = counts > low
    windows = []
    k = 0
    while k < len(counts):
        if not hot[k]:
            k += 1
            continue
        a = k
        while a > 0 and warm[a - 1]:
            a -= 1
        b = k
        while b + 1 < len(counts) and warm[b + 1]:
            b += 1
        short = (b + 1 - a) * params.bin_us <= params.max_us
        if short and counts[a : b + 1].sum() >= params.min_events_fraction * n_pixels:
            windows.append((t0 + a * params.bin_us, t0 + (b + 1) * params.bin_us))
        k = b + 1
    return windows


def iter_blinks(stream: Stream, width: int, height: int, params: BlinkParams = DEFAULT_PARAMS) -> Iterator[Blink]:
    """The stream's blinks in time order, each with its event-count image (two passes over the stream)."""
    windows = blink_windows(stream, width * height, params)
    if not windows:
        return
    starts = np.array([w[0] for w in windows])
    ends = np.array([w[1] for w in windows])
    k = 0
    image = np.zeros(width * height, np.int64)
    n = 0
    for ev in stream():
        while len(ev) and k < len(windows):
            t = ev["t"]
            if int(t[-1]) < starts[k]:
                break
            a, b = np.searchsorted(t, [starts[k], ends[k]])
            sel = ev[a:b]
            if len(sel):
                image += np.bincount(sel["y"].astype(np.int64) * width + sel["x"], minlength=width * height)
                n += len(sel)
            if b < len(ev):  # the window closed inside this slice
                yield Blink(int(starts[k]), int(ends[k]), n, _as_image(image, width, height))
                image[:] = 0
                n = 0
                k += 1
                ev = ev[b:]
            else:
                break
    if k < len(windows):
        yield Blink(int(starts[k]), int(ends[k]), n, _as_image(image, width, height))


def _as_image(flat: np.ndarray, width: int, height: int) -> np.ndarray:
    return np.minimum(flat, np.iinfo(np.uint16).max).astype(np.uint16).reshape(height, width)
