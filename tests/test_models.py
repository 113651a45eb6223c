import os
import subprocess
import sys

import cv2
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from evservo import _evcore as ec
from evservo import models

CAM = ec.Camera.imx636().rectified()


def pose(z_m: float, euler_deg=(25.0, -35.0, 10.0)) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", euler_deg, degrees=True).as_matrix()
    T[:3, 3] = (0.01, -0.02, z_m)
    return T


@pytest.mark.parametrize("name", models.BUILTIN_OBJECTS)
def test_builtin_loads_with_stated_size_and_is_closed(name):
    mesh = models.load_object(name)
    assert isinstance(mesh, trimesh.Trimesh)
    np.testing.assert_allclose(mesh.extents, models.BUILTIN_SIZES_M[name], atol=0.01)
    # Object frame at the centre of the bounding box.
    np.testing.assert_allclose(mesh.bounds.mean(axis=0), 0.0, atol=1e-9)
    if name in ("box", "can", "checker-can", "plate"):
        # Texture and colour seams duplicate vertices; the geometry itself is closed.
        merged = mesh.copy()
        merged.merge_vertices(merge_tex=True, merge_norm=True)
        assert merged.is_watertight and not mesh.is_watertight
    else:
        assert mesh.is_watertight
    assert models.load_object(name).vertices.tobytes() == mesh.vertices.tobytes(), "deterministic"


def test_football_radius_and_panels():
    ball = models.load_object("football")
    np.testing.assert_allclose(np.linalg.norm(ball.vertices, axis=1), models.FOOTBALL_RADIUS_M, rtol=1e-9)
    grey = ball.visual.face_colors[:, 0]
    dark_area = ball.area_faces[grey < 128].sum() / ball.area
    # 12 pentagons and 20 hexagons of equal edge: pentagons hold about 28 % of the area.
    assert 0.22 < dark_area < 0.34, dark_area


@pytest.mark.parametrize("name", models.BUILTIN_OBJECTS)
@pytest.mark.parametrize("z_m", [0.6, 0.9])
def test_point_set_size_and_kinds(name, z_m):
    core = models.to_core_mesh(models.load_object(name))
    points, kinds = ec.extract_point_set(core, CAM, pose(z_m), max_points=1000, seed=1)
    assert points.shape[1] == 3 and len(points) == len(kinds) >= 500
    # Outline points stand half a pixel outwards of their pixel's centre (on the outline itself), so
    # up to that far off the surface: 0.5 px at the object's far side.
    half_px_m = 0.5 * (z_m + core.bounding_radius) / CAM.fx
    assert np.all(np.linalg.norm(points, axis=1) <= core.bounding_radius + half_px_m + 1e-6)
    present = set(np.unique(kinds).tolist())
    if name == "box":
        assert present == {0, 1, 2}, present
    else:
        assert 0 in present


def test_to_core_mesh_keeps_appearance():
    T = pose(0.6, (0.0, 0.0, 0.0))
    ball = ec.render(models.to_core_mesh(models.load_object("football")), CAM, T, ambient=1.0, diffuse=0.0)
    seen = ball["intensity"][np.isfinite(ball["depth"])]
    # Linear albedos 0.03 (pentagons) and 0.85 (hexagons) survive the sRGB round trip.
    assert np.mean(np.abs(seen - 0.03) < 0.01) > 0.1 and np.mean(np.abs(seen - 0.85) < 0.01) > 0.5
    box = ec.render(models.to_core_mesh(models.load_object("box")), CAM, T, ambient=1.0, diffuse=0.0)
    front = box["intensity"][np.isfinite(box["depth"])]
    assert front.min() < 0.02 and front.max() > 0.85, "the print has dark ink and white areas"
    plain = trimesh.creation.box((0.1, 0.1, 0.1))
    r = ec.render(models.to_core_mesh(plain, default_intensity=0.4), CAM, T, ambient=1.0, diffuse=0.0)
    np.testing.assert_allclose(r["intensity"][np.isfinite(r["depth"])], 0.4, atol=1e-6)


def test_load_from_file_keeps_vertex_colours(tmp_path):
    drill = models.load_object("drill")
    path = tmp_path / "drill.ply"
    drill.export(path)
    loaded = models.load_object(str(path))
    assert loaded.visual.kind == "vertex" and len(loaded.faces) == len(drill.faces)
    a = ec.render(models.to_core_mesh(drill), CAM, pose(0.6))
    b = ec.render(models.to_core_mesh(loaded), CAM, pose(0.6))
    np.testing.assert_allclose(a["intensity"], b["intensity"], atol=1e-4)


def test_unknown_object_lists_builtins():
    with pytest.raises(ValueError, match="box, drill, football"):
        models.load_object("teapot")


def test_render_agrees_with_opencv_projection():
    box = models.load_object("box")
    T = pose(0.6)
    r = ec.render(models.to_core_mesh(box), CAM, T)
    depth, fg = r["depth"], np.isfinite(r["depth"])
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    uv, _ = cv2.projectPoints(box.vertices, rvec, T[:3, 3], CAM.k, np.zeros(5))
    hull = cv2.convexHull(uv.reshape(-1, 2).astype(np.float32))
    # Each pixel centre clearly inside the projected outline is covered, clearly outside is not.
    ys, xs = np.mgrid[0 : CAM.height : 3, 0 : CAM.width : 3]
    for x, y in zip(xs.ravel(), ys.ravel(), strict=True):
        s = cv2.pointPolygonTest(hull, (float(x), float(y)), True)
        if abs(s) > 0.5:
            assert fg[y, x] == (s > 0), (x, y, s)
    # The vertex nearest the camera lands where the render puts its depth.
    p_c = box.vertices @ T[:3, :3].T + T[:3, 3]
    k = int(np.argmin(p_c[:, 2]))
    u, v = uv[k, 0]
    ys, xs = np.nonzero(fg & (depth < p_c[k, 2] + 2e-3))
    assert len(xs) > 0
    nearest = np.min(np.hypot(xs - u, ys - v))
    assert nearest <= 0.5 * np.sqrt(2) + 0.5, nearest
    # Back-projecting a rendered depth with K and projecting with OpenCV returns the same pixel.
    y0, x0 = np.argwhere(fg)[len(np.argwhere(fg)) // 2]
    ray = np.linalg.solve(CAM.k, [x0, y0, 1.0])
    p_o = T[:3, :3].T @ (ray * depth[y0, x0] - T[:3, 3])
    back, _ = cv2.projectPoints(p_o[None], rvec, T[:3, 3], CAM.k, np.zeros(5))
    np.testing.assert_allclose(back.ravel(), [x0, y0], atol=1e-3)


def test_render_roi_and_normals():
    core = models.to_core_mesh(models.load_object("football"))
    full = ec.render(core, CAM, pose(0.6))
    part = ec.render(core, CAM, pose(0.6), roi=(600, 300, 50, 40))
    assert part["depth"].shape == (40, 50) and part["roi"] == (600, 300, 50, 40)
    np.testing.assert_array_equal(part["intensity"], full["intensity"][300:340, 600:650])
    n = full["normal"][np.isfinite(full["depth"])]
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    assert np.all(n[:, 2] < 0), "normals face the camera"
    with pytest.raises(ValueError):
        ec.render(core, CAM, pose(0.6), roi=(1270, 0, 20, 20))


def test_bad_meshes_and_poses_raise_value_error():
    v = np.array([[0.0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]])
    f = np.array([[0, 1, 2]])
    ec.Mesh(v, f)
    with pytest.raises(ValueError):
        ec.Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    bad = v.copy()
    bad[1, 2] = np.nan
    with pytest.raises(ValueError, match="not finite"):
        ec.Mesh(bad, f)
    with pytest.raises(ValueError, match="indexes past"):
        ec.Mesh(v, np.array([[0, 1, 3]]))
    with pytest.raises(ValueError):
        ec.Mesh(v, np.array([[0, -1, 2]]))
    with pytest.raises(ValueError):
        ec.Mesh(v, f.astype(np.uint32), vertex_intensity=np.ones(2))
    with pytest.raises(ValueError, match="degenerate"):
        ec.Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]), f)
    mesh = ec.Mesh(v, f.astype(np.uint32))
    T = pose(0.6)
    T[0, 0] = np.nan
    with pytest.raises(ValueError):
        ec.render(mesh, CAM, T)
    with pytest.raises(ValueError):
        ec.extract_point_set(mesh, CAM, np.eye(3))
    far = pose(0.6)
    far[2, 3] = -1.0
    with pytest.raises(ValueError, match="not in view"):
        ec.extract_point_set(mesh, CAM, far)


def test_a_ctrl_c_during_the_mesh_library_import_is_not_lost(tmp_path):
    """trimesh's optional imports catch ``BaseException``: a Ctrl-C pressed while it is imported was
    swallowed and the command went on. A stand-in ``trimesh`` that swallows the Ctrl-C it receives
    mid-import shows the one evservo holds back arriving once the import is done."""
    fake = tmp_path / "trimesh.py"
    fake.write_text(
        "import os, signal, time\n"
        "try:\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    time.sleep(0.2)\n"
        "except BaseException:\n"
        "    pass\n"
        "IMPORTED = True\n"
    )
    code = (
        "from evservo import models\n"
        "try:\n"
        "    models.trimesh_module()\n"
        "except KeyboardInterrupt:\n"
        "    import sys; print('interrupted after import', sys.modules['trimesh'].IMPORTED)\n"
        "else:\n"
        "    print('lost')\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "interrupted after import True", out.stdout + out.stderr
