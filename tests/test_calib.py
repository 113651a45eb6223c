"""`evservo calib`: intrinsics and hand-eye from a blinking checkerboard seen by the rendered event camera.

The recordings are rendered once per module (four frames around each blink). The IMX636 views are
carried by the simulated Panda (MuJoCo scene, camera on the flange at a known T_e_c, board fixed in the
world, flange poses from forward kinematics); the wide-angle lens's views are camera poses generated
directly, with the flange poses that a board fixed in the base implies.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from evservo import _evcore, geometry
from evservo import io as evio
from evservo.calib.blinks import blink_windows
from evservo.calib.board import Board, find_board
from evservo.calib.capture import capture
from evservo.calib.handeye import match_views, read_poses, write_poses
from evservo.calib.intrinsics import calibrate_intrinsics
from evservo.calib.views import scan_recording
from evservo.camera_file import load_camera_file
from evservo.cli import main
from evservo.limits import CartesianLimits
from evservo.robots.config import load_rig_config
from evservo.robots.kinematic import DEFAULT_START, KinematicArm
from evservo.sim.blinkboard import BlinkingScreen, look_at_board, panda_views, record_views, spread_view_poses

BOARD = Board(9, 6, 0.025)
#: A wide-angle lens with much stronger barrel distortion than the IMX636's.
STRONG = _evcore.Camera(640, 480, 520.0, 524.0, 323.5, 236.0, (-0.42, 0.20, 0.0, 0.0, 0.0))
#: Ground truth of the hand-eye set-up: camera on the flange, board fixed in the robot base.
T_E_C = geometry.pose((0.012, 0.071, 0.043), (0.02, -0.03, 1.55))
T_B_BOARD = geometry.pose((0.55, 0.05, 0.0), (np.pi, 0.0, 0.3))
REPO = Path(__file__).resolve().parents[1]


def _flange_poses(T_c_board: list[np.ndarray]) -> np.ndarray:
    return np.array([T_B_BOARD @ geometry.inv(T) @ geometry.inv(T_E_C) for T in T_c_board])


def _record(tmp_path_factory, name: str, camera, T_c_board: list[np.ndarray], T_b_e: np.ndarray) -> dict:
    path = tmp_path_factory.mktemp("calib") / f"{name}.h5"
    mids = record_views(path, camera, BOARD, T_c_board)
    csv = path.with_suffix(".csv")
    write_poses(csv, mids * 1e-6, T_b_e)
    return dict(path=path, camera=camera, poses_csv=csv, mids=mids)


@pytest.fixture(scope="module")
def imx_rec(tmp_path_factory):
    camera = _evcore.Camera.imx636()
    T_c_board, T_b_e = panda_views(camera, BOARD, 20, T_E_C, seed=2)
    return _record(tmp_path_factory, "imx636", camera, T_c_board, T_b_e)


@pytest.fixture(scope="module")
def strong_rec(tmp_path_factory):
    T_c_board = spread_view_poses(STRONG, BOARD, 15, seed=3, distance_m=(0.25, 0.45))
    return _record(tmp_path_factory, "strong", STRONG, T_c_board, _flange_poses(T_c_board))


def _run_json(args: list[str], capsys) -> dict:
    assert main(args) == 0
    return json.loads(capsys.readouterr().out)


def _fails(args: list[str], capsys) -> str:
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("evservo: error: ")
    return err


def _intrinsics(rec: dict) -> tuple[dict, Path]:
    """`calib intrinsics --json --out cam.yaml` on a recording: the printed JSON and the camera file."""
    cam_file = rec["path"].with_name(rec["path"].stem + "-cam.yaml")
    args = ["calib", "intrinsics", str(rec["path"]), "--board", "9x6", "--square", "0.025", "--json"]
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        assert main([*args, "--out", str(cam_file)]) == 0
    return json.loads(out.getvalue()), cam_file


@pytest.fixture(scope="module")
def imx_intrinsics(imx_rec):
    return _intrinsics(imx_rec)


def _assert_intrinsics_match(got: dict, cam) -> None:
    assert abs(got["fx"] / cam.fx - 1) < 0.005 and abs(got["fy"] / cam.fy - 1) < 0.005
    assert abs(got["cx"] - cam.cx) < 2.0 and abs(got["cy"] - cam.cy) < 2.0
    assert abs(got["dist"][0] - cam.dist[0]) < 0.01
    assert got["dist"][2:] == [0.0, 0.0, 0.0]  # k1k2: no tangential terms, no k3


def test_intrinsics_of_the_imx636_from_blinks(imx_rec, imx_intrinsics):
    got, cam_file = imx_intrinsics
    _assert_intrinsics_match(got, imx_rec["camera"])
    assert got["views_used"] == 20 and got["rms_px"] < 0.5
    # The camera file reads back through the project's camera-file reader with the printed values.
    cam = load_camera_file(cam_file)
    assert (cam.width, cam.height) == (1280, 720)
    assert np.allclose(
        [cam.fx, cam.fy, cam.cx, cam.cy, *cam.dist], [got[k] for k in ("fx", "fy", "cx", "cy")] + got["dist"]
    )


def test_intrinsics_of_a_strongly_distorting_lens(strong_rec):
    got, _ = _intrinsics(strong_rec)
    _assert_intrinsics_match(got, STRONG)
    assert abs(got["dist"][1] - STRONG.dist[1]) < 0.05


def test_hand_eye_recovers_T_e_c_and_updates_the_rig_file(imx_rec, imx_intrinsics, tmp_path, capsys):
    _, cam_file = imx_intrinsics  # the chain a lab runs: calibrated, not true, intrinsics
    rig = tmp_path / "rig.yaml"
    shutil.copy(REPO / "examples" / "rig.yaml", rig)
    args = ["calib", "hand-eye", str(imx_rec["path"]), "--poses", str(imx_rec["poses_csv"]), "--board", "9x6"]
    got = _run_json([*args, "--square", "0.025", "--camera", str(cam_file), "--out", str(rig), "--json"], capsys)
    T = np.array(got["T_e_c"])
    assert geometry.translation_error_m(T, T_E_C) < 1e-3
    assert np.degrees(geometry.rotation_error_rad(T, T_E_C)) < 0.1
    assert got["views_used"] == 20
    assert 0 <= got["rot_spread_deg"] < 1.0 and 0 <= got["trans_spread_mm"] < 10.0
    # servo --robot --config reads the merged file: the new hand-eye and camera, the old limits.
    cfg = load_rig_config(rig)
    assert np.allclose(cfg.T_e_c, T, atol=1e-9)
    assert cfg.camera.fx == load_camera_file(cam_file).fx
    assert cfg.limits.max_lin_vel == 0.25 and cfg.model == "box"


def test_wrong_board_size_is_a_clear_error(strong_rec, capsys):
    err = _fails(["calib", "intrinsics", str(strong_rec["path"]), "--board", "8x6", "--square", "0.025"], capsys)
    assert "8x6 board was found in none of the 30 blinks" in err and "--board" in err


@pytest.fixture(scope="module")
def strong_cam_file(tmp_path_factory):
    from evservo.calib.camfile import write_camera_file

    path = tmp_path_factory.mktemp("cam") / "cam.yaml"
    write_camera_file(path, STRONG)
    return path


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t, T: (t[:-1], T[:-1]), "has 14 pose(s) but the recording shows the whole board in 15"),
        (lambda t, T: (t + 10.0, T), "s from the nearest view (allowed 0.5 s)"),
    ],
    ids=["number", "time"],
)
def test_poses_that_do_not_match_the_views_are_an_error(strong_rec, strong_cam_file, tmp_path, capsys, edit, message):
    t, T = edit(*read_poses(strong_rec["poses_csv"]))
    poses = tmp_path / "poses.csv"
    write_poses(poses, t, T)
    args = ["calib", "hand-eye", str(strong_rec["path"]), "--poses", str(poses), "--board", "9x6", "--square", "0.025"]
    err = _fails([*args, "--camera", str(strong_cam_file)], capsys)
    assert message in err


def test_too_few_views_is_an_error(tmp_path, capsys):
    rec = tmp_path / "few.h5"
    record_views(rec, STRONG, BOARD, spread_view_poses(STRONG, BOARD, 3, seed=4, distance_m=(0.25, 0.45)))
    err = _fails(["calib", "intrinsics", str(rec), "--board", "9x6", "--square", "0.025"], capsys)
    assert "only 3 view(s) show the whole 9x6 board" in err


def test_board_half_outside_the_image_is_an_error(tmp_path, capsys):
    # The board's centre on the right edge of the image: half of it is outside in every view.
    z = 0.35
    centre = np.array([(STRONG.width - 1 - STRONG.cx) / STRONG.fx * z, 0.0, z])
    poses = [
        look_at_board(BOARD, centre + np.array([0, dy, 0]), (0.1, 0.2 * s, 0.0)) for dy, s in ((-0.03, 1), (0.03, -1))
    ]
    rec = tmp_path / "half.h5"
    record_views(rec, STRONG, BOARD, poses)
    err = _fails(["calib", "intrinsics", str(rec), "--board", "9x6", "--square", "0.025"], capsys)
    assert "found in none of the 4 blinks" in err


def test_a_recording_without_blinks_is_an_error(tmp_path, capsys):
    rng = np.random.default_rng(0)
    n = 20_000
    ev = np.zeros(n, evio.EVENT_CD)
    ev["x"], ev["y"] = rng.integers(0, 64, n), rng.integers(0, 48, n)
    ev["t"] = np.sort(rng.integers(0, 2_000_000, n))
    rec = tmp_path / "noise.npz"
    evio.write_events(rec, ev, 64, 48)
    err = _fails(["calib", "intrinsics", str(rec), "--board", "9x6", "--square", "0.025"], capsys)
    assert "no blinks found" in err


@pytest.mark.parametrize("board", ["9", "9x", "axb", "1x6"])
def test_bad_board_option_is_an_error(board, tmp_path, capsys):
    _fails(["calib", "intrinsics", str(tmp_path / "missing.h5"), "--board", board, "--square", "0.025"], capsys)


def test_blinks_are_the_sharp_peaks_not_noise_or_motion():
    """Noise at 1 kev/s, a stretch of camera motion at 200 kev/s, and three blinks of 3000 events in
    0.6 ms: exactly the three blinks are found, each window holding its burst."""
    rng = np.random.default_rng(1)
    w, h = 160, 120
    parts = [rng.integers(0, 3_000_000, 3000)]  # noise
    parts.append(rng.integers(1_000_000, 1_400_000, 80_000))  # motion from 1.0 to 1.4 s
    blinks = [500_000, 1_200_000, 2_500_000]  # one of them during the motion
    parts += [t + rng.integers(0, 600, 3000) for t in blinks]
    t = np.sort(np.concatenate(parts))
    ev = np.zeros(len(t), evio.EVENT_CD)
    ev["t"] = t
    ev["x"], ev["y"] = rng.integers(0, w, len(t)), rng.integers(0, h, len(t))
    windows = blink_windows(lambda: [ev], w * h)
    assert len(windows) == 3
    for (a, b), t0 in zip(windows, blinks, strict=True):
        assert a <= t0 and b >= t0 + 600 and b - a <= 3000


class _LiveScreenCamera:
    """A fake live camera: renders one blink of the screen every 40 ms of wall time, seen from where
    the arm holds the camera now (board fixed in the world), stamped with wall-clock microseconds."""

    def __init__(self, camera, arm: KinematicArm, T_w_board: np.ndarray) -> None:
        self.width, self.height = camera.width, camera.height
        self._screen = BlinkingScreen(camera, BOARD, seed=5)
        self._arm, self._T_w_board = arm, T_w_board
        self._closed = threading.Event()

    def __iter__(self):
        start = time.monotonic()
        t_us = 1000
        while not self._closed.is_set():
            T_c_board = geometry.inv(self._arm.T_w_c()) @ self._T_w_board
            yield self._screen.blink(T_c_board, t_us)
            t_us += 40_000
            time.sleep(max(0.0, start + t_us * 1e-6 - time.monotonic()))

    def close(self) -> None:
        self._closed.set()


def test_capture_writes_views_and_poses_that_match(tmp_path):
    """Capture with a kinematic stand-in arm moved between views and a fake live camera: every view is
    kept, poses.csv holds the arm's flange poses, and the written recording's views match them."""
    clock = [0.0]
    camera = _evcore.Camera(320, 240, 260.0, 262.0, 160.5, 119.5, (-0.1, 0.0, 0.0, 0.0, 0.0))
    arm = KinematicArm(
        T_e_c=T_E_C, limits=CartesianLimits(2.0, 2.0, 100.0, 100.0), watchdog_s=30.0, clock=lambda: clock[0]
    )
    # The board 0.3 m in front of the camera's start pose, facing it.
    T_w_board = arm.T_w_c() @ look_at_board(BOARD, (0.0, 0.0, 0.4), (0.0, 0.0, 0.0))
    moves = iter([(0.0, 0.0, 0.0, 0.0, 0.0, 0.0), (0.01, 0, 0, 0, 0.05, 0), (-0.01, 0.01, 0, 0.05, 0, 0.05)])
    said = []
    answers = []

    def ask(prompt: str) -> str:
        v = next(moves, None)
        if v is None:
            return "q"
        arm.command_twist(np.array(v), 1.0)  # held for one second of the arm's clock, then stopped
        clock[0] += 1.0
        arm.stop()
        answers.append(arm.T_w_e())
        return ""

    source = _LiveScreenCamera(camera, arm, T_w_board)
    with arm:
        result = capture(source, arm, BOARD, 5, tmp_path / "calib.h5", tmp_path / "poses.csv", hold_s=0.3, ask=ask,
                         say=said.append)  # fmt: skip
    assert len(result.t_s) == 3, said
    t_s, T_b_e = read_poses(tmp_path / "poses.csv")
    assert np.allclose(T_b_e, np.array(answers), atol=1e-8)
    assert not np.allclose(T_b_e[0], T_b_e[1])
    scan = scan_recording(tmp_path / "calib.h5", BOARD)
    assert len(scan.views) == 3 and all(v.n_blinks >= 2 for v in scan.views)  # at least one on + off each
    assert match_views(scan.views, t_s, max_dt_s=0.01) == [0, 1, 2]


def _drawn_board(x0: int = 120, y0: int = 90, s: int = 36) -> tuple[np.ndarray, np.ndarray]:
    """A count image of BOARD drawn axis-aligned (lit squares 5 events, the rest 0) and its inner
    corners (pixel-centre coordinates) in the board frame's order."""
    img = np.zeros((480, 640))
    for k in range(BOARD.cols + 1):
        for m in range(BOARD.rows + 1):
            if (k + m) % 2 == 0:  # square (1, 1), after corner (0, 0), is lit
                img[y0 + (m - 1) * s : y0 + m * s, x0 + (k - 1) * s : x0 + k * s] = 5
    j, i = np.mgrid[0 : BOARD.rows, 0 : BOARD.cols]
    corners = np.stack([x0 + i.ravel() * s - 0.5, y0 + j.ravel() * s - 0.5], axis=1)
    return img, corners


@pytest.mark.parametrize("turns", [0, 1, 2, 3])
def test_corner_order_follows_the_board_not_the_image(turns):
    """However the board is turned in the image, corner k is the same physical corner (the order a
    board pose needs), found within a tenth of a pixel."""
    img, truth = _drawn_board()
    turned = np.rot90(img, turns).copy()
    found = find_board(turned, BOARD).corners
    assert found is not None
    # Undo the turns: np.rot90 moves pixel (x, y) of an image W wide to (y, W - 1 - x).
    p = found.astype(float)
    h, w = turned.shape
    for _ in range(turns):
        p = np.stack([h - 1 - p[:, 1], p[:, 0]], axis=1)
        h, w = w, h
    assert np.abs(p - truth).max() < 0.1


@pytest.fixture(scope="module")
def strong_scan(strong_rec):
    return scan_recording(strong_rec["path"], BOARD)


def test_distortion_models_estimate_what_they_say(strong_scan):
    """On the wide lens (k1 −0.42, k2 0.20): k1 alone cannot fit (RMS more than doubles, k2 stays 0);
    k1k2 fits with p1 = p2 = k3 = 0; full frees all five and fits no better than k1k2."""
    fits = {m: calibrate_intrinsics(strong_scan.views, BOARD, 640, 480, m) for m in ("k1", "k1k2", "full")}
    assert fits["k1"].camera.dist[1:] == (0.0, 0.0, 0.0, 0.0)
    assert fits["k1k2"].camera.dist[2:] == (0.0, 0.0, 0.0)
    assert all(v != 0.0 for v in fits["full"].camera.dist)
    assert fits["k1"].rms_px > 2 * fits["k1k2"].rms_px
    assert fits["full"].rms_px <= fits["k1k2"].rms_px + 1e-6
    assert abs(fits["k1k2"].camera.dist[1] - 0.20) < 0.05


def test_an_outlier_view_is_rejected(strong_scan):
    """One view's corners pushed 3 px off (a smeared blink): it is dropped, the others kept, and the
    camera is the same as without it."""
    views = [dataclasses.replace(v, corners=v.corners.copy()) for v in strong_scan.views]
    rng = np.random.default_rng(0)
    views[4].corners += rng.normal(0.0, 3.0, views[4].corners.shape).astype(np.float32)
    fit = calibrate_intrinsics(views, BOARD, 640, 480)
    assert fit.rejected == [4] and len(fit.used) == len(views) - 1 and np.isnan(fit.view_rms_px[4])
    clean = calibrate_intrinsics([v for i, v in enumerate(views) if i != 4], BOARD, 640, 480)
    assert abs(fit.camera.fx - clean.camera.fx) < 1e-6 and fit.rms_px < 0.5


def test_too_few_views_left_after_rejection_is_an_error(strong_scan):
    with pytest.raises(ValueError, match="view\\(s\\) show the whole 9x6 board"):
        calibrate_intrinsics(strong_scan.views[:5], BOARD, 640, 480)


def test_blinks_are_found_through_a_noisy_sensor(tmp_path):
    """The `noisy` sensor preset (5 Hz shot noise per pixel: ≈ 1.5 Mev/s on 640×480, more than the
    blinks' own rate averaged over the recording): every blink is found and shows the whole board."""
    poses = spread_view_poses(STRONG, BOARD, 3, seed=6, distance_m=(0.25, 0.45))
    rec = tmp_path / "noisy.h5"
    record_views(rec, STRONG, BOARD, poses, preset="noisy")
    n_events = evio.info(rec)["n_events"]
    scan = scan_recording(rec, BOARD)
    assert n_events > 1_000_000
    assert (scan.n_blinks, scan.n_detected, len(scan.views)) == (6, 6, 3)


def test_capture_command_on_a_replayed_recording(tmp_path, monkeypatch, capsys):
    """`evservo calib capture --robot sim --camera FILE`: a still camera's recording (the screen
    blinking every 50 ms) replayed as a live camera, the kinematic stand-in arm opened read-only; one
    view, then q."""
    camera = _evcore.Camera(320, 240, 260.0, 262.0, 160.5, 119.5, (-0.1, 0.0, 0.0, 0.0, 0.0))
    rec = tmp_path / "still.h5"
    record_views(rec, camera, BOARD, [look_at_board(BOARD, (0.0, 0.0, 0.4), (0.2, -0.1, 0.0))], blinks_per_view=16)
    answers = iter(["", "q"])
    monkeypatch.setattr("builtins.input", lambda prompt="": next(answers))
    out = tmp_path / "cap"
    args = ["calib", "capture", "--robot", "sim", "--camera", str(rec), "--board", "9x6", "--square", "0.025"]
    assert main([*args, "--hold", "0.5", "--out", str(out)]) == 0
    t_s, T_b_e = read_poses(out / "poses.csv")
    assert len(t_s) == 1 and np.allclose(T_b_e[0], DEFAULT_START)  # the stand-in arm's pose
    views = scan_recording(out / "calib.h5", BOARD).views
    assert len(views) == 1 and views[0].n_blinks >= 2
    assert "wrote" in capsys.readouterr().out
