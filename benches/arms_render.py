"""Render throughput of the rendered event camera at 1280×720 (IMX636 model), with and without the
robot arms drawn (issue 4). Run: ``.venv/bin/python benches/arms_render.py [--renders N]``.

Each render is one ``SimCamera.advance`` on the bench's start view (box at Z = 0.9 m, textured
background plane 0.6 m behind it): render, composite, remap to the distorted grid, sensor step.
Two regimes, as in the closed loop:

* ``moving camera``: the background pose changes every render (the camera moves against the
  world), so every render is a full frame;
* ``moving object``: only the box moves (and the UR5e carrying it, when drawn), so renders cover
  the changed region only.

With arms, the UR5e's joints move a little every render, so its links are re-posed each time.
``--episode S`` also runs a closed-loop episode of S simulated seconds (``--events render``, fixed
cost model, 0.3 m/s) with and without the arms and counts its renders.
"""

from __future__ import annotations

import argparse
import os
import time

from evservo import _evcore, geometry
from evservo.models import load_object, to_core_mesh
from evservo.sim.arms import ArmMeshes
from evservo.sim.record import background_pose
from evservo.sim.scene import DualArmScene


def run(n: int, arms: ArmMeshes | None, moving_camera: bool) -> float:
    scene = arms.scene if arms is not None else DualArmScene()
    T_c_o = scene.reset_to_start(0.9, (0.35, -0.45, 0.1))
    q0 = scene.ur.joint_positions()
    cam = _evcore.Camera.imx636()
    T_c_bg = background_pose(0.9, 0.6)
    sim = _evcore.SimCamera(cam, to_core_mesh(load_object("box")), preset="imx636", seed=1, T_c_bg=T_c_bg)
    occ = None
    if arms is not None:
        sim.set_occluders(arms.core_meshes())
        occ = arms.camera_poses()
    sim.advance(T_c_o, 0, T_c_bg=T_c_bg, occluders=occ)
    start = time.perf_counter()
    for k in range(1, n + 1):
        # ~0.3 px of motion per render, the half-pixel rule's regime.
        q = q0.copy()
        q[0] += 3e-4 * k
        scene.ur.set_joint_positions(q)
        T_c_o = scene.T_c_o()
        bg = T_c_bg @ geometry.pose((2e-4 * k, 0.0, 0.0)) if moving_camera else T_c_bg
        occ = arms.camera_poses() if arms is not None else None
        sim.advance(T_c_o, 100 * k, T_c_bg=bg, occluders=occ)
    elapsed = time.perf_counter() - start
    scene.ur.set_joint_positions(q0)
    return n / elapsed


def episode(duration_s: float, render_arms: bool) -> str:
    from evservo.sim import sources
    from evservo.sim.episode import EpisodeConfig, run_episode, summarize

    renders = 0
    advance = _evcore.SimCamera.advance

    class Counted:
        def __init__(self, sim: _evcore.SimCamera) -> None:
            self.sim = sim

        def __getattr__(self, name: str) -> object:
            return getattr(self.sim, name)

        def advance(self, *args: object, **kwargs: object) -> object:
            nonlocal renders
            renders += 1
            return advance(self.sim, *args, **kwargs)

    init = sources.RenderedSource.__init__

    def counted_init(self: sources.RenderedSource, *args: object, **kwargs: object) -> None:
        init(self, *args, **kwargs)
        self.sim = Counted(self.sim)  # type: ignore[assignment]

    sources.RenderedSource.__init__ = counted_init  # type: ignore[method-assign]
    try:
        t = time.perf_counter()
        cfg = EpisodeConfig(duration_s=duration_s, cost_model="fixed", event_source="render", render_arms=render_arms)
        s = summarize(run_episode(cfg))
    finally:
        sources.RenderedSource.__init__ = init  # type: ignore[method-assign]
    return (
        f"episode {duration_s} s (+0.1 s pre-roll), arms {'on' if render_arms else 'off'}: {renders} renders, "
        f"{time.perf_counter() - t:.1f} s wall, completed {s['completed']}, tracking error "
        f"{s['gt_track_pos_rms_mm']:.2f} mm / {s['gt_track_rot_rms_deg']:.2f} deg"
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--renders", type=int, default=60)
    p.add_argument("--episode", type=float, default=0.0, help="also time a closed-loop episode of this length (s)")
    args = p.parse_args()
    scene = DualArmScene()
    arms = ArmMeshes(scene)
    load = os.getloadavg()[0]
    print(f"CPUs {os.cpu_count()}, load {load:.1f}; arms: {len(arms.links)} links, {arms.n_faces()} triangles")
    for moving_camera in (True, False):
        regime = "moving camera (full frames)" if moving_camera else "moving object (ROI)"
        plain = run(args.renders, None, moving_camera)
        with_arms = run(args.renders, arms, moving_camera)
        print(f"{regime:30} without arms {plain:6.1f} renders/s   with arms {with_arms:6.1f} renders/s")
    if args.episode > 0:
        for render_arms in (False, True):
            print(episode(args.episode, render_arms))


if __name__ == "__main__":
    main()
