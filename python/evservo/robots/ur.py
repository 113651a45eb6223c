"""Universal Robots e-Series arm over RTDE (the ``ur-rtde`` package), behind the :class:`Arm` protocol.

Frames: w is the robot base frame as the controller reports it; e is the controller's active TCP (set
the TCP offset to zero on the pendant to make e the flange). State comes from an
``RTDEReceiveInterface`` (500 Hz on e-Series); commands go through an ``RTDEControlInterface`` as
``speedL`` (a TCP twist in base coordinates, held by the controller until the next one), after the
:class:`~evservo.robots.safety.SafetyGate`. Call :meth:`UrArm.command_twist` at up to the controller's
500 Hz (``PoseFollower`` and ``Pbvs`` default to a 2 ms period).

Two watchdogs guard the stream: the gate's thread halts the arm (``speedStop``) when the application
stops commanding, and the controller-side RTDE watchdog (``setWatchdog``), kicked from that thread,
stops the arm if this whole process hangs. A lost link (socket closed, or state frozen for
``state_timeout_s``) makes the next call attempt a stop and raise ``ConnectionError`` naming the host.

In ``dry_run`` mode only the receive interface is opened (it cannot move the arm): no control script
is uploaded, and commands are limited and logged but never sent.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from evservo.geometry import rotmat
from evservo.limits import CartesianLimits
from evservo.robots.gated import GatedArm
from evservo.robots.safety import Workspace

__all__ = ["RECEIVE_VARIABLES", "UrArm"]

log = logging.getLogger(__name__)

#: RTDE outputs the driver subscribes to (a short recipe keeps each 500 Hz package small).
RECEIVE_VARIABLES = ["timestamp", "actual_q", "actual_qd", "actual_TCP_pose", "actual_TCP_speed", "robot_mode",
                     "safety_mode"]  # fmt: skip

# Controller codes (UR's RTDE guide): robot_mode 7 is RUNNING; safety_mode 1 NORMAL, 2 REDUCED.
_ROBOT_RUNNING = 7
_SAFETY_OK = (1, 2)


def _ur_rtde() -> tuple[Any, Any]:
    try:
        import rtde_control
        import rtde_receive
    except ImportError as err:
        raise ImportError("UrArm needs the 'ur-rtde' package (pip install ur-rtde==1.6.5)") from err
    return rtde_receive.RTDEReceiveInterface, rtde_control.RTDEControlInterface


def pose_from_rtde(x: list[float] | np.ndarray) -> np.ndarray:
    """4×4 pose from RTDE's ``[x, y, z, rx, ry, rz]`` (metres, rotation vector in radians)."""
    a = np.asarray(x, dtype=float).reshape(6)
    T = np.eye(4)
    T[:3, :3] = rotmat(a[3:])
    T[:3, 3] = a[:3]
    return T


class UrArm(GatedArm):
    """A UR e-Series arm streamed with ``speedL`` through a :class:`SafetyGate`.

    ``host``: controller address. ``T_e_c``: camera frame in the TCP frame (4×4, metres).
    ``limits``: Cartesian limits of the TCP (also the ``speedL``/``speedStop`` accelerations).
    ``workspace``: box for the TCP origin in the base frame. ``watchdog_s``: halt when commands stop for
    this long. ``controller_watchdog_hz``: minimum kick rate of the controller-side watchdog.
    ``state_timeout_s``: a state timestamp frozen this long counts as a lost link.
    ``receive_factory``/``control_factory``: constructors of the two ur_rtde interfaces, called as
    ``factory(host, ...)``; the defaults are ur_rtde's (override to inject fakes in tests).
    Use as a context manager: leaving the block, however, stops the arm and closes the connections.
    """

    def __init__(
        self,
        host: str,
        T_e_c: np.ndarray | None = None,
        limits: CartesianLimits | None = None,
        workspace: Workspace | None = None,
        dry_run: bool = False,
        watchdog_s: float = 0.05,
        controller_watchdog_hz: float = 10.0,
        state_timeout_s: float = 0.1,
        receive_factory: Callable[..., Any] | None = None,
        control_factory: Callable[..., Any] | None = None,
    ) -> None:
        if not (state_timeout_s > 0 and controller_watchdog_hz > 0):
            raise ValueError("state_timeout_s and controller_watchdog_hz must be > 0")
        super().__init__(f"the UR controller at {host}", T_e_c, limits, dry_run)
        self.host = host
        self.state_timeout_s = float(state_timeout_s)
        if receive_factory is None or (control_factory is None and not dry_run):
            default_receive, default_control = _ur_rtde()
            receive_factory = receive_factory or default_receive
            control_factory = control_factory or default_control
        self._state_lock = threading.Lock()
        self._last_stamp: float | None = None
        self._last_stamp_change = time.monotonic()
        self._receive: Any = None
        self._control: Any = None
        try:
            self._receive = receive_factory(host, -1.0, list(RECEIVE_VARIABLES))
            if not dry_run:
                assert control_factory is not None
                self._control = control_factory(host)
                if not self._control.setWatchdog(float(controller_watchdog_hz)):
                    raise RuntimeError("the controller refused setWatchdog")
        except Exception as err:
            self._disconnect()
            raise ConnectionError(f"cannot connect to the UR controller at {host}: {err}") from err
        self._open_gate(f"UR {host}", workspace, watchdog_s, tick=None if dry_run else self._kick)

    # -- Arm protocol ----------------------------------------------------------------------------

    def T_w_e(self) -> np.ndarray:
        """TCP pose in the base frame (4×4, metres), from the latest RTDE state."""
        return pose_from_rtde(self._read(lambda r: r.getActualTCPPose()))

    def joint_positions(self) -> np.ndarray:
        """Joint positions (rad), from the latest RTDE state."""
        return np.asarray(self._read(lambda r: r.getActualQ()), dtype=float)

    def twist_w(self) -> np.ndarray:
        """Measured TCP twist (base frame; m/s, rad/s)."""
        return np.asarray(self._read(lambda r: r.getActualTCPSpeed()), dtype=float)

    def _check_ready(self) -> None:
        """Refuse (after a stop) to command an arm that is not running or is in a safety stop."""
        if self.dry_run:
            return
        mode, safety = self._read(lambda r: (r.getRobotMode(), r.getSafetyMode()))
        if mode != _ROBOT_RUNNING or safety not in _SAFETY_OK:
            self.gate.stop("arm not ready")
            raise RuntimeError(f"UR at {self.host} is not ready: robot_mode {mode} (want 7, running), "
                               f"safety_mode {safety} (want 1 normal or 2 reduced)")  # fmt: skip

    def _on_command_error(self, err: Exception) -> None:
        if isinstance(err, RuntimeError):  # ur_rtde reports a failed speedL as RuntimeError
            self._lose(f"speedL failed: {err}")

    # -- connection ------------------------------------------------------------------------------

    def _disconnect(self) -> None:
        for iface in (self._control, self._receive):
            if iface is None:
                continue
            try:
                iface.disconnect()
            except Exception:
                log.exception("UR %s: disconnect failed", self.host)
        self._control = self._receive = None

    def _read(self, get: Callable[[Any], Any]) -> Any:
        """Read state after checking the link is alive and fresh."""
        self._check_link()
        r = self._receive
        if r is None:
            raise ConnectionError(f"UrArm for {self.host} is closed")
        try:
            if not r.isConnected():
                self._lose("RTDE receive connection closed")
            if self._control is not None and not self._control.isConnected():
                self._lose("RTDE control connection closed")
            stamp = float(r.getTimestamp())
            now = time.monotonic()
            with self._state_lock:
                if stamp != self._last_stamp:
                    self._last_stamp, self._last_stamp_change = stamp, now
                elif now - self._last_stamp_change > self.state_timeout_s:
                    self._lose(f"no new robot state for {now - self._last_stamp_change:.3f} s")
            return get(r)
        except RuntimeError as err:  # ur_rtde reports socket failures as RuntimeError
            self._lose(str(err))

    # -- what the gate calls ---------------------------------------------------------------------

    def _send(self, v: np.ndarray, dt_s: float) -> None:  # speedL
        if not self._control.speedL([float(x) for x in v], float(self.limits.max_lin_acc), 0.0):
            raise RuntimeError("speedL was not accepted by the controller")

    def _halt(self) -> None:  # speedStop
        if self._control is not None:
            self._control.speedStop(float(self.limits.max_lin_acc))

    def _kick(self) -> None:
        if self._control is not None and self._lost is None:
            self._control.kickWatchdog()
