"""est.confidence and est.lost on scripted streams (evservo.sim.scenarios): the pose turning wrong is
flagged within 50 ms and never trusted for more than 100 ms, and a locked pose is not flagged."""

from dataclasses import replace

import numpy as np
import pytest

from evservo import _evcore
from evservo.sim.scenarios import run_scenario, scenarios, score
from evservo.tracking import Tracker

DETECT_MS = 50.0
CONFIDENT_WRONG_MS = 100.0


def _short(name: str, **changes):
    return replace(scenarios()[name], **changes)


def test_a_locked_pose_is_confident_and_not_lost():
    run = run_scenario(_short("tracking", duration_s=0.3))
    assert not run.wrong.any(), "the tracker must stay on the object in this easy case"
    s = score(run)
    assert s["false_loss"] <= 0.01, s
    assert np.median(run.confidence) > 0.3, np.percentile(run.confidence, [1, 50, 99])


def test_pure_noise_after_lock_is_flagged_within_50_ms():
    noisy = lambda t: t >= 0.2  # noqa: E731
    sc = _short("pure-noise", duration_s=0.3, hidden=noisy, noise_hz=lambda t: 1e7 if t >= 0.2 else 0.0)
    run = run_scenario(sc)
    s = score(run)
    after = run.t_s >= 0.2 + DETECT_MS * 1e-3
    assert run.lost[after].all(), "10 Mev/s of noise must never look like the object"
    assert s["detection_delay_ms"] <= DETECT_MS and s["confident_wrong_ms"] <= CONFIDENT_WRONG_MS, s
    assert s["false_loss"] <= 0.01, s


def test_events_stopping_while_the_object_moves_is_flagged_within_50_ms():
    hide = lambda t: 0.25 <= t < 0.4  # noqa: E731
    run = run_scenario(_short("events-stop", duration_s=0.4, hidden=hide, reappear_s=None))
    s = score(run)
    assert s["detection_delay_ms"] <= DETECT_MS and s["confident_wrong_ms"] <= CONFIDENT_WRONG_MS, s
    assert run.lost[run.t_s >= 0.25 + DETECT_MS * 1e-3].all()


def test_a_wrong_model_is_never_trusted_for_long():
    run = run_scenario(_short("wrong-model", duration_s=0.3))
    s = score(run)
    assert run.wrong.all()
    assert s["confident_wrong_ms"] <= CONFIDENT_WRONG_MS, s


def test_an_object_leaving_fast_is_flagged_within_50_ms():
    run = run_scenario(_short("fast-leave", duration_s=0.7))
    s = score(run)
    assert not run.visible[-1], "the object must have left by the end"
    assert s["detection_delay_ms"] <= DETECT_MS and s["confident_wrong_ms"] <= CONFIDENT_WRONG_MS, s


def test_starting_without_a_pose_needs_the_search_and_starts_lost():
    cam = _evcore.Camera.imx636()
    with pytest.raises(ValueError, match="reacquire"):
        Tracker(cam, "box", None, reacquire=False)
    with pytest.raises(ValueError, match="mesh"):
        _evcore.Tracker(cam, None, None)
    with pytest.raises(ValueError, match="both"):
        _evcore.Tracker(cam, None, np.eye(4))
    tracker = Tracker(cam, "box", None, view_spacing_deg=40.0)
    est = tracker.latest()
    assert est.lost and est.confidence == 0.0
