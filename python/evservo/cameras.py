"""Live event sources: iterators of :data:`evservo.io.EVENT_CD` arrays (x, y pixels; p 0/1; t µs).

* :class:`PropheseeCamera` — a Prophesee camera through OpenEB's / Metavision's Python API
  (``metavision_core``; OpenEB is built from source, it has no PyPI wheel).
* :class:`InivationCamera` — an iniVation camera (DVXplorer, DAVIS) through ``dv_processing``.
* :class:`ReplaySource` — any file :func:`evservo.io.open_events` reads, played back at ``speed`` × real
  time against a monotonic clock, so that a threaded tracker sees live-like input.

Each source has ``width`` and ``height`` (pixels), iterates batches until the stream ends (or forever
for a camera), and is a context manager whose exit releases the device. A source that knows how far
its stream has gone sets ``stream_time_us`` before it yields a batch: the sensor time (µs) up to
which no event exists beyond those yielded; the real loop hands it to the tracker
(``Tracker.advance_time``) with each empty batch, so events stopping while the sensor's clock runs
reads ``lost`` 20 ms in. None (the default) when the source cannot tell. A missing driver package
raises ``ImportError`` naming it; no camera raises :class:`CameraNotFoundError`.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from evservo import io
from evservo.input_files import require_regular_file
from evservo.io import EVENT_CD

__all__ = [
    "CameraNotFoundError",
    "EventSource",
    "InivationCamera",
    "PropheseeCamera",
    "ReplaySource",
    "open_camera",
    "open_source",
]


class CameraNotFoundError(RuntimeError):
    """The driver is installed but found no camera (or not the one asked for)."""


@runtime_checkable
class EventSource(Protocol):
    """An iterable of EVENT_CD batches from a sensor of ``width`` × ``height`` pixels."""

    width: int
    height: int

    def __iter__(self) -> Iterator[np.ndarray]: ...

    def close(self) -> None: ...


class _Source:
    width: int
    height: int
    #: Sensor time (µs) the stream is complete up to after the batch last yielded; None: unknown.
    stream_time_us: int | None = None

    def close(self) -> None:
        """Release the device (idempotent)."""

    def __enter__(self) -> _Source:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class PropheseeCamera(_Source):
    """A Prophesee camera via ``metavision_core.event_io.EventsIterator``, in slices of ``delta_t_us``.

    ``serial``: the camera's serial number, or None for the first one found. OpenEB's ``EventCD`` has
    our layout, so batches are passed on without conversion when the dtypes agree.
    """

    def __init__(self, serial: str | None = None, delta_t_us: int = 1000) -> None:
        try:
            from metavision_core.event_io import EventsIterator
        except ImportError as err:
            raise ImportError(
                "PropheseeCamera needs OpenEB's Python bindings (package metavision_core, from OpenEB or the "
                "Metavision SDK; not on PyPI)"
            ) from err
        if delta_t_us < 1:
            raise ValueError(f"delta_t_us must be >= 1, got {delta_t_us}")
        try:
            # OpenEB opens a live camera when input_path is a serial number, or "" for the first one.
            self._it: Any = EventsIterator(input_path=serial or "", mode="delta_t", delta_t=int(delta_t_us))
        except (OSError, RuntimeError, ValueError) as err:
            raise CameraNotFoundError(f"no Prophesee camera {serial or '(any)'} could be opened: {err}") from err
        self.height, self.width = (int(v) for v in self._it.get_size())

    def __iter__(self) -> Iterator[np.ndarray]:
        # In delta_t mode the driver serves every slice, empty ones too, and its current time is the
        # slice's end on the sensor clock (the camera's time-high words advance it without CD
        # events), so an empty slice is the sensor saying that time went on without events.
        now = getattr(self._it, "get_current_time", None)
        for events in self._it:
            if now is not None:
                self.stream_time_us = int(now()) - 1
            yield events if events.dtype == EVENT_CD else io._as_cd(events)

    def close(self) -> None:
        """Release the camera (OpenEB closes the device when its iterator goes away)."""
        self._it = ()


class InivationCamera(_Source):
    """An iniVation camera via ``dv_processing.io.camera``; batches as the camera delivers them.

    ``serial``: the camera's serial number, or None for the first one found. ``poll_s``: how long to
    wait before asking again when the camera has no new events.
    """

    def __init__(self, serial: str | None = None, poll_s: float = 0.0005) -> None:
        try:
            import dv_processing as dv
        except ImportError as err:
            raise ImportError("InivationCamera needs the 'dv-processing' package (pip install dv-processing)") from err
        found = dv.io.camera.discover()
        if not found:
            raise CameraNotFoundError("no iniVation camera connected (dv_processing found none)")
        try:
            self._cam: Any = dv.io.camera.open(serial) if serial else dv.io.camera.open()
        except (IndexError, RuntimeError) as err:
            raise CameraNotFoundError(f"iniVation camera {serial or '(any)'} could not be opened: {err}") from err
        resolution = self._cam.getEventResolution()
        if resolution is None:
            raise CameraNotFoundError(f"iniVation camera {self._cam.getCameraName()} has no event stream")
        self.width, self.height = int(resolution[0]), int(resolution[1])
        self.poll_s = float(poll_s)

    def __iter__(self) -> Iterator[np.ndarray]:
        while self._cam is not None and self._cam.isRunning():
            store = self._cam.getNextEventBatch()
            if store is None:
                time.sleep(self.poll_s)  # nothing new yet: the driver does not block
                continue
            yield dv_store_to_cd(store)

    def close(self) -> None:
        """Release the camera (dv_processing closes the device when its object goes away)."""
        self._cam = None


def dv_store_to_cd(store: Any) -> np.ndarray:
    """A ``dv_processing.EventStore`` as an EVENT_CD array (polarity true → p = 1)."""
    a = store.numpy()
    out = np.empty(len(a), dtype=EVENT_CD)
    out["x"], out["y"], out["p"], out["t"] = a["x"], a["y"], a["polarity"], a["timestamp"]
    return out


def open_camera(kind: str, serial: str | None = None) -> PropheseeCamera | InivationCamera:
    """Open a live camera: ``kind`` is ``"prophesee"`` or ``"inivation"``."""
    if kind == "prophesee":
        return PropheseeCamera(serial)
    if kind == "inivation":
        return InivationCamera(serial)
    raise ValueError(f"unknown camera kind {kind!r} (want 'prophesee' or 'inivation')")


class ReplaySource(_Source):
    """Play an event file back as a live camera would deliver it, ``speed`` × faster than recorded.

    The file is read in ``delta_t_us`` slices (as :func:`evservo.io.open_events`, so empty slices are
    kept). A slice is released once the wall clock has reached the recording time of its end, scaled
    by ``1/speed``, counted from when iteration started; waiting is against ``time.monotonic`` so that
    sleeps do not accumulate error. A consumer slower than the recording gets each slice as soon as it
    asks (like a camera's buffer filling up); :attr:`lag_s` tells how late the last slice was.
    """

    def __init__(self, path: str | os.PathLike, speed: float = 1.0, delta_t_us: int = 1000) -> None:
        if not (np.isfinite(speed) and speed > 0):
            raise ValueError(f"speed must be finite and > 0, got {speed}")
        if delta_t_us < 1:
            raise ValueError(f"delta_t_us must be >= 1, got {delta_t_us}")
        self.path, self.speed, self.delta_t_us = Path(path), float(speed), int(delta_t_us)
        if self.path.suffix.lower() == ".raw":
            from evservo._evcore import RawReader

            reader = RawReader(self.path)  # the header alone gives the geometry
            self.width, self.height = int(reader.width), int(reader.height)
        else:
            meta = io.info(self.path)
            self.width, self.height = int(meta["width"]), int(meta["height"])
        self.lag_s = 0.0

    def __iter__(self) -> Iterator[np.ndarray]:
        start = None
        end_us = t0_us = 0
        for events in io.open_events(self.path, delta_t_us=self.delta_t_us):
            if start is None:  # the first slice always holds the first event
                start = time.monotonic()
                t0_us = int(events["t"][0])
                end_us = (t0_us // self.delta_t_us + 1) * self.delta_t_us
            due = start + (end_us - t0_us) * 1e-6 / self.speed
            now = time.monotonic()
            if due > now:
                time.sleep(due - now)
            self.lag_s = max(0.0, time.monotonic() - due)
            self.stream_time_us = end_us - 1  # the file holds no event before the slice's end
            yield events
            end_us += self.delta_t_us


#: Live camera kinds of :func:`open_source` (``dv`` and ``inivation`` are the same driver).
LIVE_KINDS = {"prophesee": "prophesee", "dv": "inivation", "inivation": "inivation"}


def open_source(spec: str, speed: float = 1.0, delta_t_us: int = 1000) -> EventSource:
    """The event source a command-line ``--camera`` names.

    ``prophesee``, ``dv`` (or ``inivation``), optionally ``:SERIAL`` (e.g. ``prophesee:00050423``):
    a live camera; ``speed`` must then be 1. Anything else is an event file (any format
    :func:`evservo.io.open_events` reads) replayed at ``speed`` × real time in ``delta_t_us`` slices.
    Raises ``ImportError`` naming a missing driver package, :class:`CameraNotFoundError` when no
    camera answers, ``FileNotFoundError``/``ValueError`` for a missing or unreadable file.
    """
    kind, _, serial = spec.partition(":")
    if kind.lower() in LIVE_KINDS:
        if speed != 1.0:
            raise ValueError(f"--replay-speed applies to files only, not to the live camera {spec!r}")
        return open_camera(LIVE_KINDS[kind.lower()], serial or None)
    path = Path(spec)
    try:
        require_regular_file(path, "event file")
    except FileNotFoundError:
        raise FileNotFoundError(
            f"no such event file: {path} (--camera takes prophesee[:SERIAL], dv[:SERIAL] or an event file)"
        ) from None
    return ReplaySource(path, speed=speed, delta_t_us=delta_t_us)
