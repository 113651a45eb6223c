#!/usr/bin/env python3
"""Criterion A/B on a noisy machine: two bench binaries (e.g. main's and a branch's `tracker` bench)
alternated for N rounds (the order flips every round), each timed by thread CPU time
(EVCORE_BENCH_CLOCK=cpu), under `nice -n 10`; prints the median of the rounds' criterion estimates
and the ratio branch / main per benchmark.

    python3 benches/crit_ab.py MAIN_BIN BRANCH_BIN 'REGEX' [ROUNDS]

Build MAIN_BIN from main's sources in a separate target dir, e.g.
`git -C <main checkout> archive HEAD | tar -x -C /tmp/m && (cd /tmp/m && CARGO_TARGET_DIR=/tmp/m-target
cargo bench -p evcore --bench tracker --no-run)`, and copy both executables aside before rebuilding.
"""

import json
import os
import re
import statistics
import subprocess
import sys

UNIT_US = {"ns": 1e-3, "µs": 1.0, "us": 1.0, "ms": 1e3, "s": 1e6}
ESTIMATE = re.compile(r"^(\S*)\s+time:\s+\[\S+ \S+ (\S+) (\S+) \S+ \S+\]")


def run(binary: str, filt: str) -> dict[str, float]:
    """One criterion run: {benchmark: point estimate in µs}."""
    out = subprocess.run(
        ["nice", "-n", "10", binary, "--bench", filt, "--measurement-time", "3", "--warm-up-time", "1"],
        env=dict(os.environ, EVCORE_BENCH_CLOCK="cpu"),
        capture_output=True,
        text=True,
        cwd=os.environ.get("CRIT_AB_CWD", "/tmp"),
        check=True,
    ).stdout
    found, name = {}, None
    for line in out.splitlines():
        if line and not line[0].isspace():
            name = line.split()[0]
        m = ESTIMATE.match(line)
        if m and name:
            found[name] = float(m.group(2)) * UNIT_US[m.group(3)]
    return found


def main() -> None:
    bins = {"main": sys.argv[1], "branch": sys.argv[2]}
    filt = sys.argv[3]
    rounds = int(sys.argv[4]) if len(sys.argv) > 4 else 3
    res: dict[str, dict[str, list[float]]] = {}
    loads = []
    for r in range(rounds):
        order = list(bins.items()) if r % 2 == 0 else list(bins.items())[::-1]
        for who, binary in order:
            loads.append(os.getloadavg()[0])
            for bench, us in run(binary, filt).items():
                res.setdefault(bench, {}).setdefault(who, []).append(us)
            print(f"round {r} {who} done, load {loads[-1]:.1f}", file=sys.stderr, flush=True)
    print(f"load avg (1 min) during runs: {min(loads):.1f}-{max(loads):.1f}")
    print(f"{'bench':32s} {'main us':>10s} {'branch us':>10s} {'ratio':>6s}   rounds main / branch")
    for bench, v in res.items():
        m = statistics.median(v.get("main", [float("nan")]))
        b = statistics.median(v.get("branch", [float("nan")]))
        rows = " / ".join(", ".join(f"{x:.1f}" for x in v.get(w, [])) for w in ("main", "branch"))
        print(f"{bench:32s} {m:10.1f} {b:10.1f} {b / m:6.2f}   {rows}")
    with open(os.environ.get("CRIT_AB_OUT", "/tmp") + "/crit_ab.json", "w") as f:
        json.dump(res, f)


if __name__ == "__main__":
    main()
