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


def test_a_report_put_together_from_two_runs_says_which_figure_is_from_which(tmp_path):
    """Episodes of this code in ``out`` (run A), an older run's summaries for other rows (run B): each row
    is labelled with its run; an episode of older code left in ``out`` is not passed off as this code's."""
    rows = dict((paper.episode_key(cfg), (sec, cfg)) for sec, cfg in paper.plan(quick=False))
    this, older, stale = (
        "box-z0.6-trans-rot-v0.3-edft+-ff-s1-d20",
        "drill-z0.9-trans-v0.2-edft+-s1-d20",
        "box-z0.9-stop-go-v0.3-edft+-ff-s1-d20",
    )
    code = paper.code_version()

    def write(directory, key, servo_mm, stamp=None):
        (directory / key).mkdir(parents=True)
        summary = {**dict.fromkeys(paper.METRICS, 1.0), "servo_pos_rms_mm": servo_mm, "completed": True}
        (directory / key / "summary.json").write_text(json.dumps({**summary, "lost_at_s": None, "loss": {}}))
        if stamp is not None:
            (directory / key / "config_hash").write_text(stamp)

    write(tmp_path / "out" / "episodes", this, 11.5, paper.config_hash(rows[this][1], code))
    write(tmp_path / "out" / "episodes", stale, 9.0, "0" * 64)  # run on other code
    write(tmp_path / "r3", older, 57.7)
    write(tmp_path / "r3", this, 99.0)  # the older run's figure for a row this run has: not used
    episodes, runs = paper.collect(tmp_path / "out", [("B", tmp_path / "r3")])
    assert runs == {this: "A", older: "B"}
    assert {(sec, key) for sec, key, _, _ in episodes} == {(rows[this][0], this), (rows[older][0], older)}
    assert [s["servo_pos_rms_mm"] for _, key, _, s in episodes if key == this] == [11.5]
    text = paper.report(tmp_path / "out", episodes, False, 0.0, runs=runs, run_notes=["A: this code", "B: round 3"])
    assert "- A: this code" in text and "- B: round 3" in text and "episodes run in" not in text
    ff_row = next(line for line in text.splitlines() if line.startswith("| box | 0.6 | trans-rot"))
    drill_row = next(line for line in text.splitlines() if line.startswith("| drill | 0.9 | trans | 0.2"))
    assert f"[1](episodes/{this}/summary.json) (A)" in ff_row and "11.50" in ff_row
    assert f"[1](episodes/{older}/summary.json) (B)" in drill_row and "57.70" in drill_row
