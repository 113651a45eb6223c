"""Latency suite: per-step costs, updates per second and event-to-pose latency of the threaded
tracker under live-like input, plus decode and simulator throughput.

Event-to-pose latency of an estimate = the wall time at which the producer first sees it via
``latest()`` minus the wall time at which the newest event it reflects (its ``t_us``) was pushed.
Events are replayed in real time: a batch covering ``batch_us`` of event time is pushed when the
wall clock reaches it, at 5, 20 and 50 Mev/s. The input is the moving box's edge events, each
repeated (with jittered times) as often as needed to reach the rate, as a high-contrast edge fires
several events per pixel, plus uniform noise making up 5 % of the stream. Uniform noise alone at
these rates would put several events on every pixel per second, which no real scene does and which
buries any object under any front-end.
"""

from __future__ import annotations

import json
import platform
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

import evservo
from evservo import geometry, trajectories
from evservo.events import EVENT_CD
from evservo.synth import edge_events
from evservo.tracking import Tracker, model_point_set


@dataclass
class LatencyRow:
    rate_mev_s: float
    solver: str
    updates_per_s: float
    latency_p50_ms: float
    latency_p99_ms: float
    events_dropped: int
    events_pushed: int
    pos_err_end_mm: float


def _stream(camera: evservo.Camera, duration_s: float, rate_mev_s: float, batch_us: int, seed: int):
    """Batches (EventCD) of the box moving at 0.3 m/s at ``rate_mev_s`` (see the module docstring), and
    the true T_c_o at the end of each batch."""
    T0 = geometry.pose((0.0, 0.0, 0.6), (0.35, -0.45, 0.1))
    times = np.arange(0, int(duration_s * 1e6) + 1, batch_us, dtype=np.int64)
    truth = trajectories.apply(trajectories.make_trajectory("trans", speed_mps=0.3)(times * 1e-6), T0)
    dense = model_point_set(camera, "box", T0, n_points=30000, seed=seed)
    signal = edge_events(camera, dense, truth, times, noise_fraction=0.0, seed=seed)
    rng = np.random.default_rng(seed)
    per_batch = int(rate_mev_s * 1e6 * batch_us * 1e-6)
    out = []
    for k, ev in enumerate(signal):
        n_noise = per_batch // 20
        n_signal = max(per_batch - n_noise, 0)
        picks = ev[rng.integers(0, len(ev), n_signal)] if len(ev) else np.empty(0, EVENT_CD)
        picks["t"] = rng.integers(times[k], times[k + 1], len(picks))
        noise = np.empty(n_noise, dtype=EVENT_CD)
        noise["x"] = rng.integers(0, camera.width, n_noise)
        noise["y"] = rng.integers(0, camera.height, n_noise)
        noise["p"] = rng.integers(0, 2, n_noise)
        noise["t"] = rng.integers(times[k], times[k + 1], n_noise)
        b = np.concatenate([picks, noise])
        b.sort(order="t", kind="stable")
        out.append(b)
    return T0, out, truth[1:]


def measure_latency(
    rate_mev_s: float, solver: str = "edft+", duration_s: float = 2.0, batch_us: int = 500, seed: int = 0
) -> LatencyRow:
    camera = evservo.Camera.imx636()
    T0, batches, truth = _stream(camera, duration_s, rate_mev_s, batch_us, seed)
    pushed_at: dict[int, float] = {}
    latencies = []
    trk = Tracker(camera, "box", T0, solver=solver)
    with trk:
        trk.start()
        start = time.perf_counter()
        last_seq = 0
        first_seq = None
        for k, b in enumerate(batches):
            due = start + (k + 1) * batch_us * 1e-6
            while True:
                now = time.perf_counter()
                est = trk.latest()
                if est.seq != last_seq:
                    last_seq = est.seq
                    first_seq = first_seq or est.seq
                    if est.t_us in pushed_at:
                        latencies.append(now - pushed_at[est.t_us])
                if now >= due:
                    break
                time.sleep(min(due - now, 1e-4))
            trk.push(b)
            pushed_at[int(b["t"][-1])] = time.perf_counter()
        time.sleep(0.02)
        est = trk.latest()
        wall = time.perf_counter() - start
    stats = trk.stats()
    lat = np.array(latencies) * 1e3 if latencies else np.array([np.nan])
    return LatencyRow(
        rate_mev_s=rate_mev_s,
        solver=solver,
        updates_per_s=(est.seq - (first_seq or 0)) / wall,
        latency_p50_ms=float(np.percentile(lat, 50)),
        latency_p99_ms=float(np.percentile(lat, 99)),
        events_dropped=int(stats["events_dropped"]),
        events_pushed=int(sum(len(b) for b in batches)),
        pos_err_end_mm=geometry.translation_error_m(est.T_c_o, truth[-1]) * 1e3,
    )


def step_costs(solver: str = "edft+", n_batches: int = 500) -> dict[str, float]:
    """Mean wall time per LM and per search update (ms) over a synchronous run of 1 ms batches."""
    camera = evservo.Camera.imx636()
    T0, batches, _ = _stream(camera, n_batches * 1e-3, 5.0, 1000, 1)
    trk = Tracker(camera, "box", T0, solver=solver)
    for b in batches:
        trk.update(b)
    s = trk.stats()
    lm = s["lm_seconds"] / s["lm_steps"] * 1e3 if s["lm_steps"] else float("nan")
    search = s["search_seconds"] / s["search_steps"] * 1e3 if s["search_steps"] else float("nan")
    total = s["lm_seconds"] + s["search_seconds"]
    return {
        "lm_update_ms": lm,
        "search_update_ms": search,
        "updates_per_s": (s["lm_steps"] + s["search_steps"]) / total if total else float("nan"),
    }


def decode_throughput(path: Path) -> float:
    """Mev/s of decoding a RAW file end to end through evservo.io (Python included)."""
    from evservo.io import read_events

    t0 = time.perf_counter()
    ev = read_events(path)
    return len(ev) / (time.perf_counter() - t0) / 1e6


def simulator_throughput(n_steps: int = 100) -> dict[str, float]:
    """Events/s and steps/s of the sensor model on a moving stripe pattern at 1280×720."""
    sim = evservo._evcore.EventSimulator(1280, 720, preset="imx636", seed=0)
    xx = np.arange(1280, dtype=np.float32)[None, :]
    frame = lambda k: (0.5 + 0.4 * np.sin((xx + 0.5 * k) * 0.2)).repeat(720, 0).astype(np.float32)  # noqa: E731
    sim.reset(frame(0), 0)
    frames = [frame(k) for k in range(1, n_steps + 1)]
    t0 = time.perf_counter()
    n = sum(len(sim.step(f, 700 * (k + 1))) for k, f in enumerate(frames))
    dt = time.perf_counter() - t0
    return {"steps_per_s": n_steps / dt, "mev_per_s": n / dt / 1e6}


def run(out: Path, quick: bool = False, samples: Path | None = None) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    rates = (5.0, 20.0) if quick else (5.0, 20.0, 50.0)
    duration = 0.5 if quick else 2.0
    rows = []
    for rate in rates:
        for solver in ("edft+", "edopts"):
            print(f"latency: {solver} at {rate:g} Mev/s ...", flush=True)
            rows.append(measure_latency(rate, solver, duration_s=duration))
    costs = {s: step_costs(s, 200 if quick else 1000) for s in ("edft+", "edopts", "edft")}
    result = {
        "command": "evservo bench --suite latency" + (" --quick" if quick else ""),
        "machine": {
            "cpus": __import__("os").cpu_count(),
            "python": platform.python_version(),
            "evservo": evservo.__version__,
        },
        "latency": [asdict(r) for r in rows],
        "step_costs": costs,
        "simulator": simulator_throughput(20 if quick else 100),
    }
    if samples is not None and samples.exists():
        result["decode_mev_per_s"] = {p.name: decode_throughput(p) for p in sorted(samples.glob("*.raw"))}
    (out / "latency.json").write_text(json.dumps(result, indent=2))
    m = result["machine"]
    lines = [
        f"Command: `{result['command']} --out {out}`; evservo {m['evservo']}, Python {m['python']}, {m['cpus']} CPUs; "
        f"{duration:g} s per run, events replayed in real time into the threaded tracker.",
        "",
        "| rate Mev/s | solver | updates/s | latency p50 ms | p99 ms | dropped/pushed | end error mm |",
        "|---:|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r.rate_mev_s:g} | {r.solver} | {r.updates_per_s:.0f} | {r.latency_p50_ms:.2f} | "
            f"{r.latency_p99_ms:.2f} | {r.events_dropped}/{r.events_pushed} | {r.pos_err_end_mm:.2f} |"
        )
    lines += ["", "| solver | LM update ms | search update ms | updates/s (sync) |", "|---|---:|---:|---:|"]
    for s, c in costs.items():
        lines.append(f"| {s} | {c['lm_update_ms']:.3f} | {c['search_update_ms']:.3f} | {c['updates_per_s']:.0f} |")
    sim = result["simulator"]
    lines += ["", f"Simulator (1280×720 full frames): {sim['steps_per_s']:.0f} steps/s, {sim['mev_per_s']:.2f} Mev/s."]
    for name, v in result.get("decode_mev_per_s", {}).items():
        lines.append(f"Decode through evservo.io: {name}: {v:.0f} Mev/s.")
    report = "\n".join(lines) + "\n"
    (out / "latency.md").write_text(report)
    print(report)
    return result
