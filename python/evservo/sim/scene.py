"""Dual-robot MuJoCo scene: a UR5e carries the target box, a Panda ~1.2 m away carries the camera.

The arms are robosuite 1.5.2's MIT-licensed MJCF models, loaded by path from the installed package
(robosuite itself is never imported) and composed with ``MjSpec``: the UR5e's base is the world origin,
the Panda's base stands ``base_distance_m`` along world x turned to face it. World z is up.

The target is a box (Cheez-It sized placeholder) whose frame o is its centre: x along its width, y along
its height, z through its thickness; the camera sees its −z face. It hangs off the UR5e flange at
``T_e_o``. The camera optical frame c (z forward, x right, y down) sits on the Panda flange at ``T_e_c``.

Time runs on a simulated clock with a fixed 1 kHz physics step; the arms are kinematic (see
:mod:`evservo.robots.sim_arm`). :meth:`DualArmScene.reset_to_start` places both arms so that the camera
looks at the target face-on at depth Z on its optical axis.
"""

from __future__ import annotations

import copy
import functools
import importlib.util
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from evservo import geometry
from evservo.robots.limits import PANDA, UR5E
from evservo.robots.sim_arm import SimArm, forward, pose_of

UR_JOINTS = [
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
]
PANDA_JOINTS = [f"joint{i}" for i in range(1, 8)]
# Seeds for the start-pose IK: the UR5e elbow-up with the flange pointing towards the Panda; the Panda
# in Franka's "ready" pose.
UR_SEED = np.array([-0.9, -1.2, 1.6, -0.4, 1.57, 0.0])
PANDA_SEED = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])


def robosuite_robot_xml(name: str) -> Path:
    """Path of robosuite's MJCF for robot ``name`` (``"ur5e"``, ``"panda"``), found without importing it."""
    spec = importlib.util.find_spec("robosuite")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError("robosuite is not installed (pip install --no-deps robosuite==1.5.2)")
    path = Path(next(iter(spec.submodule_search_locations))) / "models/assets/robots" / name / "robot.xml"
    if not path.is_file():
        raise FileNotFoundError(path)
    return path


def look_at(eye_w: np.ndarray, target_w: np.ndarray) -> np.ndarray:
    """Camera optical frame (z forward, x right, y down with world z up) at ``eye_w`` looking at
    ``target_w`` (metres)."""
    z = np.asarray(target_w, float) - np.asarray(eye_w, float)
    z /= np.linalg.norm(z)
    up = np.array([0.0, 0.0, 1.0])
    y = -up + (up @ z) * z
    y /= np.linalg.norm(y)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([np.cross(y, z), y, z])
    T[:3, 3] = eye_w
    return T


@dataclass(frozen=True)
class SceneConfig:
    """Layout of the bench. Lengths in metres, poses 4×4.

    ``T_e_c``: camera on the Panda flange (default 5 cm out along the flange axis, looking along it).
    ``T_e_o``: target on the UR5e flange (default: box centre 5 cm out along the flange axis, its −z face
    away from the flange). ``target_start_w``: target centre at the start. ``view_dir_w``: direction from
    the target towards the camera at the start (normalised); the default looks across the bench at a
    slant so that the Panda reaches both Z = 0.6 and 0.9 m without its own base in the way.
    """

    base_distance_m: float = 1.2
    T_e_c: np.ndarray = field(default_factory=lambda: geometry.pose((0.0, 0.0, 0.05)))
    T_e_o: np.ndarray = field(default_factory=lambda: geometry.pose((0.0, 0.0, 0.05), (np.pi, 0.0, 0.0)))
    box_size_m: tuple[float, float, float] = (0.16, 0.21, 0.06)
    target_start_w: tuple[float, float, float] = (0.25, -0.45, 0.5)
    view_dir_w: tuple[float, float, float] = (0.5, 0.75, 0.05)
    physics_dt_s: float = 0.001


class DualArmScene:
    """The composed model, its data, the two arms and the simulated clock."""

    def __init__(self, config: SceneConfig | None = None) -> None:
        self.config = cfg = config or SceneConfig()
        # A copy, so that no scene sees another's changes to the shared compiled model.
        self.model = copy.deepcopy(_compiled_model(_layout_key(cfg)))
        self.data = mujoco.MjData(self.model)
        self.ur = SimArm(self.model, self.data, [f"ur_{j}" for j in UR_JOINTS], "ur_right_hand", UR5E)
        self.panda = SimArm(
            self.model, self.data, [f"panda_{j}" for j in PANDA_JOINTS], "panda_right_hand", PANDA, cfg.T_e_c
        )
        self._target = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, "ur_target")
        self._camera = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, "panda_camera")
        self.ur.set_joint_positions(np.clip(UR_SEED, UR5E.q_min, UR5E.q_max))
        self.panda.set_joint_positions(PANDA_SEED)
        self._steps = 0

    @property
    def t_s(self) -> float:
        """Simulated time (seconds)."""
        return self._steps * self.config.physics_dt_s

    def step(self, n: int = 1) -> None:
        """Advance the clock by ``n`` physics steps, moving both arms."""
        h = self.config.physics_dt_s
        for _ in range(n):
            self.ur.integrate(h)
            self.panda.integrate(h)
            forward(self.model, self.data)
            self._steps += 1

    def T_w_o(self) -> np.ndarray:
        """Target (box centre) pose in the world (4×4, metres)."""
        return pose_of(self.data.xpos[self._target], self.data.xmat[self._target])

    def T_w_c(self) -> np.ndarray:
        """Camera optical frame in the world, from MuJoCo's site (4×4, metres)."""
        return pose_of(self.data.site_xpos[self._camera], self.data.site_xmat[self._camera])

    def T_c_o(self) -> np.ndarray:
        """Ground-truth target pose in the camera frame."""
        return geometry.inv(self.T_w_c()) @ self.T_w_o()

    def start_poses(self, Z_m: float, rotvec_c_o: object = (0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """The start ``(T_w_o, T_w_c)``: the target at ``target_start_w``, facing the camera turned by
        ``rotvec_c_o`` (radians, camera frame; e.g. to show the camera several faces of a box), and
        the camera at depth ``Z_m`` along ``view_dir_w`` looking at the target centre."""
        cfg = self.config
        d = np.asarray(cfg.view_dir_w, float)
        p_o = np.asarray(cfg.target_start_w, float)
        T_w_c = look_at(p_o + Z_m * d / np.linalg.norm(d), p_o)
        T_w_o = T_w_c @ geometry.pose((0.0, 0.0, Z_m), rotvec_c_o)
        return T_w_o, T_w_c

    def reset_to_start(self, Z_m: float = 0.9, rotvec_c_o: object = (0.0, 0.0, 0.0)) -> np.ndarray:
        """Put both arms at rest in the start configuration for depth ``Z_m`` (m) and target
        orientation ``rotvec_c_o`` (see :meth:`start_poses`); returns ``T_c_o``."""
        T_w_o, T_w_c = self.start_poses(Z_m, rotvec_c_o)
        q_ur = self.ur.solve_ik(T_w_o @ geometry.inv(self.config.T_e_o), UR_SEED)
        q_pa = self.panda.solve_ik(T_w_c @ geometry.inv(self.config.T_e_c), PANDA_SEED)
        self.ur.set_joint_positions(q_ur)
        self.panda.set_joint_positions(q_pa)
        self.ur.q_rest, self.panda.q_rest = q_ur, q_pa
        return self.T_c_o()


def _quat_wxyz(T: np.ndarray) -> list[float]:
    """MuJoCo's (w, x, y, z) quaternion of a pose's rotation."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(T[:3, :3]).reshape(9))
    return q.tolist()


# base distance (m), T_e_c and T_e_o (4×4 row-major), box size (m), physics step (s)
_LayoutKey = tuple[float, tuple[float, ...], tuple[float, ...], tuple[float, ...], float]


def _layout_key(cfg: SceneConfig) -> _LayoutKey:
    """What of ``cfg`` the compiled model depends on, hashable (the start pose and view do not)."""
    return (
        cfg.base_distance_m,
        tuple(np.asarray(cfg.T_e_c, float).ravel()),
        tuple(np.asarray(cfg.T_e_o, float).ravel()),
        tuple(cfg.box_size_m),
        cfg.physics_dt_s,
    )


@functools.lru_cache(maxsize=4)
def _compiled_model(key: _LayoutKey) -> mujoco.MjModel:
    """The two arms composed and compiled for the layout ``key`` (see :func:`_layout_key`).

    Compiling reads and processes the arms' ~690 000 mesh vertices (≈ 2 s); an episode, a test module
    or a benchmark worker builds many scenes in one process, so each layout is compiled once and
    copied (≈ 0.05 s)."""
    base_distance_m, T_e_c, T_e_o, box_size_m, physics_dt_s = key
    T_e_c, T_e_o = np.reshape(T_e_c, (4, 4)), np.reshape(T_e_o, (4, 4))
    world = mujoco.MjSpec()
    world.option.timestep = physics_dt_s
    world.worldbody.add_light(pos=[0.6, 0.0, 2.5], dir=[0.0, 0.0, -1.0])
    ur = mujoco.MjSpec.from_file(str(robosuite_robot_xml("ur5e")))
    panda = mujoco.MjSpec.from_file(str(robosuite_robot_xml("panda")))
    hand = ur.body("right_hand")
    box = hand.add_body(name="target", pos=T_e_o[:3, 3], quat=_quat_wxyz(T_e_o))
    half = [s / 2 for s in box_size_m]
    box.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=half, rgba=[0.8, 0.2, 0.1, 1.0])
    panda.body("right_hand").add_site(name="camera", pos=T_e_c[:3, 3], quat=_quat_wxyz(T_e_c))
    world.worldbody.add_frame(pos=[0.0, 0.0, 0.0]).attach_body(ur.body("base"), "ur_", "")
    facing_ur = [0.0, 0.0, 0.0, 1.0]  # (w, x, y, z): half a turn about world z
    world.worldbody.add_frame(pos=[base_distance_m, 0.0, 0.0], quat=facing_ur).attach_body(
        panda.body("base"), "panda_", ""
    )
    model = world.compile()
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    return model
