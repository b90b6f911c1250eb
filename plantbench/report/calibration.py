"""``plantbench calibrate``: which metrics tell a faithful reconstruction from a plausible one (docs/design.md).

The suite's plants are captured as usual; the rungs of the ladder (:mod:`plantbench.methods.ladder`: the ground
truth pruned, jittered, scaled, with moved leaves; the no-data prior with two seeds; another species) run as oracle
methods through the runner and are scored by every metric. Per metric and plant, the verdict asks whether the metric
orders the rungs as their fidelity does:

* ``orders<=2`` better than both prior rungs, and ``jitter-0.5%`` better than both prior rungs (the acceptance of
  a headline metric);
* pruning monotone: gt, orders <= 3, 2, 1 never better than the rung before, and orders <= 1 worse than gt (a plant
  whose branches stop at order 2, as the Weber-Penn trees do, loses nothing to "orders <= 2": equal is right there,
  whereas a metric blind to missing branches, such as the one-way vertex distance D, ranks a pruned tree above the
  whole one and fails);
* jitter monotone: gt, jitter 0.25, 0.5, 1, 2 % never better than the rung before, and 2 % worse than gt.

"Better" follows the metric's direction (:class:`plantbench.metrics.info.MetricInfo`); a missing value fails. A metric
*discriminates* when every plant but at most :data:`ALLOWED_FAILURES` per 10 passes (>= 9 of 10). Descriptive metrics
(no direction) have no verdict.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np

__all__ = ["LADDER", "calibration_suite", "run_calibration", "verdicts", "ladder_means", "calibration_markdown",
           "ladder_figure", "write_calibration", "ALLOWED_FAILURES", "LADDER_FILE", "observation_split"]

LADDER = ("gt", "orders<=3", "orders<=2", "orders<=1", "jitter-0.25%", "jitter-0.5%", "jitter-1%", "jitter-2%",
          "scale-1.05", "scale-1.1", "scale-1.25", "leaves-10%", "leaves-25%", "leaves-50%", "twigs+25%",
          "twigs+100%", "twigs+400%", "tangle-20%", "prior-a", "prior-b", "other-species", "observed")
"""Rung names in the order of the tables."""
OBSERVED = "observed"
"""The rung cut to the wood the capture observed (:func:`plantbench.methods.ladder.cut_to_observed`)."""
OBSERVATION_CHECK = {"skeleton.vf1_observed@1%": (">=", 0.95), "skeleton.vrecall_hidden@1%": ("<=", 0.05)}
"""What the observed rung must score on each plant (observation about 1, inference about 0) for the observation
and inference metrics to mean what they say."""
JITTER = ("gt", "jitter-0.25%", "jitter-0.5%", "jitter-1%", "jitter-2%")
PRUNING = ("gt", "orders<=3", "orders<=2", "orders<=1")
TWIGS = ("gt", "twigs+25%", "twigs+100%", "twigs+400%")
TANGLE = "tangle-20%"
PRIORS = ("prior-a", "prior-b")
MATERIAL = 0.25
"""Share of the distance from the exact plant to the better prior that the ``twigs+400%`` rung (about five times
the true branch count) must lose, for a metric to see invented branches: a metric that loses less orders the twig
rungs by a rounding's worth without telling a tree from a tangle of twigs."""
VOLUME_CHECKS = ("orders<=2>prior", "jitter-0.5%>prior", "pruning monotone", "jitter monotone")
"""The checks of the volume verdict (every fidelity metric of the headline passes them)."""
STRUCTURE_CHECKS = ("twigs ordered", "tangle<gt", "twigs+400% material")
"""The checks a structure metric passes too: it sees invented branches and wrong forks."""
LADDER_FILE = "ladder.csv.gz"
"""The committed ladder table (gzip: ~90 metrics x 17 rungs x the plants)."""
ALLOWED_FAILURES = 0.1
"""Share of plants on which a discriminating metric may misorder the rungs (1 of 10)."""


def calibration_suite(suite, *, seed: int | None = None, species: list[str] | None = None):
    """``suite`` renamed '<name>-calibration' (or '<name>-calibration-seed<N>') with the ladder as its methods;
    ``seed`` replaces every case's seeds (plants not in the suite), ``species`` keeps only those cases."""
    from plantbench.errors import InputError
    from plantbench.methods.ladder import PREFIX

    cases = [c for c in suite.cases if species is None or c.species in species]
    if not cases:
        raise InputError(f"calibrate: none of {species} is a case of suite {suite.name}")
    if seed is not None:
        cases = [c.model_copy(update={"seeds": [int(seed)]}) for c in cases]
    name = f"{suite.name}-calibration" + (f"-seed{seed}" if seed is not None else "")
    return suite.model_copy(update={"name": name, "cases": cases, "methods": [PREFIX + r for r in LADDER],
                                    "method_options": {}, "sweep": None})


def run_calibration(suite, out: str | os.PathLike, *, workers: int = 1, progress=None,
                    seed: int | None = None, species: list[str] | None = None):
    """Run the ladder on the suite's plants (shared cache ``out/cache``); returns the runner's RunResult."""
    from plantbench.runner import run_suite

    spec = calibration_suite(suite, seed=seed, species=species)
    return run_suite(spec, Path(out), workers=workers, progress=progress)


def _rung(method: str) -> str:
    return method.split(":", 1)[1] if ":" in method else method


def _pivot(table):
    """case x rung values per metric: DataFrame indexed (metric, case), columns the rungs."""
    t = table[table["status"] == "ok"].copy()
    t["rung"] = t["method"].map(_rung)
    return t.pivot_table(index=["metric", "case"], columns="rung", values="value", aggfunc="first")


def _better(a: float, b: float, higher: bool) -> bool:
    if not (math.isfinite(a) and math.isfinite(b)):
        return False
    return a > b if higher else a < b


def _not_better(a: float, b: float, higher: bool) -> bool:
    """a is not better than b (ties allowed)."""
    if not (math.isfinite(a) and math.isfinite(b)):
        return False
    return a <= b if higher else a >= b


def _monotone(v: dict[str, float], rungs: tuple[str, ...], higher: bool) -> bool:
    """Each rung no better than the one before, and the last worse than the first."""
    return all(_not_better(v[b], v[a], higher) for a, b in zip(rungs, rungs[1:])) and \
        _better(v[rungs[0]], v[rungs[-1]], higher)


def _best_prior(v: dict[str, float], higher: bool) -> float:
    if any(not math.isfinite(v[p]) for p in PRIORS):
        return float("nan")
    return max(v[p] for p in PRIORS) if higher else min(v[p] for p in PRIORS)


def plant_checks(row: dict[str, float], higher: bool) -> dict[str, bool]:
    """The checks of one plant (:data:`VOLUME_CHECKS`, then :data:`STRUCTURE_CHECKS`): rung -> value (NaN or
    absent when missing: the checks that need it fail), the metric's direction."""
    v = {r: float(row.get(r, float("nan"))) for r in LADDER}
    best_prior = _best_prior(v, higher)
    gap = v["gt"] - best_prior
    return {
        "orders<=2>prior": _better(v["orders<=2"], best_prior, higher),
        "jitter-0.5%>prior": _better(v["jitter-0.5%"], best_prior, higher),
        "pruning monotone": _monotone(v, PRUNING, higher),
        "jitter monotone": _monotone(v, JITTER, higher),
        "twigs ordered": all(_better(v[a], v[b], higher) for a, b in zip(TWIGS, TWIGS[1:])),
        "tangle<gt": _better(v["gt"], v[TANGLE], higher),
        "twigs+400% material": _better(v["gt"], best_prior, higher) and _not_better(
            v[TWIGS[-1]], v["gt"] - MATERIAL * gap, higher),
    }


def _verdict(passed: int, n: int) -> str:
    return "discriminates" if n > 0 and passed >= n - math.floor(ALLOWED_FAILURES * n + 1e-9) else \
        "does not discriminate"


def verdicts(table):
    """Per metric with a direction: plants passing each check, and two verdicts.

    Returns a DataFrame: metric, higher_is_better, plants, one column per check (plants passing it), passed
    (plants passing every volume check, :data:`VOLUME_CHECKS`), verdict ('discriminates' or 'does not
    discriminate'), structure_passed (plants passing every check, the structure ones too) and structure (the
    verdict of a structure metric: 'discriminates' or 'does not discriminate')."""
    import pandas as pd

    from plantbench.report.tables import metric_info

    piv = _pivot(table)
    rows = []
    for metric, grp in piv.groupby(level=0, sort=True):
        info = metric_info(metric)
        if info is None or info.higher_is_better is None:
            continue
        checks = [plant_checks(r.to_dict(), info.higher_is_better) for _, r in grp.iterrows()]
        n = len(checks)
        counts = {k: sum(c[k] for c in checks) for k in VOLUME_CHECKS + STRUCTURE_CHECKS}
        passed = sum(all(c[k] for k in VOLUME_CHECKS) for c in checks)
        structure = sum(all(c.values()) for c in checks)
        rows.append({"metric": metric, "higher_is_better": info.higher_is_better, "plants": n, **counts,
                     "passed": passed, "verdict": _verdict(passed, n), "structure_passed": structure,
                     "structure": _verdict(structure, n)})
    return pd.DataFrame(rows)


def ladder_means(table, metrics: list[str]):
    """Mean over plants of each rung (columns) for ``metrics`` (rows), rungs in :data:`LADDER` order."""
    piv = _pivot(table)
    means = piv.groupby(level=0).mean()
    return means.loc[[m for m in metrics if m in means.index], [r for r in LADDER if r in means.columns]]


def _fmt(v: float) -> str:
    """Three decimals (a count or a large distance: none)."""
    if not np.isfinite(v):
        return "-"
    return f"{v:.3f}" if abs(v) < 100 else f"{v:.0f}"



def _missed_lines(rows, checks, n: int, means, words: str) -> list[str]:
    """One line per verdict row: the checks it passed on fewer than all ``n`` plants, then its ladder means, each
    ``{rung}`` of ``words`` replaced by the metric's mean on that rung."""
    import re

    out = []
    for d in rows.to_dict("records"):
        missed = ", ".join(f"{c} on {int(d[c])}/{n}" for c in checks if int(d[c]) < n)
        m = means.loc[d["metric"]]
        said = re.sub(r"\{([^}]+)\}", lambda k, m=m: _fmt(m.get(k.group(1), np.nan)), words)
        out.append(f"- `{d['metric']}`: {missed} plants (means: {said}).")
    return out

def observation_split(table):
    """Per plant, the observed rung's observation and inference scores and whether they pass
    :data:`OBSERVATION_CHECK` (a plant without hidden wood, inference None, passes that half). Returns a DataFrame:
    case, one column per metric, passed."""
    import pandas as pd

    piv = _pivot(table)
    rows = []
    for case in sorted(piv.index.get_level_values(1).unique()):
        row, ok = {"case": case}, True
        for metric, (op, bound) in OBSERVATION_CHECK.items():
            v = piv[OBSERVED].get((metric, case), float("nan")) if OBSERVED in piv.columns else float("nan")
            row[metric] = v
            if math.isfinite(v):
                ok &= v >= bound if op == ">=" else v <= bound
            elif metric == "skeleton.vf1_observed@1%":
                ok = False
        rows.append({**row, "passed": ok})
    return pd.DataFrame(rows)


def _observation_lines(table) -> list[str]:
    split = observation_split(table)
    if split.empty or split[list(OBSERVATION_CHECK)].isna().all().all():
        return []
    lines = ["", "## Observation and inference", "",
             "The `observed` rung is the ground truth cut to the wood its capture's views observed "
             "(`plantbench.capture.observed`): it must score " + ", ".join(
                 f"`{m}` {op} {b:g}" for m, (op, b) in OBSERVATION_CHECK.items())
             + f" on every plant: {int(split['passed'].sum())} of {len(split)} do.", "",
             "| plant | " + " | ".join(OBSERVATION_CHECK) + " | passed |", "|---" * (len(OBSERVATION_CHECK) + 2) + "|"]
    for d in split.to_dict("records"):
        lines.append(f"| {d['case']} | " + " | ".join(_fmt(d[m]) for m in OBSERVATION_CHECK)
                     + f" | {'yes' if d['passed'] else 'no'} |")
    return lines


def calibration_markdown(table, verdict, *, header: str = "", headline: tuple[str, ...] = (),
                         structure: tuple[str, ...] = ()) -> str:
    """The README of reports/calibration: the verdict table (every metric), the ladder's means for the key metrics.
    ``headline``: the headline fidelity metrics; ``structure``: those of them that must pass the structure checks."""
    n = int(verdict["plants"].max()) if len(verdict) else 0
    need = n - math.floor(ALLOWED_FAILURES * n + 1e-9)
    lines = ["# Metric calibration", "", header, "",
             "Each plant of the suite is reconstructed by controlled degradations of its ground truth "
             "(`plantbench.methods.ladder`), scored by every metric. A metric **discriminates** when on at least "
             f"{need} of {n} plants it ranks the skeleton pruned to branch "
             "orders <= 2 above both no-data priors (the species grown with seeds 0 and 1, scaled to the plant's "
             "height), the ground truth with every node jittered by 0.5 % of the height above both priors, the "
             "pruning rungs (gt, orders <= 3, 2, 1) in order and the jitter rungs (gt, 0.25, 0.5, 1, 2 %) in order "
             "(ties allowed between neighbours: a plant without order-3 branches loses nothing to orders <= 2; the "
             "last rung must be worse than gt).", "",
             "A metric **sees structure** when, on at least the same number of plants, it also passes three checks "
             "on rungs that add structure to the exact plant: *twigs ordered*, the exact plant strictly above twigs "
             "added at +25 %, +100 % and +400 % of its branch count, each strictly above the next (invented twigs "
             "drawn from the plant's own terminal branches, attached at random nodes); *tangle<gt*, the exact plant "
             "strictly above the tangle (a fifth of the nodes re-hung on a nearby node of an unrelated branch, the "
             "jumps across gaps a graph method makes on a noisy cloud); and *twigs+400% material*, the +400 % rung "
             f"(about five times the true branch count) at least {MATERIAL:g} of the way from the exact plant down "
             "to the better prior, so that a metric which orders the twig rungs only by rounding fails.", ""]
    if headline:
        lines += ["Headline fidelity metrics (`plantbench metrics --headline`): "
                  + ", ".join(f"`{m}`" for m in headline) + "; of them "
                  + ", ".join(f"`{m}`" for m in structure) + " must also see structure. The headline's GT-free "
                  "column, `support.skeleton@1%`, is not a fidelity metric and is not meant to pass: it asks only "
                  "whether the skeleton lies where the capture saw something, so it cannot see missing branches "
                  "(pruning) and it is what a real capture without ground truth allows.", ""]
    key = list(headline) + [m for m in ("skeleton.lf1@1%", "skeleton.branch_count_log2_error", "stava.S_T",
                                         "mesh_to_surface.D_cm", "leaves.accuracy", "leaves.f1", "skeleton.f1@1.0",
                                         "surface.all.fscore@2%", "reprojection.iou", "support.skeleton@1%")
                            if m not in headline]
    means = ladder_means(table, key)
    lines += ["## The ladder (mean over plants)", "", "Rows: metrics; columns: rungs.", "",
              "| metric | " + " | ".join(means.columns) + " |", "|---" * (len(means.columns) + 1) + "|"]
    for metric, row in means.iterrows():
        lines.append(f"| {metric} | " + " | ".join(_fmt(v) for v in row) + " |")
    checks = list(VOLUME_CHECKS + STRUCTURE_CHECKS)
    failing = verdict[(verdict["verdict"] != "discriminates") & verdict["metric"].isin(means.index)]
    if len(failing):
        lines += ["", "## Why the older columns are not headline metrics", ""]
        lines += _missed_lines(failing, VOLUME_CHECKS, n, means, "orders<=2 {orders<=2}, orders<=1 {orders<=1}, "
                               "jitter 0.5 % {jitter-0.5%}, priors {prior-a} and {prior-b}")
    blind = verdict[(verdict["verdict"] == "discriminates") & (verdict["structure"] != "discriminates")
                    & verdict["metric"].isin(means.index)]
    if len(blind):
        lines += ["", "## Fidelity metrics that do not see structure", ""]
        lines += _missed_lines(blind, STRUCTURE_CHECKS, n, means, "gt {gt}, twigs +25 / +100 / +400 % {twigs+25%} / "
                               "{twigs+100%} / {twigs+400%}, tangle {" + TANGLE + "}")
    lines += _observation_lines(table)
    lines += ["", "## Verdict per metric", "",
              "Counts are plants passing each check (of " + str(n) + "); *all*: every volume check, *all+s*: every "
              "check.", "",
              "| metric | dir | " + " | ".join(checks) + " | all | verdict | all+s | structure |",
              "|---" * (len(checks) + 6) + "|"]
    order = verdict.assign(_d=verdict["verdict"] != "discriminates",
                           _s=verdict["structure"] != "discriminates").sort_values(["_d", "_s", "metric"])
    for d in order.to_dict("records"):
        lines.append(f"| {d['metric']} | {'↑' if d['higher_is_better'] else '↓'} | "
                     + " | ".join(str(int(d[c])) for c in checks)
                     + f" | {d['passed']} | {d['verdict']} | {d['structure_passed']} | "
                     + ("sees structure" if d["structure"] == "discriminates" else "-") + " |")
    return "\n".join(lines) + "\n"


def ladder_figure(table, metrics: list[str], path: str | os.PathLike) -> Path:
    """One panel per metric: each plant's value per rung (grey lines), the mean (black), priors shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from plantbench.report.figures import save_png

    piv = _pivot(table)
    rungs = [r for r in LADDER if r in piv.columns]
    cols = min(3, len(metrics))
    rows_n = math.ceil(len(metrics) / cols)
    fig, axes = plt.subplots(rows_n, cols, figsize=(5.2 * cols, 3.6 * rows_n), squeeze=False)
    x = np.arange(len(rungs))
    for ax, metric in zip(axes.ravel(), metrics):
        if metric not in piv.index.get_level_values(0):
            ax.set_visible(False)
            continue
        data = piv.loc[metric, rungs]
        kind = [re.split(r"[-<+]", r)[0] for r in rungs]  # lines join rungs of one kind only
        breaks = [i for i in range(1, len(rungs)) if kind[i] != kind[i - 1] and kind[i - 1] != "gt"]

        def gapped(values: np.ndarray, breaks: list[int] = breaks) -> tuple[np.ndarray, np.ndarray]:
            return np.insert(x.astype(float), breaks, np.nan), np.insert(values.astype(float), breaks, np.nan)

        for _, row in data.iterrows():
            ax.plot(*gapped(row.to_numpy(float)), color="0.75", lw=0.8)
        ax.plot(*gapped(data.mean().to_numpy(float)), color="k", lw=1.8, marker="o", ms=3, label="mean")
        for p in PRIORS:
            if p in rungs:
                ax.axvspan(rungs.index(p) - 0.4, rungs.index(p) + 0.4, color="tab:red", alpha=0.12)
        ax.set_xticks(x, rungs, rotation=70, fontsize=7)
        ax.set_title(metric, fontsize=9)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(metrics):]:
        ax.set_visible(False)
    fig.suptitle("Calibration ladder: each plant (grey), mean (black); no-data priors shaded red", fontsize=10)
    fig.tight_layout()
    return save_png(fig, path)


def write_calibration(table, folder: str | os.PathLike, *, header: str = "") -> tuple[object, list[Path]]:
    """Write ladder.csv.gz (every rung's every metric), verdicts.csv, ladder.png and README.md into ``folder``;
    returns (the verdict frame, the files written)."""
    from plantbench.io.atomic import atomic_write
    from plantbench.metrics.info import HEADLINE_FIDELITY, HEADLINE_STRUCTURE

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    verdict = verdicts(table)
    ladder = table.assign(rung=table["method"].map(_rung), value=table["value"].where(table["status"] == "ok"))
    with atomic_write(folder / LADDER_FILE) as fh:  # one row per plant, rung and metric; failed cells empty
        ladder[["case", "species", "family", "rung", "metric", "value"]].to_csv(
            fh, index=False, compression={"method": "gzip", "mtime": 0})
    with atomic_write(folder / "verdicts.csv", "w") as fh:
        verdict.to_csv(fh, index=False)
    figure = ladder_figure(table, list(HEADLINE_FIDELITY) + [m for m in (
        "skeleton.lf1@1%", "skeleton.branch_count_log2_error", "support.skeleton@1%", "stava.S_T",
        "skeleton.f1@1.0", "mesh_to_surface.D_cm") if m not in HEADLINE_FIDELITY], folder / "ladder.png")
    header += (f" {LADDER_FILE} holds every rung's every metric, verdicts.csv the verdicts; the figure shows the "
               f"headline metrics and the older ones per rung.\n\n![ladder]({figure.name})")
    with atomic_write(folder / "README.md", "w") as fh:
        fh.write(calibration_markdown(table, verdict, header=header, headline=HEADLINE_FIDELITY,
                                      structure=HEADLINE_STRUCTURE))
    return verdict, [folder / LADDER_FILE, folder / "verdicts.csv", figure, folder / "README.md"]
