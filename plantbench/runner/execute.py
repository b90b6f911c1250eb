"""Running a plan: each job in its own process with a timeout, on local threads or a Dask cluster.

A job that finished before (its ``status.json`` is in the cache) is reused, whatever its status: the cache key
covers the code, so a fixed method gets a new key and runs again. A job whose process crashes, times out or
writes an invalid output becomes a failed job with its log kept; jobs downstream of it are marked failed without
running; every other job goes on. Ctrl-C kills the running job processes, removes their temporary folders and
leaves every finished job in the cache, so the same command resumes.
"""

from __future__ import annotations

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
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict
from pathlib import Path

from plantbench.io.atomic import write_json
from plantbench.runner.plan import Job, Plan
from plantbench.runner.worker import job_folder

__all__ = ["execute_job", "execute_plan", "kill_running", "ExecutionStats", "Interrupted"]

_RUNNING: dict[int, subprocess.Popen] = {}
_LOCK = threading.Lock()
_STOP = threading.Event()


class Interrupted(Exception):
    """The run was interrupted (Ctrl-C); the job's temporary folder was removed, nothing was cached."""


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


def execute_job(cache: str, job: dict) -> dict:
    """Run one job (a :class:`Job` as a dict) unless it is cached; return its status record plus 'reused'.

    Safe to call from threads and from Dask workers (it only needs the shared cache folder).
    """
    cache_p = Path(cache)
    kind, key = job["kind"], job["key"]
    final = job_folder(cache_p, kind, key)
    status = _read_status(final)
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
    cmd = [sys.executable, "-m", "plantbench.runner.worker", str(cache_p), kind, key, str(tmp), params]
    t0 = time.perf_counter()
    try:
        with open(tmp / "job.log", "w") as log:
            proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                                    stdin=subprocess.DEVNULL)
            with _LOCK:
                _RUNNING[proc.pid] = proc
            try:
                proc.wait(timeout=job.get("timeout_s"))
                record = _read_status(tmp)
                if record is None:
                    sig = -proc.returncode if proc.returncode < 0 else None
                    why = f"killed by signal {sig}" if sig else f"exited {proc.returncode} without a status"
                    record = {"status": "failed", "error": f"process {why}", "kind": kind, "key": key}
            except subprocess.TimeoutExpired:
                _kill(proc)
                record = {"status": "timeout", "error": f"timed out after {job['timeout_s']:.0f} s", "kind": kind,
                          "key": key}
            finally:
                with _LOCK:
                    _RUNNING.pop(proc.pid, None)
        if _STOP.is_set():
            raise Interrupted(f"{kind} {key}")
        record["seconds"] = record.get("seconds") or (time.perf_counter() - t0)
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
    """Run every job of ``plan`` phase by phase; return {key: status record} and the counts."""
    cache = Path(cache)
    _STOP.clear()
    phases = plan.phases()
    total = sum(len(p) for p in phases)
    results: dict[str, dict] = {}
    stats = ExecutionStats(computed=0, reused=0, skipped=0, failed=0, by_kind={})
    done = 0

    def record(job: Job, rec: dict) -> None:
        nonlocal done
        results[job.key] = rec
        done += 1
        outcome = "reused" if rec.get("reused") else "skipped" if rec.get("upstream") else "computed"
        stats[outcome] += 1
        if rec["status"] != "ok":
            stats["failed"] += 1
        kind_stats = stats["by_kind"].setdefault(job.kind, {"computed": 0, "reused": 0, "skipped": 0, "failed": 0})
        kind_stats[outcome] += 1
        kind_stats["failed"] += rec["status"] != "ok"
        if progress:
            progress(done, total, {"kind": job.kind, **rec})

    if executor == "dask":
        own_client = client is None
        if own_client:
            try:
                from dask.distributed import Client
            except ImportError as exc:
                from plantbench.errors import InputError

                raise InputError("the dask executor needs the 'cluster' extra: pip install 'plantbench[cluster]'") from exc
            client = Client(scheduler) if scheduler else Client(n_workers=workers, threads_per_worker=1)
        try:
            from dask.distributed import as_completed as dask_completed

            for phase in phases:
                futures = {client.submit(execute_job, str(cache), asdict(job), key=f"{job.kind}-{job.key}",
                                         pure=False): job for job in phase}
                for fut in dask_completed(futures):
                    record(futures[fut], fut.result())
        finally:
            if own_client:
                client.close()
    elif executor == "local":
        with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
            try:
                for phase in phases:
                    futures = {pool.submit(execute_job, str(cache), asdict(job)): job for job in phase}
                    for fut in as_completed(futures):
                        record(futures[fut], fut.result())
            except BaseException:
                kill_running()
                pool.shutdown(wait=True, cancel_futures=True)
                raise
    else:
        from plantbench.errors import InputError

        raise InputError(f"unknown executor {executor!r}; choose 'local' or 'dask'")
    return results, stats
