"""Scoring the tracker's lost flag (evservo.runtime.loss), the stream disturbances of the simulated bench
(evservo.sim.disturb) and the episode's reaction to a lost object, with a tracker whose lost flag is an
oracle of the occlusion (the honest flag itself is the tracker's business, tested with it)."""

from dataclasses import dataclass, replace

import numpy as np
import pytest

from evservo import _evcore
from evservo.commands.servo import parse_spells
from evservo.geometry import pose_errors
from evservo.robots.limits import PANDA_CARTESIAN
from evservo.runtime.loss import loss_metrics, reappearances, spells, wrong_pose
from evservo.sim import episode
from evservo.sim.disturb import HIDDEN_T_C_O, Disturbances
from evservo.sim.episode import EpisodeConfig, run_episode, summarize
from evservo.sim.sources import EDGE_NOISE_RATE_HZ, edge_source
from evservo.tracking import Tracker, model_point_set


def test_wrong_pose_bounds_scale_with_depth():
    mm = 1e-3
    assert wrong_pose(np.array([31 * mm, 29 * mm]), np.zeros(2), np.full(2, 0.6)).tolist() == [True, False]
    # At 1.2 m the bounds double: 59 mm and 19° are still right, 61 mm is not.
    assert wrong_pose(np.array([59 * mm, 61 * mm, 0.0]), np.deg2rad([0, 0, 19]), np.full(3, 1.2)).tolist() == [
        False, True, False,
    ]  # fmt: skip


def test_loss_metrics_on_a_scripted_run():
    t = np.arange(1000) * 1e-3
    visible = ~((t >= 0.2) & (t < 0.4))  # hidden 200–400 ms
    wrong = ~visible | ((t >= 0.4) & (t < 0.45))  # and wrong until re-locked at 450 ms
    lost = (t >= 0.23) & (t < 0.47)  # flagged 30 ms late, cleared 20 ms after the pose is right again
    lost |= (t >= 0.8) & (t < 0.81)  # a false loss of 10 ms
    m = loss_metrics(t, lost, wrong, visible)
    assert m["loss_detection_delay_ms"] == pytest.approx(30.0)
    assert m["confident_wrong_ms"] == pytest.approx(30.0) and m["confident_wrong_total_ms"] == pytest.approx(30.0)
    assert m["relock_ms"] == pytest.approx(70.0)  # from 400 ms to the first right, trusted pose at 470 ms
    right = visible & ~wrong
    assert m["false_loss_rate"] == pytest.approx((20 + 10) / right.sum())
    assert m["wrong_spells"] == 1 and m["undetected_spells"] == 0
    never = loss_metrics(t, np.zeros(1000, bool), wrong, visible)
    assert never["relock_ms"] == pytest.approx(50.0) and never["loss_detection_delay_ms"] == pytest.approx(250.0)
    assert never["undetected_spells"] == 1
    assert loss_metrics(t, lost & (t < 0.45), wrong, visible)["relock_ms"] == pytest.approx(50.0)
    gone = loss_metrics(t, np.ones(1000, bool), wrong, visible)
    assert gone["relock_ms"] == float("inf")
    assert spells(np.array([0, 1, 1, 0, 1], bool)) == [(1, 3), (4, 5)]
    assert reappearances(t[:4], np.array([1, 0, 0, 1], bool), started_lost=True) == [0.0, 0.003]


def test_an_occluded_object_fires_no_event_and_the_background_goes_on():
    cam = _evcore.Camera.imx636()
    T0 = episode.geometry.pose((0.0, 0.0, 0.7), (0.35, -0.45, 0.1))
    src = edge_source(cam, "box", T0, 0, seed=3)
    d = Disturbances(cam.width, cam.height, occlusions=((0.1, 0.2),), seed=3)
    uv = cam.project(model_point_set(cam, "box", T0, 400) @ T0[:3, :3].T + T0[:3, 3])
    (x0, y0), (x1, y1) = uv.min(axis=0) - 20, uv.max(axis=0) + 20
    box_share = (x1 - x0) * (y1 - y0) / (cam.width * cam.height)
    counts, on_object = [], []
    for k in range(1, 300):
        T = T0.copy()
        T[0, 3] += 0.2 * k * 1e-3  # 0.2 m/s across the view
        ev = d.events(k * 1000 - 1000, k * 1000, src.events_until(k * 1000, d.source_pose(src, k * 1000, T)))
        inside = (ev["x"] >= x0) & (ev["x"] <= x1) & (ev["y"] >= y0) & (ev["y"] <= y1)
        counts.append(len(ev))
        on_object.append(int(inside.sum()))
    counts, on_object = np.array(counts), np.array(on_object)
    hidden = slice(100, 199)  # batches ending in [0.1, 0.2) s
    assert np.allclose(d.source_pose(src, 150_000, T0), HIDDEN_T_C_O)
    # Outside the spell the object fires hundreds of events a millisecond; inside only the background
    # (50 kev/s: 50 a millisecond over the whole sensor) and no more on the object than its share of it.
    assert counts[:99].mean() > 300 and counts[200:].mean() > 300
    assert abs(counts[hidden].mean() - EDGE_NOISE_RATE_HZ * 1e-3) < 5
    assert on_object[hidden].sum() < 3 * box_share * counts[hidden].sum() + 10


def test_dropout_and_noise_spells():
    d = Disturbances(1280, 720, dropout=(0.0, 0.001), noise=(0.001, 0.002), noise_rate_hz=1e7, seed=1)
    ev = np.zeros(100, episode._evcore.EVENT_CD)
    ev["t"] = np.arange(100) * 20  # 0–2 ms
    kept = d.events(0, 2000, ev)
    scene = kept[kept["t"] < 1000]
    assert len(scene) == 0  # the dropout ate the first millisecond
    assert abs(len(kept) - 10_000) < 500  # the second is 10 Mev/s of noise only (Poisson, ±5 σ)
    assert np.all(np.diff(kept["t"]) >= 0)
    assert not d.seen(0.0005) and not d.seen(0.0015) and d.seen(0.0025)


def test_bad_spells_are_refused():
    with pytest.raises(ValueError, match="occlusions"):
        EpisodeConfig(occlusions=((0.5, 0.2),))
    with pytest.raises(ValueError, match="false_losses"):
        EpisodeConfig(false_losses=((0.3, 0.3),))
    with pytest.raises(ValueError, match="coast_s"):
        EpisodeConfig(coast_s=-0.1)
    with pytest.raises(ValueError, match="--occlude"):
        parse_spells(["1:x"])
    assert parse_spells(["1:2,0.2:0.5", "3:4"]) == ((0.2, 0.5), (1.0, 2.0), (3.0, 4.0))


@dataclass
class _Est:
    T_c_o: np.ndarray
    t_us: int
    seq: int
    step: str
    lost: bool


class _OracleTracker:
    """The real tracker, but flagging the object lost from 5 ms into each occlusion until 30 ms after it."""

    def __init__(self, spells_s, *args, **kwargs):
        self._core = Tracker(*args, **kwargs)
        self.spells = spells_s
        self.cycle_len = self._core.cycle_len

    def ingest(self, events, thin=False):
        self._core.ingest(events, thin=thin)

    def advance_time(self, t_us):
        self._core.advance_time(t_us)

    def step(self, n=1):
        e = self._core.step(n)
        t = e.t_us * 1e-6
        lost = e.lost or any(a + 0.005 <= t < b + 0.03 for a, b in self.spells)
        return _Est(e.T_c_o, e.t_us, e.seq, e.step, lost)


def test_the_episode_holds_still_while_lost_and_keeps_the_desired_pose(monkeypatch):
    occ = ((0.35, 0.65),)
    monkeypatch.setattr(episode, "Tracker", lambda *a, **k: _OracleTracker(occ, *a, **k))
    cfg = EpisodeConfig(
        duration_s=0.75, speed_mps=0.4, cost_model="fixed", occlusions=occ, end_on_loss=False, feedforward=True
    )
    r = run_episode(cfg)
    s = summarize(r)
    speed = np.linalg.norm(r.v_cmd_w[:, :3], axis=1)
    lost_from = r.t_s[np.argmax(r.lost)]
    assert 0.35 + 0.005 <= lost_from <= 0.35 + 0.005 + cfg.sensing_latency_s + 0.003
    v0 = speed[np.searchsorted(r.t_s, lost_from) - 1]
    assert v0 > 0.05, "the camera must be moving when the object is lost"
    # It follows the predicted motion until the newest trusted pose (taken before lost_from) is
    # coast_s old, no longer; then brakes at the controller's acceleration limit (the Panda's), and
    # stays at rest until re-lock.
    coast = r.coasting & r.lost
    assert coast.any() and r.t_s[coast].max() <= lost_from + cfg.coast_s
    at_rest = (r.t_s >= lost_from + cfg.coast_s + v0 / PANDA_CARTESIAN.max_lin_acc + 0.004) & r.lost
    braking = r.lost & ~r.coasting
    dv = np.linalg.norm(np.diff(r.v_cmd_w[:, :3], axis=0), axis=1)
    assert dv[braking[1:]].max() <= PANDA_CARTESIAN.max_lin_acc * cfg.control_period_s * (1 + 1e-9)
    assert at_rest.sum() > 100 and np.all(speed[at_rest] == 0.0)
    assert np.all(r.holding[braking])
    # The desired pose is still the start pose (the tracker's start estimate), not one from the loss.
    np.testing.assert_allclose(r.T_c_o_des, r.T_c_o_true[0], atol=1e-9)
    loss = s["loss"]
    assert loss["loss_detection_delay_ms"] <= 10.0 + 1e3 * cfg.sensing_latency_s
    assert loss["holding_s"] >= 0.2 and 0.09 <= loss["coasting_s"] <= cfg.coast_s


def test_a_short_false_loss_does_not_cost_the_episode():
    """The tracker's flag forced on for 60 ms and 50 ms while its pose is right (the false losses of the
    rendered drill episode): coasting on the predicted motion, the camera keeps the object where it was
    (true servo error as without the losses); braking at once (coast_s = 0), each loss costs a hold, a
    restart and a ramp, and the object runs ~0.1 m off the desired pose."""
    spells = ((0.7, 0.76), (1.0, 1.05))
    base = EpisodeConfig(duration_s=1.3, speed_mps=0.4, cost_model="fixed", feedforward=True, false_losses=spells)
    errors = {}
    for coast_s in (0.1, 0.0):
        r = run_episode(replace(base, coast_s=coast_s))
        s = summarize(r)
        assert s["completed"] and s["loss"]["false_loss_rate"] == pytest.approx(0.11 / 1.3, abs=0.002)
        g_pos, _ = pose_errors(r.T_c_o_true, np.broadcast_to(r.T_c_o_des, (len(r.t_s), 4, 4)))
        errors[coast_s] = (g_pos[r.t_s >= 0.7].max(), g_pos[(r.t_s >= 0.5) & (r.t_s < 0.7)].max(), s["loss"])
    worst, before, loss = errors[0.1]
    assert loss["holding_s"] == 0.0 and loss["coasting_s"] == pytest.approx(0.11, abs=0.004)
    assert worst < before + 0.005, (worst, before)
    worst0, _, loss0 = errors[0.0]
    assert loss0["holding_s"] > 0.5 and loss0["coasting_s"] == 0.0
    assert worst0 > 0.05 and worst0 > 5 * worst, (worst0, worst)


def test_leave_return_dashes_out_and_comes_back_elsewhere():
    from evservo import trajectories

    traj = trajectories.make_trajectory("leave-return", speed_mps=1.5)
    p = traj(np.linspace(0, 4, 401))[:, :3, 3]
    x = p @ trajectories.LEAVE_DIR  # across the view: no part along the start view's direction
    assert abs(trajectories.LEAVE_DIR @ np.array([0.5, 0.75, 0.05])) < 0.01
    assert x.max() == pytest.approx(trajectories.LEAVE_M, abs=1e-9)
    assert x[-1] == pytest.approx(0.3 * trajectories.LEAVE_M, abs=1e-9)
    assert p[-1, 2] == pytest.approx(-0.05, abs=1e-9)
    v = np.abs(np.diff(x)) / 0.01
    assert v.max() == pytest.approx(1.5, rel=0.02)
