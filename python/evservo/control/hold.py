"""What the servo loop does while the tracker has lost the object: bridge a short loss, come to rest
after a long one, then resume smoothly.

The tracker's ``est.lost`` says its pose is not to be trusted (object occluded, out of view, events
stopped, a wrong pose). :class:`LossHold` sits between the tracker and :class:`~evservo.control.Pbvs`
in both loops (the simulated episode and the real loop) and has five modes:

- ``"servoing"``: the controller's command, as it is;
- ``"coasting"``: the tracker has just flagged the object lost: no pose reaches the controller, which
  keeps following the object's motion *predicted* from the poses it had accepted before (its motion
  estimate, fed forward), until the newest of them is ``coast_s`` old (by its time stamp). A pose
  the tracker trusts again within that time is gated against the prediction and servoing goes on
  with the same motion estimate: a short false loss (a dip of the confidence for a few tens of ms)
  costs nothing. Nothing the tracker flagged lost ever drives the arm, and no pose drives it longer
  than ``coast_s`` after it was taken (at 0.1 s an unmodelled target acceleration of 5 m/s² moves the
  object ½·a·t² = 25 mm from the prediction, under the 30 mm at Z = 0.6 m by which issue 12 calls a
  pose wrong);
- ``"holding"``: the loss outlasted the coast (or came while the controller was already braking for
  want of poses, or while it was ramping back in): the camera brakes to rest at the acceleration limit
  (:func:`~evservo.control.saturation.brake`: the velocity falls linearly, no step) and stays there;
  the desired pose ``T_c_o_des`` is kept;
- ``"resuming"``: the tracker has reported the object found again (not lost) for ``confirm_s``; the
  controller restarts from that pose (its filter's motion estimate described the motion before the
  loss) with the kept desired pose, and its command is blended in from the braking command over
  ``ramp_s`` with a smoothstep weight. Both commands are within the limits (norm balls), so their
  convex blend is too, and the weight starts at zero, so the acceleration does not jump either;
- ``"searching"``: started without a pose (:meth:`LossHold.search`): at rest until the tracker has
  been locked for ``confirm_s``; then, as in the paper, the tracked pose becomes the desired one
  (unless one was given) and servoing starts with the same ramp.

A spell of the controller's own watchdog (no fresh pose for ``stale_after_s``) that ends is ramped
out of the same way.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from evservo import geometry
from evservo.control import saturation
from evservo.control.pbvs import Pbvs, PbvsCommand

Mode = Literal["searching", "servoing", "coasting", "holding", "resuming"]


@dataclass(frozen=True)
class HoldCommand:
    """One control period's output: ``v_c_w`` the camera twist to hold next (world frame; m/s, rad/s),
    ``a_c_w`` the acceleration applied (m/s², rad/s²), ``mode`` (see the module docstring), ``pbvs``
    the controller's own command this period (None while holding or searching: it is not run)."""

    v_c_w: np.ndarray
    a_c_w: np.ndarray
    mode: Mode
    pbvs: PbvsCommand | None = None

    @property
    def watchdog(self) -> bool:
        """The controller braked for want of a fresh pose (its watchdog), not for a reported loss."""
        return self.pbvs is not None and self.pbvs.watchdog


def ramp_weight(t_s: float, ramp_s: float) -> float:
    """Smoothstep from 0 at ``t_s = 0`` to 1 at ``ramp_s`` (zero slope at both ends)."""
    if ramp_s <= 0 or t_s >= ramp_s:
        return 1.0
    s = max(t_s, 0.0) / ramp_s
    return s * s * (3.0 - 2.0 * s)


class LossHold:
    """The loop's reaction to ``est.lost`` around a :class:`~evservo.control.Pbvs` (module docstring).

    ``confirm_s``: how long the tracker must report the object found (not lost) before servoing
    resumes after a hold (s; a flickering flag does not restart the controller on every sample).
    ``ramp_s``: how long the controller's command takes to be blended in after a hold (s).
    ``coast_s``: how old (by its time stamp, s) the newest accepted pose may grow while the loop
    follows the predicted object motion through a loss before it brakes (0: brake at once).

    Call :meth:`start` (a locked start: the pose is the desired one) or :meth:`search` (no pose yet),
    then :meth:`update` every control period instead of ``Pbvs.update``.
    """

    def __init__(self, pbvs: Pbvs, confirm_s: float = 0.02, ramp_s: float = 0.3, coast_s: float = 0.1) -> None:
        if not all(np.isfinite(x) and x >= 0 for x in (confirm_s, ramp_s, coast_s)):
            raise ValueError("confirm_s, ramp_s and coast_s must be finite and >= 0")
        self.pbvs = pbvs
        self.confirm_s = float(confirm_s)
        self.ramp_s = float(ramp_s)
        self.coast_s = float(coast_s)
        self.mode: Mode = "searching"
        self.T_c_o_des: np.ndarray | None = None  # kept across losses; None: captured at the first lock
        self._found_at: float | None = None  # loop time since when the tracker reports the object found
        self._ramp_t0 = 0.0
        self._was_watchdog = False
        self._stopped = False

    def start(self, T_w_c: np.ndarray, T_c_o: np.ndarray, t_s: float | None = None) -> None:
        """Servo from a locked pose: ``T_c_o`` (taken at ``t_s``, camera at ``T_w_c``) is the desired one."""
        self.pbvs.start(T_w_c, T_c_o, t_s)
        self.T_c_o_des = self.pbvs.T_c_o_des
        self.mode = "servoing"

    def set_desired(self, T_c_o_des: np.ndarray) -> None:
        """Servo to ``T_c_o_des`` (object in the camera, 4×4, metres) from now on, and keep it across losses."""
        self.pbvs.set_desired(T_c_o_des)
        self.T_c_o_des = self.pbvs.T_c_o_des

    def search(self, T_c_o_des: np.ndarray | None = None) -> None:
        """Start without a pose: hold still until the tracker locks; the desired pose is then
        ``T_c_o_des``, or the first locked pose if None."""
        self.T_c_o_des = None if T_c_o_des is None else geometry.as_pose(T_c_o_des, "T_c_o_des").copy()
        self.mode = "searching"
        self.pbvs.stop()

    def stop(self) -> None:
        """Stop servoing for good: every later command brakes to rest, whatever the tracker reports."""
        self._stopped = True
        if self.mode == "coasting":
            self.mode = "holding"
        self.pbvs.stop()

    def update(
        self,
        t_s: float,
        T_w_c: np.ndarray,
        v_c_w: np.ndarray,
        T_c_o: np.ndarray | None,
        pose_t_s: float | None,
        lost: bool,
    ) -> HoldCommand:
        """One control period at loop time ``t_s`` (s). ``T_c_o``: a fresh, not-lost tracker pose
        estimated at ``pose_t_s`` (or None); ``lost``: the tracker's flag on its newest estimate. The
        other arguments as for :meth:`Pbvs.update <evservo.control.Pbvs.update>`."""
        v_c_w = np.asarray(v_c_w, dtype=float).reshape(6)
        if lost:
            self._found_at = None
            if self.mode == "servoing" and not self._was_watchdog and self.coast_s > 0 and not self._stopped:
                self.mode = "coasting"
            elif self.mode in ("servoing", "resuming"):
                self.mode = "holding"
        elif self._found_at is None:
            self._found_at = t_s
        if self.mode == "coasting":
            return self._coast(t_s, T_w_c, v_c_w, None if lost else T_c_o, pose_t_s)
        if self.mode in ("holding", "searching"):
            found = self._found_at is not None and t_s - self._found_at >= self.confirm_s
            if self._stopped or not (found and T_c_o is not None):
                return self._brake(v_c_w)
            self._restart(t_s, T_w_c, v_c_w, T_c_o, t_s if pose_t_s is None else pose_t_s)
        cmd = self.pbvs.update(t_s, T_w_c, v_c_w, T_c_o, pose_t_s)
        if self.mode == "servoing" and self._was_watchdog and not cmd.watchdog:
            self.mode, self._ramp_t0 = "resuming", t_s  # the controller's watchdog spell ended
        self._was_watchdog = cmd.watchdog
        if self.mode != "resuming":
            return HoldCommand(cmd.v_c_w, cmd.a_c_w, self.mode, cmd)
        w = ramp_weight(t_s - self._ramp_t0, self.ramp_s)
        if w >= 1.0:
            self.mode = "servoing"
        v = (1.0 - w) * saturation.brake(v_c_w, self.pbvs.limits, self.pbvs.period_s) + w * cmd.v_c_w
        return HoldCommand(v, (v - v_c_w) / self.pbvs.period_s, "resuming", cmd)

    def _coast(
        self, t_s: float, T_w_c: np.ndarray, v_c_w: np.ndarray, T_c_o: np.ndarray | None, pose_t_s: float | None
    ) -> HoldCommand:
        """Follow the predicted object motion through a loss; back to servoing on the first pose the
        tracker trusts that agrees with the prediction, holding once the prediction is ``coast_s`` old."""
        newest = self.pbvs.filter.pose_t_s
        if newest is None or t_s - newest > self.coast_s:
            # The prediction is coast_s old: brake as for any loss (before a pose found again could be
            # taken as a re-acquisition by the controller: that is the hold's re-lock, confirmed first).
            self.mode = "holding"
            return self._brake(v_c_w)
        cmd = self.pbvs.update(t_s, T_w_c, v_c_w, T_c_o, pose_t_s, coast_s=self.coast_s)
        if self.pbvs.filter.pose_t_s != newest:  # a new pose was accepted: the object is followed again
            self.mode = "servoing"
        return HoldCommand(cmd.v_c_w, cmd.a_c_w, self.mode, cmd)

    def _restart(self, t_s: float, T_w_c: np.ndarray, v_c_w: np.ndarray, T_c_o: np.ndarray, pose_t_s: float) -> None:
        """Restart the controller from a pose found again: its filter starts over (the motion before
        the loss says nothing about now) and the desired pose is the kept one."""
        T_w_c_then = geometry.advance(geometry.as_pose(T_w_c, "T_w_c"), v_c_w, pose_t_s - t_s)
        self.pbvs.start(T_w_c_then, T_c_o, pose_t_s)
        if self.T_c_o_des is None:
            self.T_c_o_des = self.pbvs.T_c_o_des
        else:
            self.pbvs.set_desired(self.T_c_o_des)
        self.mode, self._ramp_t0, self._was_watchdog = "resuming", t_s, False

    def _brake(self, v_c_w: np.ndarray) -> HoldCommand:
        v = saturation.brake(v_c_w, self.pbvs.limits, self.pbvs.period_s)
        return HoldCommand(v, (v - v_c_w) / self.pbvs.period_s, self.mode)
