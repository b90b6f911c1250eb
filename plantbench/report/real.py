"""The report's part on real captures: each method's tree traits, against reference cylinder models where a case
has them, and pictures of each skeleton over its scan.

A scan case of a suite may name reference QSMs of the same cloud (``references``: TreeQSM, SimpleForest, aRchi;
:mod:`plantbench.io.references`). Their traits are computed as a method's are (:func:`plantbench.metrics.traits.
cylinder_traits`, after moving them into the case's frame), so a method's DBH, height, trunk volume and lengths are
read against the spread of three published tools: :func:`reference_traits`, :func:`trait_comparison` and
:func:`trait_figure`. :func:`skeleton_figure` draws every method's skeleton over the scan from the front and the
side, so a person can see a tangle that a number hides.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

__all__ = ["COMPARED_TRAITS", "reference_traits", "method_traits", "trait_comparison", "trait_figure",
           "skeleton_figure", "real_tables", "real_figures"]

COMPARED_TRAITS = ("dbh_cm", "height_m", "trunk_volume_l", "total_volume_l", "total_length_m", "branch_count")
"""The traits held to the references (per-order lengths stay in results.csv: the tools split axes differently)."""

_TOOL_NAMES = {"treeqsm": "TreeQSM", "simpleforest": "SimpleForest", "archi": "aRchi"}


def _scan_cases(run_dir: Path) -> dict[str, dict]:
    """case id -> the suite's scan case entry (scan, references...), from run.json's config."""
    from plantbench.report.gate import read_run_meta
    from plantbench.runner.plan import scan_case_id

    cases = (read_run_meta(run_dir).get("config") or {}).get("cases") or []
    return {scan_case_id(c["scan"]): c for c in cases if c.get("scan")}


def _capture_dirs(run_dir: Path) -> dict[str, Path]:
    import json

    cells = json.loads((run_dir / "cells.json").read_text()) if (run_dir / "cells.json").is_file() else []
    return {c["case"]: (run_dir / c["capture"]).resolve() for c in cells}


def reference_traits(run_dir: str | os.PathLike, *, breast_height: float = 1.3):
    """Traits of every reference QSM of the run's scan cases, in the case frame: a DataFrame (case, source, trait,
    value), source the tool's name. Empty when no case has references."""
    import pandas as pd

    from plantbench.capture.importers import read_case_json
    from plantbench.io.references import read_reference, reference_in_case_frame
    from plantbench.metrics.traits import cylinder_traits

    run_dir = Path(run_dir)
    captures = _capture_dirs(run_dir)
    rows = []
    for case, entry in _scan_cases(run_dir).items():
        if not entry.get("references") or case not in captures:
            continue
        frame = read_case_json(captures[case]).frame
        for tool, file in entry["references"].items():
            table = reference_in_case_frame(read_reference(tool, file), frame)
            for trait, value in cylinder_traits(table, breast_height=breast_height).items():
                rows.append({"case": case, "source": _TOOL_NAMES.get(tool, tool), "trait": trait, "value": value})
    return pd.DataFrame(rows, columns=["case", "source", "trait", "value"])


def method_traits(table):
    """Each method's traits on the real cases, from its QSM export (``qsm.*``) and its skeleton (``skeleton.*``,
    where the skeleton gives them): a DataFrame (case, source, from, trait, value)."""
    import pandas as pd

    from plantbench.metrics.traits import TRAITS

    t = table[(table["family"] == "real") & (table["status"] == "ok")]
    rows = []
    for prefix, origin in (("qsm.", "qsm"), ("skeleton.", "skeleton")):
        sub = t[t["metric"].isin([prefix + k for k in TRAITS])]
        for r in sub.itertuples(index=False):
            rows.append({"case": r.case, "source": r.method, "from": origin, "trait": r.metric[len(prefix):],
                         "value": r.value})
    return pd.DataFrame(rows, columns=["case", "source", "from", "trait", "value"])


def _against(value: float, lo: float, hi: float) -> str:
    """'within' the references' range, or how far outside it, relative to the nearer end ('+12 %', '-30 %')."""
    if value is None or not np.isfinite(value):
        return "-"
    if lo <= value <= hi:
        return "within"
    end = hi if value > hi else lo
    return f"{100 * (value - end) / end:+.0f} %" if end else "-"


def trait_comparison(run_dir: str | os.PathLike, table):
    """Per reference case and compared trait (:data:`COMPARED_TRAITS`): each reference's value, their range, and
    each method's value from its QSM export with where it falls against the range. A DataFrame of strings (empty
    without references)."""
    import pandas as pd

    from plantbench.report.tables import format_value

    refs = reference_traits(run_dir)
    if refs.empty:
        return pd.DataFrame()
    mine = method_traits(table)
    mine = mine[mine["from"] == "qsm"]
    rows = []
    for case in sorted(refs["case"].unique()):
        r = refs[refs["case"] == case]
        for trait in COMPARED_TRAITS:
            vals = r[r["trait"] == trait].set_index("source")["value"].astype(float)
            finite = vals[np.isfinite(vals)]
            lo, hi = (float(finite.min()), float(finite.max())) if len(finite) else (np.nan, np.nan)
            row = {"case": case, "trait": trait, **{s: format_value(v) for s, v in vals.items()},
                   "references": f"{format_value(lo)} - {format_value(hi)}"}
            m = mine[(mine["case"] == case) & (mine["trait"] == trait)]
            for meth in sorted(m["source"].unique()):
                v = float(m[m["source"] == meth]["value"].iloc[0])
                row[meth] = f"{format_value(v)} ({_against(v, lo, hi)})"
            rows.append(row)
    return pd.DataFrame(rows).fillna("-")


def trait_figure(run_dir: str | os.PathLike, table, path: str | os.PathLike) -> Path | None:
    """One panel per compared trait: the references' range as a band with each reference marked, each method's
    value from its QSM export as a point (from its skeleton as a hollow point), one row per reference case. None
    without references."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from plantbench.report.figures import save_png

    refs = reference_traits(run_dir)
    if refs.empty:
        return None
    mine = method_traits(table)
    cases = sorted(refs["case"].unique())
    methods = sorted(mine["source"].unique())
    traits = list(COMPARED_TRAITS)
    fig, axes = plt.subplots(len(cases), len(traits), figsize=(2.6 * len(traits), 3.0 * len(cases)), squeeze=False)
    colours = plt.get_cmap("tab10")
    for row, case in enumerate(cases):
        for col, trait in enumerate(traits):
            ax = axes[row, col]
            r = refs[(refs["case"] == case) & (refs["trait"] == trait)].dropna(subset=["value"])
            if len(r):
                ax.axhspan(r["value"].min(), r["value"].max(), color="0.85", zorder=0, label="references' range")
                for k, ref in enumerate(r.itertuples()):
                    ax.plot([-0.4, len(methods) - 0.6], [ref.value] * 2, ls=(0, (2, 2)), lw=0.8, color="0.45")
                    ax.annotate(ref.source, (len(methods) - 0.6, ref.value), fontsize=6, color="0.35",
                                va="bottom" if k % 2 else "top", ha="right")
            for i, meth in enumerate(methods):
                for origin, face in (("qsm", colours(i)), ("skeleton", "none")):
                    v = mine[(mine["case"] == case) & (mine["source"] == meth) & (mine["trait"] == trait)
                             & (mine["from"] == origin)]["value"]
                    if len(v) and np.isfinite(v.iloc[0]):
                        ax.scatter([i], [v.iloc[0]], s=36, facecolors=face, edgecolors=colours(i), zorder=3)
            ax.set_xticks(range(len(methods)), methods, rotation=45, fontsize=7)
            ax.set_xlim(-0.6, len(methods) - 0.4)
            ax.set_title(f"{case}: {trait}", fontsize=8)
            ax.tick_params(axis="y", labelsize=7)
            ax.grid(alpha=0.3, axis="y")
    fig.suptitle("Traits against three reference QSMs (grey band: their range; filled: from the method's QSM "
                 "export, hollow: from its skeleton)", fontsize=9)
    fig.tight_layout()
    return save_png(fig, path)


def skeleton_figure(run_dir: str | os.PathLike, case: str, path: str | os.PathLike, *,
                    max_points: int = 20_000, seed: int = 0) -> Path | None:
    """The scan of ``case`` (grey, at most ``max_points``) with each method's skeleton over it (its edges, line width
    growing with the radius), from the front (x-z) and the side (y-z), one row per method. None when the case has
    no scan or no skeleton."""
    import json

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    from plantbench.io.plantio import read_reconstruction
    from plantbench.io.ply import read_points
    from plantbench.report.figures import save_png

    run_dir = Path(run_dir)
    cells = [c for c in json.loads((run_dir / "cells.json").read_text()) if c["case"] == case and c["status"] == "ok"]
    if not cells:
        return None
    scan_file = (run_dir / cells[0]["capture"] / "scan" / "scan.ply").resolve()
    if not scan_file.is_file():
        return None
    pts = read_points(scan_file)[0]
    rng = np.random.Generator(np.random.PCG64(seed))
    if len(pts) > max_points:
        pts = pts[rng.choice(len(pts), max_points, replace=False)]
    skeletons = []
    for c in sorted(cells, key=lambda c: c["method"]):
        rec = read_reconstruction((run_dir / c["recon"]).resolve())
        if rec.skeleton is not None and len(rec.skeleton) > 1:
            skeletons.append((c["method"], rec.skeleton))
    if not skeletons:
        return None
    fig, axes = plt.subplots(len(skeletons), 2, figsize=(8, 4.2 * len(skeletons)), squeeze=False)
    for row, (method, sk) in enumerate(skeletons):
        e = sk.edges
        width = np.minimum(0.3 + 6.0 * np.sqrt(np.maximum(sk.radii[e[:, 1]], 0)), 3.0)
        for col, (ax_i, name) in enumerate(((0, "front (x-z)"), (1, "side (y-z)"))):
            ax = axes[row, col]
            ax.scatter(pts[:, ax_i], pts[:, 2], s=0.5, c="0.45", linewidths=0, rasterized=True)
            segs = np.stack([sk.positions[e[:, 0]][:, [ax_i, 2]], sk.positions[e[:, 1]][:, [ax_i, 2]]], axis=1)
            ax.add_collection(LineCollection(segs, linewidths=width, colors="tab:red", alpha=0.8))
            ax.set_aspect("equal")
            ax.set_title(f"{case}, {method}: {name}", fontsize=9)
            ax.tick_params(labelsize=7)
    fig.tight_layout()
    return save_png(fig, path, dpi=90)


def real_tables(run_dir: str | os.PathLike, table) -> list[tuple[str, str, object]]:
    """(slug, caption, DataFrame) of the report's real-capture tables: every method's traits per real case (from
    its QSM export), and the comparison with the reference QSMs where a case has them."""
    import pandas as pd

    from plantbench.report.tables import format_value

    mine = method_traits(table)
    out = []
    if not mine.empty:
        q = mine[mine["from"] == "qsm"]
        wide = q.pivot_table(index=["case", "source"], columns="trait", values="value", aggfunc="first")
        cols = [t for t in COMPARED_TRAITS if t in wide.columns]
        df = wide[cols].map(format_value).reset_index().rename(columns={"source": "method"})
        for metric, column in (("support.skeleton@spacing", "support@spacing"),
                               ("support.coverage@spacing", "coverage@spacing")):
            rows = table[(table["metric"] == metric) & (table["status"] == "ok") & (table["family"] == "real")]
            got = {(r.case, r.method): format_value(r.value) for r in rows.itertuples()}
            df[column] = [got.get((c, m), "-") for c, m in zip(df["case"], df["method"])]
        out.append(("traits", "Real captures: each method's traits from its QSM export (plantbench qsm export), its "
                              "skeleton's share within max(1 % H, 2 x spacing) of the scan (support: precision) and "
                              "the scan's share within that of its surface (coverage: completeness)", df))
    comp = trait_comparison(run_dir, table)
    if not comp.empty:
        out.append(("references", "Traits against the reference QSMs of the same cloud (TreeQSM, SimpleForest, "
                                  "aRchi): each reference, their range, and each method's value with where it "
                                  "falls ('within', or its distance from the nearer end of the range)",
                    pd.DataFrame(comp)))
    return out


def real_figures(run_dir: str | os.PathLike, table, folder: str | os.PathLike) -> list[Path]:
    """The trait figure (cases with references) and one skeleton figure per real case."""
    folder = Path(folder)
    figures = [trait_figure(run_dir, table, folder / "traits.png")]
    for case in sorted(table.loc[table["family"] == "real", "case"].unique()):
        figures.append(skeleton_figure(run_dir, case, folder / f"skeletons_{case}.png"))
    return [f for f in figures if f is not None]
