"""Events synthesised straight from a model's edges: the quick, geometric stand-in for the event
camera simulator, used by tests and benchmarks that need exact ground truth without rendering.

A dense edge point set of the model is moved along a pose trajectory; every time a point's raw
(distorted) pixel changes, that pixel fires one event, with polarity from the sign of the motion
and a time drawn uniformly inside the sampling interval. Uniform noise events are added as a
fraction of the signal events.
"""

from __future__ import annotations

import numpy as np

from evservo import _evcore
from evservo.events import EVENT_CD


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
    rng = np.random.default_rng(seed)
    times_us = np.asarray(times_us, dtype=np.int64)
    if len(poses) != len(times_us) or len(times_us) < 2:
        raise ValueError("need one pose per time and at least two times")
    if np.any(np.diff(times_us) <= 0):
        raise ValueError("times must be strictly increasing")
    W, H = camera.width, camera.height
    P = np.asarray(points_o, dtype=np.float64)

    def pixels(T: np.ndarray) -> np.ndarray:
        uv = camera.project(P @ T[:3, :3].T + T[:3, 3])
        return np.floor(uv + 0.5)

    prev = pixels(poses[0])
    batches = []
    for k in range(1, len(times_us)):
        cur = pixels(poses[k])
        ok = np.all(np.isfinite(cur), axis=1) & np.all(np.isfinite(prev), axis=1)
        moved = ok & np.any(cur != prev, axis=1)
        inside = moved & (cur[:, 0] >= 0) & (cur[:, 0] < W) & (cur[:, 1] >= 0) & (cur[:, 1] < H)
        sig = cur[inside].astype(np.int64)
        # Pixels hit by several points fire once.
        sig = np.unique(sig[:, 1] * W + sig[:, 0])
        n_noise = rng.binomial(len(sig), noise_fraction) if noise_fraction > 0 else 0
        noise = rng.integers(0, W * H, size=n_noise)
        idx = np.concatenate([sig, noise])
        t0, t1 = times_us[k - 1], times_us[k]
        ev = np.empty(len(idx), dtype=EVENT_CD)
        ev["x"] = idx % W
        ev["y"] = idx // W
        ev["p"] = rng.integers(0, 2, size=len(idx))
        ev["t"] = rng.integers(t0, t1, size=len(idx))
        ev.sort(order="t", kind="stable")
        batches.append(ev)
        prev = cur
    return batches
