"""The leaves suite's own measures, beside the metrics (``reports/leaves``): how well the per-view depth maps of a
method's input hold the leaves (:func:`leaf_depth_accuracy`, the mvs stage measured against the exact depth: the
issue's "keeps small foreground leaves"), read from a run's cache by the report.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["leaf_depth_accuracy"]


def leaf_depth_accuracy(case_dir: str | Path, depth_dir: str | Path, *, tol: float = 0.01) -> dict:
    """How well per-view depth maps (``depth_dir/STEM.npz``, key ``depth``, NaN where rejected: the mvs stage's
    output; or ``STEM.npy``) hold the leaves of a capture with ground truth.

    Per view with leaf pixels (instance >= 2): ``within`` = leaf pixels whose depth is within ``tol`` x plant height
    of the exact depth / leaf pixels; ``kept`` = leaf pixels with a finite depth / leaf pixels.

    Returns
    -------
    dict: height, tol, views, leaf_pixels (all views), within and kept pooled over the views' leaf pixels,
    within_median and kept_median over the views, within_of_kept (pooled, among the pixels with a depth)
    """
    from PIL import Image

    from plantbench.cameras import read_cameras
    from plantbench.io.plantio import read_plant

    case = Path(case_dir)
    _, meta = read_plant(case)
    height = float(meta.height)
    _, names = read_cameras(case / "views" / "cameras.json")
    estimated = [_depth_map(Path(depth_dir), Path(name).stem) for name in names]
    n_leaf = n_kept = n_within = 0
    per_within, per_kept = [], []
    for name, est in zip(names, estimated, strict=True):
        stem = Path(name).stem
        leaf = np.array(Image.open(case / "views" / "instance" / f"{stem}.png")) >= 2
        if not leaf.any():
            continue
        exact = np.load(case / "views" / "depth" / f"{stem}.npy").astype(np.float64)
        est = np.full(exact.shape, np.nan) if est is None else est
        kept = leaf & np.isfinite(est)
        within = kept & (np.abs(np.where(kept, est, 0.0) - exact) <= tol * height)
        n_leaf, n_kept, n_within = n_leaf + leaf.sum(), n_kept + kept.sum(), n_within + within.sum()
        per_within.append(within.sum() / leaf.sum())
        per_kept.append(kept.sum() / leaf.sum())
    if not n_leaf:
        return {"height": height, "tol": tol, "views": 0, "leaf_pixels": 0, "within": None, "kept": None,
                "within_median": None, "kept_median": None, "within_of_kept": None}
    return {"height": height, "tol": tol, "views": len(per_within), "leaf_pixels": int(n_leaf),
            "within": float(n_within / n_leaf), "kept": float(n_kept / n_leaf),
            "within_median": float(np.median(per_within)), "kept_median": float(np.median(per_kept)),
            "within_of_kept": float(n_within / n_kept) if n_kept else None}


def _depth_map(folder: Path, stem: str) -> np.ndarray | None:
    """``folder/STEM.npz`` (key ``depth``, the mvs stage's output) or ``STEM.npy``; None when neither exists."""
    if (folder / f"{stem}.npz").is_file():
        with np.load(folder / f"{stem}.npz") as z:
            return np.asarray(z["depth"], np.float64)
    if (folder / f"{stem}.npy").is_file():
        return np.asarray(np.load(folder / f"{stem}.npy"), np.float64)
    return None


LEAF_COLUMNS = {
    "leaves.strict_f1": "F1",
    "leaves.strict_precision": "P",
    "leaves.strict_recall": "R",
    "leaves.count_pred": "leaves",
    "leaves.count_gt": "GT leaves",
    "leaves.accuracy": "count acc.",
    "leaves.shape_error": "shape err.",
    "leaves.normal_error_deg": "normal err. (deg)",
}
"""The leaves report's columns: strict detection, counts, matched leaves' shape and orientation."""


def leaf_rows(rows: list[tuple[str, str | Path, str]]):
    """One row per (configuration, case): ``rows`` lists (label, run folder, method); the run's values of
    :data:`LEAF_COLUMNS` for that method. Returns a DataFrame: config, species, case and one column per metric."""
    import pandas as pd

    from plantbench.report.gate import read_results

    out = []
    for label, run_dir, method in rows:
        table = read_results(run_dir)
        table = table[(table["method"] == method) & table["metric"].isin(list(LEAF_COLUMNS))]
        wide = table.pivot_table(index=["species", "case"], columns="metric", values="value", aggfunc="first")
        for (species, case), values in wide.iterrows():
            out.append({"config": label, "species": species, "case": case,
                        **{LEAF_COLUMNS[m]: values.get(m) for m in LEAF_COLUMNS}})
    return pd.DataFrame(out)


def depth_rows(run_dir: str | Path):
    """Per case of a run whose points jobs link the mvs stage's depth maps (``points/KEY/depth`` in the cache beside
    the run, ``OUT/cache`` for ``OUT/SUITE``; the keys from the run's ``timeline.csv``): the capture's leaf sizes
    (capture.json ``leaf_pixels``) and :func:`leaf_depth_accuracy` of the mvs depth. Only the run's own jobs count:
    a cache shared by runs of other mvs settings holds other depth maps of the same captures."""
    import json

    import pandas as pd

    run_dir = Path(run_dir)
    timeline = pd.read_csv(run_dir / "timeline.csv")
    out = []
    for key in timeline.key[timeline.kind == "points"]:
        folder = run_dir.parent / "cache" / "points" / key
        views, depth = folder / "views", folder / "depth"
        if not (views.is_dir() and depth.is_dir()):
            continue
        capture = views.resolve().parent
        doc = json.loads((capture / "views" / "capture.json").read_text())
        acc = leaf_depth_accuracy(capture, depth.resolve())
        px = doc.get("leaf_pixels") or {}
        out.append({"species": doc["plant"]["species"], "height_m": doc["plant"]["height"],
                    "leaf px (median)": px.get("median_px"), "leaves >= 200 px in 2 views":
                    f"{px.get('resolved_2_views')} / {px.get('leaves')}",
                    "leaf px with depth": acc["kept"], "within 1 % H": acc["within"],
                    "within 1 % H, of those with depth": acc["within_of_kept"]})
    return pd.DataFrame(out).drop_duplicates("species")
