"""The robot arms in the rendered event camera: robosuite's link meshes load with sane sizes, the UR5e's
wrist shows (and hides behind the box) where the camera model puts it, its moving edges fire, and a
short closed loop with the arms drawn holds tracking."""

import cv2
import numpy as np
import pytest
from scipy.ndimage import binary_dilation

from evservo import _evcore, cli, geometry
from evservo.sim.arms import ArmMeshes
from evservo.sim.episode import EpisodeConfig, run_episode, summarize
from evservo.sim.scene import DualArmScene
from evservo.sim.sources import REALISM, RenderedSource

VIEW = (0.35, -0.45, 0.1)  # EpisodeConfig's default start orientation


@pytest.fixture(scope="module")
def bench():
    scene = DualArmScene()
    T_c_o = scene.reset_to_start(0.9, VIEW)
    return scene, ArmMeshes(scene), T_c_o


def project(camera, p_c: np.ndarray) -> np.ndarray:
    """cv2.projectPoints of camera-frame points (N, 3) with the camera's intrinsics and distortion."""
    K = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1]])
    uv, _ = cv2.projectPoints(np.asarray(p_c, float), np.zeros(3), np.zeros(3), K, np.array(camera.dist))
    return uv.reshape(-1, 2)


def test_arm_meshes_load_with_sane_links(bench):
    _, arms, _ = bench
    ur = [n for n in arms.names if n.startswith("ur_")]
    panda = [n for n in arms.names if n.startswith("panda_")]
    assert len(ur) == 7 and len(panda) == 7, arms.names  # UR5e base..wrist 3; Panda link0..6
    assert "panda_link7" not in arms.names  # rigid with the camera: excluded
    sizes = {lk.name: lk.size_m() for lk in arms.links}
    for name, size in sizes.items():
        assert 0.04 < size.max() < 0.7, (name, size)
    # The UR5e's upper arm and forearm are ~0.43 m and ~0.39 m between joints, plus their housings.
    assert 0.45 < sizes["ur_upper_arm_link"].max() < 0.65
    assert 0.4 < sizes["ur_forearm_link"].max() < 0.6
    assert sizes["ur_wrist_2_link"].max() < 0.15
    for lk in arms.links:
        assert 100 < len(lk.faces) < 20_000 and lk.faces.max() < len(lk.vertices)
        assert np.all((lk.albedo > 0.1 - 1e-6) & (lk.albedo < 0.85 + 1e-6))
    assert 20_000 < arms.n_faces() < 120_000  # decimated from ~250 000


def test_ur_wrist_shows_where_the_camera_model_puts_it(bench, camera):
    _, arms, T_c_o = bench
    plain = RenderedSource(camera, "box", T_c_o, 0, seed=1).sim.frame()
    with_arms = RenderedSource(camera, "box", T_c_o, 0, seed=1, arms=arms).sim.frame()
    changed = np.abs(with_arms - plain) > 1e-6
    assert 0.02 < changed.mean() < 0.4, changed.mean()
    P = arms.camera_poses()
    at = dict(zip(arms.names, P, strict=True))
    # Wrist 1 and 2 stand beside the box, nearer than the background: the arm covers their origins.
    for name in ("ur_wrist_1_link", "ur_wrist_2_link"):
        u, v = project(camera, at[name][:3, 3][None])[0]
        assert 0 <= u < camera.width and 0 <= v < camera.height, (name, u, v)
        win = changed[int(v) - 3 : int(v) + 4, int(u) - 3 : int(u) + 4]
        assert win.all(), (name, u, v)
    # Wrist 3 carries the box and sits right behind it: the box hides its origin (z-test).
    p3 = at["ur_wrist_3_link"][:3, 3]
    assert p3[2] > T_c_o[2, 3]
    u, v = project(camera, p3[None])[0]
    assert not changed[int(v) - 3 : int(v) + 4, int(u) - 3 : int(u) + 4].any()
    # No part of the view is the Panda (it stands beside and behind the camera).
    assert all(p[2, 3] < 0.1 for n, p in at.items() if n.startswith("panda_"))


def test_moving_arm_fires_on_its_edges(bench, camera):
    scene, arms, _ = bench
    q0 = scene.ur.joint_positions()
    try:
        T0, P0 = scene.T_c_o(), arms.camera_poses()
        src = RenderedSource(camera, "box", T0, 0, seed=2, arms=arms)
        frame = src.sim.frame()
        plain = RenderedSource(camera, "box", T0, 0, seed=2).sim.frame()
        # Turn the shoulder by 4 mrad: the wrist, ~0.8 m out, moves ~3 mm, several pixels.
        q = q0.copy()
        q[1] += 0.004
        scene.ur.set_joint_positions(q)
        T1, P1 = scene.T_c_o(), arms.camera_poses()
        # The half-pixel rule sees the arm's motion: at least the wrist origin's image motion.
        wrist = arms.names.index("ur_wrist_1_link")
        moved = np.linalg.norm(np.diff(project(camera, np.stack([P0[wrist], P1[wrist]])[:, :3, 3]), axis=0))
        bound = src.sim.occluder_displacement_px(P0, P1)
        assert 2.0 < moved <= bound + 1e-6, (moved, bound)
        ev = src.events_until(1000, T1, occluders=P1)
    finally:
        scene.ur.set_joint_positions(q0)
    arm = np.abs(frame - plain) > 1e-6
    # Events off the arm (and off the box, which moved too) are the sensor's noise.
    arm_only = binary_dilation(arm, iterations=6) & ~binary_dilation(box_mask(camera, T0), iterations=8)
    on_arm = arm_only[ev["y"], ev["x"]]
    assert on_arm.sum() > 300, on_arm.sum()
    # On the arm they sit on its intensity edges: the silhouette and the shading creases.
    log = np.log(frame.astype(float) + 1e-3)
    grad = np.hypot(*np.gradient(log))
    edges = binary_dilation(grad > 0.05, iterations=3)
    assert edges[ev["y"][on_arm], ev["x"][on_arm]].mean() > 0.9
    assert edges[arm_only].mean() < 0.7  # ... which are not the whole arm


def box_mask(camera, T_c_o: np.ndarray) -> np.ndarray:
    """Pixels where the box (alone, at ``T_c_o``) changes the view of the background."""
    src = RenderedSource(camera, "box", T_c_o, 0, seed=2)
    with_box = src.sim.frame()
    away = T_c_o.copy()
    away[0, 3] += 50.0
    src.sim.advance(away, 1, T_c_bg=src.T_c_bg0)
    return np.abs(with_box - src.sim.frame()) > 1e-6


def test_pose_interpolation_matches_the_ends_and_stays_rigid():
    rng = np.random.default_rng(0)
    from evservo import geometry

    A = np.stack([geometry.pose(rng.normal(size=3), rng.normal(size=3)) for _ in range(5)])
    B = np.stack([geometry.pose(rng.normal(size=3), 0.3 * rng.normal(size=3)) @ a for a in A])
    assert np.allclose(geometry.interpolate(A, B, 0.0), A) and np.allclose(geometry.interpolate(A, B, 1.0), B)
    M = geometry.interpolate(A, B, 0.5)
    R = M[:, :3, :3]
    assert np.allclose(R @ R.transpose(0, 2, 1), np.eye(3), atol=1e-9)
    # Halfway in rotation: the same angle to either end.
    for a, m, b in zip(A, M, B, strict=True):
        assert np.isclose(geometry.rotation_error_rad(a, m), geometry.rotation_error_rad(m, b), atol=1e-9)


def test_render_arms_needs_the_rendered_source(capsys):
    with pytest.raises(ValueError, match="render"):
        EpisodeConfig(render_arms=True)
    assert cli.main(["servo", "--sim", "--render-arms", "--duration", "0.01"]) == 2
    assert "--events render" in capsys.readouterr().err


def test_closed_loop_with_arms_holds_tracking():
    cfg = EpisodeConfig(
        duration_s=0.2, distance_m=0.9, speed_mps=0.3, cost_model="fixed", event_source="render", render_arms=True
    )
    result = run_episode(cfg)
    s = summarize(result)
    assert s["completed"], s
    assert s["gt_track_pos_rms_mm"] < 3.0 and s["gt_track_rot_rms_deg"] < 1.0, s


def test_occluder_poses_need_arms(camera, bench):
    _, arms, T_c_o = bench
    src = RenderedSource(camera, "box", T_c_o, 0, seed=1)
    with pytest.raises(ValueError, match="without arms"):
        src.events_until(1000, T_c_o, occluders=arms.camera_poses())
    assert isinstance(src.sim, _evcore.SimCamera) and src.sim.n_occluders == 0


@pytest.mark.parametrize("preset", ["clean", "lab"])
def test_sparse_frames_with_the_arms_give_the_reference_events(bench, camera, preset):
    # The fast path (sparse frames: tiles redrawn, composited and stepped only where something can
    # change) against the full-frame reference at 1280×720 with the 14 links in view: the camera
    # moving 0.3 mm per 1 ms tick (object, links and background all move in its frame, the loop's
    # regime) and the UR5e's links moving 0.2 mm per tick more on their own. Per-pixel event counts:
    # equal, event for event without leak and noise (clean); with the lab preset's leak, shot
    # noise, hot pixels and flicker, at most 0.1 % of the firing pixels off by one event (the
    # leak's f32 catch-up on skipped tiles).
    from evservo.models import load_object, to_core_mesh
    from evservo.sim.record import background_pose

    _, arms, T_c_o = bench
    preset_name, cell_m = {"clean": ("clean", 0.02), "lab": REALISM["lab"]}[preset]
    T_c_bg, P = background_pose(float(T_c_o[2, 3]), 0.6), arms.camera_poses()
    ur = np.array([n.startswith("ur_") for n in arms.names])
    mesh = to_core_mesh(load_object("box"))
    sims = []
    for sparse in (True, False):
        sim = _evcore.SimCamera(camera, mesh, preset=preset_name, seed=4, T_c_bg=T_c_bg, cell_m=cell_m, sparse=sparse)
        sim.set_occluders(arms.core_meshes())
        sim.advance(T_c_o, 0, T_c_bg=T_c_bg, occluders=P)
        sims.append(sim)
    counts = [np.zeros(camera.height * camera.width, np.int64) for _ in sims]
    for k in range(1, 13):
        step = geometry.pose((3e-4 * k, -1e-4 * k, 0.0))  # the world in the moving camera
        P_k = step @ P
        P_k[ur, 0, 3] += 2e-4 * k
        for sim, c in zip(sims, counts, strict=True):
            ev = sim.advance(step @ T_c_o, 1000 * k, T_c_bg=step @ T_c_bg, occluders=P_k)
            np.add.at(c, ev["y"].astype(np.int64) * camera.width + ev["x"], 1)
    fast, ref = counts
    assert ref.sum() > 20_000, ref.sum()
    assert sims[0].last_roi[4] is False and sims[1].last_roi[4] is True
    differ = fast != ref
    if preset == "clean":
        np.testing.assert_array_equal(fast, ref)
    else:
        assert differ.sum() <= 1e-3 * (ref > 0).sum(), (differ.sum(), (ref > 0).sum())
        assert np.abs(fast - ref).max(initial=0) <= 1
