"""What the gt-free checks say about a skeleton's fidelity: each cell of a scan suite with ground truth, its share
of skeleton length on the scan (``support.skeleton@spacing``, the check the real suite uses) against its share within
1 % of the height of a true branch (``skeleton.lprecision@1%``), the truth's own skeleton included; with
``--coverage``, the share of the scan within the tolerance of its surface (``support.coverage@spacing``) against its
volume-weighted recall of the true wood (``skeleton.vrecall@1%``), the completeness pair.

usage: python scripts/support_calibration.py RESULTS OUT_PNG [THRESHOLD] [--coverage]

RESULTS is a run's or report's results.parquet (or .csv) of a suite with a ``gt`` row (``scan-sparse``); THRESHOLD
(default 0.9) is drawn as the line a target would set. Prints, per sweep value and method, the mean support, the mean
length precision and on how many plants the method's support is above the truth's.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

SUPPORT, PRECISION = "support.skeleton@spacing", "skeleton.lprecision@1%"
COVERAGE, RECALL = "support.coverage@spacing", "skeleton.vrecall@1%"
STYLE = {"gt": ("black", "*"), "prior": ("0.6", "x"), "guo": ("tab:green", "o"), "livny": ("tab:blue", "s"),
         "xu": ("tab:red", "^")}


def main(results: str, out_png: str, threshold: float = 0.9, coverage: bool = False) -> None:
    x, y = (COVERAGE, RECALL) if coverage else (SUPPORT, PRECISION)
    path = Path(results)
    table = pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path)
    table = table[(table["status"] == "ok") & table["metric"].isin([x, y])]
    wide = table.pivot_table(index=["sweep", "case", "method"], columns="metric", values="value").reset_index()
    levels = sorted(wide["sweep"].unique())
    fig, axes = plt.subplots(1, len(levels), figsize=(5.5 * len(levels), 4.8), sharey=True, squeeze=False)
    for ax, level in zip(axes[0], levels, strict=True):
        at = wide[wide["sweep"] == level]
        truth = at[at["method"] == "gt"].set_index("case")[x]
        for method, grp in at.groupby("method"):
            colour, marker = STYLE.get(method, ("tab:purple", "D"))
            ax.scatter(grp[x], grp[y], c=colour, marker=marker, s=60 if method == "gt" else 28,
                       label=method, alpha=0.85)
            above = int((grp.set_index("case")[x] > truth.reindex(grp["case"]).to_numpy()).sum())
            print(f"{level} {method:6s} {x} {grp[x].mean():.3f} {y} {grp[y].mean():.3f} "
                  f"above the truth's on {above} of {len(grp)}; of the truth's: "
                  f"{(grp[x].to_numpy() / truth.reindex(grp['case']).to_numpy()).mean():.3f}")
        ax.axvline(threshold, color="0.3", ls="--", lw=1)
        ax.set_title(f"beam spacing {float(level) * 100:g} cm")
        ax.set_xlabel(f"{x} (no ground truth)")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel(f"{y} (against the truth)")
    axes[0][-1].legend(loc="lower left")
    fig.suptitle(f"The gt-free {x} against the truth: the truth's skeleton (stars) and each method's")
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--coverage"]
    if len(args) not in (2, 3):
        sys.exit(__doc__)
    main(args[0], args[1], float(args[2]) if len(args) == 3 else 0.9, coverage="--coverage" in sys.argv)
