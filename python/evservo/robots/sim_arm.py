"""A kinematic arm inside a MuJoCo model.

Kinematic, not dynamic: joints are position-controlled and follow the commanded joint velocities
exactly, as a stiff industrial joint controller would. Each command (a twist, resolved by the QP of
:mod:`evservo.robots.ik` within the joint velocity, acceleration and jerk limits) sets a joint-velocity
setpoint to be reached by the end of the command's period and held until the next command; every
physics step moves the joint velocities towards it with the acceleration changing by no more than the
jerk limit and staying within the acceleration limit (the rate limiter of the Franka and UR
controllers), clips them to the velocity limit and integrates the positions, clamped to their range.
Several arms may share one ``MjModel``/``MjData``; whoever owns the data calls
:meth:`SimArm.integrate` on each and then :func:`forward` once.
"""

from __future__ import annotations

import mujoco
import numpy as np

from evservo import geometry
from evservo.robots.ik import clamp, solve_joint_velocities
from evservo.robots.limits import JointLimits


def forward(model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """Update body and site poses and what the Jacobians need (no collision, no dynamics)."""
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)


def pose_of(xpos: np.ndarray, xmat: np.ndarray) -> np.ndarray:
    """4×4 pose from MuJoCo's position and row-major 3×3 orientation."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(xmat).reshape(3, 3)
    T[:3, 3] = xpos
    return T


class SimArm:
    """One arm of a MuJoCo model, driven kinematically (see the module docstring).

    ``joint_names``: the arm's hinge joints, base to tip. ``ee_body``: the end-effector (flange) body.
    ``limits``: joint limits of the real arm. ``T_e_c``: camera/tool frame in the end-effector frame.
    ``q_rest``: posture the IK drifts towards in its null space (defaults to the start configuration).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        joint_names: list[str],
        ee_body: str,
        limits: JointLimits,
        T_e_c: np.ndarray | None = None,
        q_rest: np.ndarray | None = None,
    ) -> None:
        if len(joint_names) != limits.n:
            raise ValueError("one limit per joint")
        self.model, self.data, self.limits = model, data, limits
        ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in joint_names]
        if min(ids) < 0:
            raise ValueError(f"joint not in model: {joint_names}")
        self._qadr = np.array([model.jnt_qposadr[i] for i in ids])
        self._dadr = np.array([model.jnt_dofadr[i] for i in ids])
        self._ee = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, ee_body)
        if self._ee < 0:
            raise ValueError(f"body not in model: {ee_body}")
        self._T_e_c = geometry.as_pose(np.eye(4) if T_e_c is None else T_e_c, "T_e_c")
        self.qd = np.zeros(limits.n)  # joint velocities being applied (rad/s)
        self.qdd = np.zeros(limits.n)  # joint accelerations of the last physics step (rad/s²)
        self.qd_target = np.zeros(limits.n)  # setpoint of the last command (rad/s)
        self._target_in_s = 0.0  # time left to reach the setpoint (s)
        self.q_rest = self.joint_positions() if q_rest is None else np.asarray(q_rest, dtype=float)
        self._scratch = mujoco.MjData(model)

    @property
    def T_e_c(self) -> np.ndarray:
        """Camera/tool frame in the end-effector frame (4×4, metres)."""
        return self._T_e_c.copy()

    def T_w_e(self) -> np.ndarray:
        """End-effector pose in the world (4×4, metres), as of the last :func:`forward`."""
        return pose_of(self.data.xpos[self._ee], self.data.xmat[self._ee])

    def T_w_c(self) -> np.ndarray:
        """Camera/tool pose in the world (4×4, metres)."""
        return self.T_w_e() @ self._T_e_c

    def joint_positions(self) -> np.ndarray:
        """Joint positions (rad)."""
        return self.data.qpos[self._qadr].copy()

    def jacobian(self) -> np.ndarray:
        """6×n Jacobian of the end-effector origin (rows: linear, angular; world frame)."""
        jp = np.zeros((3, self.model.nv))
        jr = np.zeros((3, self.model.nv))
        mujoco.mj_jacBody(self.model, self.data, jp, jr, self._ee)
        return np.vstack([jp[:, self._dadr], jr[:, self._dadr]])

    def twist_w(self) -> np.ndarray:
        """Current end-effector twist (world frame; m/s, rad/s)."""
        return self.jacobian() @ self.qd

    def command_twist(self, v_e_w: np.ndarray, dt_s: float) -> None:
        """Resolve end-effector twist ``v_e_w`` (world frame, (6,)) into a joint-velocity setpoint that
        respects the joint limits over the next ``dt_s`` seconds, reached at their end."""
        v = np.asarray(v_e_w, dtype=float).reshape(6)
        if not np.isfinite(v).all() or not dt_s > 0:
            raise ValueError("twist must be finite and dt_s > 0")
        self.qd_target = solve_joint_velocities(
            self.jacobian(), v, self.joint_positions(), self.qd, dt_s, self.limits, q_rest=self.q_rest, qdd=self.qdd
        )
        self._target_in_s = dt_s

    def stop(self) -> None:
        """Zero the setpoint: the joints decelerate at their acceleration (and jerk) limits."""
        self.qd_target = np.zeros(self.limits.n)
        self._target_in_s = 0.0

    def set_joint_positions(self, q: np.ndarray) -> None:
        """Teleport the joints to ``q`` (rad, within limits) at rest; updates the kinematics."""
        q = np.asarray(q, dtype=float)
        if np.any(q < self.limits.q_min) or np.any(q > self.limits.q_max):
            raise ValueError("joint positions outside the limits")
        self.data.qpos[self._qadr] = q
        self.qd[:] = 0.0
        self.qdd[:] = 0.0
        self.qd_target[:] = 0.0
        forward(self.model, self.data)

    def integrate(self, h_s: float) -> None:
        """Advance the joints by one physics step of ``h_s`` seconds (kinematics not updated)."""
        L = self.limits
        wanted = (self.qd_target - self.qd) / max(self._target_in_s, h_s)
        self._target_in_s = max(self._target_in_s - h_s, 0.0)
        jerk = L.qddd_max * h_s
        qdd = clamp(clamp(wanted, self.qdd - jerk, self.qdd + jerk), -L.qdd_max, L.qdd_max)
        qd = clamp(self.qd + qdd * h_s, -L.qd_max, L.qd_max)
        self.qdd, self.qd = (qd - self.qd) / h_s, qd
        q = self.data.qpos[self._qadr] + self.qd * h_s
        at_limit = (q <= L.q_min) | (q >= L.q_max)
        if at_limit.any():
            self.qd[at_limit] = 0.0
            self.qdd[at_limit] = 0.0
        self.data.qpos[self._qadr] = clamp(q, L.q_min, L.q_max)

    def fk(self, q: np.ndarray) -> np.ndarray:
        """End-effector pose (4×4) at joint positions ``q`` (rad), leaving the simulation untouched.
        Other arms sharing the model sit at their current positions."""
        d = self._scratch
        d.qpos[:] = self.data.qpos
        d.qpos[self._qadr] = q
        mujoco.mj_kinematics(self.model, d)
        return pose_of(d.xpos[self._ee], d.xmat[self._ee])

    def solve_ik(self, T_w_e: np.ndarray, q0: np.ndarray, tol: float = 1e-5, max_iter: int = 300) -> np.ndarray:
        """Joint positions (rad) placing the end effector at ``T_w_e``, by damped Gauss–Newton from
        ``q0`` within the position limits, staying near ``q0`` in the null space of a redundant arm.
        Raises ``RuntimeError`` if it does not converge."""
        T_w_e = geometry.as_pose(T_w_e, "T_w_e")
        d = self._scratch
        q0 = np.clip(np.asarray(q0, dtype=float), self.limits.q_min, self.limits.q_max)
        q = q0.copy()
        jp = np.zeros((3, self.model.nv))
        jr = np.zeros((3, self.model.nv))
        d.qpos[:] = self.data.qpos
        for _ in range(max_iter):
            d.qpos[self._qadr] = q
            mujoco.mj_kinematics(self.model, d)
            mujoco.mj_comPos(self.model, d)
            T = pose_of(d.xpos[self._ee], d.xmat[self._ee])
            R_err = T_w_e[:3, :3] @ T[:3, :3].T
            w = np.array([R_err[2, 1] - R_err[1, 2], R_err[0, 2] - R_err[2, 0], R_err[1, 0] - R_err[0, 1]])
            err = np.concatenate([T_w_e[:3, 3] - T[:3, 3], 0.5 * w])
            if np.linalg.norm(err) < tol and np.trace(R_err) > 2.9:
                return q
            mujoco.mj_jacBody(self.model, d, jp, jr, self._ee)
            J = np.vstack([jp[:, self._dadr], jr[:, self._dadr]])
            J_pinv = J.T @ np.linalg.inv(J @ J.T + 1e-6 * np.eye(6))
            # The null-space pull towards q0 keeps a redundant arm near the seed's posture.
            dq = J_pinv @ err
            if len(q) > 6:
                dq += (np.eye(len(q)) - J_pinv @ J) @ (0.1 * (q0 - q))
            q = np.clip(q + np.clip(dq, -0.2, 0.2), self.limits.q_min, self.limits.q_max)
        raise RuntimeError(f"IK did not converge (residual {np.linalg.norm(err):.2e})")
