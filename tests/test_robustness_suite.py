"""evservo bench --suite robustness: its plan covers the issue's scenarios for the three solvers, and its
episodes are cached by configuration hash like the paper suite's (a rerun reuses them)."""

import json
from dataclasses import replace

from evservo.bench import robustness
from evservo.sim.episode import EpisodeConfig


def test_the_plan_covers_the_issue_scenarios_for_every_solver():
    names = {name for name, _ in robustness.plan()}
    assert names == {"occlusion-0.5s", "occlusion-2s", "leave-return", "events-stop", "wrong-model", "pure-noise",
                     "start-without-pose"}  # fmt: skip
    solvers = {cfg.tracker for _, cfg in robustness.plan()}
    assert solvers == {"edft+", "edopts", "edft"}
    assert all(not cfg.end_on_loss and cfg.event_source == "edges" for _, cfg in robustness.plan())
    keys = [robustness.episode_key(n, c) for n, c in robustness.plan()]
    assert len(set(keys)) == len(keys)


def test_every_disturbance_leaves_time_to_see_a_relock_within_the_bound():
    # A re-lock slower than the time left after a disturbance reads "never": each episode runs 0.6 s past its
    # disturbance, twice the issue's 0.3 s re-lock bound (pure-noise once ran only 0.2 s past it).
    for quick in (False, True):
        for name, cfg in robustness.scenarios(quick).items():
            spells = [
                *cfg.occlusions,
                *([cfg.dropout_s] if cfg.dropout_s else []),
                *([cfg.noise_s] if cfg.noise_s else []),
            ]
            if spells:
                end = max(t1 for _, t1 in spells)
                assert cfg.duration_s >= end + 0.6 - 1e-9, name


def test_a_rerun_reuses_the_finished_episodes(tmp_path, monkeypatch):
    short = EpisodeConfig(duration_s=0.25, cost_model="fixed", end_on_loss=False, occlusions=((0.1, 0.2),))
    monkeypatch.setattr(robustness, "scenarios", lambda quick=False: {"occlusion-0.1s": short})
    first = robustness.run(tmp_path, quick=True)
    assert first["reused"] == 0 and len(first["rows"]) == 1
    loss = first["rows"][0]["summary"]["loss"]
    assert loss["wrong_spells"] >= 1  # the object was hidden: every pose in the spell is wrong
    md = (tmp_path / "robustness.md").read_text()
    assert "| occlusion-0.1s | edft+ |" in md
    again = robustness.run(tmp_path, quick=True)
    assert again["reused"] == 1
    assert json.loads((tmp_path / "robustness.json").read_text())["rows"][0]["summary"]["loss"] == loss
    # Another configuration under the same key is not taken for the cached one.
    monkeypatch.setattr(
        robustness, "scenarios", lambda quick=False: {"occlusion-0.1s": replace(short, occlusions=((0.1, 0.15),))}
    )
    assert robustness.run(tmp_path, quick=True)["reused"] == 0
