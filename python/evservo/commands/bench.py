"""``evservo bench``: end-to-end benchmark suites with reports."""

from __future__ import annotations

import argparse
import os
import shutil
from pathlib import Path

SUITES = ("latency", "paper", "objects", "robustness")
#: Each suite's report files, removed at the start so an interrupted run leaves none of an earlier one.
REPORTS = {
    "latency": ("latency.md", "latency.json"),
    "paper": ("report.md", "results.json"),
    "objects": ("objects.md", "objects.json"),
    "robustness": ("robustness.md", "robustness.json"),
}
#: Marks a directory of copied report files as ours to replace on the next run.
STAMP = "SOURCE.txt"


def run(args: argparse.Namespace) -> int:
    from evservo.outputs import check_out_file, prepare_out_dir

    if args.jobs < 1:
        raise ValueError("--jobs must be at least 1")
    if args.cache is not None and args.suite != "objects":
        raise ValueError("--cache applies to the objects suite only")
    if args.sections is not None and args.suite != "paper":
        raise ValueError("--sections applies to the paper suite only")
    if args.suite == "paper":
        from evservo.bench import paper

        sections = paper.SECTIONS if args.sections is None else tuple(x.strip() for x in args.sections.split(","))
        paper.plan(args.quick, args.events, sections)  # a bad --sections is an error before any output
    # Checked before any episode runs; the paper suite's finished episodes in it are reused.
    prepare_out_dir(args.out, stale=REPORTS[args.suite])
    if args.results is not None:
        check_out_file(args.results, (".md",), option="--results")
    if args.suite == "paper":
        paper.run(
            Path(args.out),
            quick=args.quick,
            jobs=args.jobs,
            events=args.events,
            scheduler=args.scheduler,
            sections=sections,
        )
        print(f"wrote {Path(args.out) / 'report.md'} and results.json")
        _refresh(args, "paper" if args.events == "edges" else f"paper-{args.events}", Path(args.out) / "report.md")
        return 0
    if args.suite == "objects":
        from evservo.bench import objects

        objects.run(Path(args.out), quick=args.quick, cache=None if args.cache is None else Path(args.cache))
        print(f"wrote {Path(args.out) / 'objects.md'} and objects.json")
        _refresh(args, "objects", Path(args.out) / "objects.md")
        return 0
    if args.suite == "robustness":
        from evservo.bench import robustness

        if args.scheduler is not None or args.jobs != 1:
            raise ValueError("--scheduler and --jobs apply to the paper suite only")
        robustness.run(Path(args.out), quick=args.quick, events=args.events)
        print(f"wrote {Path(args.out) / 'robustness.md'} and robustness.json")
        section = "robustness" if args.events == "edges" else f"robustness-{args.events}"
        _refresh(args, section, Path(args.out) / "robustness.md")
        return 0
    if args.events != "edges" or args.scheduler is not None:
        raise ValueError("--events applies to the paper and robustness suites, --scheduler to the paper suite only")
    from evservo.bench import latency

    samples = Path(os.environ.get("EVSERVO_SAMPLES", Path(__file__).resolve().parents[4] / "shared/event-samples"))
    latency.run(Path(args.out), quick=args.quick, samples=samples)
    print(f"wrote {Path(args.out) / 'latency.md'} and latency.json")
    _refresh(args, "latency", Path(args.out) / "latency.md")
    return 0


def _refresh(args: argparse.Namespace, section: str, report: Path) -> None:
    """Copy the suite's report into the results file's generated section, if one was named."""
    if args.results is None:
        return
    from evservo.bench.results import embed_report, splice

    results = Path(args.results)
    artifacts = results.parent / f"{section}-run"
    stamp = artifacts / STAMP
    if artifacts.exists():
        if not stamp.is_file():
            raise FileExistsError(f"{artifacts} exists and was not written by evservo bench: move it away")
        shutil.rmtree(artifacts)  # the previous run's copies; stale episodes must not linger
    splice(results, section, embed_report(report.read_text(), report.parent, results.parent, artifacts))
    if artifacts.exists():  # only a report that links to files gets a copy directory
        stamp.write_text(f"Copied by `evservo bench --suite {section} --results {results}` from {report.parent}.\n")
    print(f"refreshed the {section} section of {args.results}")


def add_parser(sub: argparse._SubParsersAction) -> None:
    b = sub.add_parser("bench", help="benchmark suites: latency, paper, objects, robustness")
    b.add_argument("--suite", choices=SUITES, default="latency")
    b.add_argument("--out", default="out/bench", help="output directory")
    b.add_argument("--quick", action="store_true", help="short runs, one seed (for tests)")
    b.add_argument("--jobs", type=int, default=1, help="worker processes on this machine (paper suite)")
    b.add_argument(
        "--events",
        choices=("edges", "render"),
        default="edges",
        help="paper and robustness suites' event source: the idealised edges, or the rendered camera (paper "
        "suite: lab preset, arms drawn)",
    )
    b.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="run the paper suite's episodes on this running dask.distributed cluster instead of --jobs",
    )
    b.add_argument(
        "--sections",
        metavar="A,B",
        help="paper suite: run only these sections (comma-separated: table1, table2, fig2, feedforward, sweep, "
        "predictor); the report says which ran",
    )
    b.add_argument(
        "--cache",
        metavar="DIR",
        help="objects suite: keep the rendered recordings here and reuse them (to compare tracker changes)",
    )
    b.add_argument(
        "--results",
        metavar="MD",
        help="also replace this suite's generated section of a results file (make bench: benches/RESULTS.md)",
    )
    b.set_defaults(func=run)
