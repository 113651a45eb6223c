"""The per-cycle record of a run: named arrays preallocated for the longest run, filled one cycle at a
time, handed back trimmed. Both loops record through it, so a new column is one line in each."""

from __future__ import annotations

from typing import Any

import numpy as np


class CycleRecord:
    """Arrays for at most ``n_max`` cycles; ``columns`` maps a name to its per-cycle shape (``()``
    for a scalar, ``(4, 4)`` for a pose, …) or to ``(shape, dtype)``."""

    def __init__(self, n_max: int, **columns: Any) -> None:
        if n_max < 0:
            raise ValueError(f"n_max must be >= 0, got {n_max}")
        self._data: dict[str, np.ndarray] = {}
        for name, spec in columns.items():
            shape, dtype = (
                spec if isinstance(spec, tuple) and len(spec) == 2 and isinstance(spec[0], tuple) else (spec, float)
            )
            self._data[name] = np.empty((n_max, *shape), dtype)
        self.n = 0
        self.n_max = n_max

    @property
    def full(self) -> bool:
        """No room for another cycle."""
        return self.n >= self.n_max

    def add(self, **values: Any) -> None:
        """Append one cycle; every column must be given."""
        if self.full:
            raise IndexError(f"the record holds at most {self.n_max} cycles")
        missing = self._data.keys() - values.keys()
        if missing:
            raise KeyError(f"cycle record: no value for {sorted(missing)}")
        for name, v in values.items():
            self._data[name][self.n] = v
        self.n += 1

    def arrays(self) -> dict[str, np.ndarray]:
        """Copies of the recorded cycles, by column."""
        return {name: a[: self.n].copy() for name, a in self._data.items()}
