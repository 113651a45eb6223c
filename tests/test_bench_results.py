"""benches/RESULTS.md refresh: generated sections are replaced in place, hand-written text survives."""

import json

import pytest

from evservo.bench.results import criterion_table, embed_report, main, splice


def test_splice_replaces_only_its_section_and_appends_missing_ones(tmp_path):
    md = tmp_path / "RESULTS.md"
    md.write_text("# Results\n\nanalysis above\n\n<!-- bench:paper -->\nold numbers\n<!-- /bench:paper -->\n\nbelow\n")
    splice(md, "paper", "new numbers 1.23")
    splice(md, "latency", "p50 1.6 ms")
    text = md.read_text()
    assert "old numbers" not in text and "new numbers 1.23" in text
    assert text.index("analysis above") < text.index("new numbers") < text.index("below") < text.index("p50 1.6 ms")
    splice(md, "paper", "third")
    assert md.read_text().count("<!-- bench:paper -->") == 1 and "new numbers" not in md.read_text()


def test_splice_refuses_unpaired_markers(tmp_path):
    md = tmp_path / "RESULTS.md"
    md.write_text("<!-- /bench:paper -->\n<!-- bench:paper -->\n")
    with pytest.raises(ValueError, match="unpaired or out of order"):
        splice(md, "paper", "x")
    with pytest.raises(ValueError, match="section name"):
        splice(md, "Paper Suite", "x")


def test_embed_report_demotes_headings_and_reroots_links_and_images(tmp_path):
    out, results_dir = tmp_path / "out" / "paper", tmp_path / "benches"
    md = "# Suite\n\n## Table I\n\n![Fig. 5](fig5_motion.png) lag 0.4 s\n| a | [1](episodes/k/summary.json) |"
    text = embed_report(md, out, results_dir)
    assert text.splitlines()[0] == "## Suite" and "### Table I" in text
    assert "(plot: `../out/paper/fig5_motion.png`) lag 0.4 s" in text and "![" not in text
    assert "[1](../out/paper/episodes/k/summary.json)" in text
    assert embed_report("[docs](https://x.org/a)", out, results_dir) == "[docs](https://x.org/a)"


def test_embed_report_copies_linked_files_beside_the_results(tmp_path):
    out, results_dir = tmp_path / "out" / "paper", tmp_path / "benches"
    (out / "episodes" / "k").mkdir(parents=True)
    (out / "episodes" / "k" / "summary.json").write_text('{"completed": true}')
    (out / "fig5_motion.png").write_bytes(b"png")
    md = "![Fig. 5](fig5_motion.png)\n| a | [1](episodes/k/summary.json) | [web](https://x.org) |"
    text = embed_report(md, out, results_dir, results_dir / "paper-run")
    assert "![Fig. 5](paper-run/fig5_motion.png)" in text and "[1](paper-run/episodes/k/summary.json)" in text
    assert "[web](https://x.org)" in text
    assert (results_dir / "paper-run" / "episodes" / "k" / "summary.json").read_text() == '{"completed": true}'
    with pytest.raises(FileNotFoundError, match="links to it"):
        embed_report("[2](episodes/missing/summary.json)", out, results_dir, results_dir / "paper-run")


def test_criterion_table_reads_means_and_throughput(tmp_path):
    d = tmp_path / "decode" / "evt3" / "new"
    d.mkdir(parents=True)
    (d / "benchmark.json").write_text(json.dumps({"full_id": "decode/evt3", "throughput": {"Elements": 2_000_000}}))
    ci = {"lower_bound": 9.9e6, "upper_bound": 10.1e6}
    (d / "estimates.json").write_text(json.dumps({"mean": {"point_estimate": 10e6, "confidence_interval": ci}}))
    d = tmp_path / "tracker" / "update" / "new"
    d.mkdir(parents=True)
    (d / "benchmark.json").write_text(json.dumps({"full_id": "tracker/update", "throughput": {"Elements": 1}}))
    (d / "estimates.json").write_text(json.dumps({"mean": {"point_estimate": 500e3, "confidence_interval": ci}}))
    table = criterion_table(tmp_path)
    assert "| `decode/evt3` | 10 ms ± 100 µs | 200.0 M elements/s |" in table
    assert "| `tracker/update` | 500 µs ± 100 µs | 2000 elements/s |" in table
    md = tmp_path / "R.md"
    assert main(["criterion", str(tmp_path), str(md)]) == 0
    assert "decode/evt3" in md.read_text()
    with pytest.raises(FileNotFoundError, match="cargo bench"):
        criterion_table(tmp_path / "nothing")
