"""The PBVS controller: pose filter → control law → saturation, once per control period.

Per control period :class:`Pbvs`

1. folds the tracker's ``T_c_o`` (if a new one arrived) into the :class:`~evservo.control.pose_filter.PoseFilter`
   (checks, EMA, latency compensation, the object's motion estimate), which gives the object's world
   pose ``T_w_o`` (Eq. 5's first half);
2. forms the camera target and applies Eq. (5)–(6) (:mod:`evservo.control.law`), with the target's
   motion fed forward when ``feedforward`` is on;
3. saturates the camera's acceleration and velocity (:mod:`evservo.control.saturation`) and returns the
   twist to hold for the next period.

When no fresh pose has arrived for ``stale_after_s`` the command decelerates to rest at the acceleration
limit; so it does after :meth:`Pbvs.stop` and before :meth:`Pbvs.start`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from evservo import geometry
from evservo.control import law, saturation
from evservo.control.pose_filter import PoseFilter
from evservo.limits import CartesianLimits

State = Literal["ok", "stale", "rejected", "stopped"]

#: ``reach(v_c_w, W, dt_s)``: the camera twist (world frame) nearest ``v_c_w`` in the 6×6 weight ``W``
#: that the arm can deliver over the next ``dt_s`` seconds (``v_c_w`` itself if it can), e.g.
#: :class:`evservo.robots.reach.ReachableTwist`.
Reach = Callable[[np.ndarray, np.ndarray, float], np.ndarray]


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
    ``arm_limited``: the arm could not deliver the saturated twist, ``v_c_w`` is what it can (see ``reach``).
    """

    v_c_w: np.ndarray
    a_c_w: np.ndarray
    e: np.ndarray
    state: State
    reason: str = ""
    T_w_ctgt: np.ndarray | None = None
    v_ref_w: np.ndarray = field(default_factory=lambda: np.zeros(6))
    watchdog: bool = False
    arm_limited: bool = False


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
    ff_bandwidth_hz: bandwidth of the object's motion estimator
        (:class:`~evservo.control.pose_filter.TwistEstimator`), used for feed-forward and for the jump
        gate's prediction.
    ff_accel: with feed-forward, also feed the target's estimated acceleration forward (mc_rtc's
        ``refAccel``); without it Eq. 6 trails an accelerating target by ``a_ref / (k + 2√k s + s²)``.
    ff_accel_tau_s: time constant of the acceleration estimate's low-pass (s).
    max_image_rate_rad_s: with feed-forward, limit the camera's motion *relative to the target's*
        so that the object moves in the image no faster than this (rad/s; see
        :func:`~evservo.control.saturation.image_motion_matrix`): a camera that fell behind catches up
        no faster than the tracker can follow. None: no limit.
    reach: what the arm can deliver at its configuration (:data:`Reach`); the saturated twist is
        replaced by the deliverable one nearest it, image motion first
        (:func:`~evservo.control.saturation.image_priority_weights`), so the commands, which are also
        the controller's velocity state, stay true. None: only the Cartesian limits.
    object_radius_m: the object's radius for the image-motion rates (m).
    lookahead_s: with feed-forward, the command takes effect this long after :meth:`update` (the arm's
        command latency): the object and the camera (at its current twist) are predicted to then.
    predict_accel: with feed-forward, extrapolate the object across the pose's age and ``lookahead_s``
        at its estimated acceleration (constant-acceleration predictor) instead of at constant velocity.
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
        max_image_rate_rad_s: float | None = None,
        reach: Reach | None = None,
        object_radius_m: float = 0.1,
        lookahead_s: float = 0.0,
        predict_accel: bool = False,
    ) -> None:
        if not (np.isfinite(k) and k > 0):
            raise ValueError("k must be finite and > 0")
        if not period_s > 0:
            raise ValueError("period_s must be > 0")
        if max_image_rate_rad_s is not None and not max_image_rate_rad_s > 0:
            raise ValueError("max_image_rate_rad_s must be > 0")
        if not object_radius_m > 0:
            raise ValueError("object_radius_m must be > 0")
        if not (np.isfinite(lookahead_s) and lookahead_s >= 0):
            raise ValueError("lookahead_s must be finite and >= 0")
        self.filter = PoseFilter(ema_alpha, stale_after_s, max_jump_m, max_jump_rad, ff_bandwidth_hz, ff_accel_tau_s)
        self.k = float(k)
        self.feedforward = feedforward
        self.period_s = float(period_s)
        self.limits = limits or CartesianLimits()
        self.ff_accel = ff_accel
        self.max_image_rate_rad_s = max_image_rate_rad_s
        self.reach = reach
        self.object_radius_m = float(object_radius_m)
        self.lookahead_s = float(lookahead_s)
        self.predict_accel = predict_accel
        self.T_c_o_des: np.ndarray | None = None
        self._running = False

    @property
    def stale_after_s(self) -> float:
        """Watchdog delay (s): braking starts once the last accepted pose is older than this."""
        return self.filter.stale_after_s

    def start(self, T_w_c: np.ndarray, T_c_o: np.ndarray, t_s: float | None = None) -> None:
        """Begin servoing: the current ``T_c_o`` becomes ``T_c_o_des`` and the first measurement
        (taken at ``t_s`` seconds if given, else at the time of the next :meth:`update`)."""
        T_w_c = geometry.as_pose(T_w_c, "T_w_c")
        T_c_o = geometry.as_pose(T_c_o, "T_c_o")
        self.T_c_o_des = T_c_o.copy()
        self.filter.restart(T_w_c, T_c_o, t_s)
        self._running = True

    def set_desired(self, T_c_o_des: np.ndarray) -> None:
        """Servo to ``T_c_o_des`` (object in the camera, 4×4, metres) from now on instead."""
        self.T_c_o_des = geometry.as_pose(T_c_o_des, "T_c_o_des").copy()

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
        coast_s: float | None = None,
    ) -> PbvsCommand:
        """One control period at time ``t_s`` (seconds).

        ``T_w_c``: camera pose now (forward kinematics · hand–eye). ``v_c_w``: camera twist now (world
        frame). ``T_c_o``: the tracker's latest pose, if any, estimated at ``pose_t_s`` (defaults to
        ``t_s``); a pose with the timestamp of the last accepted one is treated as no news. Between
        ``pose_t_s`` and ``t_s`` the camera pose is back-extrapolated with ``v_c_w`` to lift the pose to
        the world. ``coast_s``: keep servoing on the predicted object motion until the last accepted
        pose is this old (s) instead of ``stale_after_s`` (:class:`~evservo.control.hold.LossHold`
        bridging a short loss); a pose arriving within it is gated against the prediction and continues
        the motion estimate.
        """
        T_w_c = geometry.as_pose(T_w_c, "T_w_c")
        v_c_w = np.asarray(v_c_w, dtype=float).reshape(6)
        if not np.all(np.isfinite(v_c_w)):
            raise ValueError("v_c_w must be finite")
        if not self._running or self.T_c_o_des is None:
            return self._brake(v_c_w, "stopped", "not started" if self.T_c_o_des is None else "stopped")
        f = self.filter
        f.anchor(t_s)  # start() without a time: the start pose is as of the first update
        reason = ""
        if T_c_o is not None:
            reason = f.ingest(t_s, T_w_c, v_c_w, T_c_o, t_s if pose_t_s is None else pose_t_s, coast_s)
        assert f.T_w_o is not None

        if f.stale(t_s, coast_s):
            T_w_ctgt = law.camera_target(f.T_w_o, self.T_c_o_des)
            cmd = self._brake(v_c_w, "rejected" if reason else "stale", reason or "no fresh pose")
            return PbvsCommand(cmd.v_c_w, cmd.a_c_w, law.pose_error(T_w_c, T_w_ctgt), cmd.state, cmd.reason,
                               T_w_ctgt, watchdog=True)  # fmt: skip

        v_ref, a_ref = np.zeros(6), np.zeros(6)
        if self.feedforward:
            T_w_o, twist_o = f.object_at(t_s + self.lookahead_s, self.predict_accel)
            T_w_ctgt = law.camera_target(T_w_o, self.T_c_o_des)
            v_ref, a_ref = law.rigid_reference(T_w_o, T_w_ctgt, twist_o, f.motion.accel_w if self.ff_accel else None)
            T_w_c_then = geometry.advance(T_w_c, v_c_w, self.lookahead_s)
        else:
            T_w_o, T_w_c_then = f.T_w_o, T_w_c
            T_w_ctgt = law.camera_target(T_w_o, self.T_c_o_des)
        e_w = law.world_error(T_w_c_then, T_w_ctgt)
        a = law.acceleration(self.k, e_w, v_c_w, v_ref, a_ref)
        h = self.period_s
        A = None
        if self.reach is not None or (self.feedforward and self.max_image_rate_rad_s is not None):
            A = saturation.image_motion_matrix(T_w_c, T_w_o[:3, 3], self.object_radius_m)
        if A is not None and self.feedforward and self.max_image_rate_rad_s is not None:
            a = (saturation.limit_image_rate(v_c_w + a * h, v_ref, A, self.max_image_rate_rad_s) - v_c_w) / h
        v_cmd, a_cmd = saturation.saturate(v_c_w, a, self.limits, h)
        limited = False
        if A is not None and self.reach is not None:
            depth = float(np.linalg.norm(T_w_o[:3, 3] - T_w_c[:3, 3]))
            v_arm = self.reach(v_cmd, saturation.image_priority_weights(A, depth), h)
            limited = not np.array_equal(v_arm, v_cmd)
            v_cmd, a_cmd = v_arm, (v_arm - v_c_w) / h
        R = T_w_c[:3, :3]
        e_c = np.concatenate([R.T @ e_w[:3], R.T @ e_w[3:]])
        state: State = "rejected" if reason else "ok"
        return PbvsCommand(v_cmd, a_cmd, e_c, state, reason, T_w_ctgt, v_ref, arm_limited=limited)

    def _brake(self, v: np.ndarray, state: State, reason: str) -> PbvsCommand:
        """Decelerate towards rest at the acceleration limit."""
        v_new = saturation.brake(v, self.limits, self.period_s)
        return PbvsCommand(v_new, (v_new - v) / self.period_s, np.zeros(6), state, reason)
