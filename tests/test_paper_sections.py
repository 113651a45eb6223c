"""`evservo bench --suite paper --sections`: only the named sections' episodes run, and the report says so."""

import json

import pytest

from evservo.bench import paper
from evservo.cli import main


def test_sections_pick_their_episodes_and_nothing_else():
    full = paper.plan(quick=False)
    picked = paper.plan(quick=False, sections=("feedforward", "sweep", "predictor"))
    assert picked == [(sec, cfg) for sec, cfg in full if sec in ("feedforward", "sweep", "predictor")]
    # Issue 14's rows: 5 feed-forward rows x 3 seeds, 8 speeds x 2 trackers, 2 trajectories x 2 predictors.
    assert [sum(sec == s for sec, _ in picked) for s in ("feedforward", "sweep", "predictor")] == [15, 16, 4]
    assert all(cfg.feedforward for _, cfg in picked)
    assert paper.plan(quick=False, sections=paper.SECTIONS) == full
    for bad in (("sweep", "tabel1"), ()):
        with pytest.raises(ValueError, match="paper-suite section"):
            paper.plan(quick=False, sections=bad)


def test_bad_sections_are_refused_before_any_episode_runs(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["bench", "--suite", "paper", "--sections", "sweep,nope", "--out", str(out)]) == 2
    assert "paper-suite section" in capsys.readouterr().err and not out.exists()
    assert main(["bench", "--suite", "latency", "--sections", "sweep", "--out", str(out)]) == 2
    assert "--sections applies to the paper suite only" in capsys.readouterr().err


def test_one_section_runs_alone_and_its_report_says_which(tmp_path, monkeypatch):
    """Which episodes run and what the report says; the episodes themselves are stand-ins (the quick suite
    of tests/test_bench.py runs real ones)."""
    ran = []

    def episode(cfg, out_dir):
        ran.append(paper.episode_key(cfg))
        metrics = dict.fromkeys(paper.METRICS, 1.0)
        return {**metrics, "completed": True, "lost_at_s": None, "overshoot_mm": 2.5, "loss": {}}

    monkeypatch.setattr(paper, "_run_one", episode)
    assert main(["bench", "--suite", "paper", "--sections", "predictor", "--out", str(tmp_path)]) == 0
    results = json.loads((tmp_path / "results.json").read_text())
    planned = [(e["section"], e["config"]["trajectory"], e["config"]["predictor"]) for e in results["episodes"]]
    assert sorted(planned) == sorted(
        ("predictor", traj, pred) for traj in ("stop-go", "reversal") for pred in ("velocity", "acceleration")
    )
    assert sorted(ran) == sorted(e["key"] for e in results["episodes"])
    assert "--sections predictor" in results["command"]
    report = (tmp_path / "report.md").read_text()
    assert "**Sections run: predictor**" in report and "--sections predictor" in report
    assert report.count("| stop-go |") == 2 and report.count("| reversal |") == 2
    assert "| box |" not in report  # no table row of another section
