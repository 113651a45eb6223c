"""The tracker's own `lost` flag in the closed loop (issue 12): an occlusion while the camera follows the
object, and events that stop, are flagged within 50 ms and never trusted for more than 100 ms, without
flagging the right poses before them (simulated episodes, fixed cost model so the figures are exact)."""

import pytest

from evservo.sim.episode import EpisodeConfig, run_episode, summarize

DETECT_MS = 50.0
CONFIDENT_WRONG_MS = 100.0
SPELL = (0.55, 0.7)  # s: the target is at speed (its start ramp ends at 0.5 s), the camera following it


@pytest.mark.parametrize("disturbance", ["occlusions", "dropout_s"])
def test_the_object_hidden_or_the_events_stopped_while_the_camera_follows_is_flagged_within_50_ms(disturbance):
    spell = (SPELL,) if disturbance == "occlusions" else SPELL
    cfg = EpisodeConfig(
        duration_s=0.8, speed_mps=0.3, feedforward=True, cost_model="fixed", end_on_loss=False, **{disturbance: spell}
    )
    r = run_episode(cfg)
    loss = summarize(r)["loss"]
    assert loss["wrong_spells"] >= 1 and loss["undetected_spells"] == 0, loss
    assert loss["loss_detection_delay_ms"] <= DETECT_MS, loss
    assert loss["confident_wrong_ms"] <= CONFIDENT_WRONG_MS, loss
    assert not r.lost[r.t_s < SPELL[0]].any(), "a right pose before the spell was flagged lost"
    assert r.lost[(r.t_s >= SPELL[0] + DETECT_MS * 1e-3) & (r.t_s < SPELL[1])].all()
