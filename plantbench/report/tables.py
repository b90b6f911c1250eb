"""Aggregating a tidy results table: per-method (and per-species / per-family) means with bootstrap intervals.

Pure functions over pandas DataFrames with the columns of :data:`plantbench.runner.run.RESULT_COLUMNS`.
"""

from __future__ import annotations

import numpy as np

from plantbench.metrics.info import HEADLINE, short_label
from plantbench.metrics.info import KEY_METRICS as _KEY

__all__ = ["bootstrap_ci", "stratified_bootstrap_ci", "aggregate", "KEY_METRICS", "metric_info", "paired_differences",
           "format_value", "HEADLINE", "compare_runs", "summary_lines"]

KEY_METRICS = (*_KEY, "runtime_s")
"""The columns of the report's first table, in this order (when present): :data:`plantbench.metrics.info.KEY_METRICS`
and the running time."""


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


def format_value(v: float, unit: str = "") -> str:
    """Fixed notation for a table: 2840 (never 2.84e+03), 12.3, 0.412; '-' for a missing value."""
    if v is None or not np.isfinite(v):
        return "-"
    a = abs(v)
    if a >= 100 or (a == int(a) and a >= 10):
        return f"{v:.0f}"
    if a >= 10 or unit == "cm":
        return f"{v:.1f}" if a >= 10 else f"{v:.2f}"
    return f"{v:.3f}"


def stratified_bootstrap_ci(values: np.ndarray, strata: np.ndarray, *, n_boot: int = 2000, level: float = 0.95,
                            seed: int = 0) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of ``values`` (n,) resampled within each stratum (``strata``, (n,)
    labels: the species of a suite whose species are its fixed design, each stratum keeping its size); (nan, nan)
    when a stratum holds fewer than 2 values (resampling one value gives no interval) or there is one stratum (the
    plain bootstrap, :func:`bootstrap_ci`, is then the same interval)."""
    v = np.asarray(values, float)
    labels = np.asarray(strata)
    keep = np.isfinite(v)
    v, labels = v[keep], labels[keep]
    groups = [v[labels == s] for s in sorted(set(labels.tolist()))]
    if len(groups) < 2 or min(len(g) for g in groups) < 2:
        return float("nan"), float("nan")
    rng = np.random.Generator(np.random.PCG64(seed))
    sums = np.zeros(n_boot)
    for g in groups:
        sums += g[rng.integers(0, g.size, (n_boot, g.size))].sum(axis=1)
    a = (1 - level) / 2
    lo, hi = np.quantile(sums / v.size, [a, 1 - a])
    return float(lo), float(hi)


def _verdict(a: str, b: str, lo: float, hi: float, higher: bool | None, n: int) -> str:
    """'a beats b' when the interval excludes 0 on the metric's good side, 'a below b' on its bad side, else
    'within noise'."""
    if n > 1 and higher is not None and np.isfinite(lo) and (lo > 0 or hi < 0):
        return f"{a} beats {b}" if (lo > 0) == bool(higher) else f"{a} below {b}"
    return "within noise"


def _paired_values(table, metrics: tuple[str, ...], failed_as_zero: bool):
    """(metric, case) x method values and the species of each case; with ``failed_as_zero``, a failed cell of a
    higher-is-better metric counts 0 (a method that returns nothing has shown nothing)."""
    sub = table[table["metric"].isin(metrics)].copy()
    ok = sub["status"] == "ok"
    if failed_as_zero:
        higher = sub["metric"].map(lambda m: bool(getattr(metric_info(m), "higher_is_better", None)))
        sub.loc[~ok & higher, "value"] = 0.0
        ok |= higher
    sub = sub[ok]
    wide = sub.pivot_table(index=["metric", "case"], columns="method", values="value", aggfunc="first")
    species = sub.drop_duplicates("case").set_index("case")["species"] if "species" in sub.columns else None
    return wide, species


def paired_differences(table, metrics: tuple[str, ...], pairs: list[tuple[str, str]], *, n_boot: int = 5000,
                       level: float = 0.95, seed: int = 0, failed_as_zero: bool = False):
    """Method a minus method b per metric, paired over the cases both scored: mean difference, percentile bootstrap
    interval of the mean (cases resampled), and a verdict in the metric's direction: 'a beats b' only when the
    interval excludes 0 on the good side, 'a below b' when it excludes 0 on the bad side, else 'within noise'. A pair
    with no case scored by both is left out. With ``failed_as_zero`` a failed cell of a higher-is-better metric
    counts 0 instead of leaving the pair.

    A suite with two or more cases of every species (seeds of a fixed set of species, multiview-30) also gets the
    interval with the seeds resampled within each species (``lo_species``, ``hi_species``): the species are the
    suite's design, and that interval is the one for claims about them; the verdict is then read from it. The
    across-plant interval (``lo``, ``hi``) stays beside it, the interval for claims about new species. With one case
    of a species the within-species columns are NaN and the verdict is the across-plant one.

    ``mdd``, the minimum detectable difference, is the verdict's interval's half-width: the smallest mean difference
    this suite's n cases and their spread let the paired bootstrap tell from 0.

    Returns a DataFrame: metric, a, b, n, diff, lo, hi, lo_species, hi_species, mdd, verdict.
    """
    import pandas as pd

    wide, species = _paired_values(table, metrics, failed_as_zero)
    cols = ["metric", "a", "b", "n", "diff", "lo", "hi", "lo_species", "hi_species", "mdd", "verdict"]
    rows = []
    for metric in metrics:
        if metric not in wide.index.get_level_values(0):
            continue
        info = metric_info(metric)
        higher = info.higher_is_better if info is not None else None
        w = wide.loc[metric]
        for a, b in pairs:
            if a not in w.columns or b not in w.columns:
                continue
            diff = w[a] - w[b]
            diff = diff[np.isfinite(diff.to_numpy(float))]
            d = diff.to_numpy(float)
            if d.size == 0:  # one of the two does not score this metric (e.g. a skeleton-only method's surface)
                continue
            lo, hi = bootstrap_ci(d, n_boot=n_boot, level=level, seed=seed)
            ls, hs = (stratified_bootstrap_ci(d, species.reindex(diff.index).to_numpy(), n_boot=n_boot, level=level,
                                              seed=seed) if species is not None else (float("nan"),) * 2)
            vlo, vhi = (ls, hs) if np.isfinite(ls) else (lo, hi)
            rows.append({"metric": metric, "a": a, "b": b, "n": int(d.size), "diff": float(d.mean()), "lo": lo,
                         "hi": hi, "lo_species": ls, "hi_species": hs,
                         "mdd": (vhi - vlo) / 2 if d.size > 1 else float("nan"),
                         "verdict": _verdict(a, b, vlo, vhi, higher, d.size)})
    return pd.DataFrame(rows, columns=cols)


def compare_runs(table_a, table_b, *, label_a: str = "a", label_b: str = "b", metrics: tuple[str, ...] = KEY_METRICS,
                 n_boot: int = 5000, seed: int = 0):
    """Each method of two runs of the same cases (e.g. on the mvs cloud and on the oracle cloud, or with and without
    a hint), paired over the cases both scored: the two means, and run b minus run a with its bootstrap interval and
    verdict (:func:`paired_differences`; 'b better' / 'b worse' in the metric's direction). Methods in only one run
    are left out.

    Returns a DataFrame: method, metric, n, mean_a, mean_b, diff (b - a), lo, hi, verdict.
    """
    import pandas as pd

    cols = ["method", "metric", "n", "mean_a", "mean_b", "diff", "lo", "hi", "verdict"]
    common = sorted(set(table_a["method"]) & set(table_b["method"]))
    rows = []
    for method in common:
        a = table_a[table_a["method"] == method].assign(method=label_a)
        b = table_b[table_b["method"] == method].assign(method=label_b)
        both = pd.concat([a, b], ignore_index=True)
        diff = paired_differences(both, metrics, [(label_b, label_a)], n_boot=n_boot, seed=seed)
        means = both[(both["status"] == "ok")].pivot_table(index=["metric", "case"], columns="method", values="value",
                                                          aggfunc="first")
        for r in diff.itertuples():
            w = means.loc[r.metric].dropna()  # the cases both scored, as the difference uses
            verdict = r.verdict.replace(f"{label_b} beats {label_a}", f"{label_b} better").replace(
                f"{label_b} below {label_a}", f"{label_b} worse")
            rows.append({"method": method, "metric": r.metric, "n": r.n, "mean_a": float(w[label_a].mean()),
                         "mean_b": float(w[label_b].mean()), "diff": r.diff, "lo": r.lo, "hi": r.hi,
                         "verdict": verdict})
    return pd.DataFrame(rows, columns=cols)


def _compact(mean: float, lo: float, hi: float) -> str:
    """'0.531±0.12': the mean to 3 significant digits, the half-width of its interval to 2 (no '±' for one case)."""
    if not np.isfinite(mean):
        return "-"
    text = f"{mean:.3f}" if abs(mean) < 10 else f"{mean:.3g}"
    if np.isfinite(lo) and lo != hi:
        text += f"±{(hi - lo) / 2:.2g}"
    return text


def _column_blocks(rows: list[list[str]], width: int) -> list[list[int]]:
    """Column indices in blocks whose lines fit ``width`` characters, each block led by the first (label) column."""
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    blocks: list[list[int]] = [[0]]
    for i in range(1, len(widths)):
        if len(blocks[-1]) > 1 and sum(widths[j] + 2 for j in blocks[-1]) + widths[i] > width:
            blocks.append([0])
        blocks[-1].append(i)
    return blocks


def _aligned(rows: list[list[str]]) -> list[str]:
    """Rows as lines: the first column left-aligned, the others right-aligned, two spaces apart."""
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return ["  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))).rstrip()
            for r in rows]


def summary_lines(table, metrics: tuple[str, ...] = HEADLINE, *, oracles: tuple[str, ...] = ()) -> list[str]:
    """The run summary as plain text: methods down the side, the headline metrics across (short labels), cells
    'mean±half-width of the 95 % bootstrap interval over cases', a last column counting failed cells. Plain
    characters only, fitting an 80-column terminal for the headline (no cell is cut: the columns are as wide as
    their widest entry), so it reads the same on a terminal, in a pipe and in a CI log. ``oracles``: methods marked
    with '*' (they read ground truth)."""
    agg = aggregate(table)
    scored = set(agg.loc[np.isfinite(agg["mean"].to_numpy(float)), "metric"])
    if "family" in table.columns and (table["family"] == "real").any():  # real captures: the sparse-scan support
        metrics = (*metrics, "support.skeleton@spacing")
    present = [m for m in metrics if m in scored]  # (a run without ground truth has no fidelity column)
    methods = sorted(agg["method"].unique(), key=lambda m: (m not in oracles, m))
    idx = agg.set_index(["metric", "method"])
    cells = table.groupby(["method", "case"])["status"].agg(lambda s: (s != "ok").any())
    failed = cells.groupby(level=0).sum()
    header = ["method", *(short_label(m) for m in present)]
    rows = [[m + (" *" if m in oracles else ""),
             *(_compact(*idx.loc[(m_, m), ["mean", "lo", "hi"]]) if (m_, m) in idx.index else "-" for m_ in present)]
            for m in methods]
    cases = table["case"].nunique()
    arrows = {("↑" if (metric_info(m) and metric_info(m).higher_is_better) else "↓") for m in present}
    out = [f"mean±half-width of the 95 % bootstrap interval over {cases} case{'s' * (cases != 1)}"
           + (" (higher is better)" if arrows == {"↑"} else "")]
    for block in _column_blocks([header, *rows], width=80):  # columns wider than a terminal: stacked blocks
        out += ([""] if len(out) > 1 else []) + _aligned([[r[i] for i in block] for r in [header, *rows]])
    bad = [f"{m} {int(failed[m])}" for m in methods if failed.get(m, 0)]
    out.append("failed cells: " + (", ".join(bad) if bad else "none"))
    if oracles:
        out.append("* oracle: reads ground truth")
    out.append("every metric: results.csv; tables and figures: plantbench report RUN")
    return out
