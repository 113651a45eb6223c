"""`evservo bench --suite latency --quick` end to end: the report exists and every row has numbers."""

import json
import math

from evservo.cli import main


def test_latency_suite_quick_writes_a_complete_report(tmp_path):
    assert main(["bench", "--suite", "latency", "--quick", "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "latency.json").read_text())
    rows = result["latency"]
    assert {r["rate_mev_s"] for r in rows} == {5.0, 20.0}
    for r in rows:
        assert r["updates_per_s"] > 0 and r["events_pushed"] > 0
        assert math.isfinite(r["latency_p50_ms"]) and r["latency_p99_ms"] >= r["latency_p50_ms"]
    for solver, c in result["step_costs"].items():
        assert c["updates_per_s"] > 0, solver
    assert result["simulator"]["mev_per_s"] > 0
    assert "| rate Mev/s |" in (tmp_path / "latency.md").read_text()
