"""A blinking checkerboard screen seen by the rendered event camera, for testing calibration.

The screen is a textured plane (:func:`screen_mesh`, built through :mod:`evservo.models`): the
checkerboard of :class:`evservo.calib.board.Board` (its lit squares bright, its dark squares at the
scene's background level), a dark margin of ``margin_squares`` around it and a darker bezel around
that. Rendered unlit (ambient 1, diffuse 0: a screen emits), in front of a uniform background of
the dark level. A *blink* shows the screen for ``on_us`` and hides it again: only the lit squares
and the bezel change, so each blink fires the lit squares (ON, then OFF) and the bezel's outline
(the events a real screen's border adds), plus the sensor's noise.

Only the few frames a blink needs are rendered (the switch on, the hold, the switch off), each
switch taking ``switch_us``, so a view costs four renders whatever the time between views; the
sensor's noise still runs over the whole time line.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
from PIL import Image

from evservo import _evcore, geometry
from evservo import io as evio
from evservo.calib.board import Board
from evservo.models import to_core_mesh, trimesh_module

__all__ = [
    "BlinkingScreen",
    "look_at_board",
    "panda_views",
    "record_views",
    "screen_mesh",
    "spread_view_poses",
    "view_pose_candidates",
]

#: sRGB levels of the screen: lit squares, dark squares and margin (linear 0.0999, the background),
#: bezel.
LIT_SRGB, DARK_SRGB, BEZEL_SRGB = 150, 89, 50
#: Linear intensity of the uniform background: the screen's dark level, so that dark squares do not blink.
BACKGROUND = 0.0999
#: Texels per board square.
_TEXELS = 48
#: A pose that puts the screen behind the camera: nothing of it is drawn.
_HIDDEN = geometry.pose((0.0, 0.0, -50.0))


def screen_mesh(board: Board, margin_squares: float = 1.0, bezel_squares: float = 0.5) -> _evcore.Mesh:
    """The screen as a core mesh in the board frame (see :mod:`evservo.calib.board`): one textured
    quad at z = 0 spanning the (cols + 1) × (rows + 1) squares, the margin and the bezel."""
    s = board.square_m
    pad = margin_squares + bezel_squares
    lo = np.array([-(1 + pad), -(1 + pad)]) * s
    hi = np.array([board.cols + pad, board.rows + pad]) * s
    w, h = (np.round((hi - lo) / s * _TEXELS)).astype(int)
    # Texel centres in the board frame; texture row 0 is the top (v = 1), at y = lo.
    x = lo[0] + (np.arange(w) + 0.5) * (hi[0] - lo[0]) / w
    y = lo[1] + (np.arange(h) + 0.5) * (hi[1] - lo[1]) / h
    X, Y = np.meshgrid(x, y)
    k, j = np.floor(X / s) + 1, np.floor(Y / s) + 1  # square index: square (1, 1) spans [0, s]²
    on_board = (k >= 0) & (k <= board.cols) & (j >= 0) & (j <= board.rows)
    inset = np.minimum.reduce([X - lo[0], hi[0] - X, Y - lo[1], hi[1] - Y])  # distance to the screen's edge
    in_screen = inset > bezel_squares * s
    image = np.full((h, w), BEZEL_SRGB, np.uint8)
    image[in_screen] = DARK_SRGB
    image[on_board & ((k + j) % 2 == 0)] = LIT_SRGB
    corners = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]])
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], float)
    visual = trimesh_module().visual.TextureVisuals(uv=uv, image=Image.fromarray(image).convert("RGB"))
    mesh = trimesh_module().Trimesh(corners, [[0, 1, 2], [0, 2, 3]], visual=visual, process=False)
    return to_core_mesh(mesh)


class BlinkingScreen:
    """The rendered event camera ``camera`` looking at a blinking screen showing ``board``.

    :meth:`blink` renders one blink with the screen at ``T_c_board`` (board frame in the camera).
    Time only moves forward; the first call also starts the sensor (at ``t_us - 1`` ms).
    """

    def __init__(self, camera: _evcore.Camera, board: Board, preset: str = "imx636", seed: int = 0) -> None:
        self.camera, self.board = camera, board
        self._sim = _evcore.SimCamera(
            camera, screen_mesh(board), preset=preset, seed=seed, background_intensity=BACKGROUND,
            ambient=1.0, diffuse=0.0,
        )  # fmt: skip
        self._started = False

    def blink(self, T_c_board: np.ndarray, t_us: int, on_us: int = 20_000, switch_us: int = 300) -> np.ndarray:
        """Events (EVENT_CD) of one blink starting at ``t_us``: the screen switches on over
        ``switch_us``, stays on for ``on_us`` and switches off over ``switch_us``."""
        if not self._started:
            self._sim.advance(_HIDDEN, int(t_us) - 1000)
            self._started = True
        parts = [self._sim.advance(_HIDDEN, int(t_us))]
        t_on = int(t_us) + switch_us
        parts.append(self._sim.advance(T_c_board, t_on))
        parts.append(self._sim.advance(T_c_board, t_on + on_us))
        parts.append(self._sim.advance(_HIDDEN, t_on + on_us + switch_us))
        return np.concatenate(parts, dtype=evio.EVENT_CD)


def record_views(
    out: str | Path,
    camera: _evcore.Camera,
    board: Board,
    T_c_board: Sequence[np.ndarray],
    period_us: int = 300_000,
    blinks_per_view: int = 1,
    preset: str = "imx636",
    seed: int = 0,
) -> np.ndarray:
    """Write an event file (any format :func:`evservo.io.write_events` writes) of the screen blinking
    ``blinks_per_view`` times (50 ms apart) at each pose of ``T_c_board``, one view every ``period_us``
    starting at 100 ms; returns the views' mid times (µs), the times an arm would report."""
    screen = BlinkingScreen(camera, board, preset=preset, seed=seed)
    parts, mids = [], []
    for k, T in enumerate(T_c_board):
        t0 = 100_000 + k * period_us
        for b in range(blinks_per_view):
            parts.append(screen.blink(T, t0 + 50_000 * b))
        mids.append(t0 + 25_000 * blinks_per_view)
    events = np.concatenate(parts, dtype=evio.EVENT_CD) if parts else np.empty(0, evio.EVENT_CD)
    evio.write_events(out, events, camera.width, camera.height)
    return np.array(mids, dtype=np.int64)


def look_at_board(board: Board, centre_c: np.ndarray, tilt_rad: Sequence[float]) -> np.ndarray:
    """``T_c_board`` with the board's centre at ``centre_c`` (camera frame, metres), first facing the
    camera square-on (board x along camera x, z away), then turned by the rotation vector ``tilt_rad``
    about its centre."""
    R = geometry.pose((0, 0, 0), tilt_rad)[:3, :3]
    half = np.array([(board.cols - 1) / 2, (board.rows - 1) / 2, 0.0]) * board.square_m
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(centre_c, float) - R @ half
    return T


def view_pose_candidates(
    camera: _evcore.Camera, board: Board, seed: int = 0, distance_m: tuple[float, float] = (0.35, 0.55),
    max_tilt_rad: float = 0.6, margin_px: float = 20.0,
) -> Iterator[np.ndarray]:  # fmt: skip
    """Endless board poses ``T_c_board`` that a calibration would want: the board tilted up to
    ``max_tilt_rad`` about random axes, turned in-plane, at depths in ``distance_m``, its centre
    aimed at a 3×3 grid of image regions in turn (corners included, where distortion shows), and
    always wholly in view (every square's corner ``margin_px`` inside the image, through the
    camera's distortion)."""
    import cv2

    rng = np.random.default_rng(seed)
    K = camera.k
    dist = np.array(camera.dist, float)
    s = board.square_m
    outline = np.array(
        [[-s, -s, 0], [board.cols * s, -s, 0], [board.cols * s, board.rows * s, 0], [-s, board.rows * s, 0]]
    )
    n = 0
    while True:
        g = n % 9
        u = (0.2 + 0.3 * (g % 3) + rng.uniform(-0.08, 0.08)) * camera.width
        v = (0.2 + 0.3 * (g // 3) + rng.uniform(-0.08, 0.08)) * camera.height
        z = rng.uniform(*distance_m)
        centre = np.array([(u - camera.cx) / camera.fx * z, (v - camera.cy) / camera.fy * z, z])
        axis = rng.normal(size=3)
        axis[2] = 0.0
        tilt = axis / np.linalg.norm(axis) * rng.uniform(0.25, 1.0) * max_tilt_rad
        tilt[2] = rng.uniform(-0.35, 0.35)
        T = look_at_board(board, centre, tilt)
        pts_c = outline @ T[:3, :3].T + T[:3, 3]
        if np.any(pts_c[:, 2] < 0.05):
            continue
        img, _ = cv2.projectPoints(pts_c, np.zeros(3), np.zeros(3), K, dist)
        img = img.reshape(-1, 2)
        inside = (img[:, 0] > margin_px) & (img[:, 0] < camera.width - 1 - margin_px)
        inside &= (img[:, 1] > margin_px) & (img[:, 1] < camera.height - 1 - margin_px)
        if inside.all():
            n += 1
            yield T


def spread_view_poses(
    camera: _evcore.Camera, board: Board, n: int, seed: int = 0, distance_m: tuple[float, float] = (0.35, 0.55)
) -> list[np.ndarray]:
    """The first ``n`` of :func:`view_pose_candidates`."""
    return list(itertools.islice(view_pose_candidates(camera, board, seed, distance_m), n))


def panda_views(
    camera: _evcore.Camera, board: Board, n: int, T_e_c: np.ndarray, seed: int = 0,
    distance_m: tuple[float, float] = (0.35, 0.55),
) -> tuple[list[np.ndarray], np.ndarray]:  # fmt: skip
    """The simulated Panda (:mod:`evservo.sim.scene`) carries the camera, mounted at ``T_e_c`` on its
    flange, to ``n`` views of a board fixed in the world, 0.45 m in front of the camera's start pose.
    Views come from :func:`view_pose_candidates`; one the Panda cannot reach within its joint limits
    (the scene's IK does not converge) is skipped. Returns the board poses the camera then has
    (``T_c_board``, from MuJoCo's forward kinematics) and the flange poses in the Panda's base
    (``T_b_e``, (n, 4, 4)), what the arm would report."""
    import mujoco

    from evservo.robots.sim_arm import pose_of
    from evservo.sim.scene import DualArmScene, SceneConfig

    scene = DualArmScene(SceneConfig(T_e_c=T_e_c))
    scene.reset_to_start(0.6)
    T_w_board = scene.T_w_c() @ look_at_board(board, (0.0, 0.0, 0.45), (0.0, 0.0, 0.0))
    base = mujoco.mj_name2id(scene.model, mujoco.mjtObj.mjOBJ_BODY, "panda_base")
    T_b_w = geometry.inv(pose_of(scene.data.xpos[base], scene.data.xmat[base]))
    q_start = scene.panda.joint_positions()
    T_c_board, T_b_e = [], []
    for T in view_pose_candidates(camera, board, seed, distance_m):
        if len(T_c_board) == n:
            break
        try:
            q = scene.panda.solve_ik(T_w_board @ geometry.inv(T) @ geometry.inv(T_e_c), q_start)
        except RuntimeError:
            continue
        scene.panda.set_joint_positions(q)
        T_c_board.append(geometry.inv(scene.T_w_c()) @ T_w_board)
        T_b_e.append(T_b_w @ scene.panda.T_w_e())
    return T_c_board, np.array(T_b_e)
