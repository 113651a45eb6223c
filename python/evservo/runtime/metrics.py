"""Metrics of a run, shared by the simulated episode and the real loop."""

from __future__ import annotations

import numpy as np


def rms(x: np.ndarray) -> float:
    """Root mean square of ``x``; NaN when empty."""
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def estimate_lag_s(t_s: np.ndarray, d_lead: np.ndarray, d_follow: np.ndarray, max_lag_s: float = 1.0) -> float:
    """How far ``d_follow`` (N, 3) trails ``d_lead`` (N, 3), both sampled at uniform times ``t_s``:
    the shift maximising their normalised cross-correlation (summed over the axes, means removed),
    searched in ``[−max_lag_s/2, max_lag_s]`` and refined by a parabola through the peak. NaN if
    either signal is flat."""
    dt = float(t_s[1] - t_s[0])
    a = d_lead - d_lead.mean(axis=0)
    b = d_follow - d_follow.mean(axis=0)
    if np.sum(a * a) < 1e-12 or np.sum(b * b) < 1e-12:
        return float("nan")
    max_k = min(round(max_lag_s / dt), len(a) // 2)
    lags = np.arange(-max_k // 2, max_k + 1)
    c = np.empty(len(lags))
    for i, L in enumerate(lags):
        x, y = (a[: len(a) - L], b[L:]) if L >= 0 else (a[-L:], b[: len(b) + L])
        c[i] = np.sum(x * y) / np.sqrt(np.sum(x * x) * np.sum(y * y))
    i = int(np.argmax(c))
    shift = 0.0
    if 0 < i < len(c) - 1:
        den = c[i - 1] - 2 * c[i] + c[i + 1]
        shift = 0.5 * (c[i - 1] - c[i + 1]) / den if den < 0 else 0.0
    return float((lags[i] + shift) * dt)
