"""Ctrl-C as a request to stop a run at its next step, so the run can still write its partial outputs.

A loop runs inside ``with StopOnInterrupt() as stop:`` and checks ``stop.requested`` once per step.
The first SIGINT only sets the flag (the step in progress completes, nothing is left half-updated);
a second one raises ``KeyboardInterrupt`` at once, for a run stuck inside a step. Outside the main
thread signals cannot be caught, and the context manager does nothing: ``requested`` stays False.

``with ctrl_c_held_back():`` is the short form for a few statements that must not be split (an
arm command and its log row; an import whose ``except BaseException`` would swallow the Ctrl-C):
a Ctrl-C pressed inside is raised as ``KeyboardInterrupt`` once the block is done.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType, TracebackType

__all__ = ["INTERRUPTED", "StopOnInterrupt", "ctrl_c_held_back"]

#: The ``ended`` reason of a run stopped by Ctrl-C.
INTERRUPTED = "interrupted (Ctrl-C)"


class StopOnInterrupt:
    """Turns the first SIGINT inside the block into ``requested = True``; restores the previous
    handler on exit."""

    def __init__(self) -> None:
        self.requested = False
        self._previous: object = None
        self._installed = False

    def _handle(self, _signum: int, _frame: FrameType | None) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __enter__(self) -> StopOnInterrupt:
        # A process that ignores SIGINT (a bench worker: its parent stops it) keeps ignoring it.
        main = threading.current_thread() is threading.main_thread()
        if main and signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
            self._previous = signal.signal(signal.SIGINT, self._handle)
            self._installed = True
        return self

    def __exit__(
        self, _type: type[BaseException] | None, _value: BaseException | None, _tb: TracebackType | None
    ) -> None:
        if self._installed:
            signal.signal(signal.SIGINT, self._previous)  # type: ignore[arg-type]
            self._installed = False


@contextmanager
def ctrl_c_held_back() -> Iterator[None]:
    """Hold a Ctrl-C pressed inside the block back until the block is done, then raise it through the
    previous handler (the default one raises ``KeyboardInterrupt``); a second Ctrl-C raises at once,
    for a block that hangs. Does nothing outside the main thread, or when SIGINT is ignored, left to
    the OS default, or handled outside Python (rclpy's handler): it must not be replaced there."""
    previous = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or not callable(previous):
        yield
        return
    pressed: list[int] = []

    def hold(signum: int, _frame: FrameType | None) -> None:
        if pressed:
            raise KeyboardInterrupt
        pressed.append(signum)

    signal.signal(signal.SIGINT, hold)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if pressed:
        previous(signal.SIGINT, None)
