"""Aggregating a tidy results table: per-method (and per-species / per-family) means with bootstrap intervals.

Pure functions over pandas DataFrames with the columns of :data:`plantbench.runner.run.RESULT_COLUMNS`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["bootstrap_ci", "aggregate", "summary_table", "KEY_METRICS", "metric_info"]

# the columns shown first (when present), in this order
KEY_METRICS = (
    "stava.S_T",
    "mesh_to_surface.D_cm",
    "mesh_to_surface.sigma_cm",
    "mesh_to_scan.D_cm",
    "reprojection.error",
    "reprojection.iou",
    "leaves.accuracy",
    "skeleton.f1@1.0",
    "points.all.fscore@1%",
    "runtime_s",
)


def metric_info(name: str):
    """The registered MetricInfo of ``name``, or None (run-level columns such as runtime_s are not metrics)."""
    from plantbench.registry import metrics

    try:
        return metrics.get(name)
    except Exception:  # noqa: BLE001 - unknown or not yet registered
        return None


def bootstrap_ci(values: np.ndarray, *, n_boot: int = 2000, level: float = 0.95, seed: int = 0) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of ``values`` (n,); (nan, nan) when empty, (v, v) when n == 1."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return float("nan"), float("nan")
    if v.size == 1:
        return float(v[0]), float(v[0])
    rng = np.random.Generator(np.random.PCG64(seed))
    means = v[rng.integers(0, v.size, (n_boot, v.size))].mean(axis=1)
    a = (1 - level) / 2
    lo, hi = np.quantile(means, [a, 1 - a])
    return float(lo), float(hi)


def aggregate(table, by: tuple[str, ...] = ("method",), *, n_boot: int = 2000, seed: int = 0):
    """Mean, 95 % bootstrap interval, count of ok values and of failed cells per group and metric.

    Returns a DataFrame with columns ``by + (metric, mean, lo, hi, n, failed)``.
    """
    import pandas as pd

    rows = []
    for key, grp in table.groupby(list(by) + ["metric"], sort=True, dropna=False):
        ok = grp.loc[grp["status"] == "ok", "value"].to_numpy(float)
        ok = ok[np.isfinite(ok)]
        lo, hi = bootstrap_ci(ok, n_boot=n_boot, seed=seed)
        rows.append({**dict(zip(list(by) + ["metric"], key if isinstance(key, tuple) else (key,))),
                     "mean": float(ok.mean()) if ok.size else float("nan"), "lo": lo, "hi": hi,
                     "n": int(ok.size), "failed": int((grp["status"] != "ok").sum())})
    return pd.DataFrame(rows, columns=list(by) + ["metric", "mean", "lo", "hi", "n", "failed"])


def _fmt(mean: float, lo: float, hi: float) -> str:
    """'mean ± half-width of the interval' (compact, for terminals)."""
    if not np.isfinite(mean):
        return "-"
    if not np.isfinite(lo) or lo == hi:
        return f"{mean:.3g}"
    return f"{mean:.3g} ±{(hi - lo) / 2:.2g}"


def summary_table(table, metrics: tuple[str, ...] = KEY_METRICS):
    """A rich Table for the terminal: one row per key metric, one column per method, cells 'mean [95 % CI]',
    and a last row counting failed cells (metrics down the side fit a terminal better than across)."""
    from rich.table import Table

    agg = aggregate(table)
    present = [m for m in metrics if m in set(agg["metric"])]
    methods = sorted(agg["method"].unique())
    out = Table("metric", *methods, title="results: mean ± half-width of the 95 % bootstrap CI over cases")
    idx = agg.set_index(["metric", "method"])
    for m in present:
        info = metric_info(m)
        label = m + ("" if info is None or info.higher_is_better is None else " ↑" if info.higher_is_better else " ↓")
        out.add_row(label, *(_fmt(*idx.loc[(m, meth), ["mean", "lo", "hi"]]) if (m, meth) in idx.index else "-"
                             for meth in methods))
    cells = table.groupby(["method", "case"])["status"].agg(lambda s: (s != "ok").any())
    failed = cells.groupby(level=0).sum()
    out.add_row("failed cells", *(str(int(failed.get(meth, 0))) for meth in methods))
    return out
