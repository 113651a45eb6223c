"""Keep ``benches/RESULTS.md`` in step with the last benchmark run.

Generated sections sit between marker comments ``<!-- bench:NAME -->`` and ``<!-- /bench:NAME -->``;
:func:`splice` replaces what lies between them and leaves every hand-written line alone, so a
``make bench`` run refreshes the figures without touching the analysis around them. A section whose
markers are missing is appended at the end.

Command line (what ``make bench`` calls after ``cargo bench``)::

    python -m evservo.bench.results criterion target/criterion benches/RESULTS.md
"""

from __future__ import annotations

import json
import os
import re
import shutil
import sys
from pathlib import Path


def _markers(name: str) -> tuple[str, str]:
    if not re.fullmatch(r"[a-z0-9_-]+", name):
        raise ValueError(f"section name must be lower-case letters, digits, '-' or '_': {name!r}")
    return f"<!-- bench:{name} -->", f"<!-- /bench:{name} -->"


def splice(path: Path, name: str, body: str) -> None:
    """Replace section ``name`` of the markdown file ``path`` with ``body`` (created if absent)."""
    begin, end = _markers(name)
    text = path.read_text() if path.exists() else ""
    block = f"{begin}\n{body.strip()}\n{end}"
    i, j = text.find(begin), text.find(end)
    if (i < 0) != (j < 0) or j < i:
        raise ValueError(f"{path}: markers of section {name!r} are unpaired or out of order")
    if i < 0:
        text = (text.rstrip() + "\n\n" if text.strip() else "") + block + "\n"
    else:
        text = text[:i] + block + text[j + len(end) :]
    path.write_text(text)


def embed_report(report_md: str, source_dir: Path, results_dir: Path, artifacts: Path | None = None) -> str:
    """A suite's report made fit for a results file in ``results_dir``: headings one level down (the
    results file owns the top levels) and local links and images re-rooted.

    The suite writes into an untracked directory (``source_dir``). With ``artifacts`` (a directory
    beside the results file, e.g. ``benches/paper``), every file the report links to is copied there,
    keeping its path relative to ``source_dir``, so the committed results stay traceable to each
    episode's ``summary.json`` and show their plots; without it, links point into ``source_dir``
    and images become their paths."""
    home = source_dir if artifacts is None else artifacts
    root = Path(os.path.relpath(home, results_dir))

    def local(target: str) -> str | None:
        if re.match(r"[a-z]+:|/|#", target):
            return None
        if artifacts is not None:
            src = source_dir / target
            if not src.is_file():
                raise FileNotFoundError(f"{src}: the report links to it, but it does not exist")
            dst = artifacts / target
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, dst)
        return (root / target).as_posix()

    def image(m: re.Match) -> str:
        path = local(m[2])
        if path is None:
            return m[0]
        return f"![{m[1]}]({path})" if artifacts is not None else f"(plot: `{path}`)"

    def link(m: re.Match) -> str:
        path = local(m[2])
        return m[0] if path is None else f"[{m[1]}]({path})"

    lines = []
    for line in report_md.splitlines():
        if line.startswith("#"):
            line = "#" + line
        line = re.sub(r"!\[([^\]]*)\]\(([^)]+)\)", image, line)
        lines.append(re.sub(r"(?<!!)\[([^\]]*)\]\(([^)]+)\)", link, line))
    return "\n".join(lines)


def _human_time(ns: float) -> str:
    for unit, scale in (("s", 1e9), ("ms", 1e6), ("µs", 1e3)):
        if ns >= scale:
            return f"{ns / scale:.3g} {unit}"
    return f"{ns:.3g} ns"


def criterion_table(root: Path) -> str:
    """Markdown table of every criterion benchmark's latest mean (and throughput) under ``root``
    (``target/criterion``)."""
    rows = []
    for meta in sorted(root.glob("**/new/benchmark.json")):
        info = json.loads(meta.read_text())
        est = json.loads((meta.parent / "estimates.json").read_text())
        mean_ns = est["mean"]["point_estimate"]
        half_ns = 0.5 * (
            est["mean"]["confidence_interval"]["upper_bound"] - est["mean"]["confidence_interval"]["lower_bound"]
        )
        rate = ""
        throughput = info.get("throughput") or {}
        if "Elements" in throughput:
            per_s = throughput["Elements"] / mean_ns * 1e9
            # Per-update benches count one element per call: a rate in millions would read 0.0.
            rate = f"{per_s / 1e6:.1f} M elements/s" if per_s >= 1e6 else f"{per_s:.0f} elements/s"
        elif "Bytes" in throughput:
            rate = f"{throughput['Bytes'] / mean_ns * 1e3:.0f} MB/s"
        rows.append(f"| `{info['full_id']}` | {_human_time(mean_ns)} ± {_human_time(half_ns)} | {rate} |")
    if not rows:
        raise FileNotFoundError(f"no criterion results under {root}; run `cargo bench -p evcore` first")
    return "\n".join(["| benchmark | mean (95 % CI half-width) | throughput |", "|---|---:|---:|", *rows])


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 3 or args[0] != "criterion":
        print("usage: python -m evservo.bench.results criterion CRITERION_DIR RESULTS_MD", file=sys.stderr)
        return 2
    root, results = Path(args[1]), Path(args[2])
    body = f"Command: `make bench` (`cargo bench -p evcore`), read from `{root}` by `evservo.bench.results`.\n\n"
    splice(results, "criterion", body + criterion_table(root))
    print(f"refreshed the criterion section of {results}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
