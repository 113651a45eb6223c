"""From the tracker's pose stream to the object's pose and motion in the world (the input side of PBVS).

Each tracker pose ``T_c_o`` is checked (finite, rigid, in time order, no jump beyond the gate relative
to the prediction), lifted to the world with the camera pose *at the pose's time* (the camera pose now,
back-extrapolated across the pose's age with the camera twist: latency compensation), and folded into

- an EMA on the translation of ``T_c_o`` (what the control law servoes on), and
- a :class:`TwistEstimator` on the raw world pose (the object's twist and acceleration, used for the
  feed-forward and for the jump gate's prediction).

Frames: w world, c camera optical frame, o object; ``T_a_b`` is b in a (4×4, metres).
"""

from __future__ import annotations

import numpy as np

from evservo import geometry


class TwistEstimator:
    """Critically damped alpha–beta–gamma filter (a constant-acceleration model) on a stream of
    timestamped world poses ``T_w_o``: estimates the pose, the twist and the acceleration.

    Translation and rotation are filtered alike, the rotation residual being the rotation vector of
    ``R_meas · R_predᵀ`` (world frame). The constant-acceleration model tracks a constant-velocity
    motion and a constant acceleration without bias, and its twist estimate has no first-order delay:
    an alpha–beta (constant-velocity) filter's twist trails a smoothly varying motion by ``2/ω`` (58 ms
    at 5.5 Hz), which the feed-forward turned into the camera's lag behind the target.

    The gains are those of the fading-memory polynomial filter (a triple pole at ``ω = 2π·bandwidth_hz``)
    for each pose's interval ``dt``: ``θ = exp(−ω dt)``, ``α = 1 − θ³``, ``β = 1.5 (1 − θ)² (1 + θ)``,
    ``γ = (1 − θ)³``. Fixed per-pose gains would make the filter's bandwidth, and so the velocity noise
    it lets through, scale with the pose rate: a tracker publishing at 1 kHz instead of 100 Hz would get
    ten times the bandwidth and a velocity noise that, through the lever arm of a rotation, swamps the
    feed-forward.

    The acceleration used outside (``accel_w``: m/s², rad/s²) is the filter's acceleration state
    through a first-order low-pass of time constant ``accel_tau_s`` (seconds; discretised exactly, so
    it too means the same at any pose rate): differentiating a pose twice needs that much smoothing.
    """

    def __init__(self, bandwidth_hz: float = 5.5, accel_tau_s: float = 0.05) -> None:
        if not (bandwidth_hz > 0 and accel_tau_s > 0):
            raise ValueError("bandwidth_hz and accel_tau_s must be > 0")
        self.bandwidth_hz = float(bandwidth_hz)
        self.accel_tau_s = float(accel_tau_s)
        self.reset()

    def reset(self) -> None:
        """Forget everything; the next pose starts the estimate at rest."""
        self.t_s: float | None = None
        self.T_w_o = np.eye(4)
        self.twist_w = np.zeros(6)
        self.accel_w = np.zeros(6)
        self._accel = np.zeros(6)  # the filter's own acceleration state (unsmoothed)

    def predict(self, t_s: float) -> np.ndarray:
        """The pose extrapolated to ``t_s`` (seconds) with the current twist."""
        if self.t_s is None:
            raise RuntimeError("no pose yet")
        return geometry.advance(self.T_w_o, self.twist_w, t_s - self.t_s)

    def update(self, t_s: float, T_w_o: np.ndarray) -> None:
        """Fold in a measured pose at time ``t_s`` (seconds, strictly after the previous one)."""
        if self.t_s is None:
            self.t_s, self.T_w_o, self.twist_w = t_s, T_w_o.copy(), np.zeros(6)
            return
        dt = t_s - self.t_s
        theta = np.exp(-2.0 * np.pi * self.bandwidth_hz * dt)
        alpha, beta, gamma = 1.0 - theta**3, 1.5 * (1.0 - theta) ** 2 * (1.0 + theta), (1.0 - theta) ** 3
        # Prediction at constant acceleration: the pose moves at the mean twist over the interval.
        P = geometry.advance(self.T_w_o, self.twist_w + 0.5 * dt * self._accel, dt)
        r = np.concatenate([T_w_o[:3, 3] - P[:3, 3], geometry.rotvec(T_w_o[:3, :3] @ P[:3, :3].T)])
        T = np.eye(4)
        T[:3, 3] = P[:3, 3] + alpha * r[:3]
        T[:3, :3] = geometry.rotmat(alpha * r[3:]) @ P[:3, :3]
        self.twist_w = self.twist_w + dt * self._accel + (beta / dt) * r
        self._accel = self._accel + (2.0 * gamma / dt**2) * r
        self.accel_w += (1.0 - np.exp(-dt / self.accel_tau_s)) * (self._accel - self.accel_w)
        self.T_w_o, self.t_s = T, t_s


class PoseFilter:
    """The object's smoothed world pose and its motion from the tracker's poses (see the module docstring).

    ``ema_alpha``: weight of a new measurement in the EMA on the translation of ``T_c_o`` (1 disables it).
    ``stale_after_s``: a pose older than this (by its timestamp) is no longer fresh; the first valid pose
    after a stale spell is taken as a re-acquisition (EMA and motion estimate restart from it).
    ``max_jump_m``, ``max_jump_rad``: refuse a pose farther than this from the prediction of the previous
    accepted one (only while that one is fresh). ``bandwidth_hz``, ``accel_tau_s``: of the
    :class:`TwistEstimator`.
    """

    def __init__(
        self,
        ema_alpha: float = 0.5,
        stale_after_s: float = 0.05,
        max_jump_m: float = 0.05,
        max_jump_rad: float = 0.3,
        bandwidth_hz: float = 5.5,
        accel_tau_s: float = 0.05,
    ) -> None:
        if not (0 < ema_alpha <= 1):
            raise ValueError("ema_alpha must be in (0, 1]")
        if not (stale_after_s > 0 and max_jump_m > 0 and max_jump_rad > 0):
            raise ValueError("stale_after_s, max_jump_m and max_jump_rad must be > 0")
        self.ema_alpha = float(ema_alpha)
        self.stale_after_s = float(stale_after_s)
        self.max_jump_m = float(max_jump_m)
        self.max_jump_rad = float(max_jump_rad)
        self.motion = TwistEstimator(bandwidth_hz, accel_tau_s)
        self._t_c_o_ema = np.zeros(3)
        self.T_w_o: np.ndarray | None = None  # smoothed object pose at pose_t_s
        self.pose_t_s: float | None = None  # time stamp of the last accepted pose (s)

    def restart(self, T_w_c: np.ndarray, T_c_o: np.ndarray, t_s: float | None) -> None:
        """Start over from one pose (valid 4×4s), taken at ``t_s`` seconds, or at the time of the next
        :meth:`anchor` if None."""
        self.motion.reset()
        self._t_c_o_ema = T_c_o[:3, 3].copy()
        self.T_w_o = T_w_c @ T_c_o
        self.pose_t_s = t_s
        if t_s is not None:
            self.motion.update(t_s, self.T_w_o)

    def anchor(self, t_s: float) -> None:
        """Give a start pose taken without a time the time ``t_s`` (no-op once it has one)."""
        if self.pose_t_s is None and self.T_w_o is not None:
            self.pose_t_s = t_s
            self.motion.update(t_s, self.T_w_o)

    def stale(self, t_s: float, after_s: float | None = None) -> bool:
        """No accepted pose for longer than ``after_s`` (default ``stale_after_s``) at time ``t_s``."""
        assert self.pose_t_s is not None
        return t_s - self.pose_t_s > (self.stale_after_s if after_s is None else after_s)

    def ingest(
        self,
        t_s: float,
        T_w_c: np.ndarray,
        v_c_w: np.ndarray,
        T_c_o: np.ndarray,
        pose_t_s: float,
        fresh_for_s: float | None = None,
    ) -> str:
        """Check and fold in one tracker pose estimated at ``pose_t_s``, the camera being at ``T_w_c``
        with twist ``v_c_w`` (world frame) at ``t_s``; return '' if accepted (or no news), else why it
        was refused. ``fresh_for_s``: how long the last accepted pose counts as fresh (gate against its
        prediction, keep the motion estimate) instead of ``stale_after_s``."""
        assert self.pose_t_s is not None and self.T_w_o is not None
        try:
            T_c_o = geometry.as_pose(T_c_o, "T_c_o")
        except ValueError as err:
            return f"invalid pose: {err}"
        if not np.isfinite(pose_t_s) or pose_t_s > t_s:
            return "pose timestamp in the future"
        if pose_t_s == self.pose_t_s:
            return ""  # the same estimate read again: no news, not an error
        if pose_t_s < self.pose_t_s:
            return "pose older than the last accepted one"
        # The camera pose when the tracker's pose was valid, back-extrapolated at constant twist.
        T_w_cp = geometry.advance(T_w_c, v_c_w, pose_t_s - t_s)
        T_w_o_raw = T_w_cp @ T_c_o
        if not self.stale(t_s, fresh_for_s):
            P = self.motion.predict(pose_t_s)
            jump_m = geometry.translation_error_m(P, T_w_o_raw)
            jump_rad = geometry.rotation_error_rad(P, T_w_o_raw)
            if jump_m > self.max_jump_m or jump_rad > self.max_jump_rad:
                return f"jump of {jump_m:.3f} m / {jump_rad:.3f} rad from the prediction"
            self._t_c_o_ema = self.ema_alpha * T_c_o[:3, 3] + (1 - self.ema_alpha) * self._t_c_o_ema
        else:  # re-acquisition after a stale spell: old filter states describe another motion
            self.motion.reset()
            self._t_c_o_ema = T_c_o[:3, 3].copy()
        self.motion.update(pose_t_s, T_w_o_raw)
        T_c_o_f = T_c_o.copy()
        T_c_o_f[:3, 3] = self._t_c_o_ema
        self.T_w_o = T_w_cp @ T_c_o_f
        self.pose_t_s = pose_t_s
        return ""

    def object_at(self, t_s: float, accel: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The smoothed object pose extrapolated to ``t_s`` and its twist there (world frame): at
        constant velocity, or with ``accel`` at the estimated constant acceleration (the pose moved at
        the mean twist over the interval)."""
        assert self.T_w_o is not None and self.pose_t_s is not None
        dt = t_s - self.pose_t_s
        if not accel:
            return geometry.advance(self.T_w_o, self.motion.twist_w, dt), self.motion.twist_w
        a = self.motion.accel_w
        return geometry.advance(self.T_w_o, self.motion.twist_w + 0.5 * dt * a, dt), self.motion.twist_w + dt * a
