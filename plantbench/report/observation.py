"""Observation and inference in a report (issue 63): how much of each plant's wood its capture showed, how much of
the hidden wood each method recovered, and a figure of the ground-truth skeleton coloured observed / hidden over a
view of each plant.

The numbers are the metrics' (:mod:`plantbench.capture.observed`, ``capture.observed_wood_share``,
``skeleton.vf1_observed@1%``, ``skeleton.vrecall_hidden@1%``); this module only tabulates and draws them.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

__all__ = ["OBSERVED", "OBSERVATION", "INFERENCE", "observed_per_plant", "observation_tables", "oracle_ratio",
           "dbh_check", "observed_figure"]

OBSERVED = "capture.observed_wood_share"
OBSERVATION = "skeleton.vf1_observed@1%"
INFERENCE = "skeleton.vrecall_hidden@1%"
BREAST = "capture.breast_height_observed"
WELL_OBSERVED = 0.6
"""Plants whose capture observed at least this share of the wood: where a method's observation is held to its
oracle (issue 63's acceptance)."""


def observed_per_plant(table):
    """One row per case (per sweep level and case in a run with a sweep): species, family, the observed share of its
    wood and whether its stem's breast height was observed (both the same for every method reading the same
    capture; the median over them). Empty when the run has no observed-wood metrics."""
    import pandas as pd

    ok = table[(table["status"] == "ok") & table["metric"].isin([OBSERVED, BREAST])]
    ok = ok[np.isfinite(ok["value"].to_numpy(float))]
    if ok.empty:
        return pd.DataFrame(columns=["case", "species", "family", OBSERVED, BREAST])
    keys = [c for c in ("case", "species", "family") if c in ok.columns]
    if _levels(table):
        keys = ["sweep"] + keys
    wide = ok.pivot_table(index=keys, columns="metric", values="value", aggfunc="median").reset_index()
    for m in (OBSERVED, BREAST):
        if m not in wide.columns:
            wide[m] = np.nan
    return wide.sort_values([k for k in ("sweep",) if k in wide.columns] + [OBSERVED]).reset_index(drop=True)


def oracle_ratio(table, oracle_table=None, *, metric: str = OBSERVATION, threshold: float = WELL_OBSERVED):
    """:func:`_oracle_ratio`, per level of a run with a sweep (:func:`_per_level`)."""

    def at(sub, level):
        other = oracle_table
        if other is not None and level is not None and "sweep" in other.columns:
            other = other[other["sweep"] == level]
        return _oracle_ratio(sub, other, metric=metric, threshold=threshold)

    return _per_level(table, at)


def _oracle_ratio(table, oracle_table=None, *, metric: str = OBSERVATION, threshold: float = WELL_OBSERVED):
    """Each method's ``metric`` on its cloud over the same on the oracle cloud (ratio of the means over the plants
    both scored, a failed cell counted 0), over the plants whose observed share is at least ``threshold`` and over
    the others. The oracle cells are ``METHOD@oracle`` rows of ``table``, or the same method's rows of
    ``oracle_table`` (a run of the suite whose mvs stage is the oracle). Returns a DataFrame: method, group, plants,
    mean, oracle_mean, ratio."""
    import pandas as pd

    def values(t):
        sub = t[t["metric"] == metric]
        v = sub["value"].where(sub["status"] == "ok", 0.0).fillna(0.0)
        return sub.assign(value=v).pivot_table(index="case", columns="method", values="value", aggfunc="first")

    mine = values(table)
    other = values(oracle_table) if oracle_table is not None else None
    share = observed_per_plant(table).set_index("case")[OBSERVED]
    rows = []
    for method in mine.columns:
        base = method.split(" ")[0]
        if "@" in base or base in ("gt", "prior"):
            continue
        if other is not None and method in other.columns:
            ref = other[method]
        elif f"{base}@oracle (oracle)" in mine.columns:
            ref = mine[f"{base}@oracle (oracle)"]
        else:
            continue
        both = pd.concat([mine[method], ref], axis=1, keys=["m", "o"]).dropna()
        both = both[both.index.isin(share.index)]
        for group, sel in ((f">= {threshold:g}", share.reindex(both.index) >= threshold),
                           (f"< {threshold:g}", share.reindex(both.index) < threshold)):
            g = both[sel.to_numpy()]
            if len(g):
                rows.append({"method": method, "group": group, "plants": len(g), "mean": g["m"].mean(),
                             "oracle_mean": g["o"].mean(),
                             "ratio": g["m"].mean() / g["o"].mean() if g["o"].mean() > 0 else float("nan")})
    return pd.DataFrame(rows, columns=["method", "group", "plants", "mean", "oracle_mean", "ratio"])


def _levels(table) -> list:
    """The run's sweep levels when it has more than one (a scan suite's beam spacings), else []: a plant is a case at
    one level, and a table over plants is made per level."""
    if "sweep" not in table.columns:
        return []
    levels = list(dict.fromkeys(table["sweep"].dropna()))
    return levels if len(levels) > 1 else []


def _per_level(table, make):
    """``make(table, None)`` for a run without a sweep; else ``make(rows of one level, level)`` for each level,
    concatenated with a ``sweep`` column first."""
    import pandas as pd

    levels = _levels(table)
    if not levels:
        return make(table, None)
    out = pd.concat([make(table[table["sweep"] == level], level).assign(sweep=level) for level in levels],
                    ignore_index=True)
    return out[["sweep"] + [c for c in out.columns if c != "sweep"]]


def dbh_check(table, *, within: float = 0.10):
    """Each method's DBH against the truth (the gt row's ``skeleton.dbh_cm``) on the plants whose capture observed
    the stem at breast height: plants checked, within ``within`` of the truth, within 0.5-2x, and the plants skipped
    because the stem was hidden there or is shorter than breast height (a failed cell counts as checked and not
    within). A run with a sweep (several captures of each plant) is checked per level, with a ``sweep`` column first.
    Returns a DataFrame: [sweep,] method, checked, within, within_2x, median_rel_error, hidden, short."""
    return _per_level(table, lambda sub, _: _dbh_check(sub, within))


def _dbh_check(table, within: float):
    import pandas as pd

    plants = observed_per_plant(table).set_index("case")
    dbh = table[table["metric"] == "skeleton.dbh_cm"]
    truth = dbh[dbh["method"].str.split(" ").str[0] == "gt"].set_index("case")["value"]
    seen = plants.index[plants[BREAST] >= 0.5]
    hidden = int((plants[BREAST] < 0.5).sum())
    short = int(plants[BREAST].isna().sum())
    rows = []
    for method, grp in dbh.groupby("method", sort=True):
        if method.split(" ")[0] == "gt":
            continue
        g = grp.set_index("case")
        cases = [c for c in seen if c in g.index and np.isfinite(truth.get(c, np.nan))]
        rel = np.array([abs(g.at[c, "value"] - truth[c]) / truth[c] if g.at[c, "status"] == "ok"
                        and np.isfinite(g.at[c, "value"]) else np.inf for c in cases])
        ratio = np.array([g.at[c, "value"] / truth[c] if g.at[c, "status"] == "ok" and np.isfinite(g.at[c, "value"])
                          else np.nan for c in cases])
        rows.append({"method": method, "checked": len(cases), "within": int((rel <= within).sum()),
                     "within_2x": int(((ratio >= 0.5) & (ratio <= 2.0)).sum()),
                     "median_rel_error": float(np.median(rel)) if len(rel) else float("nan"),
                     "hidden": hidden, "short": short})
    return pd.DataFrame(rows, columns=["method", "checked", "within", "within_2x", "median_rel_error", "hidden",
                                       "short"])


def observation_tables(table, wide_table) -> list[tuple[str, str, object]]:
    """(slug, caption, DataFrame of strings) of the report's observation tables: the observed share per plant, the
    observation and inference scores per family and method (``wide_table(table, by, metrics)``: the report's
    mean [CI] table, :func:`plantbench.report.report.wide_table`), the DBH check where the stem was observed, and
    the oracle ratio on observation when the run has oracle-cloud cells; [] for a run without observed-wood
    metrics."""
    import pandas as pd

    plants = observed_per_plant(table)
    if plants.empty:
        return []
    shown = plants.assign(**{OBSERVED: plants[OBSERVED].map(lambda v: f"{v:.2f}"),
                             BREAST: plants[BREAST].map(lambda v: "-" if not np.isfinite(v) else
                                                        ("yes" if v >= 0.5 else "no"))})
    out = [("observed", "Wood the capture observed, per plant: the volume-weighted share of the ground-truth wood "
                        "seen on a wood pixel of agreeing exact depth in >= 2 views (branches >= 1 px wide; a scan: "
                        "within 2 x the median spacing of a wood return), and whether the stem's bark at breast "
                        "height was observed (a DBH is checked only there)", shown)]
    by = ("family", "method") if "family" in table.columns else ("method",)
    if _levels(table):
        by = ("sweep",) + by
    out.append(("inference", f"Observation and inference per {by[0]} and method: {OBSERVATION} (precision against "
                             f"the whole truth, recall over the observed wood) and {INFERENCE} (recall over the "
                             "hidden wood: what the method inferred), mean [95 % bootstrap CI] over plants",
                wide_table(table, by, (OBSERVATION, INFERENCE))))
    dbh = dbh_check(table)
    if len(dbh) and dbh["checked"].max() > 0:
        out.append(("dbh", "DBH against the truth where the capture observed the stem at breast height: plants "
                           "checked, within 10 %, within 0.5-2x, median relative error; plants skipped because the "
                           "stem's bark at 1.3 m was hidden, or the stem is shorter",
                    dbh.assign(median_rel_error=dbh["median_rel_error"].map(lambda v: f"{v:.2f}"))))
    ratio = oracle_ratio(table)
    if not ratio.empty:
        out.append(("oracle_ratio", f"{OBSERVATION} on the method's cloud over the same on the oracle cloud (ratio of "
                                    "means, failed cells 0), on the plants whose capture observed >= "
                                    f"{WELL_OBSERVED:g} of the wood and on the others",
                    pd.DataFrame([{**r, "mean": f"{r['mean']:.3f}", "oracle_mean": f"{r['oracle_mean']:.3f}",
                                   "ratio": f"{r['ratio']:.2f}"} for r in ratio.to_dict("records")])))
    return out


_PANEL_IN = 2.4
"""Width of a panel of :func:`observed_figure`, inches."""
_VIEW_PX = 128
"""The view behind a panel is shown at about this many pixels across."""


def observed_figure(captures: dict[str, Path], path: str | os.PathLike, *, source: str = "views", view: int = 0,
                    max_cases: int = 30) -> Path | None:
    """A panel per case (``captures``: case -> its capture folder; up to ``max_cases``): the ground-truth skeleton
    drawn over view ``view`` of its capture, each edge coloured by the share of its bark the capture observed (green
    observed, red hidden), its width the branch's projected width. ``source`` is the suite's (run.json's
    ``config.source``): 'views' colours by ``views/observed_wood.npz``, 'scan' by ``scan/observed_wood.npz``, the
    file the suite's metrics read (a multiview capture also scans, a scan capture also renders a few views). None
    when no capture has the views and that file."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from PIL import Image

    from plantbench.cameras import read_cameras
    from plantbench.capture.observed import OBSERVED_FILE, observed_share, read_observed
    from plantbench.io.plantio import read_plant
    from plantbench.report.figures import save_png

    if source not in ("views", "scan"):
        raise ValueError(f"source must be 'views' or 'scan', got {source!r}")
    cases = {case: Path(folder) for case, folder in captures.items()
             if (Path(folder) / "views" / "cameras.json").is_file() and (Path(folder) / source / OBSERVED_FILE).is_file()}
    if not cases:
        return None
    names = sorted(cases)[:max_cases]
    cols = min(5, len(names))
    rows = -(-len(names) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(_PANEL_IN * cols, (_PANEL_IN + 0.1) * rows), squeeze=False,
                             layout="constrained")
    for ax in axes.ravel():
        ax.axis("off")
    for ax, case in zip(axes.ravel(), names):
        folder = cases[case]
        plant, _ = read_plant(folder)
        share = read_observed(folder / source / OBSERVED_FILE, plant.skeleton)
        cams, images = read_cameras(folder / "views" / "cameras.json")
        cam = cams[min(view, len(cams) - 1)]
        img = np.asarray(Image.open(folder / "views" / "images" / images[min(view, len(cams) - 1)]))
        e = plant.skeleton.edges
        uv, z = cam.project(plant.skeleton.positions)
        r = 0.5 * (plant.skeleton.radii[e[:, 0]] + plant.skeleton.radii[e[:, 1]])
        points_per_px = _PANEL_IN * 72 / cam.width
        width = np.clip(2 * r * cam.K[0, 0] / np.maximum(z[e[:, 1]], 1e-6) * points_per_px, 0.15, 3.0)
        step = max(1, cam.width // _VIEW_PX)  # the view as a faint backdrop: a small one keeps the PNG small
        ax.imshow(img[::step, ::step], alpha=0.35, extent=(-0.5, cam.width - 0.5, cam.height - 0.5, -0.5))
        order = np.argsort(share)[::-1]  # hidden (red) drawn last, over the observed
        ax.add_collection(LineCollection(np.stack([uv[e[order, 0]], uv[e[order, 1]]], 1),
                                         colors=plt.cm.RdYlGn(share[order]), linewidths=width[order]))
        title = f"{case}: {observed_share(plant.skeleton, share):.2f} observed{' (scan)' if source == 'scan' else ''}"
        ax.set(xlim=(0, cam.width), ylim=(cam.height, 0), title=title)
        ax.title.set_fontsize(min(8.0, 8.0 * 34 / len(title)))  # a long case name still fits its panel
    fig.suptitle("Ground-truth skeleton over a view: bark observed (green) / hidden (red) by the capture", fontsize=9)
    return save_png(fig, path, dpi=80)
