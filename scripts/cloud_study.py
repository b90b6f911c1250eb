"""What the point cloud's quality does to the methods' structure: runs of one suite's plants that differ only in the
cloud (the mvs stage's options, the image size, the oracle cloud), side by side.

usage: python scripts/cloud_study.py OUT LABEL=RUN_DIR [LABEL=RUN_DIR ...]
       python scripts/cloud_study.py OUT            (the figure again from OUT.csv)

Writes OUT.csv (one row per run and method: means over the plants of skeleton lprecision@1%, vF1@1%, branch F1@1%,
S_T, and how many plants have a branch count within 0.5-2x the truth; beside them the run's cloud: points, median
and 90th-percentile distance to the ground-truth surface / height, wood recall at 1 % of the height over the branch
surface seen by >= 2 views, and the share of points within 1 % of the height plus the local radius of a true branch
axis) and OUT.png (lprecision against the plants within 0.5-2x, one line per method through the runs in the order
given; the oracle cloud, a run whose label says oracle, as a star). Each run's clouds are found through its timeline (the points job that follows each plant's jobs), so the
runs must be of suites with one seed per species.
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from plantbench.cameras import read_cameras
from plantbench.io.plantio import read_plant
from plantbench.io.ply import read_points
from plantbench.metrics.skeleton import skeleton_samples
from plantbench.metrics.surface import nearest_distances, point_to_mesh_distances, sample_surface
from plantbench.plant import TriMesh
from reference_impl.mvs.evaluate import visible_counts

METHODS = ("prior", "guo", "livny", "xu")
MEANS = {"lprecision": "skeleton.lprecision@1%", "vf1": "skeleton.vf1@1%", "branch_f1": "skeleton.branch_f1@1%",
         "S_T": "stava.S_T"}


def clouds(run: Path) -> dict[str, tuple[Path, Path]]:
    """species -> (capture folder, points.ply) of a run."""
    cells = json.loads((run / "cells.json").read_text())
    capture = {c["species"]: (run / c["capture"]).resolve() for c in cells}
    out, species = {}, None
    for row in list(csv.reader(open(run / "timeline.csv")))[1:]:
        if row[0] == "plant":
            species = row[2]
        elif row[0] == "points":
            if species in out:
                raise SystemExit(f"{run}: two clouds for {species}: one seed per species only")
            out[species] = (capture[species], (run / ".." / "cache" / "points" / row[3] / "points.ply").resolve())
    return out


def cloud_quality(case: Path, ply: Path) -> dict:
    pts, _ = read_points(ply)
    plant, meta = read_plant(case)
    height = float(meta.height)
    dist = point_to_mesh_distances(TriMesh.concatenate([plant.branch_mesh, plant.leaf_mesh]), pts)
    cams, names = read_cameras(case / "views" / "cameras.json")
    depths = [np.load(case / "views" / "depth" / f"{Path(n).stem}.npy") for n in names]
    wood, _ = sample_surface(plant.branch_mesh, 100_000, np.random.Generator(np.random.PCG64(0)))
    wood = wood[visible_counts(wood, cams, depths) >= 2]
    near, _ = nearest_distances(pts, wood)
    axis = skeleton_samples(plant.skeleton, 0.005)
    d, i = cKDTree(axis.points).query(pts)
    tau = 0.01 * height
    return {"points": len(pts), "accuracy_median_rel": float(np.median(dist)) / height,
            "accuracy_p90_rel": float(np.percentile(dist, 90)) / height, "wood_recall": float(np.mean(near < tau)),
            "near_axis": float(np.mean(d < tau + axis.radii[i]))}


def main() -> None:
    out = Path(sys.argv[1])
    runs = [tuple(a.split("=", 1)) for a in sys.argv[2:]]
    if not runs:
        plot(pd.read_csv(out.with_suffix(".csv")), out.with_suffix(".png"))
        return
    rows = []
    for label, folder in runs:
        run = Path(folder)
        res = pd.read_csv(run / "results.csv")
        res = res[res["status"] == "ok"]
        quality = pd.DataFrame([cloud_quality(*c) for c in clouds(run).values()]).mean()
        for method in METHODS:
            r = res[res["method"] == method]
            if r.empty:
                continue
            per = r.pivot_table(index="case", columns="metric", values="value", aggfunc="first")
            row = {"run": label, "method": method, "plants": len(per)}
            row.update({k: float(per[m].mean()) for k, m in MEANS.items()})
            row["count_within"] = int((per["skeleton.branch_count_log2_error"].abs() <= 1).sum())
            row.update(quality.to_dict())
            rows.append(row)
        print(label, "done", flush=True)
    table = pd.DataFrame(rows)
    table.to_csv(out.with_suffix(".csv"), index=False, float_format="%.4f")
    plot(table, out.with_suffix(".png"))
    print(table.round(3).to_string(index=False))


def plot(table: pd.DataFrame, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.8))
    oracle = table["run"].str.contains("oracle")
    for k, (method, g) in enumerate(table[table["method"] != "prior"].groupby("method", sort=False)):
        colour = f"C{k}"
        curve, exact = g[~oracle.loc[g.index]], g[oracle.loc[g.index]]
        ax.plot(curve["count_within"], curve["lprecision"], "-o", color=colour, label=method)
        ax.plot(exact["count_within"], exact["lprecision"], "*", color=colour, ms=12)
        for r in g.itertuples():
            ax.annotate(r.run, (r.count_within, r.lprecision), fontsize=6.5, color=colour,
                        textcoords="offset points", xytext=(5, -3 + 4 * (k - 1)))
    ax.axhline(0.45, color="grey", ls=":", lw=1)
    ax.axvline(6, color="grey", ls=":", lw=1)
    ax.set_xlabel("plants with a branch count within 0.5-2x the truth")
    ax.set_ylabel("skeleton lprecision@1% (mean)")
    ax.set_title("The cloud's precision against its completeness (issue 48's targets dotted)", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
