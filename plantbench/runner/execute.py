"""Running a plan: each job in its own process with a timeout, on local threads or a Dask cluster.

A job that finished before (its ``status.json`` is in the cache) is reused, whatever its status: the cache key
covers the code, so a fixed method gets a new key and runs again. A job whose process crashes, times out or
writes an invalid output becomes a failed job with its log kept; jobs downstream of it are marked failed without
running; every other job goes on. Ctrl-C kills the running job processes, removes their temporary folders and
leaves every finished job in the cache, so the same command resumes. A job process stopped from outside (SIGTERM,
SIGINT, SIGHUP or SIGKILL: a Dask worker shut down, a session's end, the kernel's out-of-memory killer) fails this
run but is not cached: the next run computes it again instead of reusing an interruption as the job's result.
"""

from __future__ import annotations

import heapq
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait
from dataclasses import asdict
from pathlib import Path

from plantbench.io.atomic import write_json
from plantbench.runner.plan import Job, Plan
from plantbench.runner.worker import job_folder

__all__ = ["execute_job", "execute_plan", "job_environment", "kill_running", "ExecutionStats", "Interrupted"]

_RUNNING: dict[int, subprocess.Popen] = {}
_LOCK = threading.Lock()
_STOP = threading.Event()


class Interrupted(Exception):
    """The run was interrupted (Ctrl-C); the job's temporary folder was removed, nothing was cached."""


STOP_SIGNALS = frozenset({signal.SIGTERM, signal.SIGINT, signal.SIGHUP, signal.SIGKILL})
"""Signals that stop a job from outside (its worker or session ended, the out-of-memory killer): the job failed in
this run, but that says nothing about its result, so it is not cached."""


def _job_command(cache: Path, kind: str, key: str, tmp: Path, params: str) -> list[str]:
    """The command line of a job process."""
    return [sys.executable, "-m", "plantbench.runner", str(cache), kind, key, str(tmp), params]


def _stopped_from_outside(status: dict) -> bool:
    """Whether a cached status records a job process killed by one of STOP_SIGNALS (a cache written before such
    jobs were left out of it)."""
    error = status.get("error") or ""
    return status.get("status") == "failed" and any(error == f"process killed by signal {int(s)}"
                                                     for s in STOP_SIGNALS)


def _read_status(folder: Path) -> dict | None:
    try:
        return json.loads((folder / "status.json").read_text())
    except (OSError, ValueError):
        return None


def _kill(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    proc.wait()


def job_environment(threads: int | None, budget: int | None = None) -> dict[str, str]:
    """The environment of a job process: this one's, with every thread pool capped at ``threads`` (None: no cap),
    and plantbench's own pools (``PLANTBENCH_THREADS``: Dr.Jit, the mvs stage's views, k-d tree queries) at
    ``budget`` when given. BLAS and OpenMP keep the fixed cap, so a job's bytes never depend on how many jobs ran
    beside it; plantbench's pools give the same result on any number of threads.

    Several jobs run side by side when there are several workers; a job whose libraries each start one thread per
    core (BLAS, OpenMP, Dr.Jit/Mitsuba through ``PLANTBENCH_THREADS``, see :mod:`plantbench.backend`) would then
    oversubscribe the cores.

    ``MALLOC_TRIM_THRESHOLD_`` is dropped: Dask's nanny sets it to 64 KiB in its workers
    (``distributed.nanny.pre-spawn-environ``) to keep a long-lived worker's memory down, and a job process that
    inherits it returns every freed array buffer to the kernel and faults it back in (what that cost:
    docs/tuning/runner.md). OpenBLAS, numpy and OpenCV get their pinned dispatch (:func:`plantbench.backend.pin_dispatch`)."""
    from plantbench.backend import pin_dispatch

    env = dict(os.environ)
    env.pop("MALLOC_TRIM_THRESHOLD_", None)
    pin_dispatch(env)  # a job loads numpy afresh: OpenBLAS, numpy and OpenCV pinned (a Dask worker loaded them first)
    if threads is not None:
        n = str(max(1, int(threads)))
        for var in ("PLANTBENCH_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                    "NUMEXPR_NUM_THREADS"):
            env[var] = n
    if budget is not None:
        env["PLANTBENCH_THREADS"] = str(max(1, int(budget)))
    return env


def execute_job(cache: str, job: dict, threads: int | None = None, budget: int | None = None) -> dict:
    """Run one job (a :class:`Job` as a dict) unless it is cached; return its status record plus 'reused'.

    Safe to call from threads and from Dask workers (it only needs the shared cache folder). ``threads`` caps the
    job's thread pools, ``budget`` plantbench's own (:func:`job_environment`; default ``threads``).
    """
    cache_p = Path(cache)
    kind, key = job["kind"], job["key"]
    final = job_folder(cache_p, kind, key)
    status = _read_status(final)
    if status is not None and _stopped_from_outside(status):  # cached before such jobs were left out: run it again
        shutil.rmtree(final, ignore_errors=True)
        status = None
    if status is not None:
        return {**status, "reused": True}
    for dep in job["deps"]:
        dep_status = None
        for k in ("plant", "capture", "points", "method", "metrics"):
            dep_status = _read_status(job_folder(cache_p, k, dep)) or dep_status
        if dep_status is None or dep_status["status"] != "ok":
            why = "missing" if dep_status is None else dep_status["status"]
            err = f"upstream {dep_status['kind'] if dep_status else 'job'} {dep} {why}"
            if dep_status and dep_status.get("error"):
                err += f": {dep_status['error']}"
            # not cached: an upstream job may be retried in a later run, and this one with it
            return {"status": "failed", "error": err, "seconds": 0.0, "kind": kind, "key": key, "reused": False,
                    "upstream": True}
    tmp = final.parent / f".{key}.{uuid.uuid4().hex[:8]}.tmp"
    tmp.mkdir(parents=True)
    params = json.dumps(job["params"])
    cmd = _job_command(cache_p, kind, key, tmp, params)
    t0 = time.perf_counter()
    started = time.time()
    stopped = False  # the process was stopped from outside (STOP_SIGNALS)
    try:
        with open(tmp / "job.log", "w") as log:
            proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                                    stdin=subprocess.DEVNULL, env=job_environment(threads, budget))
            with _LOCK:
                _RUNNING[proc.pid] = proc
            try:
                proc.wait(timeout=job.get("timeout_s"))
                record = _read_status(tmp)
                if record is None:
                    sig = -proc.returncode if proc.returncode < 0 else None
                    why = f"killed by signal {sig}" if sig else f"exited {proc.returncode} without a status"
                    record = {"status": "failed", "error": f"process {why}", "kind": kind, "key": key}
                    stopped = sig in STOP_SIGNALS
            except subprocess.TimeoutExpired:
                _kill(proc)
                record = {"status": "timeout", "error": f"timed out after {job['timeout_s']:.0f} s", "kind": kind,
                          "key": key}
            finally:
                with _LOCK:
                    _RUNNING.pop(proc.pid, None)
        if _STOP.is_set():
            raise Interrupted(f"{kind} {key}")
        if stopped:  # not the job's result: nothing cached, the next run computes it again
            shutil.rmtree(tmp, ignore_errors=True)
            return {**record, "error": record["error"] + " from outside; not cached, the next run computes it again",
                    "seconds": time.perf_counter() - t0, "reused": False, "interrupted": True}
        record["seconds"] = record.get("seconds") or (time.perf_counter() - t0)
        # the run's timeline (epoch seconds) and the threads of plantbench's pools
        record.update(started=started, finished=time.time(), threads=budget if budget is not None else threads)
        write_json(tmp / "status.json", record)
        try:
            os.replace(tmp, final)
        except OSError:  # another run finished the same job first: keep theirs
            shutil.rmtree(tmp, ignore_errors=True)
            record = _read_status(final) or record
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return {**record, "reused": False}


def kill_running() -> int:
    """Kill every job process started by this process (Ctrl-C); returns how many."""
    _STOP.set()
    with _LOCK:
        procs = list(_RUNNING.values())
    for p in procs:
        _kill(p)
    return len(procs)


class ExecutionStats(dict):
    """Counts per outcome: computed, reused (from the cache), skipped (upstream failed), failed (and per kind)."""


def _execute_after(cache: str, job: dict, threads: int | None, *upstream: dict) -> dict:
    """:func:`execute_job` as a Dask task: ``upstream`` are the records of the jobs it depends on, passed only so
    that Dask starts it after them (the job reads their status from the cache)."""
    return execute_job(cache, job, threads)


DASK_CLUSTER_CONFIG = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "2s",
}
"""Dask settings for a cluster that runs plantbench jobs. A task only waits on its job process, so what Dask does
to watch its own workers at a 10-500 ms cadence is CPU taken from the jobs: the stack-sampling profiler (10 ms),
the event-loop tick that detects a blocked loop (20 ms), the system monitor (500 ms) and the memory monitor
(100 ms; the job's memory is in its own process, which it does not see anyway). Applied to the executor's own
cluster; for one you start, set it before (or export ``DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False`` and the
like, see docs/cluster.md). What each setting saves: docs/tuning/runner.md."""


def _local_threads(client) -> int | None:
    """Thread budget per job on a Dask cluster whose workers all run on this machine (a LocalCluster): the cores
    shared by its worker threads; None (no cap) for a remote cluster, whose machines this one cannot see."""
    nthreads = client.nthreads()
    local = all(addr.startswith(("inproc://", "tcp://127.0.0.1:", "tcp://localhost:")) for addr in nthreads)
    total = sum(nthreads.values())
    return max(1, (os.cpu_count() or 1) // total) if local and total else None


_OUTCOMES = ("computed", "reused", "skipped", "failed")


class _Tally:
    """The bookkeeping of a running plan: each finished job's record, the counts per outcome and per kind, and the
    ``progress`` callback."""

    def __init__(self, total: int, progress: Callable[[int, int, dict], None] | None) -> None:
        self.total = total
        self.progress = progress
        self.done = 0
        self.results: dict[str, dict] = {}
        self.stats = ExecutionStats(dict.fromkeys(_OUTCOMES, 0), by_kind={})

    def record(self, job: Job, rec: dict) -> None:
        """Count the finished ``job`` with its status record ``rec`` and report it."""
        self.results[job.key] = rec
        self.done += 1
        outcome = "reused" if rec.get("reused") else "skipped" if rec.get("upstream") else "computed"
        self.stats[outcome] += 1
        if rec["status"] != "ok":
            self.stats["failed"] += 1
        kind_stats = self.stats["by_kind"].setdefault(job.kind, dict.fromkeys(_OUTCOMES, 0))
        kind_stats[outcome] += 1
        kind_stats["failed"] += rec["status"] != "ok"
        if self.progress:
            self.progress(self.done, self.total, {"kind": job.kind, **rec})


def _budget(cores: int, workers: int, threads: int | None, competing: int) -> int | None:
    """Threads of plantbench's pools for a job that starts while ``competing`` jobs (it included) are running or
    ready: the cores split among them, at least the worker's share, so that a job that runs alone (the end of a
    run, a lone long chain) leaves no core idle."""
    if threads is None:
        return None
    return max(threads, cores // max(1, min(workers, competing)))


def _run_local(plan: Plan, cache: Path, workers: int, tally: _Tally) -> None:
    """Run the plan on ``workers`` threads: a job is submitted once its dependencies have finished, the ready job
    with the highest priority (then the earliest in the plan) first. On any error or Ctrl-C the running job
    processes are killed before it propagates."""
    workers = max(1, workers)
    cores = os.cpu_count() or 1
    threads = max(1, cores // workers) if workers > 1 else None
    priority = plan.priorities()
    children = plan.children()
    waiting = {k: set(job.deps) for k, job in plan.jobs.items()}
    order = {k: i for i, k in enumerate(plan.jobs)}
    ready = [(-priority[k], order[k], k) for k in plan.jobs if not waiting[k]]
    heapq.heapify(ready)
    running: dict = {}
    with ThreadPoolExecutor(max_workers=workers) as pool:
        try:
            while ready or running:
                while ready and len(running) < workers:
                    key = heapq.heappop(ready)[2]
                    budget = _budget(cores, workers, threads, len(running) + 1 + len(ready))
                    running[pool.submit(execute_job, str(cache), asdict(plan.jobs[key]), threads, budget)] = key
                finished, _ = wait(running, return_when=FIRST_COMPLETED)
                for fut in finished:
                    key = running.pop(fut)
                    tally.record(plan.jobs[key], fut.result())
                    for child in children[key]:
                        waiting[child].discard(key)
                        if not waiting[child]:
                            heapq.heappush(ready, (-priority[child], order[child], child))
        except BaseException:
            kill_running()
            pool.shutdown(wait=True, cancel_futures=True)
            raise


def _dask_client(workers: int, scheduler: str | None):
    """A Dask client of the cluster at ``scheduler``, or of a new LocalCluster of ``workers`` single-threaded
    workers started with :data:`DASK_CLUSTER_CONFIG`."""
    try:
        from dask.distributed import Client
    except ImportError as exc:
        from plantbench.errors import InputError

        raise InputError("the dask executor needs the 'cluster' extra: pip install 'plantbench[cluster]'") from exc
    if scheduler:
        return Client(scheduler)
    import dask

    with dask.config.set(DASK_CLUSTER_CONFIG):
        return Client(n_workers=workers, threads_per_worker=1)


def _run_dask(plan: Plan, cache: Path, client, tally: _Tally) -> None:
    """Submit every job of the plan to ``client`` at once, each after the futures of its dependencies and with its
    priority, and record the jobs as they complete."""
    from dask.distributed import as_completed as dask_completed

    priority = plan.priorities()
    threads = _local_threads(client)
    futures: dict[str, object] = {}
    for key, job in plan.jobs.items():  # dependencies first
        futures[key] = client.submit(_execute_after, str(cache), asdict(job), threads,
                                     *(futures[d] for d in job.deps), key=f"{job.kind}-{job.key}",
                                     pure=False, priority=priority[key])
    jobs_of = {fut.key: plan.jobs[key] for key, fut in futures.items()}
    for fut in dask_completed(list(futures.values())):
        tally.record(jobs_of[fut.key], fut.result())


def execute_plan(
    plan: Plan,
    cache: Path,
    *,
    workers: int = 1,
    executor: str = "local",
    scheduler: str | None = None,
    client=None,
    progress: Callable[[int, int, dict], None] | None = None,
) -> tuple[dict[str, dict], ExecutionStats]:
    """Run every job of ``plan``; return {key: status record} and the counts.

    A job starts as soon as the jobs it depends on have finished (no barrier between stages), the ready job on the
    longest remaining chain first (:meth:`Plan.priorities`). With several jobs side by side, each job's thread
    pools share the cores (:func:`job_environment`).
    """
    cache = Path(cache)
    _STOP.clear()
    tally = _Tally(len(plan.jobs), progress)
    if executor == "dask":
        own_client = client is None
        if own_client:
            client = _dask_client(workers, scheduler)
        try:
            _run_dask(plan, cache, client, tally)
        finally:
            if own_client:
                client.close()
    elif executor == "local":
        _run_local(plan, cache, workers, tally)
    else:
        from plantbench.errors import InputError

        raise InputError(f"unknown executor {executor!r}; choose 'local' or 'dask'")
    return tally.results, tally.stats
