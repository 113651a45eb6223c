"""The live viewer beside the real loop (``servo --robot … --viewer rerun``, ``ros servo``), off the
control thread: a rerun frame (PNG of the events, scene, errors) costs milliseconds, a control
period at 500 Hz is 2 ms.

:meth:`LiveView.tap` wraps the event source so the camera thread also drops each batch into a short
queue (a deque append), :meth:`LiveView.observe` is the loop's per-cycle hook (it stores the cycle's
camera pose and desired pose), and a thread of its own logs one frame every ``period_s`` of wall
time from the newest of both and the tracker's newest estimate. A viewer that fails is switched
off with a warning; it never stops the loop.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from evservo.io import EVENT_CD

__all__ = ["LiveView", "viewing"]

log = logging.getLogger(__name__)

#: Event batches kept for the next frame: older ones are dropped (an event image shows the newest).
MAX_PENDING_BATCHES = 200


class _Tap:
    """A source's batches, each also handed to ``keep``; the source's sensor time (``stream_time_us``,
    see :mod:`evservo.cameras`) read through, so the real loop still advances the tracker on it."""

    def __init__(self, source: Iterable[np.ndarray], keep: Callable[[np.ndarray], None]) -> None:
        self.source, self.keep = source, keep

    @property
    def stream_time_us(self) -> int | None:
        return getattr(self.source, "stream_time_us", None)

    def __iter__(self) -> Iterator[np.ndarray]:
        for ev in self.source:
            self.keep(ev)
            yield ev


class LiveView:
    """Feeds ``viewer`` (a :class:`~evservo.viewer.RerunViewer`) from a running real loop.

    ``tracker``: the loop's (running) :class:`~evservo.tracking.Tracker`. ``period_s``: wall time
    between two frames. Use as a context manager around the loop; :attr:`error` holds what switched
    the viewer off, if anything."""

    def __init__(self, viewer: Any, tracker: Any, period_s: float = 1 / 30) -> None:
        self.viewer, self.tracker, self.period_s = viewer, tracker, float(period_s)
        self._events: deque[np.ndarray] = deque(maxlen=MAX_PENDING_BATCHES)
        self._cycle: tuple[float, np.ndarray, np.ndarray] | None = None
        self._halt = threading.Event()
        self._thread = threading.Thread(target=self._run, name="evservo-viewer", daemon=True)
        self.error: BaseException | None = None

    def tap(self, source: Iterable[np.ndarray]) -> _Tap:
        """``source``'s batches, each also kept for the next frame (its ``stream_time_us`` passed on)."""
        return _Tap(source, self._events.append)

    def observe(self, t_s: float, T_w_c: np.ndarray, T_c_o_des: np.ndarray) -> None:
        """The loop's per-cycle hook: time since servo start (s), camera pose in the world and
        desired object pose in the camera (4×4, metres)."""
        self._cycle = (t_s, T_w_c, T_c_o_des)

    def __enter__(self) -> LiveView:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._halt.set()
        self._thread.join(timeout=5.0)

    def _run(self) -> None:
        last_seq = -1
        while not self._halt.wait(self.period_s):
            cycle, est = self._cycle, self.tracker.latest()
            if cycle is None or est.seq == last_seq or not self.tracker.running:
                continue  # not servoing (yet, or any more), or nothing new to show
            last_seq = est.seq
            batches = [self._events.popleft() for _ in range(len(self._events))]
            events = np.concatenate(batches) if batches else np.empty(0, dtype=EVENT_CD)
            try:
                self.viewer.servo(
                    int(est.t_us), events, est, self.tracker, T_w_c=cycle[1], T_c_o_des=cycle[2], threaded=True
                )
            except Exception as err:  # the viewer is an aid: it must not take the loop down
                self.error = err
                log.warning("viewer failed, switched off: %r", err)
                return


@contextmanager
def viewing(
    viewer: Any, tracker: Any, source: Iterable[np.ndarray]
) -> Iterator[tuple[Iterable[np.ndarray], Callable[[float, np.ndarray, np.ndarray], None] | None]]:
    """``(source, on_cycle)`` for :func:`~evservo.realloop.run_real_loop`: with a viewer, the tapped
    source and :meth:`LiveView.observe` while a :class:`LiveView` runs, and the viewer closed (its
    ``.rrd`` complete) on the way out; without one (None), ``source`` as it is and no hook."""
    if viewer is None:
        yield source, None
        return
    try:
        with LiveView(viewer, tracker) as live:
            yield live.tap(source), live.observe
    finally:
        viewer.close()
