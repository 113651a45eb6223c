"""The event-sensor model through the Python binding: counts, timestamps, noise rate, errors."""

import numpy as np
import pytest

from evservo._evcore import EventSimulator, adaptive_dt_us

EVENT_CD = np.dtype(
    {
        "names": ["x", "y", "p", "t"],
        "formats": ["<u2", "<u2", "<i2", "<i8"],
        "offsets": [0, 2, 4, 8],
        "itemsize": 16,
    }
)


def log_i(i: float) -> float:
    # The model takes the log in float32: ln(ε + I) with ε = 1e-3.
    return float(np.log(np.float32(1e-3) + np.float32(i)))


def frame(h: int, w: int, value: float) -> np.ndarray:
    return np.full((h, w), value, dtype=np.float32)


def moving_edge(h: int, w: int, pos: float) -> np.ndarray:
    x = np.arange(w, dtype=np.float64) + 0.5
    ramp = np.clip(x - pos, -0.5, 0.5) + 0.5
    texture = 0.05 * (1 + np.sin(0.7 * np.arange(h)))[:, None]
    return (0.05 + 0.8 * ramp[None, :] + texture).astype(np.float32)


@pytest.mark.parametrize(("i0", "i1", "polarity"), [(0.05, 0.6, 1), (0.7, 0.02, 0)])
def test_uniform_step_counts_and_timestamps(i0: float, i1: float, polarity: int) -> None:
    h, w, t0, t1 = 30, 40, 5_000, 7_000
    sim = EventSimulator(w, h, preset="clean", seed=4)
    sim.reset(frame(h, w, i0), t0)
    ev = sim.step(frame(h, w, i1), t1)
    assert ev.dtype == EVENT_CD
    dl = abs(log_i(i1) - log_i(i0))
    c_on, c_off = sim.thresholds
    c = (c_on if polarity else c_off).astype(np.float64)
    expected = np.floor(dl / c).astype(int)
    counts = np.zeros((h, w), dtype=int)
    np.add.at(counts, (ev["y"], ev["x"]), 1)
    np.testing.assert_array_equal(counts, expected)
    assert np.all(ev["p"] == polarity)
    # The k-th crossing of a pixel lands at t0 + k·C/ΔL·Δt (rounded to the µs).
    order = np.lexsort((ev["t"], ev["y"].astype(int) * w + ev["x"]))
    evs = ev[order]
    k = np.concatenate([np.arange(1, n + 1) for n in expected.ravel()])
    t_expect = t0 + k * c[evs["y"], evs["x"]] / dl * (t1 - t0)
    assert np.max(np.abs(evs["t"] - t_expect)) <= 0.5 + 1e-9
    # Mean count against ΔL/C: ⌊·⌋ drops half an event on average once thresholds are spread.
    nominal = dl / sim.params["c_pos" if polarity else "c_neg"]
    assert abs(counts.mean() + 0.5 - nominal) < 0.3


def test_noisy_static_scene_rate() -> None:
    h = w = 200
    sim = EventSimulator(w, h, preset="noisy", seed=8)
    dark = frame(h, w, 0.0)
    sim.reset(dark, 0)
    n = 0
    n_on = 0
    for k in range(1, 101):
        ev = sim.step(dark, k * 20_000)
        assert np.all(np.diff(ev["t"]) >= 0)
        n += len(ev)
        n_on += int(np.count_nonzero(ev["p"]))
    p = sim.params
    expected = p["shot_noise_rate_hz"] + p["leak_rate_hz"]
    rate = n / (h * w) / 2.0
    assert abs(rate - expected) < 0.1 * expected, (rate, expected)
    assert abs(n_on / n - 0.5) < 0.01


def test_events_sorted_and_seeded() -> None:
    h, w = 48, 64

    def run(seed: int) -> list[np.ndarray]:
        sim = EventSimulator(w, h, preset="noisy", seed=seed, shot_noise_rate_hz=50.0)
        sim.reset(moving_edge(h, w, 5.0), 0)
        return [sim.step(moving_edge(h, w, 5.0 + 1.3 * k), 1000 * k) for k in range(1, 15)]

    a, b, c = run(1), run(1), run(2)
    assert sum(len(e) for e in a) > 1000
    for e in a:
        key = e["t"] * (w * h) + e["y"].astype(np.int64) * w + e["x"]
        assert np.all(np.diff(key) >= 0), "not sorted by (t, pixel)"
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not all(np.array_equal(x, y) for x, y in zip(a, c, strict=True))


def test_refractory_period_is_respected() -> None:
    h, w = 48, 64

    def gaps(refractory_us: int) -> np.ndarray:
        sim = EventSimulator(w, h, preset="imx636", seed=3, refractory_us=refractory_us)
        sim.reset(moving_edge(h, w, 5.0), 0)
        # A quarter pixel per 150 µs: each pixel's ~11 crossings spread over ~600 µs.
        evs = np.concatenate([sim.step(moving_edge(h, w, 5.0 + 0.25 * k), 150 * k) for k in range(1, 61)])
        pix = evs["y"].astype(np.int64) * w + evs["x"]
        order = np.lexsort((evs["t"], pix))
        same = np.diff(pix[order]) == 0
        return np.diff(evs["t"][order])[same]

    free, gated = gaps(0), gaps(400)
    assert free.min() < 400, "the scene must produce close events for the test to mean anything"
    assert gated.size > 500
    assert gated.min() >= 400


def test_step_roi_only_touches_the_region() -> None:
    h, w = 60, 80
    sim = EventSimulator(w, h, preset="clean", seed=2)
    sim.reset(moving_edge(h, w, 12.0), 0)
    x0, y0, rw, rh = 10, 20, 30, 25
    ev = sim.step_roi(moving_edge(h, w, 20.0)[y0 : y0 + rh, x0 : x0 + rw], (x0, y0, rw, rh), 1000)
    assert len(ev) > 100
    assert np.all((ev["x"] >= x0) & (ev["x"] < x0 + rw) & (ev["y"] >= y0) & (ev["y"] < y0 + rh))
    with pytest.raises(ValueError):
        sim.step_roi(frame(rh, rw, 0.5), (70, y0, rw, rh), 2000)


def test_bad_input_raises() -> None:
    with pytest.raises(ValueError):
        EventSimulator(0, 10)
    with pytest.raises(ValueError):
        EventSimulator(10, 10, preset="nope")
    with pytest.raises(ValueError):
        EventSimulator(10, 10, c_pos=-0.2)
    with pytest.raises(ValueError):
        EventSimulator(10, 10, shot_noise_rate_hz=float("nan"))
    with pytest.raises(TypeError):
        EventSimulator(10, 10, threshold=0.2)
    sim = EventSimulator(10, 8)
    with pytest.raises(ValueError):
        sim.reset(frame(10, 8, 0.5), 0)  # transposed
    sim.reset(frame(8, 10, 0.5), 100)
    with pytest.raises(ValueError):
        sim.step(frame(8, 10, 0.5), 100)
    with pytest.raises(ValueError):
        sim.step(frame(8, 10, 0.5), 50)
    bad = frame(8, 10, 0.5)
    bad[3, 4] = -1.0
    with pytest.raises(ValueError):
        sim.step(bad, 200)
    assert sim.time_us == 100
    assert len(sim.step(frame(8, 10, 0.5), 200)) == 0


def test_non_contiguous_frame_equals_contiguous() -> None:
    h, w = 24, 32
    big = np.ascontiguousarray(np.repeat(moving_edge(h, w, 9.0), 2, axis=1))
    a = EventSimulator(w, h, preset="clean", seed=5)
    b = EventSimulator(w, h, preset="clean", seed=5)
    a.reset(moving_edge(h, w, 4.0), 0)
    b.reset(moving_edge(h, w, 4.0), 0)
    ea = a.step(moving_edge(h, w, 9.0), 1000)
    eb = b.step(big[:, ::2], 1000)
    assert len(ea) > 50
    assert np.array_equal(ea, eb)


def test_adaptive_dt() -> None:
    # 0.4 m/s at Z = 0.6 m, fx ≈ 1163.6 px: ~776 px/s, half a pixel every ~645 µs.
    assert adaptive_dt_us(1163.59 * 0.4 / 0.6) == 644
    assert adaptive_dt_us(0.0, 0.5, 50.0) == 20_000
    with pytest.raises(ValueError):
        adaptive_dt_us(-1.0)
