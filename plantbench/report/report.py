"""``plantbench report``: tables (Markdown, LaTeX, CSV, HTML) and figures of a run.

Every table gives the per-method mean with its 95 % bootstrap interval over cases, overall and broken down by
species and by plant family; failed cells are counted, never silently dropped.
"""

from __future__ import annotations

import html
import os
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from plantbench.errors import InputError, PlantbenchError
from plantbench.io.atomic import atomic_write
from plantbench.metrics.info import HEADLINE, HEADLINE_FIDELITY
from plantbench.report.gate import read_results, read_run_meta
from plantbench.report.tables import KEY_METRICS, aggregate, format_value, metric_info

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["FORMATS", "wide_table", "headline_table", "comparison_table", "render_table", "write_report",
           "family_ranking", "family_study", "distance_figure", "leaf_figure", "calibration_note"]

ORACLES = ("gt",)
STUDY_METRICS = ("stava.S_T", "mesh_to_surface.D_cm", "reprojection.error", "skeleton.f1@1.0", "leaves.accuracy")

FORMATS = ("md", "latex", "csv", "html")

PAIRED_METRICS = (*HEADLINE, "skeleton.vrecall_hidden@1%", "stava.S_T",
                  "mesh_to_surface.D_cm", "reprojection.iou", "leaves.accuracy")
"""Metrics of the paired-comparison table: the headline, observation and inference (:mod:`.observation`), then the
paper's S_T and D and the older image and leaf columns (every metric's values are in results.csv)."""

# The columns of Guo et al. 2018, Table 3, then ours. D and sigma are the paper's vertex -> nearest-ground-truth-point
# distance with the ground truth a perfect scan: the exact distance to the GT surface (mesh_to_surface). The simulated
# scan of the case misses what its stations cannot see, so against it even the gt oracle scores D > 0 (1.3 cm on the
# quick suite's 1-station scan); that distance is the "D scan" column.
PAPER_COLUMNS = (
    ("|P|", "points.count"),
    ("H", "skeleton.height_m"),
    ("|B|", "skeleton.branch_count"),
    ("l_B", "skeleton.mean_branch_length_m"),
    ("D (cm)", "mesh_to_surface.D_cm"),
    ("sigma (cm)", "mesh_to_surface.sigma_cm"),
    ("D scan (cm)", "mesh_to_scan.D_cm"),
    ("S_T", "stava.S_T"),
    ("reproj. err.", "reprojection.error"),
    ("leaf acc.", "leaves.accuracy"),
)


def _cell(mean: float, lo: float, hi: float, n: float, failed: float, unit: str = "") -> str:
    n, failed = int(n), int(failed)
    if not np.isfinite(mean):
        return "failed" if failed else "-"
    text = format_value(mean, unit)
    if np.isfinite(lo) and n > 1:
        text += f" [{format_value(lo, unit)}, {format_value(hi, unit)}]"
    if failed:
        text += f" ({failed} failed)"
    return text


_BEST_MARK = "\u2605"
"""Prefix of a cell holding the best value of its column: :func:`render_table` writes it bold."""


def _best_rows(agg, metric: str) -> set:
    """Index labels of the rows of ``agg`` (an :func:`aggregate` frame) holding the best non-oracle mean of
    ``metric``."""
    info = metric_info(metric)
    if info is None or info.higher_is_better is None:
        return set()
    cand = agg[(agg["metric"] == metric) & ~agg["method"].str.endswith(ORACLE_MARK) & np.isfinite(agg["mean"])]
    if cand.empty:
        return set()
    best = cand["mean"].max() if info.higher_is_better else cand["mean"].min()
    return set(cand.index[cand["mean"] == best])


def wide_table(table, by: tuple[str, ...] = ("method",), metrics: tuple[str, ...] | None = None,
               labels: dict[str, str] | None = None, *, mark_best: bool = True):
    """One row per group, one column per metric, cells 'mean [lo, hi]' in fixed notation. With ``mark_best``, the
    best non-oracle mean of each column (within each group of the leading ``by`` keys other than 'method') is
    marked for bold. Returns a pandas DataFrame of strings."""
    import pandas as pd

    agg = aggregate(table, by)
    if agg.empty:
        return pd.DataFrame(columns=list(by))
    present = list(dict.fromkeys(agg["metric"]))
    cols = [m for m in (metrics or KEY_METRICS) if m in present] if metrics or set(KEY_METRICS) & set(present) \
        else present
    outer = [b for b in by if b != "method"]
    best: set = set()
    if mark_best:
        for m in cols:
            for _, grp in (agg.groupby(outer, sort=False) if outer else [(None, agg)]):
                best |= _best_rows(grp, m)
    rows = []
    for key, grp in agg.groupby(list(by), sort=True):
        row = dict(zip(by, key if isinstance(key, tuple) else (key,)))
        for m in cols:
            hit = grp[grp["metric"] == m]
            info = metric_info(m)
            text = _cell(*hit.iloc[0][["mean", "lo", "hi", "n", "failed"]], info.unit if info else "") \
                if len(hit) else "-"
            if len(hit) and hit.index[0] in best:
                text = _BEST_MARK + text
            row[(labels or {}).get(m, m)] = text
        rows.append(row)
    return pd.DataFrame(rows)


def headline_table(table, metrics: tuple[str, ...]):
    """Metrics down the side (headline first), methods across, cells 'mean [95 % CI]', best non-oracle marked: a
    long list of metrics stays readable where a wide table would run off the page."""
    import pandas as pd

    agg = aggregate(table, ("method",))
    methods = sorted(agg["method"].unique(), key=lambda m: (not m.endswith(ORACLE_MARK), m))
    rows = []
    for m in metrics:
        sub = agg[agg["metric"] == m]
        if sub.empty:
            continue
        best = _best_rows(agg, m)
        row = {"metric": _unit_label(m)}
        for method in methods:
            hit = sub[sub["method"] == method]
            info = metric_info(m)
            text = _cell(*hit.iloc[0][["mean", "lo", "hi", "n", "failed"]], info.unit if info else "") \
                if len(hit) else "-"
            row[method] = (_BEST_MARK + text) if len(hit) and hit.index[0] in best else text
        rows.append(row)
    return pd.DataFrame(rows, columns=["metric", *methods])


_WITHIN = "seeds within species [95 % CI]"
"""The column of the within-species interval (:func:`plantbench.report.tables.paired_differences`)."""


def comparison_table(table, metrics: tuple[str, ...], reference: str = "prior", *, by: str | None = None):
    """Paired differences over cases (:func:`plantbench.report.tables.paired_differences`, a failed cell of a
    higher-is-better metric counted 0): every method against ``reference`` (the no-data prior) and every pair of the
    other non-oracle methods, with the minimum detectable difference (the verdict interval's half-width for this n);
    with ``by`` (e.g. 'family'), within each group of cases. A suite with two or more seeds of every species gets the
    within-species interval too, and its verdict is read from it. Returns (DataFrame of strings, raw differences)."""
    import pandas as pd

    from plantbench.report.tables import paired_differences

    names = sorted(table["method"].unique())
    ref = next((m for m in names if m.split(" ")[0] == reference), None)
    methods = [m for m in names if not m.endswith(ORACLE_MARK) and m != ref]
    pairs = [(m, ref) for m in methods] if ref else []
    pairs += [(a, b) for i, a in enumerate(methods) for b in methods[i + 1:]]
    groups = [(None, table)] if by is None else list(table.groupby(by, sort=True))
    raws, rows = [], []
    for group, sub in groups:
        raw = paired_differences(sub, metrics, pairs, failed_as_zero=True)
        if by is not None:
            raw.insert(0, by, group)
        raws.append(raw)
        for r in raw.to_dict("records"):
            info = metric_info(r["metric"])
            unit = info.unit if info else ""
            row = {by: group} if by is not None else {}
            row.update({"metric": _unit_label(r["metric"]), "comparison": f"{r['a']} - {r['b']}", "cases": r["n"],
                        "difference [95 % CI]": f"{format_value(r['diff'], unit)} [{format_value(r['lo'], unit)}, "
                                                f"{format_value(r['hi'], unit)}]",
                        _WITHIN: f"[{format_value(r['lo_species'], unit)}, {format_value(r['hi_species'], unit)}]"
                        if np.isfinite(r["lo_species"]) else "-",
                        "MDD": format_value(r["mdd"], unit), "verdict": r["verdict"]})
            rows.append(row)
    within = any(np.isfinite(r) for raw in raws for r in raw["lo_species"])
    cols = ([by] if by is not None else []) + ["metric", "comparison", "cases", "difference [95 % CI]"] \
        + ([_WITHIN] if within else []) + ["MDD", "verdict"]
    raw = pd.concat(raws, ignore_index=True) if raws else pd.DataFrame()
    return pd.DataFrame(rows, columns=cols), raw


def _unit_label(metric: str) -> str:
    info = metric_info(metric)
    if info is None:
        return metric
    arrow = "↑" if info.higher_is_better else "↓"
    return f"{metric} ({info.unit}) {arrow}" if info.unit else f"{metric} {arrow}"


def render_table(df, fmt: str, caption: str) -> str:
    """``df`` (strings) as Markdown, LaTeX, HTML or CSV; cells marked best are bold (CSV: unmarked)."""
    def cell(v, bold: tuple[str, str]) -> str:
        v = str(v)
        return f"{bold[0]}{v[1:]}{bold[1]}" if v.startswith(_BEST_MARK) else v

    if fmt == "md":
        header = "| " + " | ".join(map(str, df.columns)) + " |"
        sep = "|" + "|".join("---" for _ in df.columns) + "|"
        body = ["| " + " | ".join(cell(v, ("**", "**")) for v in row) + " |" for row in df.itertuples(index=False)]
        return f"**{caption}**\n\n" + "\n".join([header, sep, *body]) + "\n"
    if fmt == "latex":
        def esc(s: str) -> str:
            for a, b in (("\\", r"\textbackslash{}"), ("&", r"\&"), ("%", r"\%"), ("_", r"\_"), ("#", r"\#"),
                         ("|", r"$|$"), ("↑", r"$\uparrow$"), ("↓", r"$\downarrow$")):
                s = s.replace(a, b)
            return s

        cols = "l" * len(df.columns)
        lines = [r"\begin{table}[t]", r"\centering", rf"\caption{{{esc(caption)}}}", rf"\begin{{tabular}}{{{cols}}}",
                 r"\toprule", " & ".join(esc(str(c)) for c in df.columns) + r" \\", r"\midrule"]
        lines += [" & ".join(cell(esc(str(v)), (r"\textbf{", "}")) for v in row) + r" \\"
                  for row in df.itertuples(index=False)]
        lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
        return "\n".join(lines) + "\n"
    if fmt == "html":
        head = "".join(f"<th>{html.escape(str(c))}</th>" for c in df.columns)
        body = "".join("<tr>" + "".join(f"<td>{cell(html.escape(str(v)), ('<b>', '</b>'))}</td>" for v in row)
                       + "</tr>" for row in df.itertuples(index=False))
        return (f"<h2>{html.escape(caption)}</h2>\n<div class='scroll'><table><thead><tr>{head}</tr></thead>"
                f"<tbody>{body}</tbody></table></div>\n")
    if fmt == "csv":
        return df.map(lambda v: str(v).removeprefix(_BEST_MARK)).to_csv(index=False)
    raise InputError(f"unknown report format {fmt!r}; choose one of {', '.join(FORMATS)}")


def _scored(table) -> set[str]:
    """The metrics of ``table`` with at least one finite value in an ok cell (all of them when none has one, so that
    a run whose every cell failed still lists its metrics as failed)."""
    ok = table[(table["status"] == "ok") & np.isfinite(table["value"].to_numpy(float))]
    return set(ok["metric"]) or set(table["metric"])


def sweep_description(run_dir: Path) -> str | None:
    """What a run's sweep varies (from run.json's suite config): 'capture.scan_spacing (with
    capture.registration_error, ...)', or None."""
    sweep = (read_run_meta(run_dir).get("config") or {}).get("sweep")
    if not sweep:
        return None
    linked = list(sweep.get("linked") or {})
    return sweep["parameter"] + (f" (with {', '.join(linked)})" if linked else "")


def _tables(table, sweep: str | None = None) -> list[tuple[str, str, object]]:
    """(slug, caption, DataFrame) for every table of the report: the headline (metrics down the side), the paired
    comparisons, the paper's columns, then per species and per family on the headline metrics. A metric without a
    single value (every ground-truth metric of a run on real captures) is left out of all but the paper's table."""
    present = _scored(table)
    labels = {m: _unit_label(m) for m in present}
    key = tuple(m for m in KEY_METRICS if m in present and m != "runtime_s") + (("runtime_s",) if "runtime_s" in
                                                                                 present else ())
    out = [("overall", "Per method: mean [95 % bootstrap CI] over cases; headline metrics first (bold: best "
                       "non-oracle method)", headline_table(table, key))]
    compared = tuple(m for m in PAIRED_METRICS if m in present)
    comp, _ = comparison_table(table, compared)
    if not comp.empty:
        out.append(("paired", "Paired differences over cases (mean and 95 % bootstrap CI; a failed cell of a "
                              "higher-is-better metric counts 0): each method against the no-data prior, and each "
                              "pair of methods. With two or more seeds of every species, the interval with the seeds "
                              "resampled within species beside it (the species are the suite's design; the verdict "
                              "is read from it, the across-plant interval is the one for new species). 'beats' only "
                              "when the interval excludes 0; MDD, the minimum detectable difference, is the "
                              "interval's half-width: a difference smaller than it cannot be told from 0 with this "
                              "suite's cases", comp))
    from plantbench.report.observation import observation_tables

    out += observation_tables(table, wide_table)
    if "family" in table.columns and table["family"].nunique() > 1:
        fam, _ = comparison_table(table, compared, by="family")
        if not fam.empty:
            out.append(("paired_family", "Paired differences within each plant family (mean, 95 % bootstrap CI and "
                                         "MDD over that family's cases)", fam))
    paper = [m for _, m in PAPER_COLUMNS if m in set(table["metric"])]
    if paper:
        names = {m: label for label, m in PAPER_COLUMNS}
        out.append(("paper", "Per species and method, the reference paper's Table 3 columns",
                    wide_table(table, ("species", "method"), tuple(paper), names)))
    short = tuple(m for m in HEADLINE + ("stava.S_T", "mesh_to_surface.D_cm") if m in present)
    out.append(("species", "Per species and method, headline metrics (every metric: results.csv)",
                wide_table(table, ("species", "method"), short or None, labels=labels)))
    if "family" in table.columns:
        out.append(("family", "Per plant family and method, headline metrics",
                    wide_table(table, ("family", "method"), short or None, labels=labels)))
    if "sweep" in table.columns and table["sweep"].notna().any():
        out.append(("sweep", f"Per sweep value{f' of {sweep}' if sweep else ''} and method",
                    wide_table(table, ("sweep", "method"), short or None, labels=labels)))
    return out


def calibration_note(calibration: Path | None) -> str:
    """One sentence on what S_T measures, with the calibration's numbers (reports/calibration's ladder table), or
    ''."""
    import pandas as pd

    from plantbench.report.calibration import LADDER_FILE

    path = (calibration or Path()) / LADDER_FILE
    if calibration is None or not path.is_file():
        return ""
    t = pd.read_csv(path)
    st = t[t["metric"] == "stava.S_T"]
    mean = st.groupby("rung")["value"].mean()
    if not {"prior-a", "prior-b", "orders<=2", "jitter-0.5%"} <= set(mean.index):
        return ""
    note = (f"S_T (Stava et al.) measures how species-like a tree is, not whether it is this tree: on the calibration "
            f"ladder ({st['case'].nunique()} plants) a tree of the species grown from another seed scores "
            f"{(mean['prior-a'] + mean['prior-b']) / 2:.2f}, the exact skeleton pruned to branch orders <= 2 "
            f"{mean['orders<=2']:.2f} and the exact skeleton jittered by 0.5 % of the height {mean['jitter-0.5%']:.2f}; "
            f"the headline fidelity metrics ({', '.join(HEADLINE_FIDELITY)}) are those that rank these correctly "
            f"(reports/calibration).")
    return " ".join(filter(None, [note, structure_note(t)]))


def structure_note(ladder) -> str:
    """One sentence on what the structure column (:data:`~plantbench.metrics.info.HEADLINE_STRUCTURE`) shows, with
    the calibration ladder's means (``ladder``: the ladder table), or '' when the ladder lacks its rungs."""
    from plantbench.metrics.info import HEADLINE_STRUCTURE

    metric = HEADLINE_STRUCTURE[0]
    rungs = ["twigs+100%", "twigs+400%", "tangle-20%", "prior-a", "prior-b"]
    mean = ladder[ladder["metric"].isin([metric, "skeleton.vf1@1%"])].groupby(["metric", "rung"])["value"].mean()
    if not all((m, r) in mean.index for m in (metric, "skeleton.vf1@1%") for r in rungs):
        return ""
    s, v = mean[metric], mean["skeleton.vf1@1%"]
    return (f"The structure column, {metric}, counts branches: a true branch and a reconstructed one match (one to "
            f"one) when more than half of each lies within 1 % of the height of the other, so it falls when a method "
            f"invents branches or joins them across gaps, which the volume-weighted vF1 hardly sees (on the ladder, "
            f"the exact skeleton with twigs added at +100 % and +400 % of its branch count scores {s['twigs+100%']:.2f} "
            f"and {s['twigs+400%']:.2f} on it, {v['twigs+100%']:.2f} and {v['twigs+400%']:.2f} on vF1; with a fifth of "
            f"its nodes re-hung across gaps {s['tangle-20%']:.2f}, vF1 {v['tangle-20%']:.2f}; the prior "
            f"{(s['prior-a'] + s['prior-b']) / 2:.2f}).")


def sweep_values(labels: pd.Series) -> pd.Series:
    """The x values of a sweep's levels: the labels as numbers; else the first number in each label, when that tells
    the levels apart ('512px' -> 512, a suite's ``[sweep] labels``); else the levels' order of first appearance."""
    import pandas as pd

    value = pd.to_numeric(labels, errors="coerce")
    if value.notna().all():
        return value.astype(float)
    text = labels.astype(str)
    value = pd.to_numeric(text.str.extract(r"([-+]?\d*\.?\d+(?:[eE][-+]?\d+)?)")[0], errors="coerce")
    if value.notna().all() and value.nunique() == text.nunique():
        return value.astype(float)
    order = {label: float(k) for k, label in enumerate(pd.unique(text))}
    return text.map(order).astype(float)


def sweep_ticks(labels: pd.Series, values: pd.Series) -> list[str]:
    """The sweep figure's tick labels, one per distinct x value (:func:`sweep_values`) in increasing order: the value
    where the levels are numbers, else the level's own label ('2048px-at-1024'), so a level placed by its order
    still says which it is."""
    import pandas as pd

    if pd.to_numeric(labels, errors="coerce").notna().all():
        return [f"{v:g}" for v in sorted(values.unique())]
    label_of = dict(zip(values, labels.astype(str), strict=True))  # one label per value (sweep_values)
    return [label_of[v] for v in sorted(label_of)]


def _figures(table, folder: Path, sweep: str | None = None) -> list[Path]:
    """Bar chart per key metric (mean with 95 % CI per method), and sweep curves."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    agg = aggregate(table)
    # key metrics with at least one finite mean, in rows of at most five panels
    metrics = [m for m in KEY_METRICS if np.isfinite(agg.loc[agg["metric"] == m, "mean"]).any()]
    if metrics:
        ncol = min(5, len(metrics))
        nrow = -(-len(metrics) // ncol)
        fig, axes = plt.subplots(nrow, ncol, figsize=(3.2 * ncol, 3.2 * nrow), squeeze=False)
        for ax in axes.ravel()[len(metrics):]:
            ax.axis("off")
        for ax, m in zip(axes.ravel(), metrics):
            g = agg[agg["metric"] == m].sort_values("method")
            err = np.abs(np.stack([g["mean"] - g["lo"], g["hi"] - g["mean"]]))
            colours = ["#c44e52" if meth.split(" ")[0] == "prior" else "0.6" if meth.endswith(ORACLE_MARK)
                       else "#5a8f4e" for meth in g["method"]]
            ax.bar(g["method"], g["mean"], yerr=np.nan_to_num(err), capsize=3, color=colours)
            prior = g[g["method"].str.split(" ").str[0] == "prior"]["mean"]
            if len(prior) and np.isfinite(prior.iloc[0]):  # the floor every method must clear
                ax.axhline(prior.iloc[0], color="#c44e52", lw=0.8, ls="--")
            ax.set_title(_unit_label(m), fontsize=9)
            ax.tick_params(axis="x", rotation=45, labelsize=8)
        fig.tight_layout()
        paths.append(folder / "metrics.png")
        fig.savefig(paths[-1], dpi=120)
        plt.close(fig)
    if "sweep" in table.columns and table["sweep"].notna().any():
        sw = table[table["sweep"].notna()].copy()
        sw["sweep_value"] = sweep_values(sw["sweep"])
        sagg = aggregate(sw, ("method", "sweep_value"))
        finite = set(sagg.loc[np.isfinite(sagg["mean"]), "metric"])
        metrics = [m for m in KEY_METRICS if m in finite] or sorted(finite)[:4]
        values = sw["sweep_value"].unique()
        geometric = values.min() > 0 and values.max() >= 8 * values.min()  # reads best on a log axis
        ticks = sweep_ticks(sw["sweep"], sw["sweep_value"])
        long_ticks = max(len(t) for t in ticks) > 6
        ncol = min(5, max(len(metrics), 1))
        nrow = max(-(-len(metrics) // ncol), 1)
        fig, axes = plt.subplots(nrow, ncol, figsize=(3.4 * ncol, 3.2 * nrow), squeeze=False)
        for ax in axes.ravel()[len(metrics):]:
            ax.axis("off")
        for ax, m in zip(axes.ravel(), metrics):
            for method, g in sagg[sagg["metric"] == m].groupby("method"):
                g = g.sort_values("sweep_value")
                ax.plot(g["sweep_value"], g["mean"], marker="o", label=method)
                ax.fill_between(g["sweep_value"], g["lo"], g["hi"], alpha=0.2)
            ax.set_title(_unit_label(m), fontsize=9)
            ax.set_xlabel((sweep or "sweep value").split(" (with")[0], fontsize=8)
            if geometric:
                ax.set_xscale("log")
                ax.minorticks_off()
            ax.set_xticks(sorted(values), ticks, fontsize=7, rotation=30 if long_ticks else 0)
        spare = axes.ravel()[len(metrics):]
        handles, names = axes[0][0].get_legend_handles_labels()
        if len(spare):  # the legend in an empty panel, clear of the curves
            spare[0].legend(handles, names, fontsize=8, loc="center")
        else:
            axes[0][0].legend(fontsize=7)
        fig.tight_layout()
        paths.append(folder / "sweep.png")
        fig.savefig(paths[-1], dpi=120)
        plt.close(fig)
    return paths


ORACLE_MARK = " (oracle)"


def mark_oracles(table, run_dir: Path):
    """``table`` with every oracle method (it read ground truth: run.json's ``oracles``, or for an older run the
    registry's declaration) renamed 'NAME (oracle)', so that no table shows it unmarked."""
    oracles = read_run_meta(run_dir).get("oracles")
    if oracles is None:
        from plantbench.methods.api import method_from_spec, split_cloud
        from plantbench.methods.inputs import is_oracle

        oracles = []
        for name in table["method"].unique():
            try:
                if split_cloud(name)[1] or is_oracle(method_from_spec(name)):
                    oracles.append(name)
            except PlantbenchError:
                pass
    return table.assign(method=table["method"].map(lambda m: f"{m}{ORACLE_MARK}" if m in oracles else m))


def provenance(run_dir: Path) -> str:
    """One line on where the run's inputs came from: a frozen dataset (its manifest's sha256) or generated by the
    run (code and Dr.Jit target), from run.json; empty when run.json is missing."""
    meta = read_run_meta(run_dir)
    if not meta:
        return ""
    code = f"code {meta.get('git_sha') or 'unknown'}, Dr.Jit target {meta.get('llvm_target') or 'unknown'}"
    data = meta.get("dataset")
    if data:
        return f"Inputs: frozen dataset, manifest sha256 {data['manifest_sha256']}; methods run with {code}."
    cases = (meta.get("config") or {}).get("cases") or []
    imported = sum(1 for c in cases if c.get("scan") or c.get("path"))
    if imported:
        made = len(cases) - imported
        also = f"; {made} case entries generated and captured by this run" if made else ""
        return (f"Inputs: {imported} real captures imported (scan files or case folders, keyed by their sha256){also} "
                f"({code}).")
    return f"Inputs: generated and captured by this run ({code})."


def write_report(run_dir: str | os.PathLike, formats: tuple[str, ...] = FORMATS, out: str | os.PathLike | None = None,
                 *, calibration: str | os.PathLike | None = None) -> list[Path]:
    """Write the report of ``run_dir`` into ``out`` (default ``run_dir/report``); return the files written.

    ``calibration``: a ``plantbench calibrate`` folder whose ladder gives the sentence on what S_T measures (default:
    the project's reports/calibration when it exists)."""
    for f in formats:
        if f not in FORMATS:
            raise InputError(f"unknown report format {f!r}; choose one of {', '.join(FORMATS)}")
    run_dir = Path(run_dir)
    table = mark_oracles(read_results(run_dir), run_dir)
    out = Path(out) if out else run_dir / "report"
    out.mkdir(parents=True, exist_ok=True)
    sweep = sweep_description(run_dir)
    tables = _tables(table, sweep)
    origin = provenance(run_dir)
    if calibration is None:
        from plantbench.paths import project_root

        calibration = project_root() / "reports" / "calibration"
    note = calibration_note(Path(calibration))
    if note:
        origin = f"{origin}\n\n{note}" if origin else note
    figures = _figures(table, out / "figures", sweep)
    if "family" in table.columns and (table["family"] == "real").any():
        from plantbench.report.real import real_figures, real_tables

        tables += real_tables(run_dir, table)
        figures += real_figures(run_dir, table, out / "figures")
    from plantbench.report.observation import observed_figure

    captures = {c["case"]: c["capture"] for c in _cells(run_dir)}
    source = (read_run_meta(run_dir).get("config") or {}).get("source") or "views"  # the file its metrics read
    for extra in (observed_figure(captures, out / "figures" / "observed.png", source=source),
                  distance_figure(run_dir, out / "figures" / "distances.png"),
                  leaf_figure(run_dir, out / "figures" / "leaves.png"),
                  timeline_figure(run_dir, out / "figures" / "timeline.png")):
        if extra is not None:
            figures.append(extra)
    written = list(figures)
    if "family" in table.columns and table["family"].nunique() > 1:
        path = out / "family_study.md"
        with atomic_write(path, "w") as fh:
            fh.write(family_study(table))
        written.append(path)
    ext = {"md": "md", "latex": "tex", "csv": "csv", "html": "html"}
    for fmt in formats:
        if fmt == "csv":
            for slug, _, df in tables:
                path = out / f"{slug}.csv"
                with atomic_write(path, "w") as fh:
                    fh.write(render_table(df, "csv", slug))
                written.append(path)
            continue
        parts = [render_table(df, fmt, caption) for _, caption, df in tables]
        if fmt == "md":
            body = f"# {run_dir.name}\n\n" + (f"{origin}\n\n" if origin else "") + "\n".join(parts)
            body += "".join(f"\n![{p.stem}](figures/{p.name})\n" for p in figures)
        elif fmt == "html":
            samples = _sample_views(run_dir, out)
            body = ("<!doctype html><html><head><meta charset='utf-8'><title>plantbench report</title>"
                    "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
                    "td,th{padding:2px 8px;border-bottom:1px solid #ddd;font-size:13px;white-space:nowrap;"
                    "text-align:right}td:first-child,th:first-child{text-align:left}"
                    "th{position:sticky;top:0;background:#f4f4f4}.scroll{overflow-x:auto;max-width:100%}"
                    "img{max-width:100%}</style></head><body>"
                    f"<h1>{html.escape(run_dir.name)}</h1>"
                    + "".join(f"<p>{html.escape(par)}</p>" for par in origin.split("\n\n") if par)
                    + "".join(parts)
                    + "".join(f"<h2>{p.stem}</h2><img src='figures/{p.name}'>" for p in figures)
                    + ("<h2>sample views</h2>" + "".join(f"<img src='{s}' width='256'>" for s in samples)
                       if samples else "")
                    + "</body></html>\n")
        else:
            body = (f"% {origin}\n" if origin else "") + "\n".join(parts)
        path = out / f"report.{ext[fmt]}"
        with atomic_write(path, "w") as fh:
            fh.write(body)
        written.append(path)
    return written


def family_ranking(table, metrics: tuple[str, ...] = STUDY_METRICS):
    """Per family and metric, the non-oracle methods ranked best first by their mean over the family's cases.

    Returns a DataFrame: family, metric, rank, method, mean, n.
    """
    import pandas as pd

    agg = aggregate(table[~table["method"].isin(ORACLES)], ("family", "method"), n_boot=1)
    rows = []
    for (family, metric), g in agg[agg["metric"].isin(metrics)].groupby(["family", "metric"], sort=True):
        info = metric_info(metric)
        if info is None or info.higher_is_better is None:
            continue
        g = g[np.isfinite(g["mean"])].sort_values("mean", ascending=not info.higher_is_better)
        for rank, r in enumerate(g.itertuples(), start=1):
            rows.append({"family": family, "metric": metric, "rank": rank, "method": r.method, "mean": r.mean,
                         "n": r.n})
    return pd.DataFrame(rows, columns=["family", "metric", "rank", "method", "mean", "n"])


def family_study(table, metrics: tuple[str, ...] = STUDY_METRICS) -> str:
    """A short Markdown study: does any method's advantage depend on the plant family (the inverse crime)?

    For each metric, the ranking of methods on each family, and Kendall's tau between the families' rankings
    (1: the same order on every family; lower: the order depends on the family).
    """
    from scipy.stats import kendalltau

    ranking = family_ranking(table, metrics)
    families = sorted(ranking["family"].unique())
    lines = ["# Method ranking per plant family", "",
             "The generator's space-colonisation family shares its growth model with the guo reference method; the "
             "Weber-Penn family does not. A method whose rank drops on Weber-Penn plants owes part of its score to "
             "that shared model. Oracle rows (gt) are left out; means over each family's cases.", ""]
    if len(families) < 2:
        lines.append(f"Only one family in this run ({', '.join(families) or 'none'}): nothing to compare.")
        return "\n".join(lines) + "\n"
    lines += ["| metric | " + " | ".join(families) + " | Kendall tau |", "|---" * (len(families) + 2) + "|"]
    for metric, g in ranking.groupby("metric", sort=True):
        orders = {f: list(g[g["family"] == f].sort_values("rank")["method"]) for f in families}
        cells = [" > ".join(f"{m} ({g[(g['family'] == f) & (g['method'] == m)]['mean'].iloc[0]:.3g})"
                            for m in orders[f]) or "-" for f in families]
        common = [m for m in orders[families[0]] if all(m in orders[f] for f in families)]
        taus = []
        for f in families[1:]:
            if len(common) >= 2:
                tau = kendalltau([orders[families[0]].index(m) for m in common],
                                 [orders[f].index(m) for m in common]).statistic
                taus.append(f"{tau:.2f}")
        lines.append(f"| {metric} | " + " | ".join(cells) + f" | {', '.join(taus) or '-'} |")
    lines += ["", "Read: `a (x) > b (y)` ranks a above b with family means x and y."]
    return "\n".join(lines) + "\n"


def _cells(run_dir: Path) -> list[dict]:
    """The run's cells with absolute capture and reconstruction folders (``cells.json``; [] for a run without it or
    whose cache is gone)."""
    import json

    try:
        cells = json.loads((run_dir / "cells.json").read_text())
    except (OSError, ValueError):
        return []
    for c in cells:
        c["capture"], c["recon"] = run_dir / c["capture"], run_dir / c["recon"]
    return [c for c in cells if c["capture"].is_dir()]


SAMPLE_VIEW_PX = 512
"""Longest side of the sample views copied next to a report (larger views are area-averaged down to it)."""


def _sample_views(run_dir: Path, out: Path, limit: int = 6) -> list[str]:
    """Copy the first view of a few of the run's cases next to the report, at most :data:`SAMPLE_VIEW_PX` on its
    longer side (a 1024 px view area-averaged by 2); returns relative paths."""
    from PIL import Image

    rels = []
    cases = {c["case"]: c["capture"] for c in _cells(run_dir)}
    for case, folder in list(cases.items())[:limit]:
        img = folder / "views" / "images" / "0000.png"
        if img.exists():
            dst = out / "figures" / f"view_{case}.png"
            with Image.open(img) as im:
                factor = -(-max(im.size) // SAMPLE_VIEW_PX)
                if factor > 1:
                    im.reduce(factor).save(dst)
                else:
                    shutil.copyfile(img, dst)
            rels.append(f"figures/{dst.name}")
    return rels


def timeline_figure(run_dir: str | os.PathLike, path: str | os.PathLike) -> Path | None:
    """The run's timeline (timeline.csv): one bar per job computed by this run, on the lane of the worker slot it
    ran in (first free slot in start order), coloured by stage or method, labelled with the threads it had when more
    than one. Returns the PNG written, or None when the run computed nothing."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pandas as pd

    file = Path(run_dir) / "timeline.csv"
    if not file.is_file():
        return None
    jobs = pd.read_csv(file)
    jobs = jobs[~jobs["reused"] & jobs["started"].notna()].sort_values("started")
    if jobs.empty:
        return None
    t0 = jobs["started"].min()
    start, end = (jobs["started"] - t0) / 60, (jobs["finished"] - t0) / 60
    lanes: list[float] = []
    lane_of = []
    for a, b in zip(start, end):
        i = next((k for k, last in enumerate(lanes) if last <= a + 1e-3), len(lanes))
        lanes[i:i + 1] = [b]
        lane_of.append(i)
    names = list(dict.fromkeys(jobs["job"]))
    colours = {n: plt.get_cmap("tab10")(k % 10) for k, n in enumerate(names)}
    fig, ax = plt.subplots(figsize=(10, 0.5 * len(lanes) + 1.6), layout="constrained")
    for a, b, lane, name, threads in zip(start, end, lane_of, jobs["job"], jobs["threads"]):
        ax.barh(lane, b - a, left=a, height=0.8, color=colours[name], edgecolor="white", linewidth=0.3)
        if pd.notna(threads) and threads > 1 and b - a > 0.3:
            ax.text(a + 0.05, lane, f"{int(threads)}t", va="center", fontsize=6, color="white")
    wall = float(end.max())
    busy = float((end - start).sum())
    ax.set(xlabel="minutes since the first job started", ylabel="worker slot", yticks=range(len(lanes)),
           title=f"{len(jobs)} jobs computed in {wall:.1f} min; busy {busy / max(wall, 1e-9):.2f} slots on average")
    fig.legend(handles=[matplotlib.patches.Patch(color=colours[n], label=n) for n in names], ncol=min(len(names), 8),
               fontsize=7, loc="outside lower center", frameon=False)
    ax.invert_yaxis()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def distance_figure(run_dir: str | os.PathLike, path: str | os.PathLike, *, max_cases: int = 4,
                    max_points: int = 20_000, seed: int = 0) -> Path | None:
    """Reconstructions coloured by their distance to the ground-truth surface: one row per case (the first case of
    up to ``max_cases`` species), one column per method, each panel a side view (x, z) of up to ``max_points``
    mesh vertices with the exact vertex -> GT surface distance as colour, 0 to 2 % of the plant height (the
    largest Tanks and Temples tau). Returns the PNG written, or None when the run has no drawable cell."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pandas as pd

    from plantbench.io.plantio import read_plant, read_reconstruction
    from plantbench.metrics.surface import point_to_mesh_distances
    from plantbench.plant import TriMesh

    cells = [c for c in _cells(Path(run_dir)) if c["status"] == "ok" and (c["capture"] / "plant").is_dir()]
    cases = list(dict.fromkeys(c["case"] for c in cells if c["sweep"] is None or c["sweep"] == cells[0]["sweep"]))
    by_species: dict[str, str] = {}
    for c in cells:
        if c["case"] in cases:
            by_species.setdefault(c["species"], c["case"])
    rows = list(by_species.values())[:max_cases]
    methods = sorted({c["method"] for c in cells if c["case"] in rows})
    marked = mark_oracles(pd.DataFrame({"method": methods}), Path(run_dir))["method"]
    oracles = {m for m, label in zip(methods, marked) if label != m}
    if not rows or not methods:
        return None
    fig, axes = plt.subplots(len(rows), len(methods) + 1, figsize=(2.4 * (len(methods) + 1) + 1.0, 3.0 * len(rows)),
                             squeeze=False, layout="constrained")
    rng = np.random.Generator(np.random.PCG64(seed))
    sc = None
    for i, case in enumerate(rows):
        row = {c["method"]: c for c in cells if c["case"] == case}
        plant = read_plant(next(iter(row.values()))["capture"])[0]
        gt = TriMesh.concatenate([plant.branch_mesh, plant.leaf_mesh])
        scale = 0.02 * plant.height
        v = gt.vertices[rng.permutation(len(gt.vertices))[:max_points]]
        axes[i][0].scatter(v[:, 0], v[:, 2], s=0.2, c="0.35", linewidths=0)
        axes[i][0].set_title(f"{case}: ground truth", fontsize=8)
        for j, method in enumerate(methods, start=1):
            ax = axes[i][j]
            ax.set_title(method + (ORACLE_MARK if method in oracles else ""), fontsize=8)
            cell = row.get(method)
            mesh = read_reconstruction(cell["recon"]).mesh if cell else None
            if mesh is None or len(mesh.vertices) == 0:
                ax.text(0.5, 0.5, "no mesh", ha="center", transform=ax.transAxes, fontsize=8)
                continue
            p = mesh.vertices[rng.permutation(len(mesh.vertices))[:max_points]]
            d = point_to_mesh_distances(gt, p) / scale
            order = np.argsort(d)  # far points drawn last, on top
            sc = ax.scatter(p[order, 0], p[order, 2], s=0.2, c=d[order], cmap="viridis", vmin=0.0, vmax=1.0,
                            linewidths=0)
        for ax in axes[i]:
            ax.set_aspect("equal")
            ax.set_xlim(axes[i][0].get_xlim())
            ax.set_ylim(axes[i][0].get_ylim())
            ax.set_xticks([])
            ax.set_yticks([])
    if sc is not None:
        bar = fig.colorbar(sc, ax=axes, shrink=0.6, ticks=[0, 0.25, 0.5, 0.75, 1.0])
        bar.ax.set_yticklabels(["0", "0.5", "1", "1.5", ">= 2"])
        bar.set_label("vertex -> GT surface distance (% of plant height)", fontsize=8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _label_colours(labels: np.ndarray, seed: int = 0) -> np.ndarray:
    """(h, w, 3) float RGB of an integer label image: a colour of matplotlib's tab20 per label > 0 (labels shuffled
    by ``seed`` so that neighbours rarely share one), NaN where 0."""
    from matplotlib import colormaps

    n = int(labels.max()) + 1
    shuffle = np.random.Generator(np.random.PCG64(seed)).permutation(n)
    palette = colormaps["tab20"](shuffle % 20)[:, :3]
    rgb = palette[labels]
    rgb[labels <= 0] = np.nan
    return rgb


def leaf_figure(run_dir: str | os.PathLike, path: str | os.PathLike, *, method: str = "leaves", view: int = 0,
                max_cases: int = 6) -> Path | None:
    """Leaf segmentation and fitting on one view of each case (up to ``max_cases``), one row per case: the view,
    the ground-truth leaves (instance map), the candidate leaves ``method`` segmented in the view (its
    ``candidates/`` maps), and its fitted leaves (``leaves.json``) projected into the view, each blade a polygon in
    its own colour over the greyed image. Cropped to the plant. Returns the PNG written, or None when no cell of the
    run has the method's candidate maps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection
    from PIL import Image

    from plantbench.cameras import read_cameras
    from plantbench.geometry.leaf import BezierLeaf, tessellate_placed
    from plantbench.io.plantio import read_reconstruction

    cells = [c for c in _cells(Path(run_dir)) if c["status"] == "ok" and c["method"] == method
             and (c["recon"] / "candidates").is_dir()]
    cells = list({c["case"]: c for c in cells}.values())[:max_cases]
    if not cells:
        return None
    fig, axes = plt.subplots(len(cells), 4, figsize=(12, 3.2 * len(cells)), squeeze=False, layout="constrained")
    for row, cell in zip(axes, cells, strict=True):
        views = cell["capture"] / "views"
        cameras, names = read_cameras(views / "cameras.json")
        cam, stem = cameras[view], Path(names[view]).stem
        image = np.asarray(Image.open(views / "images" / names[view]).convert("RGB"))
        grey = np.repeat(image.mean(axis=2, keepdims=True), 3, axis=2) / 255.0 * 0.6 + 0.4
        inst = np.array(Image.open(views / "instance" / f"{stem}.png")).astype(np.int64)
        cand_file = cell["recon"] / "candidates" / f"{stem}.png"
        cand = np.array(Image.open(cand_file)).astype(np.int64) if cand_file.is_file() else np.zeros_like(inst)
        plant_px = np.argwhere(inst > 0)
        (r0, c0), (r1, c1) = plant_px.min(0), plant_px.max(0)
        pad = 10
        r0, c0, r1, c1 = max(r0 - pad, 0), max(c0 - pad, 0), min(r1 + pad, inst.shape[0]), min(c1 + pad, inst.shape[1])
        leaves = read_reconstruction(cell["recon"]).leaves or []
        n_gt = len(np.unique(inst[inst >= 2]))
        panels = [(image / 255.0, f"{cell['case']}: view {view}"),
                  (_overlay(grey, _label_colours(np.where(inst >= 2, inst - 1, 0))),
                   f"ground-truth leaves ({n_gt} visible)"),
                  (_overlay(grey, _label_colours(cand, seed=1)), f"{method}: candidates ({len(np.unique(cand)) - 1})"),
                  (grey, f"{method}: fitted leaves ({len(leaves)} in all)")]
        for ax, (img, title) in zip(row, panels, strict=True):
            ax.imshow(img, interpolation="nearest")
            ax.set_title(title, fontsize=8)
            ax.set_xlim(c0, c1)
            ax.set_ylim(r1, r0)
            ax.set_xticks([])
            ax.set_yticks([])
        if leaves:
            omega = np.stack([BezierLeaf(**leaf.params).vector() for leaf in leaves])
            tr = np.stack([np.asarray(leaf.transform, float) for leaf in leaves])
            verts, faces = tessellate_placed(omega, np.array([leaf.length for leaf in leaves]), tr[:, :3, :3],
                                             tr[:, :3, 3], (3, 8))
            uv, z = cam.project(verts.reshape(-1, 3))
            tris = uv[faces]
            front = (z[faces] > 0).all(axis=1)
            per_leaf = len(faces) // len(leaves)
            colour = _label_colours(np.arange(len(leaves) + 1), seed=2)[1:]
            # draw far blades first: nearer ones cover them, as in the image
            depth = z[faces].mean(axis=1)
            order = np.argsort(-depth[front], kind="stable")
            idx = np.flatnonzero(front)[order]
            row[3].add_collection(PolyCollection(tris[idx], facecolors=colour[idx // per_leaf], edgecolors="face",
                                                 linewidths=0.2))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _overlay(grey: np.ndarray, colours: np.ndarray) -> np.ndarray:
    """``colours`` (NaN: transparent) over the greyed image."""
    return np.where(np.isnan(colours), grey, colours)
