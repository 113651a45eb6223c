"""Run benchmark tasks on a running dask.distributed cluster (``evservo bench --scheduler tcp://HOST:PORT``).

Each task is one call ``fn(*args)`` submitted to the scheduler; results come back to the submitting
process, which writes them (so ``--out`` is on the submitting machine). Workers need the same evservo
installed (``pip install`` of the same checkout, or the same venv on a shared file system).

Failure policy: a task whose worker dies is rescheduled once (the scheduler's ``allowed_failures`` is
set to 1 for the session), and a task that raises is retried once; after that the task is reported
failed with the reason, and the other tasks go on. Ctrl-C cancels every pending task on the cluster
and re-raises :class:`KeyboardInterrupt`.

Run a cluster by hand::

    dask scheduler --host 0.0.0.0 --port 8786          # on one machine
    dask worker tcp://SCHEDULER:8786 --nworkers 1 --nthreads 1   # on each machine, in evservo's venv
    evservo bench --suite paper --scheduler tcp://SCHEDULER:8786 --out out/bench-paper
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any

#: One retry of a task whose worker died (then the scheduler gives up with KilledWorker).
ALLOWED_WORKER_DEATHS = 1
#: One retry of a task that raised.
RETRIES = 1


@contextmanager
def local_cluster(workers: int, start_timeout_s: float = 120.0) -> Iterator[str]:
    """A scheduler in this process and ``workers`` single-threaded ``dask worker`` processes on this
    machine (``--jobs N`` without ``--scheduler``), stopped on exit; yields the scheduler's address.

    The same engine as a remote cluster, so a worker that dies mid-episode (out of memory, killed) is
    retried once and then reported, instead of leaving a process pool waiting for it forever. The
    workers run in sessions of their own: Ctrl-C reaches only this process, which cancels the tasks and
    stops them (a worker interrupted while it starts would print a traceback and be restarted). If this
    process dies without stopping them, they exit once the scheduler has been gone for a while."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=0, host="127.0.0.1", dashboard_address=None, silence_logs=logging.ERROR) as cluster:
        address = cluster.scheduler_address
        cmd = [sys.executable, "-m", "distributed.cli.dask_worker", address, "--nworkers", "1", "--nthreads", "1"]
        cmd += ["--no-dashboard", "--host", "127.0.0.1", "--death-timeout", "30"]
        procs = [
            subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
            for _ in range(workers)
        ]
        try:
            with Client(address, set_as_default=False) as client:
                client.wait_for_workers(workers, timeout=start_timeout_s)
            yield address
        finally:
            for p in procs:
                _stop_session(p)


def _stop_session(proc: subprocess.Popen, grace_s: float = 10.0) -> None:
    """Stop a worker and its nanny (one session): SIGTERM, then SIGKILL after ``grace_s``."""
    for sig, wait_s in ((signal.SIGTERM, grace_s), (signal.SIGKILL, None)):
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, sig)
        try:
            proc.wait(timeout=wait_s)
            return
        except subprocess.TimeoutExpired:
            continue


def _set_allowed_failures(n: int, dask_scheduler: Any = None) -> None:  # runs on the scheduler
    dask_scheduler.allowed_failures = n


def run_tasks(
    scheduler: str,
    fn: Callable[..., Any],
    tasks: Mapping[str, tuple],
    on_done: Callable[[str, Any], None],
    connect_timeout_s: float = 10.0,
) -> dict[str, str]:
    """Submit ``fn(*args)`` for every ``key: args`` of ``tasks`` to the cluster at ``scheduler``
    (``tcp://HOST:PORT``), in the mapping's order, which is the order they start in (first = most
    important); call ``on_done(key, result)`` in this process as each finishes. Returns the failed tasks
    as ``key: reason``. Raises :class:`RuntimeError` if the scheduler cannot be reached.

    Only as many tasks as the cluster has worker threads are on it at a time (with dask priorities in
    the same order), the next submitted as one finishes: a task handed to the cluster is assigned to a
    worker's own queue at once unless dask deems its group "root-ish" (large), and there it would run
    before a more important task submitted later, whatever its priority."""
    from distributed import Client, as_completed

    try:
        client = Client(scheduler, timeout=connect_timeout_s, set_as_default=False)
    except OSError as err:
        raise RuntimeError(f"cannot reach the dask scheduler at {scheduler}: {err}") from err
    failed: dict[str, str] = {}
    futures: dict[Any, str] = {}
    queue = list(tasks.items())
    running = as_completed(loop=client.loop)

    def top_up() -> None:
        # Recounted each time: workers may join or leave a running cluster.
        while queue and running.count() < max(1, sum(client.nthreads().values())):
            key, args = queue.pop(0)
            # pure=False: a rerun must run again, not reuse the cluster's memory of an earlier result.
            fut = client.submit(fn, *args, key=f"evservo-{key}", pure=False, retries=RETRIES, priority=len(queue))
            futures[fut] = key
            running.add(fut)

    try:
        client.run_on_scheduler(_set_allowed_failures, ALLOWED_WORKER_DEATHS)
        top_up()
        for fut in running:
            key = futures[fut]
            try:
                result = fut.result()
            except Exception as err:  # the task's own error or KilledWorker, after its retry
                failed[key] = f"{type(err).__name__}: {err}"
            else:
                on_done(key, result)
            top_up()
    except KeyboardInterrupt:
        client.cancel(list(futures), force=True)
        raise
    finally:
        client.close()
    return failed
