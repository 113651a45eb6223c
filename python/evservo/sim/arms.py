"""The robot arms as occluders of the rendered event camera: the UR5e and the Panda drawn into the
simulated view with the target and the background.

The meshes are robosuite's visual meshes (its MJCF, loaded by :class:`~evservo.sim.scene.DualArmScene`),
read from the *compiled* MuJoCo model rather than from the mesh files: MuJoCo has already parsed each
``<geom type="mesh">`` (OBJ/STL, with its ``pos``/``quat`` in its body) and re-expressed the mesh in
the geom's own frame, and ``data.xpos``/``data.xmat`` give each body's world pose every step. Each
link (body) becomes one mesh in its body frame, merged from its visual geoms (group 1, no collision)
and decimated by vertex clustering (a few thousand triangles per link instead of ~10⁵), with a
per-vertex albedo from the geom's material: the luminance of its rgba, clamped to
[:data:`MIN_ALBEDO`, :data:`MAX_ALBEDO`] so that no link is pure black or white.

Excluded links (:data:`EXCLUDED_BODIES`): the Panda's ``link7`` and its ``right_hand`` flange carry
the camera, 5 cm behind its optical centre: they are rigid with the camera, so they never move in the
image and would only add static, clipped-at-the-near-plane blobs at the border of the view (with a
real lens mount they are outside the field of view). Every other link of both arms is drawn, the
Panda's included; parts of them behind the camera are clipped.

Frames: w world, c camera optical frame, b a link (body); ``T_a_b`` is b in a (4×4, metres).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from evservo import _evcore, geometry
from evservo.sim.scene import DualArmScene

EXCLUDED_BODIES = ("panda_link7", "panda_right_hand")
# Side of the vertex-clustering cells (m). A vertex moves to its cell's mean, less than a cell diagonal
# (8.7 mm) and typically a few mm: with the IMX636 model's f ≈ 1160 px that is a few pixels of
# silhouette at the bench's 0.6–1.5 m, while the triangle count drops from ~250 000 to ~63 000.
DECIMATION_CELL_M = 0.005
MIN_ALBEDO, MAX_ALBEDO = 0.1, 0.85


@dataclass(frozen=True)
class Link:
    """One link's mesh in its body frame: ``vertices`` (N, 3) m, ``faces`` (M, 3), ``albedo`` (N,)."""

    name: str
    body_id: int
    vertices: np.ndarray
    faces: np.ndarray
    albedo: np.ndarray

    def size_m(self) -> np.ndarray:
        """Extent of the bounding box along the body axes (m)."""
        return self.vertices.max(axis=0) - self.vertices.min(axis=0)


def decimate(vertices: np.ndarray, faces: np.ndarray, cell_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertex clustering: vertices in the same ``cell_m`` cube merge into their mean; faces that
    collapse, or repeat another, are dropped. Returns ``(vertices, faces, index)`` where ``index``
    maps each input vertex to its output vertex."""
    keys = np.floor(vertices / cell_m).astype(np.int64)
    _, index, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    index = index.reshape(-1)
    out = np.zeros((len(counts), 3))
    np.add.at(out, index, vertices)
    out /= counts[:, None]
    f = index[faces]
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    f = np.unique(np.sort(f[keep], axis=1), axis=0) if keep.any() else f[:0]
    return out, f, index


class ArmMeshes:
    """The visual meshes of both arms of a :class:`DualArmScene`, and their poses in the camera."""

    def __init__(self, scene: DualArmScene, cell_m: float = DECIMATION_CELL_M) -> None:
        self.scene = scene
        m = scene.model
        by_body: dict[int, list[int]] = {}
        for g in range(m.ngeom):
            visual = m.geom_group[g] == 1 and m.geom_contype[g] == 0 and m.geom_conaffinity[g] == 0
            if m.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH or not visual:
                continue
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, m.geom_bodyid[g])
            if name in EXCLUDED_BODIES or not name.startswith(("ur_", "panda_")):
                continue
            by_body.setdefault(int(m.geom_bodyid[g]), []).append(g)
        self.links: list[Link] = []
        for body, geoms in sorted(by_body.items()):
            verts, faces, albedo = [], [], []
            n = 0
            for g in geoms:
                mid = m.geom_dataid[g]
                v = m.mesh_vert[m.mesh_vertadr[mid] : m.mesh_vertadr[mid] + m.mesh_vertnum[mid]].astype(float)
                f = m.mesh_face[m.mesh_faceadr[mid] : m.mesh_faceadr[mid] + m.mesh_facenum[mid]].astype(np.int64)
                R = np.zeros(9)
                mujoco.mju_quat2Mat(R, m.geom_quat[g])
                verts.append(v @ R.reshape(3, 3).T + m.geom_pos[g])  # geom frame → body frame
                faces.append(f + n)
                rgba = m.mat_rgba[m.geom_matid[g]] if m.geom_matid[g] >= 0 else m.geom_rgba[g]
                lum = 0.2126 * rgba[0] + 0.7152 * rgba[1] + 0.0722 * rgba[2]
                albedo.append(np.full(len(v), np.clip(lum, MIN_ALBEDO, MAX_ALBEDO)))
                n += len(v)
            v, f, index = decimate(np.concatenate(verts), np.concatenate(faces), cell_m)
            a = np.zeros(len(v))
            np.add.at(a, index, np.concatenate(albedo))
            a /= np.bincount(index, minlength=len(v))
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, body)
            self.links.append(Link(name, body, v, f, a))
        self._body_ids = np.array([lk.body_id for lk in self.links])
        self._core: list[_evcore.Mesh] | None = None

    @property
    def names(self) -> list[str]:
        return [lk.name for lk in self.links]

    def n_faces(self) -> int:
        return sum(len(lk.faces) for lk in self.links)

    def core_meshes(self) -> list[_evcore.Mesh]:
        """The links as renderer meshes (per-vertex albedo), built once."""
        if self._core is None:
            self._core = [_evcore.Mesh(lk.vertices, lk.faces, vertex_intensity=lk.albedo) for lk in self.links]
        return self._core

    def world_poses(self) -> np.ndarray:
        """Each link's body pose in the world now, (N, 4, 4), from MuJoCo's ``xpos``/``xmat``."""
        d = self.scene.data
        T = np.zeros((len(self.links), 4, 4))
        T[:, :3, :3] = d.xmat[self._body_ids].reshape(-1, 3, 3)
        T[:, :3, 3] = d.xpos[self._body_ids]
        T[:, 3, 3] = 1.0
        return T

    def camera_poses(self, T_w_c: np.ndarray | None = None) -> np.ndarray:
        """Each link's pose in the camera frame now, (N, 4, 4); ``T_w_c`` defaults to the scene's camera."""
        T_w_c = self.scene.T_w_c() if T_w_c is None else T_w_c
        return geometry.inv(T_w_c)[None] @ self.world_poses()
