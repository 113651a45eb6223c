"""Real-time factor of the closed loop per event source, where its seconds go, and the rendered
camera's equivalence across builds (issue 15). Run with the venv's python from the repository root.

``episode SRC [--arms] [--duration S]``: one closed-loop episode (fixed cost model, 0.3 m/s, seed 1,
+ 0.1 s pre-roll); prints the process CPU seconds, the real-time factor (simulated s / CPU s, and
/ wall s) with and without the episode's set-up (scene, models, tracker: ``loop_*``), the CPU
seconds spent in the event source (rendering + sensor), in the tracker's ``step`` and in the rest
of the loop (``rest_cpu_s``: the Python loop and ingest), events and the ground-truth tracking error.

``record OUT.npz [--arms] [--duration S]``: the rendered source's inputs of one such episode (the
object, camera and link poses at every tick) for open-loop replays.
``replay IN.npz COUNTS.npy [--source render|render-fast]``: feed the recorded inputs to this build's
rendered source; prints its CPU time per simulated second and saves the per-pixel event counts.
``compare A.npy B.npy``: per-pixel event counts of two replays (e.g. ``main``'s build and this one).
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from evservo import _evcore
from evservo.sim import sources
from evservo.sim.episode import EpisodeConfig, run_episode, summarize

SPEED_MPS, SEED, VIEW = 0.3, 1, (0.9, (0.35, -0.45, 0.1))


def cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def timed(cls: Any, name: str, acc: dict[str, float], key: str) -> Callable[[], None]:
    """Wrap ``cls.name`` to add its process CPU seconds to ``acc[key]``; returns the undo."""
    orig = getattr(cls, name)

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        t0 = cpu_s()
        acc.setdefault("loop_start_cpu_s", t0)
        try:
            return orig(*args, **kwargs)
        finally:
            acc[key] = acc.get(key, 0.0) + cpu_s() - t0

    setattr(cls, name, wrapper)
    return lambda: setattr(cls, name, orig)


def config(source: str, arms: bool, duration_s: float) -> EpisodeConfig:
    return EpisodeConfig(
        duration_s=duration_s,
        cost_model="fixed",
        event_source=source,
        render_arms=arms,
        speed_mps=SPEED_MPS,
        seed=SEED,
    )


def episode(source: str, arms: bool, duration_s: float) -> dict:
    from evservo import synth
    from evservo.tracking import Tracker

    acc: dict[str, float] = {}
    undo = [
        timed(sources.RenderedSource, "events_until", acc, "source_cpu_s"),
        timed(synth.EdgeEventGenerator, "events_until", acc, "source_cpu_s"),
        timed(Tracker, "step", acc, "tracker_step_cpu_s"),
    ]
    try:
        c0, w0 = cpu_s(), time.perf_counter()
        s = summarize(run_episode(config(source, arms, duration_s)))
        c1, wall = cpu_s(), time.perf_counter() - w0
    finally:
        for u in undo:
            u()
    # The loop: from the first call into the source (after the scene, models and tracker are
    # set up) to the end of the episode.
    cpu, loop = c1 - c0, c1 - acc.pop("loop_start_cpu_s")
    sim_s = duration_s + 0.1  # the pre-roll renders too
    return {
        "source": source + (" + arms" if arms else ""),
        "simulated_s": sim_s,
        "cpu_s": round(cpu, 2),
        "wall_s": round(wall, 2),
        "rtf_cpu": round(sim_s / cpu, 4),
        "rtf_wall": round(sim_s / wall, 4),
        "loop_cpu_s": round(loop, 2),
        "loop_rtf_cpu": round(sim_s / loop, 4),
        **{k: round(v, 2) for k, v in acc.items()},
        # The Python loop and ingest: arms, IK, controller, bookkeeping (everything but the two above).
        "rest_cpu_s": round(loop - acc.get("source_cpu_s", 0.0) - acc.get("tracker_step_cpu_s", 0.0), 2),
        "source_rtf_cpu": round(sim_s / acc["source_cpu_s"], 4) if acc.get("source_cpu_s") else None,
        "events": s["events"],
        "completed": s["completed"],
        "gt_track_pos_rms_mm": round(s["gt_track_pos_rms_mm"], 3),
        "gt_track_rot_rms_deg": round(s["gt_track_rot_rms_deg"], 3),
    }


def record(out: str, arms: bool, duration_s: float) -> None:
    log: list[tuple[int, np.ndarray, np.ndarray | None, np.ndarray | None]] = []
    init, until = sources.RenderedSource.__init__, sources.RenderedSource.events_until

    def logged_init(
        self: sources.RenderedSource, camera: Any, obj: str, T: np.ndarray, t0: int, *a: Any, **kw: Any
    ) -> None:
        init(self, camera, obj, T, t0, *a, **kw)
        log.append((t0, np.array(T), None, self.occ))

    def logged_until(
        self: sources.RenderedSource, t_us: int, T: np.ndarray, T_w_c: Any = None, occluders: Any = None
    ) -> Any:
        log.append((t_us, np.array(T), None if T_w_c is None else np.array(T_w_c), occluders))
        return until(self, t_us, T, T_w_c, occluders)

    sources.RenderedSource.__init__ = logged_init  # type: ignore[method-assign]
    sources.RenderedSource.events_until = logged_until  # type: ignore[method-assign]
    try:
        run_episode(config("render", arms, duration_s))
    finally:
        sources.RenderedSource.__init__, sources.RenderedSource.events_until = init, until  # type: ignore[method-assign]
    occ: list[np.ndarray] = []
    for _, _, _, o in log:  # during the pre-roll the links keep their poses
        occ.append(np.array(o) if o is not None else occ[-1] if occ else np.zeros((0, 4, 4)))
    np.savez(
        out,
        t=np.array([e[0] for e in log]),
        T_c_o=np.stack([e[1] for e in log]),
        T_w_c=np.stack([np.full((4, 4), np.nan) if e[2] is None else e[2] for e in log]),
        occ=np.stack(occ),
    )
    print(f"{len(log)} calls recorded in {out}")


def replay(inputs: str, counts_out: str, source: str) -> None:
    from evservo.sim.arms import ArmMeshes
    from evservo.sim.scene import DualArmScene

    d = np.load(inputs)
    t, T_c_o, T_w_c, occ = d["t"], d["T_c_o"], d["T_w_c"], d["occ"]
    arms = None
    if occ.shape[1]:
        scene = DualArmScene()
        scene.reset_to_start(*VIEW)
        arms = ArmMeshes(scene)
    cam = _evcore.Camera.imx636()
    src = sources.make_event_source(source, cam, "box", T_c_o[0], int(t[0]), SEED, arms=arms)
    assert isinstance(src, sources.RenderedSource)
    if arms is not None:
        src.occ = occ[0]
    counts = np.zeros(cam.width * cam.height, np.int64)
    c0 = cpu_s()
    for k in range(1, len(t)):
        ev = src.events_until(
            int(t[k]),
            T_c_o[k],
            None if np.isnan(T_w_c[k]).any() else T_w_c[k],
            None if arms is None else occ[k],
        )
        np.add.at(counts, ev["y"].astype(np.int64) * cam.width + ev["x"], 1)
    # The ticks after the last render (a build that renders only every few ticks).
    for ev in getattr(src, "flush", list)():
        np.add.at(counts, ev["y"].astype(np.int64) * cam.width + ev["x"], 1)
    cpu = cpu_s() - c0
    sim_s = (t[-1] - t[0]) * 1e-6
    np.save(counts_out, counts)
    print(
        json.dumps(
            {
                "ticks": len(t) - 1,
                "simulated_s": sim_s,
                "cpu_s": round(cpu, 2),
                "cpu_ms_per_tick": round(cpu / (len(t) - 1) * 1e3, 2),
                "rtf_cpu": round(sim_s / cpu, 4),
                "events": int(counts.sum()),
            }
        )
    )


def compare(a_path: str, b_path: str) -> None:
    a, b = np.load(a_path), np.load(b_path)
    diff = np.abs(a - b)
    print(
        json.dumps(
            {
                "events": [int(a.sum()), int(b.sum())],
                "pixels_firing": [int((a > 0).sum()), int((b > 0).sum())],
                "pixels_differing": int((diff > 0).sum()),
                "abs_count_difference": int(diff.sum()),
                "max_pixel_difference": int(diff.max()),
            }
        )
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("episode")
    e.add_argument("source", choices=sorted(sources.EVENT_SOURCES))
    r = sub.add_parser("record")
    r.add_argument("out")
    for q in (e, r):
        q.add_argument("--arms", action="store_true")
        q.add_argument("--duration", type=float, default=0.3)
    rp = sub.add_parser("replay")
    rp.add_argument("inputs")
    rp.add_argument("counts")
    rp.add_argument("--source", choices=sources.RENDERED_SOURCES, default="render")
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    args = p.parse_args()
    if args.cmd == "episode":
        print(json.dumps(episode(args.source, args.arms, args.duration)))
    elif args.cmd == "record":
        record(args.out, args.arms, args.duration)
    elif args.cmd == "replay":
        replay(args.inputs, args.counts, args.source)
    else:
        compare(args.a, args.b)


if __name__ == "__main__":
    main()
