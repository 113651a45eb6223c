"""Recording calibration views on a real rig: events from a live camera, flange poses from the arm.

The screen shows the board blinking the whole time (any player looping a board image and a black
image, 2–5 blinks per second). For each view the user moves the arm (hand guiding, the teach pendant:
the arm is opened read-only) so that the camera sees the whole board from a new angle, lets it stop
and confirms. :func:`capture` then records ``hold_s`` of events, reads the flange pose before and
after, and keeps the view only when the arm stayed still and the whole board was found, in the same
place, in most blinks of that stretch (earlier blinks, seen while the camera still settled, are cut
off); otherwise it says why and asks again. The events of the kept stretches are written
as one recording, and their poses as ``poses.csv`` (:mod:`evservo.calib.handeye`) with each pose's
time the middle of its view's blinks, on the camera's clock.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from evservo import geometry
from evservo import io as evio
from evservo.calib.board import Board
from evservo.calib.handeye import write_poses
from evservo.calib.views import scan_events

if TYPE_CHECKING:  # typing only: importing evservo.robots would load every arm's driver module
    from evservo.cameras import EventSource
    from evservo.robots.base import Arm

__all__ = ["CaptureResult", "capture"]

#: The arm counts as still when its flange moved less than this during a view (m, rad).
STILL_M, STILL_RAD = 0.5e-3, np.radians(0.05)


class _Recorder:
    """Drains a live source in a thread (a camera must be read continuously) and keeps the batches
    that arrive between :meth:`start` and :meth:`stop`."""

    def __init__(self, source: EventSource) -> None:
        self._source = source
        self._lock = threading.Lock()
        self._keep = False
        self._batches: list[np.ndarray] = []
        self.error: BaseException | None = None
        self.ended = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="calib-capture-camera", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            for batch in self._source:
                if self._stop.is_set():
                    break
                with self._lock:
                    if self._keep and len(batch):
                        self._batches.append(batch)
        except BaseException as err:  # reported to the caller's thread
            self.error = err
        finally:
            self.ended.set()

    def start(self) -> None:
        with self._lock:
            self._batches, self._keep = [], True

    def stop(self) -> np.ndarray:
        with self._lock:
            self._keep = False
            batches, self._batches = self._batches, []
        return np.concatenate(batches, dtype=evio.EVENT_CD) if batches else np.empty(0, evio.EVENT_CD)

    def close(self) -> None:
        self._stop.set()
        self._source.close()
        self._thread.join(timeout=2.0)


@dataclass
class CaptureResult:
    """The views kept: pose times (s, camera clock), flange poses ``T_b_e`` (N, 4, 4), events written."""

    t_s: np.ndarray
    T_b_e: np.ndarray
    n_events: int


def capture(
    source: EventSource, arm: Arm, board: Board, n_views: int, events_out: str | Path, poses_out: str | Path,
    hold_s: float = 1.0, ask: Callable[[str], str] | None = None, say: Callable[[str], None] = print,
) -> CaptureResult:  # fmt: skip
    """Guide the user through ``n_views`` views (see the module docstring) and write ``events_out`` (any
    format :func:`evservo.io.write_events` writes) and ``poses_out``. Answering ``q`` to a prompt ends
    early with the views kept so far. ``ask`` (default :func:`input`) prompts and returns the answer;
    ``say`` reports. Raises ``RuntimeError`` if the camera fails or its stream ends."""
    ask = ask or input
    if n_views < 1:
        raise ValueError(f"the number of views must be >= 1, got {n_views}")
    if not (np.isfinite(hold_s) and hold_s > 0):
        raise ValueError(f"the hold time must be finite and > 0 s, got {hold_s}")
    for out in (Path(events_out), Path(poses_out)):
        if not out.parent.is_dir():
            raise FileNotFoundError(f"output directory does not exist: {out.parent}")
    segments: list[np.ndarray] = []
    times: list[float] = []
    poses: list[np.ndarray] = []
    recorder = _Recorder(source)
    try:
        while len(poses) < n_views:
            try:
                answer = ask(
                    f"view {len(poses) + 1}/{n_views}: move the camera so it sees the whole blinking board from a new "
                    "angle, let the arm stop, then press Enter (q to finish) "
                )
            except EOFError:  # input closed: finish as with q
                answer = "q"
            if answer.strip().lower() == "q":
                break
            T0 = arm.T_w_e()
            recorder.start()
            time.sleep(hold_s)
            events = recorder.stop()
            T1 = arm.T_w_e()
            if recorder.error is not None:
                raise RuntimeError(f"the camera failed: {recorder.error}") from recorder.error
            if geometry.translation_error_m(T0, T1) > STILL_M or geometry.rotation_error_rad(T0, T1) > STILL_RAD:
                say("  the arm moved during the view; let it stop and try again")
                continue
            if not len(events):
                if recorder.ended.is_set():
                    raise RuntimeError("the camera's event stream ended")
                say("  no events from the camera; is it connected and is the screen blinking?")
                continue
            scan = scan_events(lambda ev=events: [ev], source.width, source.height, board)
            # The still view is the last one; blinks before it were seen while the camera still moved
            # and are cut off, so the recording holds one view per pose.
            view = scan.views[-1] if scan.views else None
            if view is None or (len(scan.views) > 1 and view.n_blinks < max(v.n_blinks for v in scan.views)):
                why = (
                    f"the whole {board} board was not found in {scan.n_blinks} blink(s)"
                    if view is None
                    else "the board moved between blinks"
                )
                say(f"  {why}; adjust the view and try again")
                continue
            if len(scan.views) > 1:
                events = events[events["t"] >= (scan.views[-2].t_end_us + view.t_start_us) // 2]
            segments.append(events)
            times.append(view.t_mid_us * 1e-6)
            poses.append(T0)
            say(f"  kept: {view.n_blinks} blink(s) with the whole board")
    finally:
        recorder.close()
    if not poses:
        raise ValueError("no view was kept; nothing written")
    events = np.concatenate(segments, dtype=evio.EVENT_CD)
    evio.write_events(events_out, events, source.width, source.height)
    write_poses(poses_out, np.array(times), np.array(poses))
    return CaptureResult(np.array(times), np.array(poses), len(events))
