"""`evservo bench --suite latency --quick` end to end: the report exists and every row has numbers."""

import json
import math
from pathlib import Path

import pytest

from evservo.cli import main


def test_latency_suite_quick_writes_a_complete_report(tmp_path):
    results_md = tmp_path / "RESULTS.md"
    results_md.write_text("# Measured figures\n\nhand-written analysis\n")
    assert main(["bench", "--suite", "latency", "--quick", "--out", str(tmp_path), "--results", str(results_md)]) == 0
    result = json.loads((tmp_path / "latency.json").read_text())
    rows = result["latency"]
    assert {r["rate_mev_s"] for r in rows} == {5.0, 20.0}
    for r in rows:
        assert r["updates_per_s"] > 0 and r["events_pushed"] > 0
        assert math.isfinite(r["latency_p50_ms"]) and r["latency_p99_ms"] >= r["latency_p50_ms"]
        # Each batch's own latency: at least the newest stamp's of its pose, at most the pose's bound.
        assert r["event_p50_ms"] <= r["event_p99_ms"] <= r["event_max_ms"] <= r["oldest_max_ms"]
        assert r["latency_max_ms"] <= r["event_max_ms"]
    for solver, c in result["step_costs"].items():
        assert c["updates_per_s"] > 0, solver
    assert result["simulator"]["mev_per_s"] > 0
    assert "| rate Mev/s |" in (tmp_path / "latency.md").read_text()
    refreshed = results_md.read_text()
    assert "hand-written analysis" in refreshed and "<!-- bench:latency -->" in refreshed
    assert "| rate Mev/s |" in refreshed and "Command: `evservo bench --suite latency --quick" in refreshed


# 21 episodes: a few minutes on a quiet 2-core machine, past the default hang guard at load 25.
@pytest.mark.timeout(1800)
def test_paper_suite_quick_runs_end_to_end_and_every_row_has_numbers(tmp_path):
    import re

    assert main(["bench", "--suite", "paper", "--quick", "--jobs", "2", "--out", str(tmp_path)]) == 0
    report = (tmp_path / "report.md").read_text()
    for title in ("## Table I", "## Table II", "## Fig. 2", "feed-forward", "speed sweep", "## Fig. 5", "update rates",
                  "target predictor"):  # fmt: skip
        assert title in report, title
    rows = [line for line in report.splitlines() if re.match(r"\| (box|drill|football) \|", line)]
    assert len(rows) >= 12
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        servo, true_servo, tracking = cells[9], cells[11], cells[12]
        for cell in (servo, true_servo, tracking):
            assert re.fullmatch(r"\d+\.\d\d / \d+\.\d\d", cell), row
        assert "summary.json" in cells[-1]
    results = json.loads((tmp_path / "results.json").read_text())
    assert len(results["episodes"]) == 21
    assert (tmp_path / "fig5_motion.png").stat().st_size > 10_000
    # A rerun reuses every finished episode; refreshing a results file copies what its tables link to.
    before = {p: p.stat().st_mtime for p in tmp_path.glob("episodes/*/summary.json")}
    md = tmp_path / "benches" / "RESULTS.md"
    md.parent.mkdir()
    md.write_text("# Measured figures\n")
    assert main(["bench", "--suite", "paper", "--quick", "--out", str(tmp_path), "--results", str(md)]) == 0
    assert {p: p.stat().st_mtime for p in tmp_path.glob("episodes/*/summary.json")} == before
    assert "0 episodes run in" in md.read_text() and "(21 reused from an earlier run)" in md.read_text()
    targets = re.findall(r"\]\(([^)]+)\)", md.read_text())
    assert sum(t.endswith("summary.json") for t in targets) >= 12 and "paper-run/fig5_motion.png" in targets
    for t in targets:
        copied = md.parent / t
        assert copied.is_file() and copied.resolve().is_relative_to(md.parent.resolve()), t
        original = tmp_path / Path(t).relative_to("paper-run")
        assert copied.read_bytes() == original.read_bytes(), t
