"""An arm that is a twist topic: the gated end-effector twist handed to a callable (``evservo ros
servo`` publishes it as ``geometry_msgs/TwistStamped`` for MoveIt Servo or a Cartesian velocity
controller), behind the same :class:`~evservo.robots.safety.SafetyGate` as every other arm.

What a twist sink cannot read is the arm's pose. Two ways to have one:

* ``pose=`` a callable returning the end-effector pose in the robot base frame (4×4, metres), e.g.
  the newest message of a pose topic the robot publishes; it raises ``ConnectionError`` when that
  pose is gone or stale, which the loop treats as a lost link;
* without it, the pose is the gated twists integrated over wall time from ``T_w_e0``, as
  :class:`~evservo.robots.kinematic.KinematicArm` does: right as long as the controller follows
  the commands, but blind to what the arm really did (limits of its own, a person stopping it), and
  its world is the start pose's, not the robot base's, so a workspace box means nothing then.

The twist is handed over in the end-effector frame (``v_e_e``: the end-effector origin's linear
velocity and the angular velocity, both in end-effector axes), which needs only the pose's
rotation: with the dead-reckoned pose it is exactly what the controller asked for, whatever the
real base frame is. Every halt (the gate's watchdog, a stop, closing) hands over a zero twist, so
the last twist a controller receives from a run is zero.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from evservo.limits import CartesianLimits
from evservo.robots.kinematic import KinematicArm
from evservo.robots.safety import Workspace

__all__ = ["TwistSink", "twist_in_frame"]


def twist_in_frame(v_w: np.ndarray, R_w_f: np.ndarray) -> np.ndarray:
    """Twist ``v_w`` ((6,), world coordinates) expressed in the axes of frame f (rotation ``R_w_f``)."""
    v = np.asarray(v_w, dtype=float)
    R_f_w = np.asarray(R_w_f, dtype=float).T
    return np.concatenate([R_f_w @ v[:3], R_f_w @ v[3:]])


class TwistSink(KinematicArm):
    """An arm commanded by handing its gated twist to ``send(v_e_e, dt_s)`` (see the module docstring).

    ``send``: receives the end-effector twist in end-effector axes ((6,), m/s and rad/s) and its hold
    time (s); a zero twist on every halt. ``pose``: the end-effector pose in the robot base frame
    now (None: dead reckoning from ``T_w_e0``). ``link``: who receives the twists, for messages.
    Other arguments as :class:`~evservo.robots.kinematic.KinematicArm`.
    """

    def __init__(
        self,
        send: Callable[[np.ndarray, float], None],
        *,
        pose: Callable[[], np.ndarray] | None = None,
        link: str = "the twist topic",
        T_w_e0: np.ndarray | None = None,
        T_e_c: np.ndarray | None = None,
        limits: CartesianLimits | None = None,
        workspace: Workspace | None = None,
        dry_run: bool = False,
        watchdog_s: float = 0.05,
    ) -> None:
        self._out = send
        self._pose = pose
        if pose is not None and T_w_e0 is None:
            T_w_e0 = pose()
        super().__init__(T_w_e0, T_e_c, limits, workspace, dry_run, watchdog_s)
        self.link = link

    def T_w_e(self) -> np.ndarray:
        """End-effector pose now (4×4, metres): the pose source's, or dead-reckoned."""
        if self._pose is None:
            return super().T_w_e()
        self._check_link()
        try:
            return np.asarray(self._pose(), dtype=float)
        except ConnectionError as err:
            self._lose(str(err))

    def _send(self, v: np.ndarray, dt_s: float) -> None:
        R_w_e = self.T_w_e()[:3, :3]
        self._out(twist_in_frame(v, R_w_e), dt_s)
        super()._send(v, dt_s)

    def _halt(self) -> None:
        try:
            self._out(np.zeros(6), 0.0)
        finally:
            super()._halt()
