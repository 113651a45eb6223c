"""A kinematic stand-in arm: no robot, no physics, just the commanded twist integrated over wall time.

``evservo servo --robot sim`` uses it to run the real loop (live camera or a recording replayed at
real time, threaded tracker, controller at a fixed rate) with nothing to break: the end effector
holds each twist the :class:`~evservo.robots.safety.SafetyGate` lets through until the next one, and
its pose is that twist integrated exactly over the elapsed time (constant world-frame twist of the
end-effector origin: the position moves linearly, the orientation turns about a fixed world axis).
The gate's limits, workspace and watchdog act as they would on a real arm. A halt is immediate (an
ideal arm); ``dry_run`` keeps the arm where it is and only logs.

Note: a recording cannot see the arm move, so with a replayed file the loop is open: the commands
follow the object in the recording, not a scene the camera is really looking at.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

from evservo import geometry
from evservo.geometry import rotmat
from evservo.limits import CartesianLimits
from evservo.robots.gated import GatedArm
from evservo.robots.safety import Workspace

__all__ = ["DEFAULT_START", "KinematicArm"]

#: Default start pose of the end effector (world frame): 0.4 m in front of the base, 0.4 m up, the
#: tool pointing down (z axis along −z of the world), as a UR or Franka in a usual home pose.
DEFAULT_START = np.array([[1.0, 0.0, 0.0, 0.4], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.4], [0.0, 0.0, 0.0, 1.0]])


class KinematicArm(GatedArm):
    """An ideal velocity-controlled arm behind a :class:`SafetyGate` (see the module docstring).

    ``T_w_e0``: start pose of the end effector (4×4, metres; default :data:`DEFAULT_START`, or the
    centre of ``workspace`` tool down if one is given). ``T_e_c``: camera in the end effector.
    ``clock``: monotonic seconds (injectable for tests). :attr:`commands` counts the twists that
    reached the arm (never incremented in dry run).
    """

    def __init__(
        self,
        T_w_e0: np.ndarray | None = None,
        T_e_c: np.ndarray | None = None,
        limits: CartesianLimits | None = None,
        workspace: Workspace | None = None,
        dry_run: bool = False,
        watchdog_s: float = 0.05,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if T_w_e0 is None:
            T_w_e0 = DEFAULT_START.copy()
            if workspace is not None:
                T_w_e0[:3, 3] = 0.5 * (workspace.lo + workspace.hi)
        super().__init__("the kinematic arm", T_e_c, limits, dry_run)
        self._T = geometry.as_pose(T_w_e0, "T_w_e0").copy()
        self._clock = clock
        self._lock = threading.Lock()
        self._v = np.zeros(6)
        self._t = clock()
        self.commands = 0
        self.halts = 0
        self._open_gate("sim arm", workspace, watchdog_s)

    # -- integration ---------------------------------------------------------------------------

    def _advance(self) -> None:
        """Move the pose to now with the twist held since the last change (lock held)."""
        now = self._clock()
        dt = now - self._t
        self._t = now
        if dt <= 0 or not np.any(self._v):
            return
        self._T[:3, 3] += self._v[:3] * dt
        self._T[:3, :3] = rotmat(self._v[3:] * dt) @ self._T[:3, :3]

    def _send(self, v: np.ndarray, dt_s: float) -> None:
        with self._lock:
            self._advance()
            self._v = np.asarray(v, dtype=float).copy()
            self.commands += 1

    def _halt(self) -> None:
        with self._lock:
            self._advance()
            self._v = np.zeros(6)
            self.halts += 1

    # -- Arm protocol --------------------------------------------------------------------------

    def T_w_e(self) -> np.ndarray:
        """End-effector pose in the world now (4×4, metres)."""
        with self._lock:
            self._advance()
            return self._T.copy()

    def joint_positions(self) -> np.ndarray:
        """A kinematic arm has no joints: an empty array."""
        return np.zeros(0)

    def twist_w(self) -> np.ndarray:
        """The end-effector twist in force (world frame; m/s, rad/s)."""
        with self._lock:
            return self._v.copy()
