"""Open-loop tracking runs against ground truth: feed batches to a tracker, record the estimates,
score them. Shared by the demo, the tests and the benchmarks."""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from evservo.geometry import rotation_error_rad, translation_error_m
from evservo.tracking import Tracker


@dataclass
class TrackResult:
    """Per-batch estimates and their errors against ground truth."""

    t_us: np.ndarray
    T_est: np.ndarray
    pos_err_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    rot_err_rad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    lost: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    wall_s: float = 0.0
    updates: int = 0

    @property
    def pos_rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.pos_err_m**2)) * 1e3)

    @property
    def rot_rms_deg(self) -> float:
        return float(np.rad2deg(np.sqrt(np.mean(self.rot_err_rad**2))))

    @property
    def rate_hz(self) -> float:
        """Pose updates per second of solver wall time."""
        return self.updates / self.wall_s if self.wall_s > 0 else 0.0


def track_batches(tracker: Tracker, batches: Iterable[np.ndarray], T_true: np.ndarray | None = None) -> TrackResult:
    """Run ``tracker.update`` on each batch; ``T_true`` (N, 4, 4) is ground truth at each batch's end."""
    ts, Ts, lost = [], [], []
    started = time.perf_counter()
    updates = 0
    for ev in batches:
        est = tracker.update(ev)
        ts.append(est.t_us)
        Ts.append(est.T_c_o)
        lost.append(est.lost)
        updates = est.seq
    wall = time.perf_counter() - started
    T_est = np.array(Ts)
    res = TrackResult(t_us=np.array(ts), T_est=T_est, lost=np.array(lost), wall_s=wall, updates=updates)
    if T_true is not None:
        res.pos_err_m = np.array([translation_error_m(a, b) for a, b in zip(T_est, T_true, strict=True)])
        res.rot_err_rad = np.array([rotation_error_rad(a, b) for a, b in zip(T_est, T_true, strict=True)])
    return res
