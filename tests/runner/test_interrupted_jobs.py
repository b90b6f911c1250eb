"""A job process stopped from outside (a Dask worker shut down, a session's end, the out-of-memory killer) is not
cached: the next run computes it again. A job process that crashes by itself stays a cached failure.

The job's command is replaced by a small Python process that ends the way each case needs (it signals itself, or
writes the status a worker writes), so no stage runs.
"""

from __future__ import annotations

import json
import signal
import sys
from dataclasses import asdict

import pytest

from plantbench.runner import execute
from plantbench.runner.plan import Job
from plantbench.runner.worker import job_folder


def _job() -> dict:
    return asdict(Job("plant", "k1", {}))


def _self_signal(sig: int):
    def command(cache, kind, key, tmp, params):
        # the default action first: a parent started under nohup passes SIGHUP on ignored, Python catches SIGINT
        reset = "" if sig == signal.SIGKILL else f"signal.signal({int(sig)}, signal.SIG_DFL); "
        return [sys.executable, "-c", f"import os, signal; {reset}os.kill(os.getpid(), {int(sig)})"]
    return command


def _writes_ok(cache, kind, key, tmp, params):
    status = json.dumps({"status": "ok", "kind": kind, "key": key})
    return [sys.executable, "-c", f"import pathlib; pathlib.Path({str(tmp)!r}, 'status.json').write_text({status!r})"]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL, signal.SIGINT, signal.SIGHUP])
def test_a_job_stopped_from_outside_is_not_cached_and_runs_again(tmp_path, monkeypatch, sig):
    monkeypatch.setattr(execute, "_job_command", _self_signal(sig))
    first = execute.execute_job(str(tmp_path), _job())
    assert first["status"] == "failed" and first["interrupted"] and not first["reused"]
    assert f"killed by signal {int(sig)}" in first["error"] and "not cached" in first["error"]
    folder = job_folder(tmp_path, "plant", "k1")
    assert not folder.exists()
    assert not list(folder.parent.glob(".k1.*"))  # no temporary folder left behind

    monkeypatch.setattr(execute, "_job_command", _writes_ok)
    second = execute.execute_job(str(tmp_path), _job())
    assert second["status"] == "ok" and not second["reused"]
    assert json.loads((folder / "status.json").read_text())["status"] == "ok"


def test_a_job_that_crashes_by_itself_stays_a_cached_failure(tmp_path, monkeypatch):
    monkeypatch.setattr(execute, "_job_command", _self_signal(signal.SIGABRT))
    first = execute.execute_job(str(tmp_path), _job())
    assert first["status"] == "failed" and not first.get("interrupted")
    assert first["error"] == f"process killed by signal {int(signal.SIGABRT)}"
    monkeypatch.setattr(execute, "_job_command", _writes_ok)
    second = execute.execute_job(str(tmp_path), _job())
    assert second["reused"] and second["status"] == "failed"  # the cache keeps a job's own crash


def test_an_interruption_cached_by_an_older_version_runs_again(tmp_path, monkeypatch):
    """A cache written before interruptions were left out holds them as failures: they are computed again, and a
    job's own failure beside them is still reused."""
    for key, error in (("k1", "process killed by signal 15"), ("k2", "process killed by signal 11")):
        folder = job_folder(tmp_path, "plant", key)
        folder.mkdir(parents=True)
        (folder / "status.json").write_text(json.dumps({"status": "failed", "error": error, "kind": "plant",
                                                        "key": key}))
    monkeypatch.setattr(execute, "_job_command", _writes_ok)
    again = execute.execute_job(str(tmp_path), _job())
    assert again["status"] == "ok" and not again["reused"]
    kept = execute.execute_job(str(tmp_path), asdict(Job("plant", "k2", {})))
    assert kept["reused"] and kept["error"] == "process killed by signal 11"
