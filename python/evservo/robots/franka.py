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

from evservo import geometry
from evservo.limits import CartesianLimits
from evservo.robots.safety import SafetyGate, Workspace

__all__ = ["FrankaArm"]

log = logging.getLogger(__name__)


def _franky() -> Any:
    try:
        import franky
    except ImportError as err:
        raise ImportError("FrankaArm needs the 'franky-control' package (pip install franky-control==2.0.0)") from err
    return franky


class FrankaArm:
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
        self.host = host
        self._T_e_c = geometry.as_pose(np.eye(4) if T_e_c is None else T_e_c, "T_e_c")
        self.limits = limits or CartesianLimits()
        self.dry_run = dry_run
        self._hold_ms = max(1, math.ceil(watchdog_s * 1000.0))
        self._lost: str | None = None
        config = self._fr.RealtimeConfig.Enforce if realtime == "enforce" else self._fr.RealtimeConfig.Ignore
        try:
            self.robot = (robot_factory or self._fr.Robot)(
                host, relative_dynamics_factor=relative_dynamics_factor, realtime_config=config
            )
        except self._fr.Exception as err:
            raise ConnectionError(f"cannot connect to the Franka robot at {host}: {err}") from err
        self.gate = SafetyGate(
            self._send, self._halt, self.limits, workspace, watchdog_s, dry_run, name=f"Franka {host}"
        )
        self.gate.open()

    # -- Arm protocol ----------------------------------------------------------------------------

    @property
    def T_e_c(self) -> np.ndarray:
        """Camera frame in the EE frame (4×4, metres)."""
        return self._T_e_c.copy()

    def T_w_e(self) -> np.ndarray:
        """EE pose in the base frame (4×4, metres)."""
        return np.array(self._call(lambda r: r.current_cartesian_state.pose.end_effector_pose.matrix), dtype=float)

    def T_w_c(self) -> np.ndarray:
        """Camera pose in the base frame (4×4, metres)."""
        return self.T_w_e() @ self._T_e_c

    def joint_positions(self) -> np.ndarray:
        """Joint positions (rad)."""
        return np.array(self._call(lambda r: r.current_joint_state.position), dtype=float)

    def twist_w(self) -> np.ndarray:
        """EE twist as franky reports it (base frame; m/s, rad/s): while a motion runs, the twist its
        1 kHz loop is commanding; at rest, franky's estimate from the measured state."""
        tw = self._call(lambda r: r.current_cartesian_state.velocity.end_effector_twist)
        return np.concatenate([np.asarray(tw.linear, dtype=float), np.asarray(tw.angular, dtype=float)])

    def command_twist(self, v_e_w: np.ndarray, dt_s: float) -> None:
        """Send EE twist ``v_e_w`` (base frame, (6,), m/s and rad/s), limited by the gate, for
        ``dt_s`` seconds. Raises ``ConnectionError`` (after a stop attempt) if the link is lost and
        ``RuntimeError`` on a control error (reflex, rejected motion)."""
        p = self.T_w_e()[:3, 3]
        try:
            self.gate.command(v_e_w, p, dt_s)
        except (self._fr.NetworkException, self._fr.ProtocolException) as err:
            self._lose(str(err))
        except self._fr.Exception as err:
            raise RuntimeError(f"Franka at {self.host} refused the motion: {err} (see FrankaArm.recover)") from err

    def stop(self) -> None:
        """Decelerate to rest within franky's dynamics limits."""
        self.gate.stop()

    def recover(self) -> bool:
        """Run the robot's automatic error recovery (after a reflex); returns whether it succeeded."""
        return bool(self._call(lambda r: r.recover_from_errors()))

    # -- connection ------------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the arm, wait (at most 2 s) for the motion to end and drop the connection (idempotent)."""
        if self.robot is None:
            return
        self.gate.close()
        if self._lost is None and not self.dry_run:
            try:
                self.robot.join_motion(timeout=2.0)
            except self._fr.Exception as err:
                log.warning("Franka %s: motion ended with %s", self.host, err)
        # franky has no disconnect call: the connection closes when its robot object goes away.
        self.robot = None

    def __enter__(self) -> FrankaArm:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _call(self, get: Callable[[Any], Any]) -> Any:
        if self._lost is not None:
            raise ConnectionError(f"connection to the Franka robot at {self.host} lost: {self._lost}")
        if self.robot is None:
            raise ConnectionError(f"FrankaArm for {self.host} is closed")
        try:
            return get(self.robot)
        except (self._fr.NetworkException, self._fr.ProtocolException) as err:
            self._lose(str(err))

    def _lose(self, why: str) -> None:
        if self._lost is None:
            self._lost = why
            log.error("Franka %s: %s; stopping", self.host, why)
            self.gate.stop(f"connection lost: {why}")
        raise ConnectionError(f"connection to the Franka robot at {self.host} lost: {self._lost}")

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
