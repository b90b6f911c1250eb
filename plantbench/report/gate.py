"""``plantbench gate``: compare a run's per-method metric means with a committed baseline.

The baseline (``reports/baseline.json``) lists, per (method, metric), the reference mean, an absolute tolerance and
the metric's direction. A metric regresses when it moves in its bad direction by more than its tolerance, or when
a cell that had a value in the baseline now has none (a method that newly fails). Improvements never fail the
gate. Running times are not gated (they measure the machine, not the method).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from pydantic import Field

from plantbench.errors import InputError
from plantbench.io.atomic import write_json
from plantbench.schemas import Strict, load_json

__all__ = ["BaselineEntry", "Baseline", "read_results", "compare", "make_baseline", "write_baseline"]

UNGATED = ("runtime_s",)


class BaselineEntry(Strict):
    method: str
    metric: str
    value: float = Field(description="reference mean over the suite's cases")
    tolerance: float = Field(ge=0, description="allowed move in the bad direction, in the metric's unit")
    higher_is_better: bool


class Baseline(Strict):
    format: str = "plantbench.baseline/1"
    suite: str
    entries: list[BaselineEntry]


def read_results(run_dir: str | os.PathLike):
    """The tidy results table of a run folder (results.parquet, else results.csv)."""
    import pandas as pd

    run_dir = Path(run_dir)
    for name, reader in (("results.parquet", pd.read_parquet), ("results.csv", pd.read_csv)):
        path = run_dir / name
        if path.exists():
            try:
                table = reader(path)
            except Exception as exc:  # noqa: BLE001 - corrupt file
                raise InputError(f"unreadable results table ({exc})", path=path) from None
            missing = {"method", "metric", "value", "status"} - set(table.columns)
            if missing:
                raise InputError(f"missing columns {sorted(missing)}", path=path)
            return table
    raise InputError("no results.parquet or results.csv (is this a run folder?)", path=run_dir)


def _direction(metric: str) -> bool | None:
    """True/False for a registered metric with a direction; None for a descriptive value (a count, a height)."""
    from plantbench.report.tables import metric_info

    info = metric_info(metric)
    if info is None:
        raise InputError(f"metric {metric!r} is not registered: its direction is unknown")
    return info.higher_is_better


def compare(table, baseline: Baseline):
    """One row per baseline entry: method, metric, baseline, value, tolerance, delta, regressed."""
    import pandas as pd

    from plantbench.report.tables import aggregate

    agg = aggregate(table, n_boot=1).set_index(["method", "metric"])
    rows = []
    for e in baseline.entries:
        value = float(agg.loc[(e.method, e.metric), "mean"]) if (e.method, e.metric) in agg.index else float("nan")
        if math.isnan(value):
            regressed, delta = True, float("nan")
        else:
            delta = value - e.value
            bad_move = -delta if e.higher_is_better else delta
            regressed = bad_move > e.tolerance
        rows.append({"method": e.method, "metric": e.metric, "baseline": e.value, "value": value,
                     "tolerance": e.tolerance, "delta": delta, "higher_is_better": e.higher_is_better,
                     "regressed": regressed})
    return pd.DataFrame(rows)


def make_baseline(table, suite: str, *, rel_tol: float = 0.05, abs_tol: float = 1e-3) -> Baseline:
    """A baseline from a run: every (method, metric) mean with tolerance max(abs_tol, rel_tol * |mean|).

    Descriptive values without a direction (counts, heights) and running times are not gated.
    """
    from plantbench.report.tables import aggregate

    agg = aggregate(table, n_boot=1)
    entries = []
    for r in agg.itertuples():
        if r.metric in UNGATED or not math.isfinite(r.mean):
            continue
        direction = _direction(r.metric)
        if direction is None:
            continue
        entries.append(BaselineEntry(method=r.method, metric=r.metric, value=r.mean,
                                     tolerance=max(abs_tol, rel_tol * abs(r.mean)), higher_is_better=direction))
    return Baseline(suite=suite, entries=entries)


def write_baseline(path: str | os.PathLike, baseline: Baseline) -> None:
    write_json(path, baseline.model_dump(mode="json"))


def load_baseline(path: str | os.PathLike) -> Baseline:
    return load_json(path, Baseline)
