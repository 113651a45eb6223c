"""Object models: procedural built-ins, loading from files, and conversion to the core mesh.

Every built-in is generated deterministically, in metres, with the object frame at the centre of
its bounding box. Axes follow the OpenCV camera convention so that the identity rotation shows a
useful view (x right, y down, z away from the camera):

* ``"box"``: a cereal/cracker box 0.16 (x, width) x 0.21 (y, height; the top of the box at -y)
  x 0.06 (z, depth) m. The printed front face is at -z, facing a camera under the identity
  rotation; every face carries a high-contrast print (bands, letter-like blocks, a logo disc)
  as a texture (UV + image).
* ``"drill"``: a power drill from primitives, per-part vertex colours: body cylinder and chuck
  along +x (bit tip at +x), pistol handle and battery pack below (+y).
  Bounding box 0.28 x 0.212 x 0.075 m.
* ``"football"``: a truncated icosahedron (12 black pentagons, 20 white hexagons), subdivided and
  inflated onto a sphere of radius 0.11 m, per-face colours.

The hard objects of the ``objects`` bench suite (issue 13): attitude visible only through print,
near-symmetric, low texture or thin. Cylinders run along y (upright under the identity rotation):

* ``"can"``: a 0.066 x 0.115 m drink can whose label carries an irregular print (blocks of
  different widths and heights at irregular angles), so rotation about its axis shows only there.
* ``"cylinder"``: the same can, plain mid-grey: rotation about y is unobservable.
* ``"checker-can"``: the can with a regular checker label of 8 periods: its edge set repeats under
  45° turns about y (a discrete ambiguity).
* ``"mug"``: a plain 0.08 x 0.095 m mug with a handle on +x; the handle alone fixes rotation about y.
* ``"part"``: a low-texture matte machined part, one grey: an L-bracket with a round boss.
* ``"plate"``: a thin 0.15 (x) x 0.004 (y) x 0.10 (z) m plate with a dark rim band: from the
  recordings' start pose (:data:`evservo.sim.record.START_ROTVEC`) it is seen 18° off edge-on.

Colours in the trimesh objects are sRGB; :func:`to_core_mesh` turns them into linear grayscale
intensity (0 = black, 1 = white), which is what the renderer and the event simulator use.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image

from evservo import _evcore
from evservo.interrupt import ctrl_c_held_back

if TYPE_CHECKING:
    import trimesh


@cache
def trimesh_module() -> Any:
    """trimesh, imported on first use (it takes about 2 s, which every ``evservo`` command paid at
    start), with Ctrl-C held back meanwhile: its optional imports catch ``BaseException``, so a Ctrl-C
    pressed during them would be lost; held back, it is raised as soon as the import is done."""
    with ctrl_c_held_back():
        import trimesh
    return trimesh


BUILTIN_OBJECTS = ("box", "drill", "football", "can", "cylinder", "checker-can", "mug", "part", "plate")

#: Bounding-box size (x, y, z) of each built-in, metres.
BUILTIN_SIZES_M = {
    "box": (0.16, 0.21, 0.06),
    "drill": (0.28, 0.212, 0.075),
    "football": (0.22, 0.22, 0.22),
    "can": (0.066, 0.115, 0.066),
    "cylinder": (0.066, 0.115, 0.066),
    "checker-can": (0.066, 0.115, 0.066),
    "mug": (0.114, 0.095, 0.08),
    "part": (0.12, 0.09, 0.05),
    "plate": (0.15, 0.004, 0.10),
}

#: Rotation symmetries of the built-ins' edge images (geometry and print together) as
#: (axis in the object frame, period in degrees; 0 = continuous), each about the object origin.
#: Known by construction; :func:`symmetries` finds them by rendering. A name not listed has none.
BUILTIN_SYMMETRIES = {
    "cylinder": (((0.0, 1.0, 0.0), 0.0), ((1.0, 0.0, 0.0), 180.0), ((0.0, 0.0, 1.0), 180.0)),
    # 16 columns alternating dark and light: one column's turn swaps the polarity, not the edges.
    "checker-can": (((0.0, 1.0, 0.0), 22.5), ((1.0, 0.0, 0.0), 180.0), ((0.0, 0.0, 1.0), 180.0)),
    "mug": (((1.0, 0.0, 0.0), 180.0),),
    "plate": (((1.0, 0.0, 0.0), 180.0), ((0.0, 1.0, 0.0), 180.0), ((0.0, 0.0, 1.0), 180.0)),
}

FOOTBALL_RADIUS_M = 0.11


def _linear_to_srgb8(linear: np.ndarray | float) -> np.ndarray:
    c = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    s = np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)


def _srgb8_to_linear_gray(rgb: np.ndarray) -> np.ndarray:
    """sRGB bytes (..., 3 or 4) or (...) gray to linear luminance (Rec. 709 weights), float32."""
    c = np.asarray(rgb, dtype=np.float64) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    if lin.ndim >= 1 and lin.shape[-1] in (3, 4):
        lin = lin[..., 0] * 0.2126 + lin[..., 1] * 0.7152 + lin[..., 2] * 0.0722
    return lin.astype(np.float32)


# --- box -------------------------------------------------------------------------------------

_BOX_TEX_PX = 1024
# Atlas tile of each face: (outward normal, texture-right axis, (u0, u1, v0, v1)).
_BOX_FACES = (
    ((0, 0, -1), (1, 0, 0), (0.00, 0.40, 0.30, 1.00)),  # front, the main print
    ((0, 0, 1), (-1, 0, 0), (0.40, 0.80, 0.30, 1.00)),  # back
    ((-1, 0, 0), (0, 0, -1), (0.80, 0.90, 0.30, 1.00)),  # left side
    ((1, 0, 0), (0, 0, 1), (0.90, 1.00, 0.30, 1.00)),  # right side
    ((0, -1, 0), (1, 0, 0), (0.00, 0.40, 0.15, 0.30)),  # top
    ((0, 1, 0), (1, 0, 0), (0.40, 0.80, 0.15, 0.30)),  # bottom
)


def _paint_tile(h: int, w: int, variant: int) -> np.ndarray:
    """A packaging-like print on an h x w tile: a mid-tone ground, dark bands, letter-like blocks
    and a light logo disc with a dark ring, so that every face has strong interior edges."""
    tile = np.empty((h, w, 3), np.uint8)
    tile[:] = (200, 60, 40) if variant % 2 == 0 else (230, 190, 40)
    yy, xx = np.mgrid[0:h, 0:w]
    # Two dark bands across the face.
    for top, bottom in ((0.06, 0.14), (0.82, 0.90)):
        tile[(yy >= top * h) & (yy < bottom * h)] = (30, 25, 60)
    # A title of "letters": blocks with gaps, like a word set in a heavy typeface.
    n_letters = 5 if w > h / 2 else 2
    lw = 0.8 * w / n_letters
    for k in range(n_letters):
        x0 = 0.1 * w + k * lw
        block = (xx >= x0) & (xx < x0 + 0.7 * lw) & (yy >= 0.2 * h) & (yy < 0.34 * h)
        notch = (xx >= x0 + 0.25 * lw) & (xx < x0 + 0.45 * lw) & (yy >= 0.25 * h) & (yy < 0.34 * h)
        tile[block & ~(notch if (k + variant) % 2 == 0 else np.zeros_like(notch))] = (250, 250, 245)
    # Logo disc with a ring.
    r = 0.22 * min(h, w)
    d = np.hypot(xx - 0.5 * w, yy - 0.58 * h)
    tile[d < r] = (245, 245, 240)
    tile[(d < 0.75 * r) & (d > 0.55 * r)] = (20, 20, 20)
    # A checker strip like a barcode/nutrition panel.
    checker = ((xx * 12 // max(w, 1)) + (yy * 24 // max(h, 1))) % 2 == 0
    tile[(yy >= 0.92 * h) & checker] = (10, 10, 10)
    return tile


def _make_box() -> trimesh.Trimesh:
    half = np.array(BUILTIN_SIZES_M["box"]) / 2.0
    image = np.full((_BOX_TEX_PX, _BOX_TEX_PX, 3), 128, np.uint8)
    vertices, uvs, faces = [], [], []
    for k, (n, u_axis, (u0, u1, v0, v1)) in enumerate(_BOX_FACES):
        n, u_axis = np.array(n, float), np.array(u_axis, float)
        v_axis = np.cross(n, u_axis)  # so that u x v = n: counter-clockwise seen from outside
        centre = n * half
        base = len(vertices)
        for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            vertices.append(centre + su * u_axis * half + sv * v_axis * half)
            uvs.append((u0 if su < 0 else u1, v0 if sv < 0 else v1))
        faces += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
        # Row 0 of the image is v = 1.
        r0, r1 = round((1 - v1) * _BOX_TEX_PX), round((1 - v0) * _BOX_TEX_PX)
        c0, c1 = round(u0 * _BOX_TEX_PX), round(u1 * _BOX_TEX_PX)
        image[r0:r1, c0:c1] = _paint_tile(r1 - r0, c1 - c0, k)
    visual = trimesh_module().visual.TextureVisuals(uv=np.array(uvs), image=Image.fromarray(image))
    return trimesh_module().Trimesh(np.array(vertices), np.array(faces), visual=visual, process=False)


# --- drill -----------------------------------------------------------------------------------


def _along_x(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """trimesh cylinders run along z; the drill's axis is x."""
    mesh.apply_transform(trimesh_module().transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))
    return mesh


def _make_drill() -> trimesh.Trimesh:
    # (part, linear albedo); every part is closed, so the union is watertight edge-wise.
    parts = [
        (_along_x(trimesh_module().creation.cylinder(0.032, 0.17, sections=40)), 0.45),  # motor body
        (_along_x(trimesh_module().creation.cylinder(0.02, 0.05, sections=32)), 0.03),  # chuck
        (_along_x(trimesh_module().creation.cylinder(0.004, 0.06, sections=12)), 0.7),  # bit
        (trimesh_module().creation.box((0.045, 0.12, 0.04)), 0.15),  # handle
        (trimesh_module().creation.box((0.10, 0.04, 0.075)), 0.02),  # battery pack
    ]
    offsets = [(0.0, 0.0, 0.0), (0.11, 0.0, 0.0), (0.165, 0.0, 0.0), (-0.03, 0.08, 0.0), (-0.02, 0.16, 0.0)]
    vertices, faces, colours, base = [], [], [], 0
    for (part, albedo), offset in zip(parts, offsets, strict=True):
        vertices.append(part.vertices + offset)
        faces.append(part.faces + base)
        base += len(part.vertices)
        grey = int(_linear_to_srgb8(albedo))
        colours.append(np.tile((grey, grey, grey, 255), (len(part.vertices), 1)))
    v = np.vstack(vertices)
    v -= (v.min(axis=0) + v.max(axis=0)) / 2.0
    return trimesh_module().Trimesh(
        v, np.vstack(faces), vertex_colors=np.vstack(colours).astype(np.uint8), process=False
    )


# --- football --------------------------------------------------------------------------------


def _make_football(subdivisions: int = 4) -> trimesh.Trimesh:
    ico = trimesh_module().creation.icosahedron()
    iv = ico.vertices / np.linalg.norm(ico.vertices, axis=1, keepdims=True)

    def cut(i: int, j: int) -> np.ndarray:
        """The truncation point on edge i-j next to vertex i."""
        return (2.0 * iv[i] + iv[j]) / 3.0

    polygons = []  # (corners in order, is_pentagon)
    for i in range(len(iv)):
        nbrs = sorted({int(j) for e in ico.edges_unique for j in e if i in e and j != i})
        # Order the five neighbours around the vertex.
        axis = iv[i]
        ref = np.cross(axis, iv[nbrs[0]])
        ang = [np.arctan2(np.dot(np.cross(ref, iv[j]), axis), np.dot(ref, iv[j])) for j in nbrs]
        polygons.append(([cut(i, nbrs[k]) for k in np.argsort(ang)], True))
    for a, b, c in ico.faces:
        polygons.append(([cut(a, b), cut(b, a), cut(b, c), cut(c, b), cut(c, a), cut(a, c)], False))

    n = subdivisions
    points, tris, dark = [], [], []
    for corners, is_pentagon in polygons:
        centre = np.mean(corners, axis=0)
        for k in range(len(corners)):
            a, b, c = centre, corners[k], corners[(k + 1) % len(corners)]
            index = {}
            for i in range(n + 1):
                for j in range(n + 1 - i):
                    # The same integer combination on a shared edge from either side gives
                    # bit-identical points, so the merge below closes the seams exactly.
                    index[i, j] = len(points)
                    points.append((i * a + j * b + (n - i - j) * c) / n)
            for i in range(n):
                for j in range(n - i):
                    tris.append((index[i, j], index[i + 1, j], index[i, j + 1]))
                    dark.append(is_pentagon)
                    if i + j < n - 1:
                        tris.append((index[i + 1, j], index[i + 1, j + 1], index[i, j + 1]))
                        dark.append(is_pentagon)
    pts = np.array(points)
    pts = FOOTBALL_RADIUS_M * pts / np.linalg.norm(pts, axis=1, keepdims=True)
    unique, inverse = np.unique(np.round(pts, 12), axis=0, return_inverse=True)
    faces = inverse.reshape(-1)[np.array(tris)]
    # Wind every face outward.
    tri = unique[faces]
    outward = np.einsum("ij,ij->i", np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), tri.mean(axis=1))
    faces[outward < 0] = faces[outward < 0][:, ::-1]
    black, white = int(_linear_to_srgb8(0.03)), int(_linear_to_srgb8(0.85))
    grey = np.where(np.array(dark), black, white).astype(np.uint8)
    colours = np.column_stack([grey, grey, grey, np.full_like(grey, 255)])
    return trimesh_module().Trimesh(unique, faces, face_colors=colours, process=False)


# --- cylinders: can, plain cylinder, checker can, mug -------------------------------------------

CAN_RADIUS_M, CAN_HEIGHT_M = 0.033, 0.115
_CAN_SECTIONS = 96
_LABEL_PX = (256, 1024)  # (rows = height, columns = circumference)


def _textured_cylinder(radius: float, height: float, label: np.ndarray, cap_grey: int) -> trimesh.Trimesh:
    """A closed cylinder along y (centred on the origin) whose side carries ``label`` (rows top to
    bottom = -y to +y, columns once around, starting at +x towards +z) and whose caps are ``cap_grey``.
    The side has a seam column of duplicated vertices so that the texture wraps exactly once."""
    n = _CAN_SECTIONS
    h, w = label.shape[:2]
    # Atlas: the label on the left, a one-column cap colour on the right.
    atlas = np.empty((h, w + 8, 3), np.uint8)
    atlas[:, :w] = label if label.ndim == 3 else label[..., None]
    atlas[:, w:] = cap_grey
    u_side = w / (w + 8)
    u_cap = (w + 4) / (w + 8)
    angles = np.linspace(0.0, 2 * np.pi, n + 1)
    vertices, uvs, faces = [], [], []
    for k, a in enumerate(angles):
        x, z = radius * np.cos(a), radius * np.sin(a)
        vertices += [(x, -height / 2, z), (x, height / 2, z)]
        uvs += [(u_side * k / n, 1.0), (u_side * k / n, 0.0)]
    for k in range(n):
        a, b, c, d = 2 * k, 2 * k + 1, 2 * k + 2, 2 * k + 3
        faces += [(a, c, b), (b, c, d)]
    for y in (-height / 2, height / 2):
        centre = len(vertices)
        vertices.append((0.0, y, 0.0))
        uvs.append((u_cap, 0.5))
        ring = len(vertices)
        for a in angles[:-1]:
            vertices.append((radius * np.cos(a), y, radius * np.sin(a)))
            uvs.append((u_cap, 0.5))
        for k in range(n):
            i, j = ring + k, ring + (k + 1) % n
            faces.append((centre, i, j) if y > 0 else (centre, j, i))
    visual = trimesh_module().visual.TextureVisuals(uv=np.array(uvs), image=Image.fromarray(atlas))
    return trimesh_module().Trimesh(np.array(vertices), np.array(faces), visual=visual, process=False)


def _irregular_label() -> np.ndarray:
    """A can label: light ground, a dark band of irregular width, and blocks ("letters", a logo) of
    different sizes and tilts, none repeating around the circumference."""
    h, w = _LABEL_PX
    rng = np.random.default_rng(13)
    label = np.full((h, w, 3), (225, 215, 190), np.uint8)
    yy, xx = np.mgrid[0:h, 0:w]
    # A wavy dark band over about half the circumference.
    centre = 0.7 * h + 0.08 * h * np.sin(2 * np.pi * xx / w * 1.0 + 0.4)
    band = (np.abs(yy - centre) < 0.07 * h) & (xx < 0.55 * w)
    label[band] = (40, 30, 90)
    # Letter-like blocks at irregular positions and sizes.
    for _ in range(14):
        cx, cy = rng.uniform(0.05, 0.95) * w, rng.uniform(0.12, 0.5) * h
        bw, bh = rng.uniform(0.015, 0.06) * w, rng.uniform(0.08, 0.22) * h
        tilt = rng.uniform(-0.5, 0.5)
        x_rot = (xx - cx) * np.cos(tilt) + (yy - cy) * np.sin(tilt)
        y_rot = -(xx - cx) * np.sin(tilt) + (yy - cy) * np.cos(tilt)
        label[(np.abs(x_rot) < bw / 2) & (np.abs(y_rot) < bh / 2)] = (25, 25, 25)
    # One logo disc with a ring, on one side only.
    d = np.hypot(xx - 0.8 * w, yy - 0.72 * h)
    label[d < 0.09 * w] = (200, 40, 30)
    label[(d < 0.06 * w) & (d > 0.035 * w)] = (250, 250, 250)
    return label


def _checker_label(periods: int = 8) -> np.ndarray:
    """A regular checker: ``periods`` dark/light column pairs around, three rows."""
    h, w = _LABEL_PX
    yy, xx = np.mgrid[0:h, 0:w]
    dark = ((xx * 2 * periods // w) + (yy * 3 // h)) % 2 == 0
    label = np.full((h, w, 3), 230, np.uint8)
    label[dark] = 25
    return label


def _make_can() -> trimesh.Trimesh:
    return _textured_cylinder(CAN_RADIUS_M, CAN_HEIGHT_M, _irregular_label(), cap_grey=170)


def _make_checker_can() -> trimesh.Trimesh:
    return _textured_cylinder(CAN_RADIUS_M, CAN_HEIGHT_M, _checker_label(), cap_grey=170)


def _make_cylinder() -> trimesh.Trimesh:
    mesh = trimesh_module().creation.cylinder(CAN_RADIUS_M, CAN_HEIGHT_M, sections=_CAN_SECTIONS)
    mesh.apply_transform(trimesh_module().transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
    return _plain(mesh, 0.35)


def _plain(mesh: trimesh.Trimesh, albedo: float) -> trimesh.Trimesh:
    """``mesh`` in one matte linear albedo, as vertex colours, centred on its bounding box."""
    grey = int(_linear_to_srgb8(albedo))
    colours = np.tile((grey, grey, grey, 255), (len(mesh.vertices), 1))
    mesh.visual = trimesh_module().visual.ColorVisuals(mesh, vertex_colors=colours)
    mesh.apply_translation(-(mesh.bounds[0] + mesh.bounds[1]) / 2.0)
    return mesh


def _make_mug() -> trimesh.Trimesh:
    """A mug along y: body radius 0.04 m, height 0.095 m, and a handle loop (a torus section of
    tube radius 6 mm) on +x. Parts overlap instead of being booleaned: the renderer only needs
    the visible surface."""
    body = trimesh_module().creation.cylinder(0.04, 0.095, sections=_CAN_SECTIONS)
    body.apply_transform(trimesh_module().transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
    handle = trimesh_module().creation.torus(0.028, 0.006, major_sections=48, minor_sections=12)
    # The torus lies in the x-y plane after turning its axis (z) onto the mug's side.
    handle.apply_translation((0.04, 0.0, 0.0))
    return _plain(trimesh_module().util.concatenate([body, handle]), 0.6)


def _make_part() -> trimesh.Trimesh:
    """An L-bracket 0.12 x 0.09 x 0.05 m (base plate, upright wall, round boss on the base) in one
    matte grey: only geometric edges, no print."""
    # Parts overlap a little instead of touching, so that no two share a vertex: each stays closed.
    base = trimesh_module().creation.box((0.118, 0.015, 0.05))
    base.apply_translation((0.001, 0.0375, 0.0))
    wall = trimesh_module().creation.box((0.015, 0.09, 0.05))
    wall.apply_translation((-0.0525, 0.0, 0.0))
    boss = trimesh_module().creation.cylinder(0.014, 0.02, sections=40)
    boss.apply_transform(trimesh_module().transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
    boss.apply_translation((0.025, 0.025, 0.0))
    return _plain(trimesh_module().util.concatenate([base, wall, boss]), 0.4)


def _make_plate() -> trimesh.Trimesh:
    """A thin plate 0.15 (x) x 0.004 (y) x 0.10 (z) m, light with a dark border band on both faces
    (per-vertex colour on an inner and outer ring of each face)."""
    t, hx, hz, rim = 0.002, 0.075, 0.05, 0.012
    outer = [(-hx, -hz), (hx, -hz), (hx, hz), (-hx, hz)]
    inner = [(-hx + rim, -hz + rim), (hx - rim, -hz + rim), (hx - rim, hz - rim), (-hx + rim, hz - rim)]
    dark, light = int(_linear_to_srgb8(0.04)), int(_linear_to_srgb8(0.8))
    vertices, colours, faces = [], [], []
    for y in (-t, t):
        b = len(vertices)
        vertices += [(x, y, z) for x, z in outer] + [(x, y, z) for x, z in inner] + [(x, y, z) for x, z in inner]
        colours += [dark] * 8 + [light] * 4
        for k in range(4):
            o0, o1, i0, i1 = b + k, b + (k + 1) % 4, b + 4 + k, b + 4 + (k + 1) % 4
            faces += [(o0, o1, i1), (o0, i1, i0)]
        faces += [(b + 8, b + 9, b + 10), (b + 8, b + 10, b + 11)]
    for k in range(4):  # the rim faces joining the two outer rings
        a, c = k, (k + 1) % 4
        faces += [(a, c, 12 + c), (a, 12 + c, 12 + a)]
    grey = np.array(colours, np.uint8)
    rgba = np.column_stack([grey, grey, grey, np.full_like(grey, 255)])
    return trimesh_module().Trimesh(np.array(vertices, float), np.array(faces), vertex_colors=rgba, process=False)


_BUILDERS = {
    "box": _make_box,
    "drill": _make_drill,
    "football": _make_football,
    "can": _make_can,
    "cylinder": _make_cylinder,
    "checker-can": _make_checker_can,
    "mug": _make_mug,
    "part": _make_part,
    "plate": _make_plate,
}


def load_object(obj: str | os.PathLike | trimesh.Trimesh) -> trimesh.Trimesh:
    """A built-in object by name (see :data:`BUILTIN_OBJECTS`), any mesh file trimesh can load
    (metres; texture or vertex colours are kept), or a ``trimesh.Trimesh`` passed through."""
    if isinstance(obj, trimesh_module().Trimesh):
        return obj
    if isinstance(obj, str) and obj in _BUILDERS:
        return _BUILDERS[obj]()
    if isinstance(obj, str | os.PathLike) and os.path.isfile(obj):
        loaded = trimesh_module().load(obj, force="mesh")
        if not isinstance(loaded, trimesh_module().Trimesh) or len(loaded.faces) == 0:
            raise ValueError(f"{obj!s} holds no triangle mesh")
        return loaded
    raise ValueError(f"unknown object {obj!r}: not a file; built-in objects are {', '.join(BUILTIN_OBJECTS)}")


def _texture_image(visual: trimesh.visual.TextureVisuals):
    material = visual.material
    image = getattr(material, "image", None)
    return image if image is not None else getattr(material, "baseColorTexture", None)


def to_core_mesh(mesh: trimesh.Trimesh, default_intensity: float = 0.5) -> _evcore.Mesh:
    """Convert a trimesh to the core mesh with linear grayscale appearance: a texture image
    becomes a float32 [0, 1] gray texture, vertex or face colours become per-vertex intensity
    (face colours by giving each face its own vertices), anything else ``default_intensity``."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    visual = mesh.visual
    kind = visual.kind
    if kind == "texture" and visual.uv is not None and _texture_image(visual) is not None:
        image = np.asarray(_texture_image(visual).convert("RGB"))
        texture = np.ascontiguousarray(_srgb8_to_linear_gray(image))
        uv = np.asarray(visual.uv, dtype=np.float64)
        return _evcore.Mesh(vertices, faces, uv=uv, texture=texture)
    if kind == "texture":
        colour = np.asarray(getattr(visual.material, "main_color", (128, 128, 128, 255)))[:3]
        return _evcore.Mesh(vertices, faces, intensity=float(_srgb8_to_linear_gray(colour)))
    if kind == "vertex":
        intensity = _srgb8_to_linear_gray(np.asarray(visual.vertex_colors)[:, :3]).astype(np.float64)
        return _evcore.Mesh(vertices, faces, vertex_intensity=intensity)
    if kind == "face":
        per_face = _srgb8_to_linear_gray(np.asarray(visual.face_colors)[:, :3]).astype(np.float64)
        split = vertices[faces].reshape(-1, 3)
        return _evcore.Mesh(
            split,
            np.arange(len(split), dtype=np.int64).reshape(-1, 3),
            vertex_intensity=np.repeat(per_face, 3),
        )
    return _evcore.Mesh(vertices, faces, intensity=default_intensity)


# --- symmetry ----------------------------------------------------------------------------------

#: Turns (degrees) tried about each candidate axis; the small ones decide "continuous".
SYMMETRY_ANGLES_DEG = (7.5, 15.0, 22.5, 30.0, 36.0, 45.0, 60.0, 72.0, 90.0, 120.0, 180.0)
#: Turns (degrees) that decide a continuous symmetry of a partial view (see :func:`symmetries`).
VIEW_ANGLES_DEG = (-7.5, -5.0, -2.5, 2.5, 5.0, 7.5)
#: A turn is a symmetry when the edge images before and after differ by less than this (mean
#: symmetric chamfer distance, pixels).
SYMMETRY_TOL_PX = 0.75


@dataclass(frozen=True)
class Symmetry:
    """A rotation that leaves the object's edge image unchanged (geometry and print together).

    ``axis_o`` is a unit vector in the object frame through ``centre_o`` (metres). ``period_deg`` is
    0 for a continuous symmetry (the rotation about the axis is unobservable: a tracker must hold
    it at its prior) and otherwise the smallest turn that repeats the edges (a discrete ambiguity:
    poses that far apart cannot be told apart from edges).
    """

    axis_o: tuple[float, float, float]
    centre_o: tuple[float, float, float]
    period_deg: float

    @property
    def continuous(self) -> bool:
        return self.period_deg == 0.0


def builtin_symmetries(name: str) -> list[Symmetry]:
    """The symmetries of a built-in object (see :data:`BUILTIN_SYMMETRIES`); [] for any other name."""
    return [Symmetry(axis, (0.0, 0.0, 0.0), period) for axis, period in BUILTIN_SYMMETRIES.get(name, ())]


def _candidate_axes(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """(centre (3,), axes (3, 3) as rows): the area-weighted centroid and principal axes of the surface,
    where every symmetry axis of a body lies."""
    area = np.asarray(mesh.area_faces)
    centres = np.asarray(mesh.triangles_center)
    centre = (centres * area[:, None]).sum(0) / area.sum()
    d = centres - centre
    cov = (d * area[:, None]).T @ d / area.sum()
    return centre, np.linalg.eigh(cov)[1].T


def _axis_of_revolution(mesh: trimesh.Trimesh, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(point (3,), unit direction (3,)) of the line about which most of the ``faces`` (a boolean
    mask) turn into themselves; None when they do not fix one.

    Turning about an axis (direction a through c) moves a surface point p with velocity
    a × (p − c); the surface maps onto itself where that velocity is tangent, n · (a × (p − c)) = 0
    for its normal n. That is linear in (a, c × a): the area-weighted least-squares a is the
    smallest eigenvector of the Schur complement of the six unknowns. Faces off the fitted surface
    of revolution (what is left in view of a handle) are dropped and the fit repeated. This finds
    the axis of the part in view where the whole object's principal axes miss it (a mug whose
    handle is beyond the border: its centroid leans towards the handle, the body's axis does not)."""
    w = np.asarray(mesh.area_faces)[faces]
    p = np.asarray(mesh.triangles_center)[faces]
    n = np.asarray(mesh.face_normals)[faces]
    m = np.cross(p, n)
    keep = np.ones(len(w), bool)
    axis = None
    for _ in range(3):
        if keep.sum() < 6:
            return axis
        wk = w[keep][:, None]
        a_mm, b_mn, c_nn = (m[keep] * wk).T @ m[keep], (m[keep] * wk).T @ n[keep], (n[keep] * wk).T @ n[keep]
        if np.linalg.matrix_rank(c_nn) < 3:
            return axis
        a = np.linalg.eigh(a_mm - b_mn @ np.linalg.solve(c_nn, b_mn.T))[1][:, 0]
        moment = -np.linalg.solve(c_nn, b_mn.T @ a)  # c × a
        axis = (np.cross(a, moment), a)
        # The tangential speed of each face per radian of turn, against the fit's typical one.
        off = np.abs(m @ a + n @ moment)
        keep = off <= 3.0 * np.median(off[keep]) + 1e-9
    return axis


def _in_image(camera: _evcore.Camera, p_c: np.ndarray) -> np.ndarray:
    """Which camera-frame points (N, 3) project into the (rectified) image, in front of the camera."""
    z = np.where(p_c[:, 2] > 1e-6, p_c[:, 2], np.nan)
    u = camera.fx * p_c[:, 0] / z + camera.cx
    v = camera.fy * p_c[:, 1] / z + camera.cy
    with np.errstate(invalid="ignore"):
        return (u >= 0) & (u <= camera.width - 1) & (v >= 0) & (v <= camera.height - 1)


def _edge_pixels(mesh: _evcore.Mesh, camera: _evcore.Camera, T_c_o: np.ndarray) -> np.ndarray:
    """All edge pixels (silhouette, crease, print) of one rendering, (N, 2) integer (u, v)."""
    points, _ = _evcore.extract_point_set(mesh, camera, T_c_o, max_points=1_000_000)
    p = points @ T_c_o[:3, :3].T + T_c_o[:3, 3]
    uv = np.column_stack([camera.fx * p[:, 0] / p[:, 2] + camera.cx, camera.fy * p[:, 1] / p[:, 2] + camera.cy])
    return np.round(uv).astype(int)


def _chamfer_px(a: np.ndarray, b: np.ndarray, shape: tuple[int, int]) -> float:
    """Symmetric mean chamfer distance between two pixel sets (pixels)."""
    import cv2

    def mean_distance(src: np.ndarray, dst: np.ndarray) -> float:
        img = np.full(shape, 255, np.uint8)
        img[dst[:, 1], dst[:, 0]] = 0
        dt = cv2.distanceTransform(img, cv2.DIST_L2, 5)
        return float(dt[src[:, 1], src[:, 0]].mean())

    return max(mean_distance(a, b), mean_distance(b, a))


def symmetries(
    obj: str | os.PathLike | trimesh.Trimesh,
    camera: _evcore.Camera | None = None,
    T_c_o: np.ndarray | None = None,
) -> list[Symmetry]:
    """Rotation symmetries of an object's edge image about its principal axes, judged by rendering
    it at ``T_c_o`` (default: the recordings' start rotation at the depth where it spans about
    300 px of the rectified imx636) and turned about each axis by :data:`SYMMETRY_ANGLES_DEG`.
    Edges are what the tracker sees, so print counts: a labelled can has no symmetry, a plain one a
    continuous one, a can with a regular 8-period checker label a 45° one.

    So does the border. With part of the object out of the image (its rendered edges stop there) the
    axis of revolution of the part in view is tried too, and an axis about which
    every turn of :data:`VIEW_ANGLES_DEG` leaves those edges in place is a continuous symmetry of the
    view (larger turns may bring a hidden part in; the tracker moves by small ones): a mug whose
    handle is beyond the border turns unobservably about its body's axis."""
    shape_mesh = load_object(obj)
    mesh = to_core_mesh(shape_mesh)
    camera = (camera or _evcore.Camera.imx636()).rectified()
    if T_c_o is None:
        from evservo.sim.record import start_pose

        T_c_o = start_pose(camera.fx * mesh.bounding_radius / 150.0)
    image_shape = (camera.height, camera.width)
    reference = _edge_pixels(mesh, camera, T_c_o)

    def turned_alike(centre: np.ndarray, axis: np.ndarray, angles: tuple[float, ...]) -> list[bool]:
        out = []
        for deg in angles:
            turn = np.eye(4)
            turn[:3, :3] = trimesh_module().transformations.rotation_matrix(np.deg2rad(deg), axis, centre)[:3, :3]
            turn[:3, 3] = centre - turn[:3, :3] @ centre
            turned = _edge_pixels(mesh, camera, T_c_o @ turn)
            out.append(_chamfer_px(turned, reference, image_shape) < SYMMETRY_TOL_PX)
        return out

    centre, axes = _candidate_axes(shape_mesh)
    candidates = [(centre, axis) for axis in axes]
    centres_c = np.asarray(shape_mesh.triangles_center) @ T_c_o[:3, :3].T + T_c_o[:3, 3]
    in_view = _in_image(camera, centres_c)
    partial = not in_view.all()
    if partial and (revolution := _axis_of_revolution(shape_mesh, in_view)) is not None:
        candidates.insert(0, revolution)  # reported in its place: the principal axes lean off it
    found: list[Symmetry] = []
    for centre, axis in candidates:
        if any(s.continuous and abs(float(np.dot(s.axis_o, axis))) > 0.99 for s in found):
            continue  # an axis already found through another candidate
        if partial and all(turned_alike(centre, axis, VIEW_ANGLES_DEG)):
            found.append(_symmetry(axis, centre, 0.0))
            continue
        matches = turned_alike(centre, axis, SYMMETRY_ANGLES_DEG)
        if not any(matches):
            continue
        continuous = all(matches[:3])
        period = 0.0 if continuous else SYMMETRY_ANGLES_DEG[matches.index(True)]
        found.append(_symmetry(axis, centre, period))
    return found


def _symmetry(axis: np.ndarray, centre: np.ndarray, period_deg: float) -> Symmetry:
    x, y, z = (float(v) for v in axis)
    cx, cy, cz = (float(v) for v in centre)
    return Symmetry((x, y, z), (cx, cy, cz), period_deg)
