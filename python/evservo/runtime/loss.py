"""Scoring the tracker's ``lost`` flag against ground truth (issue 12), for both loops and the
robustness suite.

Per control sample (time ``t_s``, seconds) a run gives the tracker's ``lost`` flag, whether the pose
in use is *wrong* and whether the object can be *seen* (its events reach the tracker: not occluded,
events flowing, at least half of it in the image). A pose is wrong when it is more than
:data:`WRONG_POS_M` or :data:`WRONG_ROT_DEG` off the truth at its own time, both scaled with the
depth from :data:`WRONG_AT_Z_M` (the same image error at any distance), or whenever the object
cannot be seen. From those:

- ``loss_detection_delay_ms``: over the spells of wrong poses, the longest time from the spell's start
  to the first ``lost`` in it (the whole spell when never flagged);
- ``relock_ms``: over the moments the object can be seen again (and the start of a run that began
  without a pose), the longest time until the first right pose not flagged lost (inf: never);
- ``confident_wrong_ms``: the longest spell of wrong poses not flagged lost (and the total);
- ``false_loss_rate``: the fraction of right poses of a visible object that are flagged lost (over
  ``right_samples`` of them).
"""

from __future__ import annotations

import numpy as np

WRONG_POS_M = 0.03
WRONG_ROT_DEG = 10.0
#: The depth (m) at which the bounds above hold; they scale in proportion to the true depth.
WRONG_AT_Z_M = 0.6


def wrong_pose(pos_err_m: np.ndarray, rot_err_rad: np.ndarray, z_m: np.ndarray) -> np.ndarray:
    """Pose errors (m, rad) beyond the bounds scaled to the object's true depth ``z_m`` (m)."""
    scale = np.maximum(np.asarray(z_m, float), 1e-3) / WRONG_AT_Z_M
    return (np.asarray(pos_err_m) > WRONG_POS_M * scale) | (np.asarray(rot_err_rad) > np.deg2rad(WRONG_ROT_DEG) * scale)


def spells(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(start, end)`` index pairs (end exclusive) of the runs of True in ``mask``."""
    d = np.diff(np.concatenate([[0], np.asarray(mask, bool).astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def reappearances(t_s: np.ndarray, visible: np.ndarray, started_lost: bool = False) -> list[float]:
    """Times (s) at which the object can be seen again after it could not (and the first time it can
    be seen in a run that started without a pose)."""
    v = np.asarray(visible, bool)
    k = np.flatnonzero(v[1:] & ~v[:-1]) + 1
    out = [float(t_s[i]) for i in k]
    if started_lost and len(v) and v.any():
        out.insert(0, float(t_s[int(np.argmax(v))]))
    return out


def loss_metrics(
    t_s: np.ndarray, lost: np.ndarray, wrong: np.ndarray, visible: np.ndarray, started_lost: bool = False
) -> dict:
    """The module docstring's figures (ms, JSON-ready; None where the event did not occur) of one run
    sampled at uniform times ``t_s`` (s)."""
    t = np.asarray(t_s, float)
    lost, wrong, visible = (np.asarray(a, bool) for a in (lost, wrong, visible))
    if not len(t):
        return {"loss_detection_delay_ms": None, "relock_ms": None, "confident_wrong_ms": 0.0,
                "confident_wrong_total_ms": 0.0, "false_loss_rate": None, "right_samples": 0, "wrong_spells": 0,
                "undetected_spells": 0, "lost_fraction": 0.0}  # fmt: skip
    dt_ms = float(np.median(np.diff(t))) * 1e3 if len(t) > 1 else 1.0
    delays, undetected = [], 0
    for s, e in spells(wrong):
        flagged = np.flatnonzero(lost[s:e])
        undetected += not len(flagged)
        delays.append((flagged[0] if len(flagged) else e - s) * dt_ms)
    right = ~wrong & visible
    relocks = []
    for r in reappearances(t, visible, started_lost):
        ok = np.flatnonzero(right & ~lost & (t >= r))
        relocks.append((t[ok[0]] - r) * 1e3 if len(ok) else float("inf"))
    cw = spells(wrong & ~lost)
    return {
        "loss_detection_delay_ms": max(delays) if delays else None,
        "relock_ms": max(relocks) if relocks else None,
        "confident_wrong_ms": max((e - s for s, e in cw), default=0) * dt_ms,
        "confident_wrong_total_ms": float(np.sum(wrong & ~lost)) * dt_ms,
        "false_loss_rate": float(np.mean(lost[right])) if right.any() else None,
        "right_samples": int(np.sum(right)),
        "wrong_spells": len(delays),
        "undetected_spells": undetected,
        "lost_fraction": float(np.mean(lost)),
    }


def describe(loss: dict, holding_s: float) -> str:
    """One line of :func:`loss_metrics`' figures for a command's summary; ``holding_s``: how long the
    loop held the arm instead of servoing (s)."""

    def ms(v: float | None) -> str:
        return "n/a" if v is None else ("never" if v == float("inf") else f"{v:.0f} ms")

    rate = loss["false_loss_rate"]
    false_loss = "n/a" if rate is None else f"{100 * rate:.1f} %"
    return (
        f"loss: detection delay {ms(loss['loss_detection_delay_ms'])}, re-lock {ms(loss['relock_ms'])}, "
        f"longest confident-wrong {ms(loss['confident_wrong_ms'])} ({ms(loss['confident_wrong_total_ms'])} in all), "
        f"false loss {false_loss}, loop held {holding_s:.2f} s"
    )
