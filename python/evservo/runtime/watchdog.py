"""The record of a watchdog spell, one type for the simulated episode and the real loop."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class WatchdogSpell:
    """One spell of the controller's watchdog, in seconds since servo start.

    ``start_s``: the first control cycle that braked; ``last_pose_s``: time stamp of the last pose
    accepted before it; ``zero_s``: the first cycle commanding exactly zero (None if never);
    ``end_s``: the first cycle servoing again (None if it lasted to the end: the real loop never
    resumes); ``reason``: why it fired.
    """

    start_s: float
    last_pose_s: float
    zero_s: float | None
    end_s: float | None
    reason: str = "no fresh pose"


def spells_from_flags(
    t_s: np.ndarray, braking: np.ndarray, est_t_s: np.ndarray, v_cmd: np.ndarray
) -> list[WatchdogSpell]:
    """The spells of a per-cycle record: ``braking`` (N,) True while the watchdog held, ``est_t_s``
    (N,) the time stamp of the pose in use, ``v_cmd`` (N, 6) the commanded twist."""
    w = np.asarray(braking, bool)
    out = []
    starts = np.flatnonzero(w & ~np.concatenate([[False], w[:-1]]))
    for s in starts:
        after = np.flatnonzero(~w[s:])
        e = s + after[0] if len(after) else None
        zero = np.flatnonzero(~np.any(v_cmd[s:e], axis=1))
        out.append(
            WatchdogSpell(
                start_s=float(t_s[s]),
                last_pose_s=float(est_t_s[s]),
                zero_s=float(t_s[s + zero[0]]) if len(zero) else None,
                end_s=float(t_s[e]) if e is not None else None,
            )
        )
    return out


def describe_spell(spell: Mapping[str, object]) -> str:
    """One line for a spell as stored in ``summary.json`` (a ``WatchdogSpell`` as a dict)."""

    def at(key: str, missing: str) -> str:
        v = spell.get(key)
        return missing if v is None else f"{v:.3f} s"

    return (
        f"watchdog: {spell.get('reason', 'no fresh pose')}; last pose {at('last_pose_s', '?')}, "
        f"braking from {at('start_s', '?')}, at rest {at('zero_s', 'never')}, "
        f"servoing again {at('end_s', 'never')}"
    )
