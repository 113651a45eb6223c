"""Franka (Panda / FR3) arm over FCI with the ``franky-control`` package, behind the :class:`Arm` protocol.

Frames: w is libfranka's base frame O; e is its end-effector frame EE (the flange composed with the
``F_T_EE`` configured in Desk or with ``Robot.set_ee``). Each :meth:`FrankaArm.command_twist` replaces
the running motion with a Cartesian velocity motion towards the new twist (EE twist in base
coordinates); franky's 1 kHz control thread reaches it within its jerk/acceleration limits (scaled by
``relative_dynamics_factor``) — the slow visual loop feeding a fast rate-limited inner loop, as in
ViSP's Franka backend. Every motion holds its twist for only ``watchdog_s``, so the robot itself brakes
if commands stop arriving, on top of the :class:`~evservo.robots.safety.SafetyGate` watchdog.

A lost link (``NetworkException``/``ProtocolException``) makes the call attempt a stop and raise
``ConnectionError`` naming the host; a reflex or control error raises ``RuntimeError`` (recover with
:meth:`FrankaArm.recover`). In ``dry_run`` mode the robot is connected and read but never moved.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any, Literal

import numpy as np

from evservo.limits import CartesianLimits
from evservo.robots.gated import GatedArm
from evservo.robots.safety import Workspace
from evservo.scheduling import calling_thread_scheduling_kept

__all__ = ["FrankaArm"]

log = logging.getLogger(__name__)


def _franky() -> Any:
    try:
        import franky
    except ImportError as err:
        raise ImportError("FrankaArm needs the 'franky-control' package (pip install franky-control==2.0.0)") from err
    return franky


class FrankaArm(GatedArm):
    """A Franka arm streamed with Cartesian velocity motions through a :class:`SafetyGate`.

    ``host``: FCI address of the robot (or of a franky-sim server). ``T_e_c``: camera frame in the EE
    frame (4×4, metres). ``limits``/``workspace``/``watchdog_s``/``dry_run``: see :class:`SafetyGate`.
    ``relative_dynamics_factor``: fraction (0, 1] of the robot's velocity/acceleration/jerk limits
    franky may use. ``realtime``: ``"enforce"`` (real robot: refuse to run without a realtime kernel)
    or ``"ignore"`` (simulation, development machines). ``robot_factory``: constructor of the franky
    robot, called as ``factory(host, relative_dynamics_factor=..., realtime_config=...)``.
    Use as a context manager: leaving the block, however, stops the arm.
    """

    def __init__(
        self,
        host: str,
        T_e_c: np.ndarray | None = None,
        limits: CartesianLimits | None = None,
        workspace: Workspace | None = None,
        dry_run: bool = False,
        watchdog_s: float = 0.05,
        relative_dynamics_factor: float = 0.5,
        realtime: Literal["enforce", "ignore"] = "enforce",
        robot_factory: Callable[..., Any] | None = None,
    ) -> None:
        if not 0 < relative_dynamics_factor <= 1:
            raise ValueError("relative_dynamics_factor must be in (0, 1]")
        if realtime not in ("enforce", "ignore"):
            raise ValueError("realtime must be 'enforce' or 'ignore'")
        self._fr = _franky()
        super().__init__(f"the Franka robot at {host}", T_e_c, limits, dry_run)
        self.host = host
        self._hold_ms = max(1, math.ceil(watchdog_s * 1000.0))
        config = self._fr.RealtimeConfig.Enforce if realtime == "enforce" else self._fr.RealtimeConfig.Ignore
        try:
            # libfranka raises the connecting thread (usually Python's main thread) to SCHED_FIFO 99
            # wherever the OS permits, also with RealtimeConfig.Ignore, and leaves it there; every
            # thread started from it later, e.g. a tracker's solver, would spin at that priority.
            # franky's control thread sets its own priority.
            with calling_thread_scheduling_kept():
                self.robot = (robot_factory or self._fr.Robot)(
                    host, relative_dynamics_factor=relative_dynamics_factor, realtime_config=config
                )
        except self._fr.Exception as err:
            raise ConnectionError(f"cannot connect to the Franka robot at {host}: {err}") from err
        self._open_gate(f"Franka {host}", workspace, watchdog_s)

    # -- Arm protocol ----------------------------------------------------------------------------

    def T_w_e(self) -> np.ndarray:
        """EE pose in the base frame (4×4, metres)."""
        return np.array(self._call(lambda r: r.current_cartesian_state.pose.end_effector_pose.matrix), dtype=float)

    def joint_positions(self) -> np.ndarray:
        """Joint positions (rad)."""
        return np.array(self._call(lambda r: r.current_joint_state.position), dtype=float)

    def twist_w(self) -> np.ndarray:
        """EE twist as franky reports it (base frame; m/s, rad/s): while a motion runs, the twist its
        1 kHz loop is commanding; at rest, franky's estimate from the measured state."""
        tw = self._call(lambda r: r.current_cartesian_state.velocity.end_effector_twist)
        return np.concatenate([np.asarray(tw.linear, dtype=float), np.asarray(tw.angular, dtype=float)])

    def _on_command_error(self, err: Exception) -> None:
        if isinstance(err, (self._fr.NetworkException, self._fr.ProtocolException)):
            self._lose(str(err))
        if isinstance(err, self._fr.Exception):
            raise RuntimeError(f"Franka at {self.host} refused the motion: {err} (see FrankaArm.recover)") from err

    def recover(self) -> bool:
        """Run the robot's automatic error recovery (after a reflex); returns whether it succeeded."""
        return bool(self._call(lambda r: r.recover_from_errors()))

    # -- connection ------------------------------------------------------------------------------

    def _disconnect(self) -> None:
        """Wait (at most 2 s) for the motion to end, then drop the robot (franky has no disconnect
        call: the connection closes when its robot object goes away)."""
        if self.robot is None:
            return
        if self._lost is None and not self.dry_run:
            try:
                self.robot.join_motion(timeout=2.0)
            except self._fr.Exception as err:
                log.warning("Franka %s: motion ended with %s", self.host, str(err))
        self.robot = None

    def _call(self, get: Callable[[Any], Any]) -> Any:
        self._check_link()
        if self.robot is None:
            raise ConnectionError(f"FrankaArm for {self.host} is closed")
        try:
            return get(self.robot)
        except (self._fr.NetworkException, self._fr.ProtocolException) as err:
            self._lose(str(err))

    # -- what the gate calls ---------------------------------------------------------------------

    def _send(self, v: np.ndarray, dt_s: float) -> None:
        fr = self._fr
        twist = fr.Twist(np.asarray(v[:3], dtype=float), np.asarray(v[3:], dtype=float))
        motion = fr.CartesianVelocityMotion(fr.RobotVelocity(twist), duration=fr.Duration(self._hold_ms))
        self.robot.move(motion, asynchronous=True)

    def _halt(self) -> None:
        if self._lost is not None:
            self.robot.stop()  # no motion can be planned without state; preempt whatever runs
            return
        try:
            self.robot.move(self._fr.CartesianVelocityStopMotion(), asynchronous=True)
        except self._fr.Exception:
            # A different control mode is running or the robot is in error: preempt instead.
            self.robot.stop()
