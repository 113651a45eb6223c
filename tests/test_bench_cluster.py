"""The paper suite's dask.distributed executor: a scheduler and two workers on 127.0.0.1, started here."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import replace

import pytest

from evservo.bench import paper
from evservo.bench.cluster import run_tasks
from evservo.sim.episode import EpisodeConfig

distributed = pytest.importorskip("distributed")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _dask(*args: str) -> subprocess.Popen:
    # Own session: a worker is killed with its nanny as a group, like a machine dropping out.
    return subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_" + args[0], *args[1:]],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


@pytest.fixture
def cluster():
    address = f"tcp://127.0.0.1:{_free_port()}"
    procs = [_dask("scheduler", "--host", "127.0.0.1", "--port", address.rsplit(":", 1)[1], "--no-dashboard")]
    common = ("--nworkers", "1", "--nthreads", "1", "--no-dashboard", "--host", "127.0.0.1")
    procs += [_dask("worker", address, *common) for _ in range(2)]
    client = distributed.Client(address, timeout=60, set_as_default=False)
    try:
        client.wait_for_workers(2, timeout=120)
        yield address, procs
    finally:
        client.close()
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def test_episodes_survive_a_worker_dying_and_a_task_that_kills_workers_is_reported(cluster):
    address, procs = cluster
    base = EpisodeConfig(duration_s=0.2, cost_model="fixed")
    configs = {f"s{s}": replace(base, seed=s) for s in (1, 2, 3)}
    done: dict[str, dict] = {}
    killed = False

    def on_done(key, result):
        nonlocal killed
        summary, files = result
        assert {"summary.json", "log.csv", "motion.png"} <= set(files)
        done[key] = summary
        if not killed:  # one worker drops out with episodes still queued or running
            os.killpg(procs[1].pid, signal.SIGKILL)
            killed = True

    failed = run_tasks(address, paper._remote_episode, {k: (c,) for k, c in configs.items()}, on_done)
    assert failed == {} and set(done) == set(configs)
    assert all(s["completed"] for s in done.values())
    # The cluster's episode is the local one: same configuration, fixed cost model, same result.
    local = paper._remote_episode(configs["s2"])[0]
    assert done["s2"]["gt_track_pos_rms_mm"] == pytest.approx(local["gt_track_pos_rms_mm"], rel=1e-9)

    # A task that kills every worker that runs it: one retry on the restarted worker, then reported failed;
    # the cluster still runs the next task.
    squares: dict[str, int] = {}
    t0 = time.monotonic()
    # (Library functions: workers cannot import this test module.)
    failed = run_tasks(address, os._exit, {"bad": (3,)}, squares.__setitem__)
    assert squares == {} and set(failed) == {"bad"} and "KilledWorker" in failed["bad"], failed
    assert run_tasks(address, pow, {"ok": (4, 2)}, squares.__setitem__) == {}
    assert squares == {"ok": 16}
    assert time.monotonic() - t0 < 120


def test_unreachable_scheduler_is_an_error():
    with pytest.raises(RuntimeError, match="cannot reach the dask scheduler"):
        run_tasks(f"tcp://127.0.0.1:{_free_port()}", pow, {"a": (1, 2)}, lambda k, r: None, connect_timeout_s=2)


def test_config_hash_follows_configuration_and_code():
    cfg = EpisodeConfig(duration_s=0.2)
    code = paper.code_version()
    assert len(code) == 64 and paper.code_version() == code
    h = paper.config_hash(cfg, code)
    assert paper.config_hash(replace(cfg), code) == h
    assert paper.config_hash(replace(cfg, seed=cfg.seed + 1), code) != h
    assert paper.config_hash(cfg, "0" * 64) != h
    rendered = [c for _, c in paper.plan(quick=True, events="render")]
    assert all(c.event_source == "render-lab" and c.render_arms and c.duration_s == 0.3 for c in rendered)
    assert len({paper.episode_key(c) for c in rendered}) == len({paper.config_hash(c, code) for c in rendered})
    with pytest.raises(ValueError, match="event source"):
        paper.plan(quick=True, events="frames")


def test_code_version_ignores_the_suites_and_the_commands(tmp_path, monkeypatch):
    """Editing a report or a command keeps finished episodes reusable; editing what an episode runs
    does not."""
    import evservo
    import evservo._evcore as core

    for rel in ("__init__.py", "control/law.py", "bench/paper.py", "commands/demo.py", "_evcore.so"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(f"# {rel}\n")
    monkeypatch.setattr(evservo, "__file__", str(tmp_path / "__init__.py"))
    monkeypatch.setattr(core, "__file__", str(tmp_path / "_evcore.so"))
    code = paper.code_version()
    for rel in ("bench/paper.py", "commands/demo.py"):
        (tmp_path / rel).write_text("# edited\n")
        assert paper.code_version() == code, rel
    (tmp_path / "control/law.py").write_text("# edited\n")
    assert paper.code_version() != code


def test_the_rows_issue_14_is_about_run_first():
    rows = [(sec, paper.episode_key(cfg), cfg) for sec, cfg in paper.plan(quick=False)]
    unique = {key: cfg for _, key, cfg in rows}
    order = sorted(unique.items(), key=lambda item: paper._priority(rows, *item))
    assert [cfg.seed for _, cfg in order[:3]] == [1, 2, 3]
    assert all(cfg.trajectory == "trans-rot" and cfg.distance_m == 0.6 and cfg.feedforward for _, cfg in order[:3])
    ff_rows = {key for sec, key, _ in rows if sec == "feedforward"}
    assert {key for key, _ in order[: len(ff_rows)]} == ff_rows
    # Then the speed sweep, EDFT⁺ fastest first: where the arm or the tracker gives out.
    sweep_rows = {key for sec, key, _ in rows if sec == "sweep"} - ff_rows  # some are feed-forward rows too
    sweep = order[len(ff_rows) : len(ff_rows) + len(sweep_rows)]
    assert {key for key, _ in sweep} == sweep_rows
    assert [(c.tracker, c.speed_mps) for _, c in sweep[:2]] == [("edft+", 1.7), ("edft+", 1.45)]


def test_ctrl_c_cancels_the_clusters_tasks(cluster):
    address, _ = cluster
    code = (
        "import time\n"
        "from evservo.bench.cluster import run_tasks\n"
        f"run_tasks({address!r}, time.sleep, {{'a': (60,), 'b': (60,)}}, print)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stderr=subprocess.PIPE, text=True)
    client = distributed.Client(address, timeout=30, set_as_default=False)
    try:
        deadline = time.monotonic() + 60
        while not any(client.processing().values()):
            assert time.monotonic() < deadline, "the tasks never started"
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        assert proc.returncode != 0 and "KeyboardInterrupt" in err
        deadline = time.monotonic() + 20
        while any(client.processing().values()):  # cancelled, not left sleeping on the workers
            assert time.monotonic() < deadline, client.processing()
            time.sleep(0.2)
    finally:
        client.close()
        if proc.poll() is None:
            proc.kill()


def test_jobs_run_on_a_local_cluster_where_a_dying_worker_is_reported_not_waited_for():
    """``--jobs N`` without a scheduler: a worker killed mid-task (out of memory, SIGKILL) costs one
    retry and then a reported failure; a process pool would wait for its result forever."""
    from evservo.bench.cluster import local_cluster

    results: dict[str, int] = {}
    t0 = time.monotonic()
    with local_cluster(2) as address:
        failed = run_tasks(address, os._exit, {"dies": (9,)}, results.__setitem__)
        assert set(failed) == {"dies"} and "KilledWorker" in failed["dies"], failed
        assert run_tasks(address, pow, {"a": (4, 2), "b": (2, 10)}, results.__setitem__) == {}
    assert results == {"a": 16, "b": 1024}
    assert time.monotonic() - t0 < 120


def test_the_sweep_says_whether_the_arm_or_the_tracker_gave_out():
    held = {"completed": True, "lost_at_s": None, "joint_speed_max_ratio": 1.0, "gave_out": None}
    assert "the arm gave out" in paper._sweep_verdict(held)
    assert "neither" in paper._sweep_verdict({**held, "joint_speed_max_ratio": 0.6})
    lost = {**held, "completed": False, "lost_at_s": 1.4, "gave_out": "tracker"}
    assert paper._sweep_verdict(lost) == "lost at 1.40 s, the tracker gave out"


def test_tasks_start_in_the_order_given_whatever_the_worker_queues(cluster):
    """The first task is long and the keys are of different dask groups (like the suite's objects), so
    dask would assign every task to a worker's queue at submission: the worker left free would then run
    its own queue (every other task) ahead of the busy worker's. Only as many on the cluster as it has
    threads keeps the order given."""
    address, _ = cluster
    names = ["alpha", "bravo", "charlie", "delta", "echo", "foxtrot", "golf", "hotel"]
    # Each task prints when it started (a library function: workers cannot import this test module).
    code = "import sys, time; print(time.time(), flush=True); time.sleep(float(sys.argv[1]))"
    tasks = {name: ([sys.executable, "-c", code, "4.0" if i == 0 else "0.3"],) for i, name in enumerate(names)}
    started: dict[str, float] = {}
    failed = run_tasks(address, subprocess.check_output, tasks, lambda k, out: started.__setitem__(k, float(out)))
    assert failed == {}
    order = sorted(started, key=started.__getitem__)
    # Two workers: the first two start together; every later one only after those before it.
    assert set(order[:2]) == set(names[:2]) and order[2:] == names[2:], order
