"""The calling thread's scheduling (Linux policy and priority), kept across code that may change it."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

__all__ = ["calling_thread_scheduling_kept"]


@contextlib.contextmanager
def calling_thread_scheduling_kept() -> Iterator[None]:
    """Restore the calling thread's scheduling policy and priority after the block (where the OS has
    them): threads started from it later inherit whatever it is left at."""
    if not hasattr(os, "sched_getscheduler"):
        yield
        return
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        yield
    finally:
        if (os.sched_getscheduler(0), os.sched_getparam(0)) != (policy, param):
            os.sched_setscheduler(0, policy, param)
