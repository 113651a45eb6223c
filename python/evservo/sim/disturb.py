"""Disturbances of the simulated event stream (issue 12): what makes a tracker's pose wrong on purpose.

- **occlusion** (``occlusions``): the object is fully hidden; the source is shown it far out of the
  view, so neither the edge source nor the rendered camera makes any of its events, while the rest
  (background activity, the rendered background and arms) goes on. It vanishes and reappears at
  once, as behind a passing occluder: the rendered source is told to jump, not to sweep it away;
- **dropout** (``dropout_s``): every event is lost (a sensor or link failure: the events stop);
- **noise** (``noise_s``): the scene's events are replaced by uniform noise at ``noise_rate_hz``
  over the sensor (pure noise).

Spells are ``(start, end)`` in seconds of simulated time, end excluded. :meth:`Disturbances.seen`
says whether the object's events reach the tracker, for scoring the tracker's ``lost`` flag.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from evservo.events import EVENT_CD

#: The pose an occluded object is shown to the event source at: 1 km off to the side, so no edge
#: point or triangle of it lands anywhere near the image (the scene itself is not moved).
HIDDEN_T_C_O = np.array([[1.0, 0, 0, 1000.0], [0, 1.0, 0, 0], [0, 0, 1.0, 1.0], [0, 0, 0, 1.0]])

Spell = tuple[float, float]


def within(t_s: float, spells: Sequence[Spell]) -> bool:
    """``t_s`` falls in one of the half-open spells ``[start, end)`` (seconds)."""
    return any(a <= t_s < b for a, b in spells)


def check_spells(spells: Sequence[Spell], name: str) -> None:
    """Each spell finite with ``0 <= start < end``; raises ``ValueError`` naming ``name``."""
    for s in spells:
        if len(s) != 2 or not (np.all(np.isfinite(s)) and 0 <= s[0] < s[1]):
            raise ValueError(f"{name}: each spell must be (start, end) seconds with 0 <= start < end, got {s}")


def uniform_noise(width: int, height: int, t0_us: int, t1_us: int, rate_hz: float, rng: np.random.Generator):
    """Time-sorted EventCD noise of ``[t0_us, t1_us)``: Poisson count at ``rate_hz`` over the sensor,
    uniform pixels, polarities and times."""
    n = rng.poisson(rate_hz * (t1_us - t0_us) * 1e-6)
    idx = rng.integers(0, width * height, n)
    ev = np.empty(n, EVENT_CD)
    ev["x"], ev["y"] = idx % width, idx // width
    ev["p"] = rng.integers(0, 2, n)
    ev["t"] = np.sort(rng.integers(t0_us, t1_us, n))
    return ev


class Disturbances:
    """The spells of one episode (module docstring) on a ``width`` × ``height`` sensor."""

    def __init__(
        self,
        width: int,
        height: int,
        occlusions: Sequence[Spell] = (),
        dropout: Spell | None = None,
        noise: Spell | None = None,
        noise_rate_hz: float = 1e7,
        seed: int = 0,
    ) -> None:
        self.width, self.height = width, height
        self.occlusions = tuple(occlusions)
        self.dropout = dropout
        self.noise = noise
        self.noise_rate_hz = float(noise_rate_hz)
        self._rng = np.random.default_rng(seed + 7919)
        self._hidden = False

    def occluded(self, t_s: float) -> bool:
        return within(t_s, self.occlusions)

    def seen(self, t_s: float) -> bool:
        """The object's events reach the tracker at ``t_s`` (no occlusion, dropout or noise spell)."""
        spells = [*self.occlusions, *(s for s in (self.dropout, self.noise) if s is not None)]
        return not within(t_s, spells)

    def source_pose(self, source: Any, t_us: int, T_c_o: np.ndarray) -> np.ndarray:
        """The object pose to show ``source`` for its batch ending at ``t_us`` (µs): the true one, or
        :data:`HIDDEN_T_C_O` while occluded. On a change a source with ``jump`` (the rendered camera)
        is moved there at once rather than sweeping the object across the image."""
        hidden = self.occluded(t_us * 1e-6)
        shown = HIDDEN_T_C_O if hidden else T_c_o
        if hidden != self._hidden and hasattr(source, "jump"):
            source.jump(shown)
        self._hidden = hidden
        return shown

    def events(self, t0_us: int, t1_us: int, events: np.ndarray) -> np.ndarray:
        """The batch of ``[t0_us, t1_us)`` after the dropout and noise spells."""
        for spell, fill in ((self.dropout, False), (self.noise, True)):
            if spell is None:
                continue
            a, b = round(spell[0] * 1e6), round(spell[1] * 1e6)
            if t1_us <= a or t0_us >= b:
                continue
            events = events[(events["t"] < a) | (events["t"] >= b)]
            if fill:
                noise = uniform_noise(self.width, self.height, max(t0_us, a), min(t1_us, b), self.noise_rate_hz,
                                      self._rng)  # fmt: skip
                # With the dtype: concatenate would pack EVENT_CD, and the tracker copy it back.
                events = np.sort(np.concatenate([events, noise], dtype=EVENT_CD), order="t", kind="stable")
        return events
