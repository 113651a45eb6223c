"""The shell every commanded arm shares: a :class:`~evservo.robots.safety.SafetyGate` in front of the
driver, the hand–eye transform, and the rule for a lost link.

A driver (UR, Franka, the kinematic stand-in) subclasses :class:`GatedArm` and supplies what is its
own: reading the state (``T_w_e``, ``joint_positions``, ``twist_w``), the gate's two callbacks
(``_send`` a twist, ``_halt``), and optionally ``_check_ready`` (refuse to command an arm that is not
running), ``_on_command_error`` (which driver exceptions mean a lost link) and ``_disconnect``.

Lost link: the first failure that means the connection is gone marks the arm lost, asks the gate to
stop (the controller's own watchdog stops it if that fails too) and raises ``ConnectionError``
naming the controller; every later call raises the same error.
"""

from __future__ import annotations

import logging
from typing import NoReturn

import numpy as np

from evservo import geometry
from evservo.limits import CartesianLimits
from evservo.robots.safety import SafetyGate, Workspace

__all__ = ["GatedArm"]

log = logging.getLogger(__name__)


class GatedArm:
    """Base class of the arms commanded through a :class:`SafetyGate` (see the module docstring).

    ``link``: who is at the other end, for messages (``"the UR controller at 10.0.0.2"``).
    ``T_e_c``: camera (or tool) frame in the end-effector frame (4×4, metres; identity if None).
    ``limits``: Cartesian limits of the end effector (default :class:`CartesianLimits`).
    ``dry_run``: the gate limits and logs commands but never sends them.
    Subclasses call :meth:`_open_gate` once connected.
    """

    gate: SafetyGate

    def __init__(self, link: str, T_e_c: np.ndarray | None, limits: CartesianLimits | None, dry_run: bool) -> None:
        self.link = link
        self._T_e_c = geometry.as_pose(np.eye(4) if T_e_c is None else T_e_c, "T_e_c")
        self.limits = limits or CartesianLimits()
        self.dry_run = dry_run
        self._lost: str | None = None

    def _open_gate(self, name: str, workspace: Workspace | None, watchdog_s: float, tick=None) -> None:
        """Put the gate in front of ``_send``/``_halt`` and start its watchdog."""
        self.gate = SafetyGate(
            self._send, self._halt, self.limits, workspace, watchdog_s, self.dry_run, name=name, tick=tick
        )
        self.gate.open()

    # -- the Arm protocol's shared part ----------------------------------------------------------

    @property
    def T_e_c(self) -> np.ndarray:
        """Camera frame in the end-effector frame (4×4, metres)."""
        return self._T_e_c.copy()

    def T_w_e(self) -> np.ndarray:
        """End-effector pose in the world (robot base) frame, 4×4, metres."""
        raise NotImplementedError

    def T_w_c(self) -> np.ndarray:
        """Camera pose in the world (robot base) frame, 4×4, metres."""
        return self.T_w_e() @ self._T_e_c

    def command_twist(self, v_e_w: np.ndarray, dt_s: float) -> np.ndarray:
        """Send end-effector twist ``v_e_w`` (world frame, (6,), m/s and rad/s), limited by the gate, to
        be held for ``dt_s`` seconds; returns the twist sent (what :attr:`SafetyGate.last_sent` holds
        until the next command or a halt by the gate's watchdog). Raises ``ConnectionError`` (after a
        stop attempt) when the link is lost, ``RuntimeError`` when the arm refuses."""
        self._check_ready()
        p = self.T_w_e()[:3, 3]
        try:
            return self.gate.command(v_e_w, p, dt_s)
        except Exception as err:
            self._on_command_error(err)
            raise

    def stop(self) -> None:
        """Decelerate to rest within the arm's limits."""
        self.gate.stop()

    def close(self) -> None:
        """Stop the arm, end the gate's watchdog and drop the connection (idempotent)."""
        self.gate.close()
        self._disconnect()

    def __enter__(self) -> GatedArm:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- lost link ---------------------------------------------------------------------------------

    def _check_link(self) -> None:
        """Raise ``ConnectionError`` if the link was lost before."""
        if self._lost is not None:
            raise ConnectionError(f"connection to {self.link} lost: {self._lost}")

    def _lose(self, why: str) -> NoReturn:
        """Mark the link lost, try to stop the arm, and raise ``ConnectionError`` naming the controller."""
        if self._lost is None:
            self._lost = why
            log.error("%s: %s; stopping", self.link, why)
            self.gate.stop(f"connection lost: {why}")
        raise ConnectionError(f"connection to {self.link} lost: {self._lost}")

    # -- what a driver supplies ----------------------------------------------------------------------

    def _send(self, v: np.ndarray, dt_s: float) -> None:
        raise NotImplementedError

    def _halt(self) -> None:
        raise NotImplementedError

    def _check_ready(self) -> None:
        """Raise (after stopping) if the arm cannot take commands now; by default it always can."""

    def _on_command_error(self, err: Exception) -> None:
        """Translate a driver's exception from :meth:`command_twist` (e.g. ``self._lose(...)`` for a
        network error); returning lets the exception propagate as it is."""

    def _disconnect(self) -> None:
        """Drop the connection; by default there is none."""
