"""What a run writes: ``summary.json``, ``log.csv`` and ``motion.png`` (the paper's Fig. 5).

Both loops describe their run as columns and call these writers, so the two outputs share one
layout and one plot."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from evservo.geometry import rotation_from_first_rad
from evservo.outputs import json_text, write_text_atomic
from evservo.runtime.watchdog import WatchdogSpell


def write_summary(path: str | Path, summary: dict) -> Path:
    """``summary`` as strict JSON (:func:`~evservo.outputs.json_text`), replaced atomically: a reader
    sees the previous file or the whole new one. Writers call it last, after the run's other outputs."""
    p = Path(path)
    write_text_atomic(p, json_text(summary))
    return p


def write_log(
    path: str | Path, header: Sequence[str], columns: np.ndarray, labels: Sequence[str] | None = None
) -> Path:
    """A CSV log: ``columns`` (N, len(header)) as ``%.6g`` numbers; with ``labels`` (N,) one more text
    column (its name is the last of ``header``)."""
    p = Path(path)
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(list(header))
        for i, row in enumerate(np.atleast_2d(columns) if len(columns) else []):
            cells = [f"{v:.6g}" for v in row]
            w.writerow([*cells, labels[i]] if labels is not None else cells)
    return p


def plot_motion(
    path: str | Path,
    t_s: np.ndarray,
    T_w_c: np.ndarray,
    T_w_o_est: np.ndarray,
    title: str,
    T_w_o_true: np.ndarray | None = None,
    spells: Sequence[WatchdogSpell] = (),
) -> Path:
    """The paper's Fig. 5: camera and object displacement along each world axis from their first
    poses (mm), the object as reconstructed from the camera pose and the estimate (``T_w_o_est`` =
    ``T_w_c · T_c_o``, what the paper could plot) and, in simulation, as it truly moved; the camera's
    rotation from its first orientation (deg). Watchdog spells are shaded. Stacks are (N, 4, 4)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 1, sharex=True, figsize=(8, 8), constrained_layout=True)
    if len(t_s):

        def moved(T: np.ndarray) -> np.ndarray:
            return (T[:, :3, 3] - T[:1, :3, 3]) * 1e3

        d_cam, d_est = moved(T_w_c), moved(T_w_o_est)
        d_true = moved(T_w_o_true) if T_w_o_true is not None else None
        for i, name in enumerate("xyz"):
            axes[i].plot(t_s, d_cam[:, i], color="tab:blue", label="camera")
            if d_true is not None:
                axes[i].plot(t_s, d_true[:, i], color="tab:orange", label="object (true)")
            axes[i].plot(t_s, d_est[:, i], color="tab:orange", ls=":", lw=1, label="object (camera · estimate)")
            axes[i].set_ylabel(f"{name} (mm)")
        axes[3].plot(t_s, np.rad2deg(rotation_from_first_rad(T_w_c)), color="tab:blue")
    for ax in axes:
        ax.grid(alpha=0.3)
        for w in spells:
            end = w.end_s if w.end_s is not None else (w.zero_s if w.zero_s is not None else w.start_s)
            ax.axvspan(w.start_s, end, color="red", alpha=0.2)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[3].set_ylabel("camera rot. (deg)")
    axes[3].set_xlabel("time since servo start (s)")
    fig.suptitle(title, fontsize=10)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
