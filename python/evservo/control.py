"""Pose-based visual servoing of a moving object: the paper's Eq. (5)–(6) with the safety around it.

Frames (see :mod:`evservo.geometry`): w world, c camera optical frame, o object. A *twist in the world
frame* of a frame x is ``(v, ω)``: the linear velocity of x's origin (m/s) and its angular velocity
(rad/s), both expressed in world coordinates.

Per control period the controller

1. takes the tracker's ``T_c_o`` (if a new one arrived), checks it (finite, rigid, in time order, no jump
   beyond the gate relative to the prediction), smooths its translation with an EMA and lifts it to the
   world, ``T_w_o = T_w_c · T_c_o`` (Eq. 5's first half);
2. forms the camera target ``T_w_ctgt = T_w_o · inv(T_c_o_des)`` (Eq. 5);
3. applies the second-order law ``ë* = −k e − 2√k ė`` (Eq. 6) with the error taken as target − current
   in the world, ``ė = v_ref − v_c`` where ``v_ref`` is the target's estimated velocity when feed-forward
   is on (mc_rtc's ``refVel``) and zero otherwise;
4. saturates the acceleration and then the velocity of the camera (norms of the linear and angular parts
   separately) and returns the twist to hold for the next period.

When no fresh pose has arrived for ``stale_after_s`` the command decelerates to rest at the acceleration
limit; so it does after :meth:`Pbvs.stop` and before :meth:`Pbvs.start`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from evservo import geometry
from evservo.geometry import rotmat, rotvec
from evservo.limits import CartesianLimits

__all__ = ["CartesianLimits", "Pbvs", "PbvsCommand", "TwistEstimator", "pose_error", "rotmat", "rotvec"]

State = Literal["ok", "stale", "rejected", "stopped"]


def pose_error(T_w_c: np.ndarray, T_w_ctgt: np.ndarray) -> np.ndarray:
    """The paper's error: translation (m) and angle-axis (rad) of ``inv(T_w_c) · T_w_ctgt``, both in
    the current camera frame."""
    T = geometry.inv(T_w_c) @ T_w_ctgt
    return np.concatenate([T[:3, 3], rotvec(T[:3, :3])])


def _clip_norm(x: np.ndarray, limit: float) -> np.ndarray:
    n = float(np.linalg.norm(x))
    return x if n <= limit else x * (limit / n)


@dataclass(frozen=True)
class PbvsCommand:
    """One control period's output.

    ``v_c_w``: camera twist to hold for the next period (world frame, m/s and rad/s), within the limits.
    ``a_c_w``: the camera acceleration ë* actually applied, ``(v_c_w − v_now)/period`` (m/s², rad/s²).
    ``e``: the error of Eq. 6 in the camera frame (m, rad); zeros when stopped.
    ``state``: ``"stopped"`` (not started or stopped; braking), ``"rejected"`` (this call's pose was
    refused: see ``reason``), ``"stale"`` (no fresh pose for ``stale_after_s``; braking), else ``"ok"``.
    ``T_w_ctgt``: the camera target of Eq. 5 (None before the first accepted pose).
    ``v_ref_w``: the feed-forward reference twist used (zeros without feed-forward).
    ``watchdog``: True while braking because no fresh pose arrived for ``stale_after_s``.
    """

    v_c_w: np.ndarray
    a_c_w: np.ndarray
    e: np.ndarray
    state: State
    reason: str = ""
    T_w_ctgt: np.ndarray | None = None
    v_ref_w: np.ndarray = field(default_factory=lambda: np.zeros(6))
    watchdog: bool = False


class TwistEstimator:
    """Critically damped alpha–beta filter on a stream of timestamped world poses ``T_w_o``: estimates
    the pose, the twist and the acceleration.

    Translation and rotation are filtered alike, the rotation residual being the rotation vector of
    ``R_meas · R_predᵀ`` (world frame). A constant-velocity motion is tracked without bias, which is what
    makes the feed-forward remove the ramp lag of the PD law.

    The gains follow from ``bandwidth_hz`` and each pose's interval ``dt``: ``α = 1 − exp(−4π f dt)``,
    ``β = α²/(2 − α)`` (critical damping). Fixed per-pose gains would make the filter's bandwidth, and
    so the velocity noise it lets through, scale with the pose rate: a tracker publishing at 1 kHz
    instead of 100 Hz would get ten times the bandwidth and a velocity noise that, through the lever
    arm of a rotation, swamps the feed-forward. The default 5.5 Hz equals α = 0.5 at 100 Hz.

    The acceleration (``accel_w``: m/s², rad/s²) is the twist estimate's rate of change through a
    first-order low-pass of time constant ``accel_tau_s`` (seconds; discretised exactly, so it too
    means the same at any pose rate): differentiating a pose twice needs that much smoothing.
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

    def predict(self, t_s: float) -> np.ndarray:
        """The pose extrapolated to ``t_s`` (seconds) with the current twist; the last pose if none."""
        if self.t_s is None:
            raise RuntimeError("no pose yet")
        dt = t_s - self.t_s
        T = np.eye(4)
        T[:3, :3] = rotmat(self.twist_w[3:] * dt) @ self.T_w_o[:3, :3]
        T[:3, 3] = self.T_w_o[:3, 3] + self.twist_w[:3] * dt
        return T

    def update(self, t_s: float, T_w_o: np.ndarray) -> None:
        """Fold in a measured pose at time ``t_s`` (seconds, strictly after the previous one)."""
        if self.t_s is None:
            self.t_s, self.T_w_o, self.twist_w = t_s, T_w_o.copy(), np.zeros(6)
            return
        dt = t_s - self.t_s
        alpha = 1.0 - np.exp(-4.0 * np.pi * self.bandwidth_hz * dt)
        beta = alpha * alpha / (2.0 - alpha)
        P = self.predict(t_s)
        r = np.concatenate([T_w_o[:3, 3] - P[:3, 3], rotvec(T_w_o[:3, :3] @ P[:3, :3].T)])
        T = np.eye(4)
        T[:3, 3] = P[:3, 3] + alpha * r[:3]
        T[:3, :3] = rotmat(alpha * r[3:]) @ P[:3, :3]
        dv = (beta / dt) * r
        self.accel_w += (1.0 - np.exp(-dt / self.accel_tau_s)) * (dv / dt - self.accel_w)
        self.twist_w = self.twist_w + dv
        self.T_w_o, self.t_s = T, t_s


class Pbvs:
    """PBVS controller for a camera on an arm servoing to a moving object (paper Sec. III-C).

    Call :meth:`start` once the tracker is locked, then :meth:`update` every ``period_s`` seconds.
    Deterministic: the output depends only on the arguments of the calls so far.

    Parameters
    ----------
    k: stiffness of Eq. 6 (1/s²); damping is ``2√k`` (critical). The paper uses 20.
    ema_alpha: weight of a new measurement in the EMA on the translation of ``T_c_o`` (1 disables it).
        The default 0.5 cuts white position noise to ``√(α/(2−α)) ≈ 0.58`` of its standard deviation
        for a lag of ``(1−α)/α = 1`` pose period (10–15 ms at the tracker's 68–107 Hz), small against
        the loop's ~0.15 s lag.
    feedforward: add the target's estimated velocity as the reference velocity (ė = v_ref − v_c).
    period_s: control period (s); the returned twist is meant to be held for that long, and the
        acceleration limit is applied over it.
    limits: camera velocity and acceleration limits.
    stale_after_s: without a fresh pose for this long (by the pose's timestamp), brake to rest.
    max_jump_m, max_jump_rad: refuse a pose farther than this from the prediction of the previous
        accepted pose. The gate applies only while that pose is fresh: after a stale spell the next
        valid pose is taken as a re-acquisition (EMA and velocity estimate restart from it).
    ff_bandwidth_hz: bandwidth of the object's motion estimator (:class:`TwistEstimator`), used for
        feed-forward and for the jump gate's prediction.
    ff_accel: with feed-forward, also feed the target's estimated acceleration forward (mc_rtc's
        ``refAccel``); without it Eq. 6 trails an accelerating target by ``a_ref / (k + 2√k s + s²)``.
    ff_accel_tau_s: time constant of the acceleration estimate's low-pass (s).
    """

    def __init__(
        self,
        k: float = 20.0,
        ema_alpha: float = 0.5,
        feedforward: bool = False,
        period_s: float = 0.002,
        limits: CartesianLimits | None = None,
        stale_after_s: float = 0.05,
        max_jump_m: float = 0.05,
        max_jump_rad: float = 0.3,
        ff_bandwidth_hz: float = 5.5,
        ff_accel: bool = True,
        ff_accel_tau_s: float = 0.05,
    ) -> None:
        if not (np.isfinite(k) and k > 0):
            raise ValueError("k must be finite and > 0")
        if not (0 < ema_alpha <= 1):
            raise ValueError("ema_alpha must be in (0, 1]")
        if not (period_s > 0 and stale_after_s > 0 and max_jump_m > 0 and max_jump_rad > 0):
            raise ValueError("period_s, stale_after_s, max_jump_m and max_jump_rad must be > 0")
        self.k = float(k)
        self.d = 2.0 * np.sqrt(self.k)
        self.ema_alpha = float(ema_alpha)
        self.feedforward = feedforward
        self.period_s = float(period_s)
        self.limits = limits or CartesianLimits()
        self.stale_after_s = float(stale_after_s)
        self.max_jump_m = float(max_jump_m)
        self.max_jump_rad = float(max_jump_rad)
        self.ff_accel = ff_accel
        self._motion = TwistEstimator(ff_bandwidth_hz, ff_accel_tau_s)
        self.T_c_o_des: np.ndarray | None = None
        self._running = False
        self._reset_tracking()

    def _reset_tracking(self) -> None:
        self._motion.reset()
        self._t_c_o_ema: np.ndarray | None = None
        self._T_w_o: np.ndarray | None = None  # smoothed object pose at _pose_t_s
        self._pose_t_s: float | None = None

    def start(self, T_w_c: np.ndarray, T_c_o: np.ndarray, t_s: float | None = None) -> None:
        """Begin servoing: the current ``T_c_o`` becomes ``T_c_o_des`` and the first measurement
        (taken at ``t_s`` seconds if given, else at the time of the next :meth:`update`)."""
        T_w_c = geometry.as_pose(T_w_c, "T_w_c")
        T_c_o = geometry.as_pose(T_c_o, "T_c_o")
        self.T_c_o_des = T_c_o.copy()
        self._reset_tracking()
        self._running = True
        self._t_c_o_ema = T_c_o[:3, 3].copy()
        self._T_w_o = T_w_c @ T_c_o
        self._pose_t_s = t_s
        if t_s is not None:
            self._motion.update(t_s, self._T_w_o)

    def stop(self) -> None:
        """Stop servoing: subsequent commands brake to rest at the acceleration limit."""
        self._running = False

    def update(
        self,
        t_s: float,
        T_w_c: np.ndarray,
        v_c_w: np.ndarray,
        T_c_o: np.ndarray | None = None,
        pose_t_s: float | None = None,
    ) -> PbvsCommand:
        """One control period at time ``t_s`` (seconds).

        ``T_w_c``: camera pose now (forward kinematics · hand–eye). ``v_c_w``: camera twist now (world
        frame). ``T_c_o``: the tracker's latest pose, if any, estimated at ``pose_t_s`` (defaults to
        ``t_s``); a pose with the timestamp of the last accepted one is treated as no news. Between
        ``pose_t_s`` and ``t_s`` the camera pose is back-extrapolated with ``v_c_w`` to lift the pose to
        the world.
        """
        T_w_c = geometry.as_pose(T_w_c, "T_w_c")
        v_c_w = np.asarray(v_c_w, dtype=float).reshape(6)
        if not np.all(np.isfinite(v_c_w)):
            raise ValueError("v_c_w must be finite")
        if not self._running or self.T_c_o_des is None:
            return self._brake(v_c_w, "stopped", "not started" if self.T_c_o_des is None else "stopped")
        if self._pose_t_s is None:
            self._pose_t_s = t_s  # start() without a time: the start pose is as of the first update
            self._motion.update(t_s, self._T_w_o)

        reason = ""
        if T_c_o is not None:
            reason = self._ingest(t_s, T_w_c, v_c_w, T_c_o, t_s if pose_t_s is None else pose_t_s)

        if t_s - self._pose_t_s > self.stale_after_s:
            T_w_ctgt = self._T_w_o @ geometry.inv(self.T_c_o_des)
            cmd = self._brake(v_c_w, "rejected" if reason else "stale", reason or "no fresh pose")
            return replace(cmd, e=pose_error(T_w_c, T_w_ctgt), T_w_ctgt=T_w_ctgt, watchdog=True)

        T_w_o, v_o_w = self._object_now(t_s)
        T_w_ctgt = T_w_o @ geometry.inv(self.T_c_o_des)
        e_w = np.concatenate([T_w_ctgt[:3, 3] - T_w_c[:3, 3], rotvec(T_w_ctgt[:3, :3] @ T_w_c[:3, :3].T)])
        # The camera target moves rigidly with the object: same ω, lever arm from the object's origin.
        v_ref, a_ref = np.zeros(6), np.zeros(6)
        if self.feedforward:
            lever = T_w_ctgt[:3, 3] - T_w_o[:3, 3]
            w = v_o_w[3:]
            v_ref = np.concatenate([v_o_w[:3] + np.cross(w, lever), w])
            if self.ff_accel:
                a_o = self._motion.accel_w
                a_ref = np.concatenate([a_o[:3] + np.cross(a_o[3:], lever) + np.cross(w, np.cross(w, lever)), a_o[3:]])
        a = a_ref + self.k * e_w + self.d * (v_ref - v_c_w)
        v_cmd, a_cmd = self._saturate(v_c_w, a)
        R = T_w_c[:3, :3]
        e_c = np.concatenate([R.T @ e_w[:3], R.T @ e_w[3:]])
        return PbvsCommand(v_cmd, a_cmd, e_c, "rejected" if reason else "ok", reason, T_w_ctgt, v_ref)

    def _ingest(self, t_s: float, T_w_c: np.ndarray, v_c_w: np.ndarray, T_c_o: np.ndarray, pose_t_s: float) -> str:
        """Check and fold in one tracker pose; return '' if accepted, else why it was refused."""
        assert self._pose_t_s is not None and self._t_c_o_ema is not None
        try:
            T_c_o = geometry.as_pose(T_c_o, "T_c_o")
        except ValueError as err:
            return f"invalid pose: {err}"
        if not np.isfinite(pose_t_s) or pose_t_s > t_s:
            return "pose timestamp in the future"
        if pose_t_s == self._pose_t_s:
            return ""  # the same estimate read again: no news, not an error
        if pose_t_s < self._pose_t_s:
            return "pose older than the last accepted one"
        # The camera pose when the tracker's pose was valid, back-extrapolated at constant twist.
        lag = t_s - pose_t_s
        T_w_cp = np.eye(4)
        T_w_cp[:3, :3] = rotmat(-v_c_w[3:] * lag) @ T_w_c[:3, :3]
        T_w_cp[:3, 3] = T_w_c[:3, 3] - v_c_w[:3] * lag
        T_w_o_raw = T_w_cp @ T_c_o
        fresh = t_s - self._pose_t_s <= self.stale_after_s
        if fresh:
            P = self._motion.predict(pose_t_s)
            jump_m = geometry.translation_error_m(P, T_w_o_raw)
            jump_rad = geometry.rotation_error_rad(P, T_w_o_raw)
            if jump_m > self.max_jump_m or jump_rad > self.max_jump_rad:
                return f"jump of {jump_m:.3f} m / {jump_rad:.3f} rad from the prediction"
            self._t_c_o_ema = self.ema_alpha * T_c_o[:3, 3] + (1 - self.ema_alpha) * self._t_c_o_ema
        else:  # re-acquisition after a stale spell: old filter states describe another motion
            self._motion.reset()
            self._t_c_o_ema = T_c_o[:3, 3].copy()
        self._motion.update(pose_t_s, T_w_o_raw)
        T_c_o_f = T_c_o.copy()
        T_c_o_f[:3, 3] = self._t_c_o_ema
        self._T_w_o = T_w_cp @ T_c_o_f
        self._pose_t_s = pose_t_s
        return ""

    def _object_now(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Smoothed object pose at ``t_s`` and its twist (zero without feed-forward)."""
        assert self._T_w_o is not None and self._pose_t_s is not None
        if not self.feedforward:
            return self._T_w_o, np.zeros(6)
        w = self._motion.twist_w
        dt = t_s - self._pose_t_s
        T = np.eye(4)
        T[:3, :3] = rotmat(w[3:] * dt) @ self._T_w_o[:3, :3]
        T[:3, 3] = self._T_w_o[:3, 3] + w[:3] * dt
        return T, w

    def _saturate(self, v: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Clip acceleration then velocity norms. Projecting onto the velocity ball cannot raise the
        acceleration (projection onto a convex set holding ``v`` is non-expansive)."""
        L, h = self.limits, self.period_s
        a = np.concatenate([_clip_norm(a[:3], L.max_lin_acc), _clip_norm(a[3:], L.max_ang_acc)])
        v_new = v + a * h
        v_new = np.concatenate([_clip_norm(v_new[:3], L.max_lin_vel), _clip_norm(v_new[3:], L.max_ang_vel)])
        return v_new, (v_new - v) / h

    def _brake(self, v: np.ndarray, state: State, reason: str) -> PbvsCommand:
        """Decelerate towards rest at the acceleration limit, reaching exactly zero."""
        L, h = self.limits, self.period_s
        lin = v[:3] - _clip_norm(v[:3], L.max_lin_acc * h)
        ang = v[3:] - _clip_norm(v[3:], L.max_ang_acc * h)
        v_new = np.concatenate([_clip_norm(lin, L.max_lin_vel), _clip_norm(ang, L.max_ang_vel)])
        return PbvsCommand(v_new, (v_new - v) / h, np.zeros(6), state, reason)
