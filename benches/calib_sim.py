"""Accuracy of `evservo calib` on rendered blinking-checkerboard recordings (benches/RESULTS.md,
"Calibration from events").

For each camera (the IMX636 model; a 640×480 wide-angle lens with k1 = −0.42, k2 = 0.20) and seed:
the simulated Panda carries the camera (on a known ``T_e_c``) to ``--views`` views of a 9x6 board
(25 mm squares) fixed in the world (``evservo.sim.blinkboard.panda_views``: views spread over the
image, IK in the MuJoCo scene, flange poses from forward kinematics); render the blinks and write the
flange poses, then run ``evservo calib intrinsics`` (each distortion model)
and ``evservo calib hand-eye`` (with the k1k2 intrinsics just calibrated) and compare with the truth.

    .venv/bin/python benches/calib_sim.py --views 15 --seeds 2 3 4 --out out/calib-bench
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import time
from pathlib import Path

import numpy as np

from evservo import _evcore, geometry
from evservo.calib.board import Board
from evservo.calib.handeye import write_poses
from evservo.cli import main
from evservo.sim.blinkboard import panda_views, record_views

BOARD = Board(9, 6, 0.025)
CAMERAS = {
    "imx636": (_evcore.Camera.imx636(), (0.35, 0.55)),
    "wide": (_evcore.Camera(640, 480, 520.0, 524.0, 323.5, 236.0, (-0.42, 0.20, 0.0, 0.0, 0.0)), (0.25, 0.45)),
}
T_E_C = geometry.pose((0.012, 0.071, 0.043), (0.02, -0.03, 1.55))


def _cli(args: list[str]) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
        assert main(args) == 0, args
    return json.loads(out.getvalue())


def run(name: str, seed: int, views: int, out: Path) -> list[str]:
    cam, depth = CAMERAS[name]
    rec = out / f"{name}-{seed}.h5"
    t = time.perf_counter()
    poses, T_b_e = panda_views(cam, BOARD, views, T_E_C, seed=seed, distance_m=depth)
    mids = record_views(rec, cam, BOARD, poses, seed=seed)
    render_s = time.perf_counter() - t
    write_poses(rec.with_suffix(".csv"), mids * 1e-6, T_b_e)
    board = ["--board", str(BOARD), "--square", str(BOARD.square_m)]
    rows = []
    for model in ("k1", "k1k2", "full"):
        cam_file = out / f"{name}-{seed}-{model}.yaml"
        t = time.perf_counter()
        got = _cli(["calib", "intrinsics", str(rec), *board, "--model", model, "--out", str(cam_file), "--json"])
        calib_s = time.perf_counter() - t
        errors = [
            f"{100 * (got['fx'] / cam.fx - 1):+.3f}", f"{100 * (got['fy'] / cam.fy - 1):+.3f}",
            f"{got['cx'] - cam.cx:+.2f}", f"{got['cy'] - cam.cy:+.2f}",
            f"{got['dist'][0] - cam.dist[0]:+.4f}", f"{got['dist'][1] - cam.dist[1]:+.4f}",
        ]  # fmt: skip
        tail = f"{got['rms_px']:.3f} | {got['views_used']} | {render_s:.0f} / {calib_s:.1f}"
        rows.append(f"| {name} | {seed} | {model} | {' | '.join(errors)} | {tail} |")
    t = time.perf_counter()
    he = _cli(
        ["calib", "hand-eye", str(rec), "--poses", str(rec.with_suffix(".csv")), *board,
         "--camera", str(out / f"{name}-{seed}-k1k2.yaml"), "--json"]
    )  # fmt: skip
    he_s = time.perf_counter() - t
    T = np.array(he["T_e_c"])
    rows.append(
        f"| {name} | {seed} | hand-eye | {1e3 * geometry.translation_error_m(T, T_E_C):.3f} mm | "
        f"{np.degrees(geometry.rotation_error_rad(T, T_E_C)):.4f}° | spread {he['rot_spread_deg']:.4f}° / "
        f"{he['trans_spread_mm']:.3f} mm | rms {he['rms_px']:.3f} px | {he['views_used']} views | {he_s:.1f} s |"
    )
    return rows


def cli() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--views", type=int, default=15)
    p.add_argument("--seeds", type=int, nargs="+", default=[2, 3, 4])
    p.add_argument("--cameras", nargs="+", default=list(CAMERAS), choices=list(CAMERAS))
    p.add_argument("--out", default="out/calib-bench")
    a = p.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    print(
        "| camera | seed | model | fx err % | fy err % | cx err px | cy err px | k1 err | k2 err | RMS px | views "
        "| render / calib s |"
    )
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name in a.cameras:
        for seed in a.seeds:
            for row in run(name, seed, a.views, out):
                print(row, flush=True)


if __name__ == "__main__":
    cli()
