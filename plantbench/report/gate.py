"""``plantbench gate``: compare a run's headline metrics, per method and case, with a committed baseline.

The baseline (``reports/baseline.json``) holds the reference value of every gated metric (:data:`GATED`: the headline and the paper's columns) of
every (method, case) cell of a suite, and of each method's mean over the cases (case :data:`MEAN`), with the
metric's direction. The tolerances (``reports/tolerances.json``,
beside it) come from the variability study (:mod:`plantbench.report.variability`): the suite run again under
perturbations that carry no meaning, one tolerance per cell and metric, max(3 x spread, largest change seen, floor).
A metric regresses when it moves in its bad direction by more than its tolerance, or when a cell that had a value
in the baseline now has none (a method that newly fails), unless the study saw that cell fail too (``may_fail``).
Improvements never fail the gate. Running times and the other raw columns are not gated: they stay in the results
table for reproduction.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from pydantic import Field

from plantbench.errors import InputError
from plantbench.io.atomic import write_json
from plantbench.metrics.info import KEY_METRICS, METRICS
from plantbench.schemas import Strict, load_json

__all__ = ["GATED", "FLOORS", "MEAN", "BaselineEntry", "Baseline", "ToleranceEntry", "Tolerances", "read_results",
           "read_run_meta", "cell_values", "compare", "make_baseline", "write_baseline", "load_baseline", "load_tolerances",
           "write_tolerances", "tolerances_path", "regression_lines"]

GATED = KEY_METRICS
"""The gated metrics: the headline and the reference paper's columns (:data:`plantbench.metrics.info.KEY_METRICS`);
not the running time."""

FLOORS = {m: METRICS[m].floor for m in GATED}
"""Smallest tolerance per gated metric, in its unit (:attr:`plantbench.metrics.info.MetricInfo.floor`): a change
below it is never a regression, even in a cell the study saw perfectly stable (the ground truth's own rows, a
deterministic method)."""


class BaselineEntry(Strict):
    method: str
    case: str
    metric: str
    value: float = Field(description="the metric's value in this cell of the reference run")
    higher_is_better: bool


class Baseline(Strict):
    format: str = "plantbench.baseline/2"
    suite: str
    llvm_target: str | None = Field(default=None, description="Dr.Jit code generation of the reference run")
    git_sha: str | None = None
    entries: list[BaselineEntry]


class ToleranceEntry(Strict):
    method: str
    case: str
    metric: str
    tolerance: float = Field(ge=0, description="allowed move in the bad direction, in the metric's unit")
    sd: float = Field(ge=0, description="standard deviation of the value over the study's runs")
    max_change: float = Field(ge=0, description="largest |change| from the reference run seen in the study")
    runs: int = Field(ge=0, description="runs of the study with a value in this cell")
    bound: str = Field(description="which term set the tolerance: 'spread' (3 x sd), 'max_change' or 'floor'")
    may_fail: bool = Field(default=False, description="the cell failed in a run of the study (a meaningless "
                                                      "perturbation): its failing now is not a regression")


class Tolerances(Strict):
    format: str = "plantbench.tolerances/1"
    suite: str
    rule: str = "max(3 x sd, max |change from the reference run|, floor)"
    perturbations: list[str] = Field(description="the study's runs, the reference first")
    floors: dict[str, float]
    entries: list[ToleranceEntry]


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
            missing = {"case", "method", "metric", "value", "status"} - set(table.columns)
            if missing:
                raise InputError(f"missing columns {sorted(missing)}", path=path)
            return table
    raise InputError("no results.parquet or results.csv (is this a run folder?)", path=run_dir)


def read_run_meta(run_dir: str | os.PathLike) -> dict:
    """A run folder's run.json (versions, git SHA, Dr.Jit target, oracles, dataset), or {} when it has none."""
    import json

    try:
        return json.loads((Path(run_dir) / "run.json").read_text())
    except (OSError, ValueError):
        return {}


def _direction(metric: str) -> bool | None:
    """True/False for a registered metric with a direction; None for a descriptive value (a count, a height)."""
    from plantbench.report.tables import metric_info

    info = metric_info(metric)
    if info is None:
        raise InputError(f"metric {metric!r} is not registered: its direction is unknown")
    return info.higher_is_better


MEAN = "mean"
"""The case name of a method's mean over the suite's cases (the number a paper table shows), gated beside the cases."""


def cell_values(table, metrics: tuple[str, ...] = GATED) -> dict[tuple[str, str, str], float]:
    """(method, case, metric) -> value of each headline metric in ``table``, NaN where the cell failed; and
    (method, :data:`MEAN`, metric) -> the mean over the method's cases (NaN when one of them failed)."""
    rows = table[table["metric"].isin(metrics) & (table["case"] != MEAN)]  # a table's own mean rows are recomputed
    out = {}
    for r in rows.itertuples():
        v = float(r.value) if r.status == "ok" and r.value is not None else float("nan")
        out[(r.method, r.case, r.metric)] = v
    per_method: dict[tuple[str, str], list[float]] = {}
    for (method, _, metric), v in out.items():
        per_method.setdefault((method, metric), []).append(v)
    for (method, metric), values in per_method.items():
        out[(method, MEAN, metric)] = float(sum(values) / len(values))
    return out


def tolerances_path(baseline: str | os.PathLike) -> Path:
    """Where the tolerances of ``baseline`` live: tolerances.json beside it."""
    return Path(baseline).with_name("tolerances.json")


def compare(table, baseline: Baseline, tolerances: Tolerances | None = None):
    """One row per baseline entry: method, case, metric, baseline, value, delta, tolerance, source, regressed.

    ``source`` says where the tolerance came from: 'study' (``tolerances``) or 'floor' (a cell the study did not
    cover: :data:`FLOORS`)."""
    import pandas as pd

    now = cell_values(table, tuple({e.metric for e in baseline.entries}))
    tol = {(t.method, t.case, t.metric): t.tolerance for t in (tolerances.entries if tolerances else [])}
    flaky = {(t.method, t.case, t.metric) for t in (tolerances.entries if tolerances else []) if t.may_fail}
    floors = tolerances.floors if tolerances else FLOORS
    rows = []
    for e in baseline.entries:
        key = (e.method, e.case, e.metric)
        value = now.get(key, float("nan"))
        tolerance, source = (tol[key], "study") if key in tol else (floors.get(e.metric, FLOORS.get(e.metric, 0.0)),
                                                                    "floor")
        if math.isnan(value):
            regressed, delta = not math.isnan(e.value) and key not in flaky, float("nan")
        else:
            delta = value - e.value
            bad_move = -delta if e.higher_is_better else delta
            # a relative 1e-9 of slack: a tolerance set by a study run's own change (max_change) must pass that run,
            # whose value the study and the baseline round differently in the last bits
            regressed = bad_move > tolerance * (1 + 1e-9) + 1e-12
        rows.append({"method": e.method, "case": e.case, "metric": e.metric, "baseline": e.value, "value": value,
                     "delta": delta, "tolerance": tolerance, "source": source,
                     "higher_is_better": e.higher_is_better, "regressed": bool(regressed)})
    return pd.DataFrame(rows, columns=["method", "case", "metric", "baseline", "value", "delta", "tolerance", "source",
                                       "higher_is_better", "regressed"])


def make_baseline(table, suite: str, *, llvm_target: str | None = None, git_sha: str | None = None) -> Baseline:
    """A baseline from a run: the value of every headline metric in every (method, case) cell that has one."""
    entries = []
    for (method, case, metric), value in sorted(cell_values(table).items()):
        direction = _direction(metric)
        if direction is None or not math.isfinite(value):
            continue
        entries.append(BaselineEntry(method=method, case=case, metric=metric, value=value,
                                     higher_is_better=direction))
    return Baseline(suite=suite, llvm_target=llvm_target, git_sha=git_sha, entries=entries)


def write_baseline(path: str | os.PathLike, baseline: Baseline) -> None:
    write_json(path, baseline.model_dump(mode="json"))


def load_baseline(path: str | os.PathLike) -> Baseline:
    return load_json(path, Baseline)


def write_tolerances(path: str | os.PathLike, tolerances: Tolerances) -> None:
    write_json(path, tolerances.model_dump(mode="json"))


def load_tolerances(path: str | os.PathLike) -> Tolerances:
    return load_json(path, Tolerances)


def regression_lines(result) -> list[str]:
    """One plain line per regressed row of :func:`compare`'s table, every field whole (for a log: no box, no cut):
    'regressed: method=xu case=maple-1 metric=reprojection.iou baseline=0.2492 now=0.08534 change=-0.164
    tolerance=0.0916 better=higher' ('now=missing' for a cell that newly failed; 'tolerance=... (floor)' where the
    study did not cover the cell)."""
    lines = []
    for r in result[result["regressed"]].itertuples():
        missing = r.value != r.value
        lines.append(f"regressed: method={r.method} case={r.case} metric={r.metric} baseline={r.baseline:.4g} "
                     f"now={'missing' if missing else f'{r.value:.4g}'} change={'none' if missing else f'{r.delta:+.3g}'} "
                     f"tolerance={r.tolerance:.3g}{' (floor)' if r.source == 'floor' else ''} "
                     f"better={'higher' if r.higher_is_better else 'lower'}")
    return lines
