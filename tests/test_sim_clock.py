"""The simulated clock's two timelines (:class:`evservo.sim.episode.ClockedTracker`): ingest is charged
to the producer, steps to the solver, and a step sees only the batches whose ingest has started."""

from types import SimpleNamespace

import numpy as np

from evservo.events import EVENT_CD
from evservo.sim.episode import ClockedTracker, EpisodeConfig, _cost_model


class _Core:
    """Stands in for the synchronous tracker: remembers the newest event time it has ingested, and
    stamps each step with it (as the solver stamps an estimate with the newest ingested event)."""

    cycle_len = 5

    def __init__(self) -> None:
        self.newest_t_us = -1
        self.seq = 0

    def ingest(self, events: np.ndarray, thin: bool = False) -> None:
        self.newest_t_us = int(events["t"][-1])

    def step(self, n: int = 1) -> SimpleNamespace:
        self.seq += n
        return SimpleNamespace(step="search", seq=self.seq, t_us=self.newest_t_us, lost=False)


def _batch(t_us: int, n: int) -> np.ndarray:
    ev = np.zeros(n, EVENT_CD)
    ev["t"] = t_us
    return ev


def _run(ingest_event_cost_s: float, n_batches: int = 40, events_per_batch: int = 500):
    """Batches of ``events_per_batch`` events every 1000 µs (event time = arrival time); search
    steps cost 100 µs. Returns the clock and (publish time, stamp) of every published estimate."""
    cfg = EpisodeConfig(cost_model="fixed", search_cost_s=1e-4, ingest_event_cost_s=ingest_event_cost_s)
    clock = ClockedTracker(_Core(), _cost_model(cfg), thin=False)  # type: ignore[arg-type]
    published = []
    for k in range(n_batches):
        t = k * 1000
        clock.deliver(t, _batch(t, events_per_batch))
        for now in range(t, t + 1000, 50):
            clock.advance(now)
            est = clock.latest(now)
            if not published or published[-1][1] != est.t_us:
                published.append((now, est.t_us))
    return clock, published


def test_ingest_is_charged_to_the_producer_not_the_solver():
    cheap, _ = _run(1e-9)
    dear, _ = _run(1.6e-6)  # 800 µs of ingest per 1000 µs batch: the producer is busy 80 %
    # The solver's timeline holds its steps only: the same number at the same cost either way.
    assert dear.steps == cheap.steps and dear.busy_us == cheap.busy_us == 100 * cheap.steps["search"]
    assert dear.ingest_busy_us == 40 * 800
    assert cheap.ingest_busy_us == 40 * 1  # 0.5 µs rounds up to the 1 µs minimum per batch


def test_a_producer_slower_than_the_stream_falls_behind():
    _, keeping_up = _run(1.6e-6)
    _, behind = _run(3e-6)  # 1500 µs of ingest per 1000 µs batch
    lag = lambda pub: max(now - stamp for now, stamp in pub[len(pub) // 2 :])  # noqa: E731
    # Keeping up, a batch is visible as soon as its ingest starts: a stamp is first seen one step
    # (100 µs) after its batch arrived, within the 50 µs sampling.
    assert lag(keeping_up) <= 100 + 50
    # Behind, each batch starts 500 µs later than the one before: 20 batches in, ≥ 10 ms behind.
    assert lag(behind) >= 10_000
