"""Object models: three procedural built-ins, loading from files, and conversion to the core mesh.

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

Colours in the trimesh objects are sRGB; :func:`to_core_mesh` turns them into linear grayscale
intensity (0 = black, 1 = white), which is what the renderer and the event simulator use.
"""

from __future__ import annotations

import os

import numpy as np
import trimesh
from PIL import Image

from evservo import _evcore

BUILTIN_OBJECTS = ("box", "drill", "football")

#: Bounding-box size (x, y, z) of each built-in, metres.
BUILTIN_SIZES_M = {
    "box": (0.16, 0.21, 0.06),
    "drill": (0.28, 0.212, 0.075),
    "football": (0.22, 0.22, 0.22),
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
    visual = trimesh.visual.TextureVisuals(uv=np.array(uvs), image=Image.fromarray(image))
    return trimesh.Trimesh(np.array(vertices), np.array(faces), visual=visual, process=False)


# --- drill -----------------------------------------------------------------------------------


def _along_x(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """trimesh cylinders run along z; the drill's axis is x."""
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))
    return mesh


def _make_drill() -> trimesh.Trimesh:
    # (part, linear albedo); every part is closed, so the union is watertight edge-wise.
    parts = [
        (_along_x(trimesh.creation.cylinder(0.032, 0.17, sections=40)), 0.45),  # motor body
        (_along_x(trimesh.creation.cylinder(0.02, 0.05, sections=32)), 0.03),  # chuck
        (_along_x(trimesh.creation.cylinder(0.004, 0.06, sections=12)), 0.7),  # bit
        (trimesh.creation.box((0.045, 0.12, 0.04)), 0.15),  # handle
        (trimesh.creation.box((0.10, 0.04, 0.075)), 0.02),  # battery pack
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
    return trimesh.Trimesh(v, np.vstack(faces), vertex_colors=np.vstack(colours).astype(np.uint8), process=False)


# --- football --------------------------------------------------------------------------------


def _make_football(subdivisions: int = 4) -> trimesh.Trimesh:
    ico = trimesh.creation.icosahedron()
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
    return trimesh.Trimesh(unique, faces, face_colors=colours, process=False)


_BUILDERS = {"box": _make_box, "drill": _make_drill, "football": _make_football}


def load_object(obj: str | os.PathLike | trimesh.Trimesh) -> trimesh.Trimesh:
    """A built-in object by name (see :data:`BUILTIN_OBJECTS`), any mesh file trimesh can load
    (metres; texture or vertex colours are kept), or a ``trimesh.Trimesh`` passed through."""
    if isinstance(obj, trimesh.Trimesh):
        return obj
    if isinstance(obj, str) and obj in _BUILDERS:
        return _BUILDERS[obj]()
    if isinstance(obj, str | os.PathLike) and os.path.isfile(obj):
        loaded = trimesh.load(obj, force="mesh")
        if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
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
