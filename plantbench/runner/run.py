"""``plantbench run``: plan a suite, execute it, write the tidy results table and the run metadata.

Run folder layout (``OUT/SUITE/``): ``results.parquet``, ``results.csv`` (case, species, family, seed, method,
sweep, metric, value, status), ``run.json`` (versions, git SHA, config hash, Mitsuba variant, counts),
``cells.json`` (per cell: the capture and reconstruction folders in the cache, relative to the run folder) and
``logs/`` (a link to the log of every failed cell). The content-addressed job cache is shared by all suites
under ``OUT/cache/``.
"""

from __future__ import annotations

import json
import os
import platform
import re
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from plantbench.io.atomic import atomic_write, write_json
from plantbench.paths import project_root
from plantbench.runner.execute import ExecutionStats, execute_plan
from plantbench.runner.plan import Cell, Plan, content_hash, make_plan
from plantbench.runner.worker import job_folder
from plantbench.suites import Suite

__all__ = ["RunResult", "run_suite", "run_metadata", "RESULT_COLUMNS", "PACKAGES"]

RESULT_COLUMNS = ["case", "species", "family", "seed", "method", "sweep", "metric", "value", "status"]
PACKAGES = ("plantbench", "numpy", "scipy", "mitsuba", "drjit", "open3d-cpu", "pycolmap", "trimesh", "pandas",
            "pydantic", "scikit-image", "opencv-python-headless")


@dataclass(frozen=True)
class RunResult:
    run_dir: Path
    table: object  # pandas.DataFrame
    stats: ExecutionStats
    seconds: float


def _slug(text: str) -> str:
    """A file-name-safe version of a case or method name (external commands contain paths and spaces)."""
    safe = re.sub(r"[^A-Za-z0-9._@-]+", "_", text).strip("_")
    return safe if len(safe) <= 60 else safe[:40] + "-" + content_hash(text)[:8]


def git_sha() -> str | None:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=project_root(), capture_output=True, text=True,
                             timeout=10)
        sha = out.stdout.strip() if out.returncode == 0 else None
        if sha:
            dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=project_root(),
                                   capture_output=True, text=True, timeout=10).stdout.strip()
            return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.TimeoutExpired):
        pass
    return None


def oracle_methods(suite: Suite, methods: list[str]) -> list[str]:
    """The methods of a run that read ground truth with the suite's options (marked in every table): oracles
    themselves, and the 'points' methods of a views suite whose mvs stage is one (its oracle depth makes their
    cloud)."""
    from plantbench.methods.api import method_from_spec, split_cloud
    from plantbench.methods.inputs import is_oracle
    from plantbench.runner.plan import method_options

    cloud_is_oracle = suite.source != "scan" and is_oracle(method_from_spec("mvs"), suite.method_options.get("mvs", {}))
    out = []
    for m in methods:
        spec, oracle_cloud = split_cloud(m)
        method = method_from_spec(spec)
        if is_oracle(method, method_options(suite, m)) or ((cloud_is_oracle or oracle_cloud) and method.inputs == "points"):
            out.append(m)
    return out


def run_metadata(suite: Suite, methods: list[str]) -> dict:
    """What every results file records: versions, git SHA, config hash, Mitsuba variant."""
    from plantbench import __version__
    from plantbench.backend import dispatch_id, llvm_target_id, select_variant
    from plantbench.metrics.info import HEADLINE

    pkgs = {}
    for name in PACKAGES:
        try:
            pkgs[name] = version(name)
        except PackageNotFoundError:
            pkgs[name] = None
    config = suite.model_dump(mode="json")
    return {
        "plantbench_version": __version__,
        "git_sha": git_sha(),
        "suite": suite.name,
        "methods": methods,
        "config": config,
        "config_hash": content_hash([config, methods]),
        "root_seed": suite.root_seed,
        "mitsuba_variant": select_variant(),
        "llvm_target": llvm_target_id(),
        "dispatch": dispatch_id(),
        "headline": list(HEADLINE),
        "packages": pkgs,
        "python": platform.python_version(),
        "platform": platform.platform(),
    }


def run_suite(
    suite: Suite,
    out: Path,
    *,
    methods: list[str] | None = None,
    workers: int = 1,
    executor: str = "local",
    scheduler: str | None = None,
    client=None,
    progress: Callable[[int, int, dict], None] | None = None,
    dataset: str | os.PathLike | tuple | None = None,
) -> RunResult:
    """Run ``suite`` into ``out/<suite>/`` with the shared cache ``out/cache``; return the results table.

    ``dataset``: a frozen dataset of the suite (:mod:`plantbench.dataset`), verified file by file before any work
    (or the (folder, manifest) that :func:`plantbench.dataset.open_dataset` returned); its captures replace
    generating and capturing, and run.json records its manifest's sha256."""
    t0 = time.perf_counter()
    frozen = None
    if dataset is not None:
        from plantbench.io.manifest import open_dataset

        frozen = dataset if isinstance(dataset, tuple) else open_dataset(dataset, suite)
    plan = make_plan(suite, methods, dataset=frozen)  # validates species and methods before any work
    method_names = methods or list(suite.methods)
    out = Path(out)
    cache = out / "cache"
    run_dir = out / suite.name
    run_dir.mkdir(parents=True, exist_ok=True)
    meta = _start_metadata(suite, method_names, frozen)
    records, stats = execute_plan(plan, cache, workers=workers, executor=executor, scheduler=scheduler,
                                  client=client, progress=progress)
    cell_metrics = _read_cell_metrics(plan, records, cache)
    rows = _result_rows(plan, records, cell_metrics, cache, run_dir / "logs")
    _write_cells(plan, records, cache, run_dir)
    _write_timeline(plan, records, run_dir)
    table = _write_results(rows, run_dir)
    seconds = time.perf_counter() - t0
    meta.update(finished=time.strftime("%Y-%m-%dT%H:%M:%S%z"), seconds=seconds,
                counts={k: v for k, v in stats.items()}, cells=len(plan.cells),
                failed_cells=sum(1 for c in plan.cells if c not in cell_metrics))
    write_json(run_dir / "run.json", meta)
    return RunResult(run_dir, table, stats, seconds)


def _start_metadata(suite: Suite, method_names: list[str], frozen: tuple | None) -> dict:
    """run.json as it stands before any job runs: :func:`run_metadata`, the start time, the oracle methods and the
    frozen dataset (its folder, manifest sha256, and the code and CPU that made it)."""
    meta = run_metadata(suite, method_names)
    meta["started"] = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    meta["oracles"] = oracle_methods(suite, method_names)
    if frozen is not None:
        from plantbench.io.manifest import manifest_sha256

        meta["dataset"] = {"path": str(frozen[0].resolve()), "manifest_sha256": manifest_sha256(frozen[0]),
                           "git_sha": frozen[1].git_sha, "llvm_target": frozen[1].llvm_target}
    return meta


def _read_cell_metrics(plan: Plan, records: dict[str, dict], cache: Path) -> dict:
    """{cell: its metrics.json} for every cell whose reconstruction and metrics jobs both succeeded."""
    cell_metrics = {}
    for cell in plan.cells:
        if records[cell.recon_key]["status"] == "ok" and records[cell.metrics_key]["status"] == "ok":
            path = job_folder(cache, "metrics", cell.metrics_key) / "metrics.json"
            cell_metrics[cell] = json.loads(path.read_text())
    return cell_metrics


def _sweep(cell: Cell) -> str | None:
    """A cell's sweep value as the tables write it (None outside a sweep)."""
    return None if cell.sweep_value is None else str(cell.sweep_value)


def _result_rows(plan: Plan, records: dict[str, dict], cell_metrics: dict, cache: Path, logs: Path) -> list[dict]:
    """The rows of the tidy results table: per successful cell its metrics (by name) and runtime_s; per failed cell
    every metric any cell has (or 'score' when none has), valued None with the failed job's status, and a link to
    that job's log in ``logs``."""
    metric_names = sorted(set().union(*cell_metrics.values()))
    rows = []
    for cell in plan.cells:
        base = {"case": cell.case, "species": cell.species, "family": cell.family, "seed": cell.seed,
                "method": cell.method, "sweep": _sweep(cell)}
        rec = records[cell.recon_key]
        if cell in cell_metrics:
            for name, value in sorted(cell_metrics[cell].items()):
                rows.append({**base, "metric": name, "value": value, "status": "ok"})
            rows.append({**base, "metric": "runtime_s", "value": rec.get("seconds"), "status": "ok"})
            continue
        status = rec["status"] if rec["status"] != "ok" else "failed"  # ok recon, failed metrics
        failed_key, kind = (cell.recon_key, "method") if rec["status"] != "ok" else (cell.metrics_key, "metrics")
        for name in metric_names or ["score"]:
            rows.append({**base, "metric": name, "value": None, "status": status})
        log = job_folder(cache, kind, failed_key) / "job.log"
        _link_log(log, logs / f"{_slug(cell.case)}.{_slug(cell.method)}.log")
    return rows


def _link_log(log: Path, link: Path) -> None:
    """Point ``link`` (relative) at a failed job's ``log``, replacing an older link; nothing if there is no log."""
    if not log.exists():
        return
    link.parent.mkdir(exist_ok=True)
    if link.is_symlink() or link.exists():
        link.unlink()
    link.symlink_to(os.path.relpath(log, link.parent))


def _write_cells(plan: Plan, records: dict[str, dict], cache: Path, run_dir: Path) -> None:
    """cells.json: where each cell's inputs and outputs are (relative to the run folder); the report draws from
    them."""

    def status(c: Cell) -> str:
        recon = records[c.recon_key]["status"]
        return recon if recon != "ok" else records[c.metrics_key]["status"]

    write_json(run_dir / "cells.json", [
        {"case": c.case, "species": c.species, "family": c.family, "method": c.method, "sweep": _sweep(c),
         "capture": os.path.relpath(job_folder(cache, "capture", c.case_key), run_dir),
         "recon": os.path.relpath(job_folder(cache, "method", c.recon_key), run_dir),
         "status": status(c)}
        for c in plan.cells])


TIMELINE_COLUMNS = ["kind", "job", "species", "key", "status", "reused", "started", "finished", "seconds", "threads"]


def _write_timeline(plan: Plan, records: dict[str, dict], run_dir: Path) -> None:
    """timeline.csv: every job of the run with its start and end (epoch seconds; a reused job keeps the times of
    the run that computed it), its status and the threads of plantbench's pools it had."""
    import pandas as pd

    rows = []
    for key, job in plan.jobs.items():
        rec = records.get(key, {})
        rows.append({"kind": job.kind, "job": job.params.get("method", job.kind),
                     "species": job.params.get("species", ""), "key": key, "status": rec.get("status"),
                     "reused": bool(rec.get("reused")), "started": rec.get("started"),
                     "finished": rec.get("finished"), "seconds": rec.get("seconds"), "threads": rec.get("threads")})
    with atomic_write(run_dir / "timeline.csv", "w") as fh:
        pd.DataFrame(rows, columns=TIMELINE_COLUMNS).to_csv(fh, index=False)


def _write_results(rows: list[dict], run_dir: Path):
    """The results table (a pandas DataFrame of :data:`RESULT_COLUMNS`), written as results.parquet and
    results.csv."""
    import pandas as pd

    table = pd.DataFrame(rows, columns=RESULT_COLUMNS)
    table["value"] = table["value"].astype(float)
    with atomic_write(run_dir / "results.parquet") as fh:
        table.to_parquet(fh, index=False)
    with atomic_write(run_dir / "results.csv", "w") as fh:
        table.to_csv(fh, index=False)
    return table
