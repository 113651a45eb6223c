"""Views of the board: the blinks where the whole board was found, grouped while the camera stood still.

Consecutive detections belong to one view while every corner stays within ``agree_px`` of the
view's first detection and the blinks are less than ``max_gap_us`` apart; a view's corners are the
mean of its detections. A recording of still views (one or more blinks each) so gives one view per
still, and a camera moving between blinks gives one view per blink.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evservo import io as evio
from evservo.calib.blinks import DEFAULT_PARAMS, BlinkParams, Stream, iter_blinks
from evservo.calib.board import Board, find_board

__all__ = ["View", "ViewScan", "scan_events", "scan_recording"]

#: Slice length when streaming a file (µs).
_SLICE_US = 50_000


@dataclass
class View:
    """The board seen from one still camera: corners (rows·cols, 2) float32 pixels in the board
    frame's order, the time span of its blinks (µs) and how many blinks it merges."""

    corners: np.ndarray
    t_start_us: int
    t_end_us: int
    n_blinks: int

    @property
    def t_mid_us(self) -> float:
        return 0.5 * (self.t_start_us + self.t_end_us)


@dataclass
class ViewScan:
    """What a recording holds: its sensor size, how many blinks and how many of them showed the
    whole board, and the views."""

    width: int
    height: int
    n_blinks: int
    n_detected: int
    views: list[View] = field(default_factory=list)
    #: Blinks that showed a board with more squares than asked for.
    n_larger: int = 0


def _group(detections: list[tuple[int, int, np.ndarray]], agree_px: float, max_gap_us: int) -> list[View]:
    views: list[View] = []
    members: list[np.ndarray] = []
    for t0, t1, corners in detections:
        if views:
            v = views[-1]
            still = np.abs(corners - members[0]).max() <= agree_px and t0 - v.t_end_us < max_gap_us
            if still:
                members.append(corners)
                v.corners = np.mean(members, axis=0).astype(np.float32)
                v.t_end_us, v.n_blinks = t1, v.n_blinks + 1
                continue
        views.append(View(corners, t0, t1, 1))
        members = [corners]
    return views


def scan_events(
    stream: Stream, width: int, height: int, board: Board, params: BlinkParams = DEFAULT_PARAMS,
    agree_px: float = 3.0, max_gap_us: int = 1_000_000,
) -> ViewScan:  # fmt: skip
    """Split a stream into blinks, find the whole board in each and group the detections into views."""
    detections, n_blinks, n_larger = [], 0, 0
    for blink in iter_blinks(stream, width, height, params):
        n_blinks += 1
        found = find_board(blink.image, board)
        n_larger += found.larger
        if found.corners is not None:
            detections.append((blink.t_start_us, blink.t_end_us, found.corners))
    views = _group(detections, agree_px, max_gap_us)
    return ViewScan(width, height, n_blinks, len(detections), views, n_larger)


def scan_recording(path: str | Path, board: Board, params: BlinkParams = DEFAULT_PARAMS) -> ViewScan:
    """:func:`scan_events` over an event file (any format :mod:`evservo.io` reads), streamed twice."""
    meta = evio.info(path)
    return scan_events(
        lambda: evio.open_events(path, delta_t_us=_SLICE_US), int(meta["width"]), int(meta["height"]), board, params
    )
