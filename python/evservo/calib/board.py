"""The calibration checkerboard and its detection in an event image.

Board frame (``board``): origin at the first inner corner, x along a row of ``cols`` inner corners,
y along a column of ``rows`` inner corners, z = x × y (into the screen, away from a camera that sees
it), metres. Inner corner (i, j) sits at (i·square, j·square, 0). The square between inner corners
(0, 0) and (1, 1) is a *lit* one (it blinks); with ``cols + rows`` odd this fixes the corner order
uniquely, which pose estimation (hand-eye) needs; with ``cols + rows`` even the board looks the same
turned half a turn and only intrinsics can use it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["Board", "BoardFind", "find_board", "parse_board"]


@dataclass(frozen=True)
class Board:
    """A checkerboard of ``cols`` × ``rows`` inner corners (OpenCV's pattern size) with squares of
    ``square_m`` metres."""

    cols: int
    rows: int
    square_m: float

    def __post_init__(self) -> None:
        if self.cols < 2 or self.rows < 2:
            raise ValueError(f"a board needs at least 2x2 inner corners, got {self.cols}x{self.rows}")
        if not (np.isfinite(self.square_m) and self.square_m > 0):
            raise ValueError(f"the square size must be finite and > 0 m, got {self.square_m}")

    @property
    def size(self) -> tuple[int, int]:
        """OpenCV's pattern size (cols, rows)."""
        return (self.cols, self.rows)

    @property
    def n_corners(self) -> int:
        return self.cols * self.rows

    @property
    def oriented(self) -> bool:
        """True when the corner order is unique (a half turn changes the colours: cols + rows odd)."""
        return (self.cols + self.rows) % 2 == 1

    def object_points(self) -> np.ndarray:
        """Inner corners in the board frame, (rows·cols, 3) float32, row by row (metres)."""
        j, i = np.mgrid[0 : self.rows, 0 : self.cols]
        pts = np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], axis=1) * self.square_m
        return pts.astype(np.float32)

    def __str__(self) -> str:
        return f"{self.cols}x{self.rows}"


def parse_board(text: str, square_m: float) -> Board:
    """``COLSxROWS`` (inner corners, e.g. ``9x6``) and the square side in metres."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX×]\s*(\d+)\s*", text)
    if not m:
        raise ValueError(f"--board must be COLSxROWS inner corners (e.g. 9x6), got {text!r}")
    return Board(int(m.group(1)), int(m.group(2)), float(square_m))


def normalised_image(counts: np.ndarray) -> np.ndarray:
    """An event-count image as 8-bit gray: blinking squares dark on a light ground.

    Counts are clipped at the 99th percentile of the lit pixels (a few hot or edge pixels fire far more
    than the rest) and inverted, so that the lit squares play the dark squares of a printed board, with
    the unlit screen and the world around as its light quiet zone.
    """
    c = np.asarray(counts, dtype=np.float32)
    lit = c[c > 0]
    top = float(np.percentile(lit, 99)) if lit.size else 1.0
    img = np.clip(c / max(top, 1e-6), 0.0, 1.0)
    return np.round(255.0 * (1.0 - img)).astype(np.uint8)


def _subpix_window(grid: np.ndarray) -> int:
    """Half-size (px) of cornerSubPix's window: under half the smallest square side seen, 2…10 px."""
    dx = np.linalg.norm(np.diff(grid, axis=1), axis=2).min()
    dy = np.linalg.norm(np.diff(grid, axis=0), axis=2).min()
    return int(np.clip(0.4 * min(dx, dy), 2, 10))


def _square_level(img: np.ndarray, grid: np.ndarray, j: int, i: int) -> float:
    """Mean gray of the square spanned by inner corners (j, i) … (j + 1, i + 1), sampled at its
    central quarter."""
    quad = grid[j : j + 2, i : i + 2].reshape(4, 2)
    centre = quad.mean(axis=0)
    pts = centre + 0.25 * (quad - centre)
    xs = np.clip(np.round(np.r_[pts[:, 0], centre[0]]).astype(int), 0, img.shape[1] - 1)
    ys = np.clip(np.round(np.r_[pts[:, 1], centre[1]]).astype(int), 0, img.shape[0] - 1)
    return float(img[ys, xs].mean())


def _canonical(grid: np.ndarray, img: np.ndarray, board: Board) -> np.ndarray:
    """Reorder a (rows, cols, 2) corner grid to the board frame of the module docstring: x then y turn
    clockwise in the image (image y points down, so the board's z points away from the camera), and
    the square after corner (0, 0) is lit (dark in ``img``) when the board tells a half turn apart."""
    vx, vy = grid[0, 1] - grid[0, 0], grid[1, 0] - grid[0, 0]
    if vx[0] * vy[1] - vx[1] * vy[0] < 0:
        grid = grid[::-1]
    if board.oriented and _square_level(img, grid, 0, 0) > _square_level(img, grid, 0, 1):
        grid = grid[::-1, ::-1]
    return grid


def _extends_beyond(grid: np.ndarray, img: np.ndarray) -> bool:
    """True when lit squares continue past the detected corners: the squares one and a half squares
    beyond the outer corner lines (past the board's outer squares, in its quiet zone) are lit on some
    side. That is a larger board than asked for, of which the detector found a part."""
    rows, cols = grid.shape[:2]
    j, i = np.mgrid[0:rows, 0:cols]
    H, _ = cv2.findHomography(np.stack([i.ravel(), j.ravel()], 1).astype(np.float32), grid.reshape(-1, 2))
    if H is None:
        return False

    def level(points: np.ndarray) -> np.ndarray:
        """Mean gray around each grid point (a 3×3 pattern 0.2 squares apart); NaN off the image."""
        offsets = np.array([(a, b) for a in (-0.2, 0, 0.2) for b in (-0.2, 0, 0.2)])
        pts = (points[:, None, :] + offsets[None]).reshape(-1, 1, 2).astype(np.float32)
        xy = cv2.perspectiveTransform(pts, H).reshape(len(points), len(offsets), 2)
        x, y = np.round(xy[..., 0]).astype(int), np.round(xy[..., 1]).astype(int)
        inside = ((x >= 0) & (x < img.shape[1]) & (y >= 0) & (y < img.shape[0])).all(axis=1)
        out = np.full(len(points), np.nan)
        out[inside] = img[y[inside].clip(0, img.shape[0] - 1), x[inside].clip(0, img.shape[1] - 1)].mean(axis=1)
        return out

    centres = np.stack([i[:-1, :-1].ravel() + 0.5, j[:-1, :-1].ravel() + 0.5], 1)
    inner = level(centres)
    lit = ((i[:-1, :-1] + j[:-1, :-1]) % 2 == 0).ravel()
    threshold = 0.5 * (np.nanmean(inner[lit]) + np.nanmean(inner[~lit]))
    along_i, along_j = np.arange(cols - 1) + 0.5, np.arange(rows - 1) + 0.5
    sides = [
        np.stack([np.full_like(along_j, -1.5), along_j], 1),
        np.stack([np.full_like(along_j, cols + 0.5), along_j], 1),
        np.stack([along_i, np.full_like(along_i, -1.5)], 1),
        np.stack([along_i, np.full_like(along_i, rows + 0.5)], 1),
    ]
    for side in sides:
        values = level(side)
        values = values[np.isfinite(values)]
        if len(values) >= 2 and np.mean(values < threshold) >= 0.3:
            return True
    return False


@dataclass
class BoardFind:
    """What :func:`find_board` saw: the corners (None unless the whole board was found) and whether a
    board with more squares than asked for was in view."""

    corners: np.ndarray | None
    larger: bool = False


def find_board(counts: np.ndarray, board: Board) -> BoardFind:
    """The board's inner corners in an event-count image, (rows·cols, 2) float32 pixels in the board
    frame's order, refined to sub-pixel on the event image; no corners unless the whole board is found
    (OpenCV's detector), and none when the pattern continues past them (a larger board).

    The detector sees the image with isolated noise events removed by a 3×3 median; the corners are
    refined on the image itself, slightly smoothed (a median moves edges by fractions of a pixel)."""
    img = normalised_image(counts)
    clean = cv2.medianBlur(img, 3)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(clean, board.size, flags=flags)
    if not found or corners is None or len(corners) != board.n_corners:
        return BoardFind(None)
    grid = corners.reshape(board.rows, board.cols, 2).astype(np.float32)
    if _extends_beyond(grid, clean):
        return BoardFind(None, larger=True)
    win = _subpix_window(grid)
    smooth = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 1.0)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    refined = cv2.cornerSubPix(smooth, grid.reshape(-1, 1, 2).copy(), (win, win), (-1, -1), criteria)
    grid = _canonical(refined.reshape(board.rows, board.cols, 2), clean, board)
    return BoardFind(np.ascontiguousarray(grid.reshape(-1, 2), dtype=np.float32))
