"""Detecting a manoeuvre of the target (an abrupt stop, start or reversal) from a motion filter's
innovations, and widening the filter's bandwidth while it lasts (the filter then runs a
constant-velocity model: :class:`~evservo.control.pose_filter.TwistEstimator`).

A constant-acceleration filter's twist has no first-order delay on smooth motion, and that is why the
camera no longer lags; the price is that after an abrupt change of velocity Δv its twist, integrated by
the feed-forward, runs past the target by ≈ 0.84·Δv/ω (the peak of ``Δv·t·(1 + ωt)·e^(−ωt)`` for a
triple pole at ω; 7 mm for 0.3 m/s at 5.5 Hz). A wider bandwidth shortens that in proportion but lets
more of the tracker's noise into the feed-forward, so it is widened only while the innovations say the
motion model is wrong.

The test: the innovations' short-term mean (an EMA over ``window_s``; white noise averages out there,
a manoeuvre's innovations pile up with one sign) against its own long-term RMS (over ``noise_tau_s``,
fed only outside manoeuvres, so it learns the tracker's noise, correlated in time as it is, and the
filter's own bias on smooth motion). Translation (m) and rotation (rad) are tested apart: they have
other units and noise.
"""

from __future__ import annotations

import numpy as np


class Manoeuvre:
    """Innovation-based manoeuvre detector: :meth:`update` returns the factor (≥ 1) by which to widen a
    motion filter's bandwidth for this update.

    ``window_s``: time constant of the innovations' short-term mean (s). ``noise_tau_s``: of its
    long-term mean square (s); no detection in the first ``warmup_s`` (s). ``ratio``: a manoeuvre is
    a short-term mean more than this many times its long-term RMS. ``boost``: the bandwidth factor on
    detection, decaying back to 1 with time constant ``hold_s`` (s) once the innovations are quiet.
    """

    def __init__(
        self,
        window_s: float = 0.005,
        noise_tau_s: float = 1.0,
        ratio: float = 4.0,
        boost: float = 10.0,
        hold_s: float = 0.05,
        warmup_s: float = 0.2,
    ) -> None:
        if not (window_s > 0 and noise_tau_s > window_s and ratio > 1 and boost >= 1 and hold_s > 0):
            raise ValueError("need window_s > 0, noise_tau_s > window_s, ratio > 1, boost >= 1, hold_s > 0")
        if not warmup_s >= window_s:
            raise ValueError("warmup_s must be >= window_s")
        self.window_s, self.noise_tau_s, self.warmup_s = float(window_s), float(noise_tau_s), float(warmup_s)
        self.ratio, self.boost, self.hold_s = float(ratio), float(boost), float(hold_s)
        self.reset()

    def reset(self) -> None:
        """Forget the innovations seen (the filter restarted)."""
        self._mean = np.zeros(6)  # short-term mean of the innovations (m, rad)
        self._ms = np.zeros(2)  # long-term mean square of |short-term mean|, translation and rotation
        self._ms_weight = 0.0  # the EMA's weight so far (it starts from zero: divide to unbias it)
        self._seen_s = 0.0
        self.factor = 1.0
        self.detected = False  # the last update's innovations were a manoeuvre

    @property
    def settled(self) -> float:
        """How far the bandwidth is back from a manoeuvre's boost: 0 on detection, 1 when back to normal
        (always 1 with ``boost`` 1). A constant-acceleration extrapolation is trusted that much: at
        an abrupt change the acceleration estimate is a spike, not a motion to carry on."""
        return 1.0 if self.boost == 1.0 else float((self.boost - self.factor) / (self.boost - 1.0))

    def update(self, dt_s: float, r: np.ndarray) -> float:
        """Fold in one innovation ``r`` (6: translation m, rotation rad) ``dt_s`` after the previous one;
        returns the bandwidth factor for this update."""
        self._mean += (1.0 - np.exp(-dt_s / self.window_s)) * (r - self._mean)
        m2 = np.array([self._mean[:3] @ self._mean[:3], self._mean[3:] @ self._mean[3:]])
        self._seen_s += dt_s
        warm = self._seen_s >= self.warmup_s
        self.detected = warm and bool(np.any(m2 * self._ms_weight > self.ratio**2 * self._ms))
        if self.detected:
            self.factor = self.boost
        else:
            a = 1.0 - np.exp(-dt_s / self.noise_tau_s)
            self._ms += a * (m2 - self._ms)
            self._ms_weight += a * (1.0 - self._ms_weight)
            self.factor = 1.0 + (self.factor - 1.0) * np.exp(-dt_s / self.hold_s)
        return self.factor
