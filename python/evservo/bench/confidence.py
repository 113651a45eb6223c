"""Does the tracker know when its pose is wrong? The confidence's ROC on open-loop scripted streams.

(The closed-loop ``evservo bench --suite robustness`` is :mod:`evservo.bench.robustness`.) Runs the
scenarios of :mod:`evservo.sim.scenarios` (occlusions, leaving the view, events stopping,
a wrong model, pure noise, starting without a pose) for each solver and tabulates the detection
delay, re-lock time, longest confidently-wrong spell and false-loss rate. The per-update confidences
of the edft+ runs, labelled right or wrong against the truth, give the confidence's ROC: its AUC and,
at the threshold the tracker uses, the rates at which wrong poses are flagged (TPR) and right ones
are flagged by mistake (FPR).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evservo import _evcore
from evservo.outputs import json_text
from evservo.sim.scenarios import ScenarioRun, run_scenario, scenarios, score

SOLVERS = ("edft+", "edopts", "edft")
#: The tracker's default ``lost_below``.
LOST_BELOW = _evcore.LOST_BELOW


def roc(confidence: np.ndarray, wrong: np.ndarray, threshold: float = LOST_BELOW) -> dict:
    """ROC of "confidence < t flags a wrong pose": AUC (probability that a random wrong pose scores
    lower than a random right one, ties half) and TPR / FPR at ``threshold``."""
    c, w = np.asarray(confidence, float), np.asarray(wrong, bool)
    n_w, n_r = int(w.sum()), int((~w).sum())
    if not (n_w and n_r):
        raise ValueError("the ROC needs both right and wrong poses")
    ranks = _average_ranks(c)
    # Mann–Whitney: rank sum of the right poses against the wrong ones.
    auc = (ranks[~w].sum() - n_r * (n_r + 1) / 2) / (n_r * n_w)
    return {
        "auc": float(auc),
        "threshold": threshold,
        "tpr": float(np.mean(c[w] < threshold)),
        "fpr": float(np.mean(c[~w] < threshold)),
        "right": n_r,
        "wrong": n_w,
    }


def _average_ranks(x: np.ndarray) -> np.ndarray:
    order = np.argsort(x, kind="stable")
    ranks = np.empty(len(x))
    ranks[order] = np.arange(1, len(x) + 1)
    _, inv, counts = np.unique(x, return_inverse=True, return_counts=True)
    sums = np.bincount(inv, weights=ranks)
    return (sums / counts)[inv]


def run(out: Path, quick: bool = False, sources: tuple[str, ...] = ("edges", "render")) -> dict:
    """Run the open-loop scenarios into ``out`` (``confidence.md``, ``confidence.json``); ``quick``: edft+ only,
    edges only."""
    out.mkdir(parents=True, exist_ok=True)
    solvers = ("edft+",) if quick else SOLVERS
    rows, labelled = [], []
    for source in sources[:1] if quick else sources:
        for name, sc in scenarios().items():
            for solver in solvers if source == "edges" else ("edft+",):
                r: ScenarioRun = run_scenario(sc, solver=solver, source=source)
                rows.append({"scenario": name, "source": source, "solver": solver, **score(r)})
                if solver == "edft+" and not sc.start_lost:
                    labelled.append(r)
    curve = roc(np.concatenate([r.confidence for r in labelled]), np.concatenate([r.wrong for r in labelled]))
    result = {"rows": rows, "roc": curve}
    (out / "confidence.json").write_text(json_text(result))
    (out / "confidence.md").write_text(report(result))
    return result


def _ms(v: float) -> str:
    return "–" if not np.isfinite(v) and v != np.inf else ("never" if v == np.inf else f"{v:.0f}")


def report(result: dict) -> str:
    c = result["roc"]
    lines = [
        f"Confidence ROC (edft+ updates, all sources): AUC {c['auc']:.3f}; at the threshold "
        f"{c['threshold']:g}: TPR {c['tpr']:.3f} (wrong poses flagged), FPR {c['fpr']:.3f} (right "
        f"poses flagged), over {c['right']} right and {c['wrong']} wrong updates.",
        "",
        "| scenario | source | solver | detection delay ms | re-lock ms | longest confident-wrong ms | false loss |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in result["rows"]:
        fl = "–" if not np.isfinite(r["false_loss"]) else f"{100 * r['false_loss']:.1f} %"
        lines.append(
            f"| {r['scenario']} | {r['source']} | {r['solver']} | {_ms(r['detection_delay_ms'])} | "
            f"{_ms(r['relock_ms'])} | {r['confident_wrong_ms']:.0f} | {fl} |"
        )
    return "\n".join(lines) + "\n"
