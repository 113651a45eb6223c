"""Ctrl-C as a request to stop a run at its next step, so the run can still write its partial outputs.

A loop runs inside ``with StopOnInterrupt() as stop:`` and checks ``stop.requested`` once per step.
The first SIGINT only sets the flag (the step in progress completes, nothing is left half-updated);
a second one raises ``KeyboardInterrupt`` at once, for a run stuck inside a step. Outside the main
thread signals cannot be caught, and the context manager does nothing: ``requested`` stays False.
"""

from __future__ import annotations

import signal
import threading
from types import FrameType, TracebackType

__all__ = ["INTERRUPTED", "StopOnInterrupt"]

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
