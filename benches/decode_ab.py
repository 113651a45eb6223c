"""The latency suite's decode comparison alone (``evservo.bench.latency.decode_comparison``), once
per RAW sample, one JSON line per file: our readers and every other installed Python reader,
interleaved, and the ratios of ours to the best other (median over rounds, wall and CPU time).

    python benches/decode_ab.py LABEL ROUNDS [FILE ...]

For a side-by-side of two builds, alternate runs of this script with ``PYTHONPATH`` pointing at
the other build's ``evservo`` package (see benches/RESULTS.md, "Round 6: decode speed")."""

import json
import os
import sys
from pathlib import Path

import evservo
from evservo.bench.latency import decode_comparison

label, rounds = sys.argv[1], int(sys.argv[2])
samples = Path(os.environ.get("EVSERVO_SAMPLES", Path(__file__).resolve().parents[2] / "shared/event-samples"))
for name in sys.argv[3:] or [p.name for p in sorted(samples.glob("*.raw"))]:
    r = decode_comparison(samples / name, rounds)
    print(json.dumps(dict(label=label, file=name, load=os.getloadavg()[0], package=evservo.__file__, **r)), flush=True)
