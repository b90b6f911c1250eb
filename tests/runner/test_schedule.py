"""Scheduling of a plan: dependencies first, no barrier between stages, critical path first, thread budgets.

The jobs are replaced by a fake ``execute_job`` that sleeps and records when each job started and ended, so the
order can be checked against the plan's dependency graph without running any stage.
"""

from __future__ import annotations

import threading
import time

import pytest

from plantbench.runner import execute
from plantbench.runner.plan import TYPICAL_SECONDS as T
from plantbench.runner.plan import Job, Plan


def _plan() -> Plan:
    """Two cases: a -> a2 -> a3 (a long chain) and b -> b2 (a short one), plus a lone job c."""
    plan = Plan(suite=None)
    plan.add(Job("plant", "a", {}))
    plan.add(Job("plant", "b", {}))
    plan.add(Job("plant", "c", {}))
    plan.add(Job("capture", "a2", {}, deps=("a",)))
    plan.add(Job("capture", "b2", {}, deps=("b",)))
    plan.add(Job("method", "a3", {"method": "mvs"}, deps=("a2",)))
    return plan


@pytest.fixture()
def fake_jobs(monkeypatch):
    """Replace execute_job: each job sleeps (b's chain and c are quick); returns the event log."""
    log: list[tuple[str, str, float]] = []
    lock = threading.Lock()
    durations = {"a": 0.05, "a2": 0.05, "a3": 0.05, "b": 0.01, "b2": 0.3, "c": 0.01}

    def fake(cache, job, threads=None, budget=None):
        with lock:
            log.append(("start", job["key"], time.perf_counter()))
        time.sleep(durations[job["key"]])
        with lock:
            log.append(("end", job["key"], time.perf_counter()))
        return {"status": "ok", "kind": job["kind"], "key": job["key"], "seconds": 0.0, "reused": False,
                "threads": budget if budget is not None else threads}

    monkeypatch.setattr(execute, "execute_job", fake)
    return log


def test_priorities_are_longest_remaining_chains():
    pr = _plan().priorities()
    assert pr["a3"] == T["mvs"]
    assert pr["a2"] == T["capture"] + T["mvs"]
    assert pr["a"] == T["plant"] + T["capture"] + T["mvs"]
    assert pr["b"] == T["plant"] + T["capture"]
    assert pr["c"] == T["plant"]


def test_dependencies_first_and_critical_path_first(fake_jobs, tmp_path):
    records, stats = execute.execute_plan(_plan(), tmp_path, workers=1)
    assert stats["computed"] == 6 and set(records) == {"a", "b", "c", "a2", "b2", "a3"}
    starts = [k for ev, k, _ in fake_jobs if ev == "start"]
    ends = {k: t for ev, k, t in fake_jobs if ev == "end"}
    begun = {k: t for ev, k, t in fake_jobs if ev == "start"}
    for job in _plan().jobs.values():
        for d in job.deps:
            assert ends[d] <= begun[job.key], f"{job.key} started before {d} finished"
    # one worker: always the ready job on the longest chain (a's chain holds the mvs job)
    assert starts == ["a", "a2", "a3", "b", "b2", "c"]
    assert all(r["threads"] is None for r in records.values())  # a lone worker keeps every core


def test_no_barrier_between_stages(fake_jobs, tmp_path):
    """With two workers, a's later stages run while b's slow capture is still going: a stage-by-stage executor
    would wait for b2 before starting a3."""
    records, _ = execute.execute_plan(_plan(), tmp_path, workers=2)
    t = {(ev, k): v for ev, k, v in fake_jobs}
    assert t[("start", "a3")] < t[("end", "b2")]
    cores = execute.os.cpu_count() or 1
    share = max(1, cores // 2)
    assert {r["threads"] for r in records.values()} <= {share, max(share, cores)}
    assert records["a"]["threads"] == records["b"]["threads"] == share  # three jobs ready at the start


def test_a_job_alone_gets_every_core():
    """plantbench's pools get the cores split among the jobs running or ready, at least the worker's share; BLAS
    and OpenMP keep the share (their results could depend on the thread count)."""
    assert execute._budget(16, 4, 4, competing=9) == 4
    assert execute._budget(16, 4, 4, competing=2) == 8
    assert execute._budget(16, 4, 4, competing=1) == 16
    assert execute._budget(2, 2, 1, competing=1) == 2
    assert execute._budget(2, 1, None, competing=1) is None
    env = execute.job_environment(1, 2)
    assert env["PLANTBENCH_THREADS"] == "2" and env["OMP_NUM_THREADS"] == env["OPENBLAS_NUM_THREADS"] == "1"


def test_job_environment_caps_thread_pools():
    env = execute.job_environment(1)
    assert env["PLANTBENCH_THREADS"] == env["OMP_NUM_THREADS"] == env["OPENBLAS_NUM_THREADS"] == "1"
    free = execute.job_environment(None)
    assert free.get("PLANTBENCH_THREADS") == execute.os.environ.get("PLANTBENCH_THREADS")


def test_job_environment_drops_the_dask_nannys_malloc_trim(monkeypatch):
    """A Dask worker's MALLOC_TRIM_THRESHOLD_ (its nanny's pre-spawn setting) does not reach the job processes."""
    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "65536")
    assert "MALLOC_TRIM_THRESHOLD_" not in execute.job_environment(1)
    assert "MALLOC_TRIM_THRESHOLD_" not in execute.job_environment(None)
