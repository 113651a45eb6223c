"""``evservo bench --suite robustness``: does the closed loop know when the pose is wrong (issue 12)?

Each scenario is a closed-loop episode (:func:`evservo.sim.episode.run_episode`, our controller, the
``edges`` event source unless ``events="render"``, the tracker's re-acquisition on) that runs through its losses
(``end_on_loss=False``) and scores the tracker's ``lost`` flag against the truth
(:mod:`evservo.runtime.loss`), for each of EDFT⁺, EDOPTS and EDFT:

- ``occlusion-0.5s``, ``occlusion-2s``: the object fully hidden from 0.6 s (no object events, the
  background goes on), the trans trajectory at 0.3 m/s;
- ``leave-return``: the object dashes 0.7 m across the view at 0.9 m/s, wholly out of it for ≈ 0.4 s,
  and comes back, at 0.6 m/s at most, to rest near the middle of the view of the camera that braked
  after following it for a moment, turned by 25° (Z = 0.6 m; half of it in view again ≈ 1.9 s after
  it set off, at rest ≈ 0.8 s later; re-lock counts from the moment half of it is in view again);
  without feed-forward, as when a person carries it: with the target arm's motion fed forward the
  camera kept it in view (tracking 1–2 mm RMS), so the scenario tested no leaving. At 1.0 m/s and
  above the target arm no longer follows the dash (it swings 0.1–0.4 m past and back);
- ``events-stop``: every event lost for 0.5 s while the object moves;
- ``wrong-model``: the tracker is given the drill's model, the object is the box;
- ``pure-noise``: from 0.6 s to 1.6 s the scene's events are replaced by 10 Mev/s of uniform noise
  (10⁷ events);
- ``start-without-pose``: the tracker starts without a pose and must find the object; the loop waits
  at rest and captures the desired pose once locked.

Columns: the longest loss-detection delay, the longest re-lock time, the longest confident-wrong
spell (wrong beyond 30 mm / 10° at Z = 0.6 m, scaled with depth, while not flagged lost), the
false-loss rate, and the loop's reaction: time held (not servoing) and time coasted (following the
object's predicted motion through a loss). Episodes are cached like the paper suite's
(``episodes/<key>/config_hash``: a rerun with the same configuration and code reuses them), so an
interrupted run (Ctrl-C) resumes.
"""

from __future__ import annotations

import os
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

import evservo
from evservo.bench.paper import _run_one, code_version, reuse
from evservo.outputs import json_text
from evservo.sim.episode_config import EpisodeConfig

SOLVERS = ("edft+", "edopts", "edft")
EVENTS = ("edges", "render")


def scenarios(quick: bool = False) -> dict[str, EpisodeConfig]:
    """The suite's scenarios by name (edft+, edges source). Disturbances start at 0.6 s, once the
    target's 0.5 s start ramp is over, and episodes run 0.6 s past them (the issue's re-lock bound is
    0.3 s). ``quick`` shortens the long occlusion to 1 s."""
    base = EpisodeConfig(speed_mps=0.3, feedforward=True, end_on_loss=False, reacquire=True)
    t0, long_occlusion = 0.6, 1.0 if quick else 2.0
    return {
        "occlusion-0.5s": replace(base, occlusions=((t0, t0 + 0.5),), duration_s=t0 + 1.1),
        f"occlusion-{long_occlusion:g}s": replace(
            base, occlusions=((t0, t0 + long_occlusion),), duration_s=t0 + long_occlusion + 0.6
        ),
        "leave-return": replace(
            base, trajectory="leave-return", speed_mps=0.9, distance_m=0.6, duration_s=3.6, feedforward=False
        ),
        "events-stop": replace(base, dropout_s=(t0, t0 + 0.5), duration_s=t0 + 1.1),
        "wrong-model": replace(base, model="drill", duration_s=1.0),
        "pure-noise": replace(base, noise_s=(t0, t0 + 1.0), noise_rate_hz=1e7, duration_s=t0 + 1.6),
        "start-without-pose": replace(base, start_lost=True, duration_s=1.5),
    }


def plan(quick: bool = False, events: str = "edges") -> list[tuple[str, EpisodeConfig]]:
    """(scenario, config) of every episode: each scenario for each solver."""
    if events not in EVENTS:
        raise ValueError(f"unknown event source {events!r} for the robustness suite; choose one of {EVENTS}")
    solvers = ("edft+",) if quick else SOLVERS
    return [
        (name, replace(cfg, tracker=solver, event_source=events))
        for name, cfg in scenarios(quick).items()
        for solver in solvers
    ]


def episode_key(name: str, cfg: EpisodeConfig) -> str:
    ev = "" if cfg.event_source == "edges" else f"-{cfg.event_source}"
    return f"{name}-{cfg.tracker}-s{cfg.seed}-d{cfg.duration_s:g}{ev}"


def run(out: Path, quick: bool = False, events: str = "edges") -> dict:
    """Run (or reuse) every episode into ``out/episodes``, write ``robustness.md`` and
    ``robustness.json``; returns the results. A scenario the tracker cannot run (e.g. starting
    without a pose before the tracker supports it) is reported with its error, not raised."""
    from tqdm import tqdm

    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    code = code_version()
    rows, reused = [], 0
    items = plan(quick, events)
    with tqdm(total=len(items), unit="episode", desc="robustness suite") as bar:
        for name, cfg in items:
            key = episode_key(name, cfg)
            ep = out / "episodes" / key
            summary = reuse(ep, cfg, code)
            reused += summary is not None
            if summary is None:
                bar.set_postfix_str(key)
                try:
                    summary = _run_one(cfg, str(ep))
                except (ValueError, TypeError) as err:  # the tracker cannot run this scenario
                    summary = {"failed": str(err)}
            rows.append(
                {"scenario": name, "solver": cfg.tracker, "key": key, "config": asdict(cfg), "summary": summary}
            )
            bar.update()
            tqdm.write(_line(rows[-1]))
    result = {
        "command": f"evservo bench --suite robustness{' --quick' if quick else ''}"
        f"{'' if events == 'edges' else f' --events {events}'} --out {out}",
        "evservo": evservo.__version__,
        "wall_s": time.perf_counter() - t0,
        "reused": reused,
        "rows": rows,
    }
    (out / "robustness.json").write_text(json_text(result))
    (out / "robustness.md").write_text(report(result))
    return result


def _ms(v: float | None) -> str:
    if v is None:
        return "–"
    return "never" if v == float("inf") else f"{v:.0f}"


def _with_ms(cell: str) -> str:
    return cell if cell in ("–", "never") else f"{cell} ms"


def _cells(s: dict) -> list[str]:
    if "failed" in s:
        return ["–"] * 7
    loss = s["loss"]
    fl = loss["false_loss_rate"]
    return [
        _ms(loss["loss_detection_delay_ms"]),
        _ms(loss["relock_ms"]),
        _ms(loss["confident_wrong_ms"]),
        "–" if fl is None else f"{100 * fl:.1f} %",
        f"{loss['holding_s']:.2f}",
        "–" if "coasting_s" not in loss else f"{loss['coasting_s']:.2f}",
        f"{s['gt_track_pos_rms_mm']:.0f}",
    ]


def _line(row: dict) -> str:
    s = row["summary"]
    if "failed" in s:
        return f"{row['key']}: could not run: {s['failed']}"
    c = _cells(s)
    return (
        f"{row['key']}: detection {_with_ms(c[0])}, re-lock {_with_ms(c[1])}, confident-wrong {_with_ms(c[2])}, "
        f"false loss {c[3]}, held {c[4]} s, coasted {c[5]} s"
    )


def report(result: dict) -> str:
    """The suite's table (markdown)."""
    reused = f" ({result['reused']} reused from an earlier run)" if result["reused"] else ""
    lines = [
        "# evservo robustness suite (issue 12)",
        "",
        f"Command: `{result['command']}`; evservo {result['evservo']}, {os.cpu_count()} CPUs, "
        f"{len(result['rows']) - result['reused']} episodes run in {result['wall_s'] / 60:.1f} min"
        f"{reused}, load average "
        f"{os.getloadavg()[1]:.1f} at the end. Closed-loop episodes (our controller) run through their losses. "
        "Wrong: beyond 30 mm / 10° at Z = 0.6 m (scaled with depth), or the object not seen (hidden, events "
        "stopped, pure noise, under half of it in the image), or the model not the object's. Times in ms: "
        "detection = longest delay from a pose turning wrong to `lost`; re-lock = longest time from the object "
        "being seen again (or the start without a pose) to a right pose not flagged lost; confident-wrong = "
        "longest spell wrong and not flagged lost. False loss: share of right poses of a visible object flagged "
        "lost. Held: time the loop did not servo (holding, searching or ramping back in). Coasted: time it "
        "followed the object's predicted motion through a loss (at most 0.1 s after the newest trusted pose).",
        "",
        "| scenario | solver | detection ms | re-lock ms | longest confident-wrong ms | false loss | held s "
        "| coasted s | tracking RMS mm | episode |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for row in result["rows"]:
        s = row["summary"]
        link = f"failed: {s['failed']}" if "failed" in s else f"[summary](episodes/{row['key']}/summary.json)"
        lines.append(f"| {row['scenario']} | {row['solver']} | {' | '.join(_cells(s))} | {link} |")
    worst = [r["summary"]["loss"]["confident_wrong_ms"] for r in result["rows"] if "failed" not in r["summary"]]
    if worst:
        lines += [
            "",
            f"Longest confident-wrong spell over the suite: {np.max(worst):.0f} ms (issue 12's bound: 100 ms).",
        ]
    return "\n".join(lines) + "\n"
