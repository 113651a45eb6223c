"""The rendered event camera: geometry against OpenCV, silence of static scenes, events on edges,
adaptive sub-stepping and determinism."""

import itertools

import cv2
import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

import evservo
from evservo import _evcore, geometry, trajectories
from evservo.models import load_object, to_core_mesh
from evservo.sim.record import background_pose, start_pose, substep_times
from evservo.sim.sources import scaled_camera
from evservo.tracking import model_point_set


@pytest.fixture(scope="module")
def half_camera():
    return scaled_camera(evservo.Camera.imx636(), 0.5)


@pytest.fixture(scope="module")
def box_mesh():
    return to_core_mesh(load_object("box"))


def square(side_m: float) -> _evcore.Mesh:
    h = side_m / 2
    v = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], float)
    return _evcore.Mesh(v, np.array([[0, 1, 2], [0, 2, 3]]), intensity=1.0)


def test_rendered_square_centre_lands_on_opencv_projection(camera):
    # A 4 mm white square on black, at the centre and towards the strongly distorted corners; the
    # intensity centroid in the raw frame must match cv2.projectPoints of its centre with the
    # IMX636 k1.
    sim = _evcore.SimCamera(camera, square(0.004), preset="clean", background_intensity=0.0, ambient=1.0, diffuse=0.0)
    K = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1]])
    dist = np.array(camera.dist)
    errors = []
    for k, centre in enumerate([(0.0, 0.0, 0.5), (-0.22, -0.12, 0.5), (0.24, 0.13, 0.5), (0.2, -0.1, 0.45)]):
        sim.advance(geometry.pose(centre), 1000 * (k + 1))
        f = sim.frame().astype(float)
        ys, xs = np.mgrid[0 : f.shape[0], 0 : f.shape[1]]
        u, v = (f * xs).sum() / f.sum(), (f * ys).sum() / f.sum()
        ref, _ = cv2.projectPoints(np.array([centre], float), np.zeros(3), np.zeros(3), K, dist)
        errors.append(np.hypot(u - ref[0, 0, 0], v - ref[0, 0, 1]))
        # The corner cases really are distorted: pinhole would miss by pixels.
        if k:
            pin = K @ np.array(centre) / centre[2]
            assert np.hypot(pin[0] - ref[0, 0, 0], pin[1] - ref[0, 0, 1]) > 20
    assert max(errors) < 0.5, errors


def test_static_scene_with_clean_preset_is_silent(half_camera, box_mesh):
    T = start_pose(0.6)
    sim = _evcore.SimCamera(half_camera, box_mesh, preset="clean", seed=3, T_c_bg=background_pose(0.6, 0.6))
    counts = [len(sim.advance(T, 1000 * k)) for k in range(30)]
    assert counts == [0] * 30
    # ROI steps after the first frame, each only the object's box.
    _, _, w, h, full = sim.last_roi
    assert not full and w * h < 0.5 * half_camera.width * half_camera.height


def test_moving_box_fires_on_its_projected_edges(half_camera, box_mesh):
    T0 = start_pose(0.6)
    traj = trajectories.make_trajectory("trans", speed_mps=0.4)
    sim = _evcore.SimCamera(half_camera, box_mesh, preset="clean", seed=1, T_c_bg=background_pose(0.6, 0.6))
    times = np.arange(0, 40_001, 500)
    poses = trajectories.apply(traj(times * 1e-6), T0)
    window = []
    fractions = []
    for k, (t, T) in enumerate(zip(times, poses, strict=True)):
        ev = sim.advance(T, int(t))
        window.append(ev)
        if k and k % 20 == 0:
            ev = np.concatenate(window[-2:])  # the last 1 ms
            pts = model_point_set(half_camera, "box", T, n_points=40000, seed=0)
            uv = half_camera.project(pts @ T[:3, :3].T + T[:3, 3])
            mask = np.ones((half_camera.height, half_camera.width), bool)
            iu = np.clip(np.round(uv).astype(int), 0, [half_camera.width - 1, half_camera.height - 1])
            mask[iu[:, 1], iu[:, 0]] = False
            dist = distance_transform_edt(mask)
            d = dist[ev["y"], ev["x"]]
            assert len(ev) > 1000
            fractions.append((np.mean(d <= 2.0), np.mean(d <= 8.0)))
    # Measured: 83-84 % within 2 px and 97 % within 8 px; the rest sit on print details finer than
    # S*'s texture-edge threshold (the minified checker strip, letter notches).
    assert min(f2 for f2, _ in fractions) > 0.8, fractions
    assert min(f8 for _, f8 in fractions) > 0.95, fractions


def test_adaptive_substeps_keep_motion_under_half_a_pixel(half_camera, box_mesh):
    T0 = start_pose(0.6)
    traj = trajectories.make_trajectory("trans-rot", speed_mps=0.8)
    sim = _evcore.SimCamera(half_camera, box_mesh, preset="clean")

    def pose_at(t_us):
        return trajectories.apply(traj(np.asarray(t_us) * 1e-6), T0)

    times = substep_times(sim, pose_at, 0, 2000, 0.5)
    assert times[-1] == 2000 and len(times) >= 3
    P = pose_at(np.concatenate([[0], times]))
    steps = [sim.max_displacement_px(a, b) for a, b in itertools.pairwise(P)]
    assert max(steps) <= 0.55 and sum(steps) > 1.0, steps
    # Nothing moves: one step per floor interval.
    assert list(substep_times(sim, lambda t: np.repeat(T0[None], len(t), 0), 0, 1000, 0.5)) == [1000]


def test_events_are_deterministic_per_seed(half_camera, box_mesh):
    T0 = start_pose(0.6)
    traj = trajectories.make_trajectory("circle", speed_mps=0.4)
    times = np.arange(0, 10_001, 1000)
    poses = trajectories.apply(traj(times * 1e-6), T0)

    def run(seed):
        sim = _evcore.SimCamera(half_camera, box_mesh, preset="noisy", seed=seed, T_c_bg=background_pose(0.6, 0.6))
        return np.concatenate([sim.advance(T, int(t)) for t, T in zip(times, poses, strict=True)])

    a, b, c = run(5), run(5), run(6)
    assert len(a) > 10_000
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()


def test_bad_arguments_raise_value_error(half_camera, box_mesh):
    with pytest.raises(ValueError):
        _evcore.SimCamera(half_camera, box_mesh, preset="imx999")
    with pytest.raises(ValueError):
        _evcore.SimCamera(half_camera, box_mesh, T_c_bg=np.eye(4), cell_m=-1.0)
    sim = _evcore.SimCamera(half_camera, box_mesh)
    sim.advance(start_pose(0.6), 100)
    with pytest.raises(ValueError):
        sim.advance(start_pose(0.6), 100)
    with pytest.raises(ValueError):
        sim.advance(np.full((4, 4), np.nan), 200)


def test_sparse_frames_give_the_reference_events_with_a_moving_camera(half_camera, box_mesh):
    # The rendered camera's sparse frames against the full-frame reference path, at the real lens's
    # distortion (half resolution), the box moving and the background plane moving as when the camera
    # follows: the same events, event for event (clean preset: no leak, whose f32 rounding may differ).
    T_c_o = start_pose(0.6)
    T_c_bg = background_pose(0.6, 0.6)
    sims = [
        _evcore.SimCamera(half_camera, box_mesh, preset="clean", seed=3, T_c_bg=T_c_bg, sparse=s) for s in (True, False)
    ]
    total = 0
    for k in range(12):
        step = geometry.pose((3e-4 * k, -2e-4 * k, 0.0))
        a, b = (s.advance(step @ T_c_o, 1000 * k, T_c_bg=step @ T_c_bg) for s in sims)
        np.testing.assert_array_equal(a, b)
        total += len(a)
    assert total > 2000
    assert sims[0].last_roi[4] is False and sims[1].last_roi[4] is True


def test_lab_preset_fires_with_the_mains_flicker_in_a_static_scene(half_camera, box_mesh):
    # Nothing moves; the 100 Hz flicker alone makes the lit scene fire, ON while the light rises.
    T_c_o = start_pose(0.6)
    sim = _evcore.SimCamera(half_camera, box_mesh, preset="lab", seed=1, T_c_bg=background_pose(0.6, 0.6))
    ev = np.concatenate([sim.advance(T_c_o, 500 * k) for k in range(80)])
    ev = ev[ev["t"] >= 20_000]  # pixels lock on to the flicker after a period or two
    assert len(ev) > 0.02 * half_camera.width * half_camera.height
    rising = ~((ev["t"] % 10_000 >= 2_500) & (ev["t"] % 10_000 < 7_500))
    assert np.mean(rising == (ev["p"] == 1)) > 0.95
    quiet = _evcore.SimCamera(
        half_camera, box_mesh, preset="lab", seed=1, T_c_bg=background_pose(0.6, 0.6), flicker_depth=0.0
    )
    # Without flicker only noise and hot pixels fire: ~1000 events in 40 ms against ~70 000 in 20 ms.
    n_quiet = sum(len(quiet.advance(T_c_o, 500 * k)) for k in range(80))
    assert n_quiet < 0.03 * len(ev)
