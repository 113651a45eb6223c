"""A command link with a latency: an arm whose commands take effect some time after they are sent.

Real arms do not act on a command the instant the controller computes it: the UR5e's RTDE link runs
at 500 Hz with a few milliseconds from the controller's write to the joint servo, Franka's FCI at
1 kHz with about one. :class:`DelayedArm` plays that on a simulated clock: commands are queued with
the time they were sent and reach the arm ``latency_s`` later; pose queries see the arm now.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from evservo.robots.sim_arm import SimArm


class DelayedArm:
    """``arm`` behind a command link of latency ``latency_s`` (s) on a clock the caller advances with
    :meth:`deliver` (µs). ``latency_s`` 0: commands act at once."""

    def __init__(self, arm: SimArm, latency_s: float) -> None:
        if not (np.isfinite(latency_s) and latency_s >= 0):
            raise ValueError("latency_s must be finite and >= 0")
        self.arm = arm
        self.latency_us = round(latency_s * 1e6)
        self.now_us = 0
        self._queue: deque[tuple[int, np.ndarray | None, float]] = deque()

    @property
    def T_e_c(self) -> np.ndarray:
        """Camera/tool frame in the end-effector frame (the arm's)."""
        return self.arm.T_e_c

    def joint_positions(self) -> np.ndarray:
        """Joint positions now (rad)."""
        return self.arm.joint_positions()

    def T_w_e(self) -> np.ndarray:
        """End-effector pose now (the arm's, not delayed)."""
        return self.arm.T_w_e()

    def command_twist(self, v_e_w: np.ndarray, dt_s: float) -> None:
        """Send an end-effector twist (world frame); it reaches the arm ``latency_s`` after now."""
        self._queue.append((self.now_us + self.latency_us, np.array(v_e_w, dtype=float), dt_s))
        self.deliver(self.now_us)

    def stop(self) -> None:
        """Send a stop; it too takes ``latency_s`` to arrive."""
        self._queue.append((self.now_us + self.latency_us, None, 0.0))
        self.deliver(self.now_us)

    def deliver(self, now_us: int) -> None:
        """Advance the link's clock to ``now_us`` and hand the arm every command due by then, in order."""
        self.now_us = now_us
        while self._queue and self._queue[0][0] <= now_us:
            _, v, dt = self._queue.popleft()
            if v is None:
                self.arm.stop()
            else:
                self.arm.command_twist(v, dt)
