"""Events synthesised straight from a model's edges: the quick, geometric stand-in for the event
camera simulator, used by tests, benchmarks and the closed-loop simulation when exact ground truth
matters more than photometric realism.

A dense edge point set of the model is moved along a pose trajectory; every time a point's raw
(distorted) pixel changes, that pixel fires one event, with polarity from the sign of the motion
and a time drawn uniformly inside the sampling interval. Uniform noise events are added as a
fraction of the signal events, plus optionally a constant background rate (a real sensor's
background activity, which keeps time stamps flowing when nothing moves).
"""

from __future__ import annotations

import numpy as np

from evservo import _evcore
from evservo.events import EVENT_CD


class EdgeEventGenerator:
    """Incremental form of :func:`edge_events`: feed the pose at successive times, get the events of
    each interval.

    ``points_o`` (M, 3): edge points in the object frame (metres). ``T_c_o0``: object in the camera
    frame at ``t0_us``. ``noise_fraction``: noise events per signal event. ``noise_rate_hz``:
    additional background events per second over the whole sensor.
    """

    def __init__(
        self,
        camera: _evcore.Camera,
        points_o: np.ndarray,
        T_c_o0: np.ndarray,
        t0_us: int = 0,
        noise_fraction: float = 0.2,
        noise_rate_hz: float = 0.0,
        seed: int = 0,
    ) -> None:
        if not (noise_fraction >= 0 and noise_rate_hz >= 0):
            raise ValueError("noise_fraction and noise_rate_hz must be >= 0")
        self.camera = camera
        self.points_o = np.asarray(points_o, dtype=np.float64)
        self.noise_fraction = float(noise_fraction)
        self.noise_rate_hz = float(noise_rate_hz)
        self._rng = np.random.default_rng(seed)
        self._prev = self._pixels(T_c_o0)
        self.t_us = int(t0_us)

    def _pixels(self, T: np.ndarray) -> np.ndarray:
        uv = self.camera.project(self.points_o @ T[:3, :3].T + T[:3, 3])
        return np.floor(uv + 0.5)

    def events_until(self, t_us: int, T_c_o: np.ndarray, T_w_c: np.ndarray | None = None) -> np.ndarray:
        """The time-sorted EventCD events of ``[self.t_us, t_us)`` given the pose ``T_c_o`` at ``t_us``
        (µs, strictly after the previous call's). Only the object fires, so the camera's world pose
        ``T_w_c`` does not matter here."""
        t0, t1 = self.t_us, int(t_us)
        if t1 <= t0:
            raise ValueError("times must be strictly increasing")
        W, H = self.camera.width, self.camera.height
        rng, prev = self._rng, self._prev
        cur = self._pixels(T_c_o)
        u, v = cur[:, 0], cur[:, 1]
        # A point fires where it lands on the sensor in another pixel than the one it was seen in.
        # Written element-wise: NaN and ±inf fail the range tests, and ``prev``'s x + y is finite
        # exactly when both are (row-wise ``np.all``/``np.any`` over two columns cost 3x as much).
        fires = (
            (u >= 0)
            & (u < W)
            & (v >= 0)
            & (v < H)
            & np.isfinite(prev[:, 0] + prev[:, 1])
            & ((u != prev[:, 0]) | (v != prev[:, 1]))
        )
        # Pixels hit by several points fire once.
        sig = _distinct(v[fires].astype(np.int64) * W + u[fires].astype(np.int64))
        n_noise = rng.binomial(len(sig), self.noise_fraction) if self.noise_fraction > 0 else 0
        if self.noise_rate_hz > 0:
            n_noise += rng.poisson(self.noise_rate_hz * (t1 - t0) * 1e-6)
        noise = rng.integers(0, W * H, size=n_noise)
        idx = np.concatenate([sig, noise])
        x, y = idx % W, idx // W
        p = rng.integers(0, 2, size=len(idx))
        t = rng.integers(t0, t1, size=len(idx))
        # The order of ``ev.sort(order="t")`` (ties broken by x, y, p, the fields in dtype order) by one
        # integer key; equal keys are equal events, so an unstable sort gives the same array.
        order = np.argsort((((t - t0) * W + x) * H + y) * 2 + p)
        ev = np.empty(len(idx), dtype=EVENT_CD)
        ev["x"], ev["y"], ev["p"], ev["t"] = x[order], y[order], p[order], t[order]
        self._prev, self.t_us = cur, t1
        return ev


def edge_events(
    camera: _evcore.Camera,
    points_o: np.ndarray,
    poses: np.ndarray,
    times_us: np.ndarray,
    noise_fraction: float = 0.2,
    seed: int = 0,
) -> list[np.ndarray]:
    """One EventCD batch per interval [times_us[k-1], times_us[k]) for k ≥ 1.

    ``poses`` (N, 4, 4) are ``T_c_o`` at ``times_us`` (N,), ``points_o`` (M, 3) edge points in the
    object frame. Returns N−1 time-sorted batches.
    """
    times_us = np.asarray(times_us, dtype=np.int64)
    if len(poses) != len(times_us) or len(times_us) < 2:
        raise ValueError("need one pose per time and at least two times")
    if np.any(np.diff(times_us) <= 0):
        raise ValueError("times must be strictly increasing")
    gen = EdgeEventGenerator(camera, points_o, poses[0], int(times_us[0]), noise_fraction, seed=seed)
    return [gen.events_until(int(t), T) for t, T in zip(times_us[1:], poses[1:], strict=True)]


def _distinct(values: np.ndarray) -> np.ndarray:
    """``np.unique(values)`` for a 1-D integer array by sorting: numpy 2's hashing ``unique`` takes
    ~8x as long on the few thousand pixels of one interval."""
    s = np.sort(values)
    keep = np.ones(len(s), dtype=bool)
    np.not_equal(s[1:], s[:-1], out=keep[1:])
    return s[keep]
