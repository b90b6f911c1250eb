"""What the gt-free support check says about a skeleton's fidelity: each cell of a scan suite with ground truth,
its share of skeleton length on the scan (``support.skeleton@spacing``, the check the real suite uses) against its
share within 1 % of the height of a true branch (``skeleton.lprecision@1%``), the truth's own skeleton included.

usage: python scripts/support_calibration.py RESULTS OUT_PNG [THRESHOLD]

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
STYLE = {"gt": ("black", "*"), "prior": ("0.6", "x"), "guo": ("tab:green", "o"), "livny": ("tab:blue", "s"),
         "xu": ("tab:red", "^")}


def main(results: str, out_png: str, threshold: float = 0.9) -> None:
    path = Path(results)
    table = pd.read_parquet(path) if path.suffix == ".parquet" else pd.read_csv(path)
    table = table[(table["status"] == "ok") & table["metric"].isin([SUPPORT, PRECISION])]
    wide = table.pivot_table(index=["sweep", "case", "method"], columns="metric", values="value").reset_index()
    levels = sorted(wide["sweep"].unique())
    fig, axes = plt.subplots(1, len(levels), figsize=(5.5 * len(levels), 4.8), sharey=True, squeeze=False)
    for ax, level in zip(axes[0], levels, strict=True):
        at = wide[wide["sweep"] == level]
        truth = at[at["method"] == "gt"].set_index("case")[SUPPORT]
        for method, grp in at.groupby("method"):
            colour, marker = STYLE.get(method, ("tab:purple", "D"))
            ax.scatter(grp[SUPPORT], grp[PRECISION], c=colour, marker=marker, s=60 if method == "gt" else 28,
                       label=method, alpha=0.85)
            above = int((grp.set_index("case")[SUPPORT] > truth.reindex(grp["case"]).to_numpy()).sum())
            print(f"{level} {method:6s} support {grp[SUPPORT].mean():.3f} lprecision {grp[PRECISION].mean():.3f} "
                  f"support above the truth's on {above} of {len(grp)}")
        ax.axvline(threshold, color="0.3", ls="--", lw=1)
        ax.set_title(f"beam spacing {float(level) * 100:g} cm")
        ax.set_xlabel("support.skeleton@spacing (no ground truth)")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("skeleton lprecision@1% (share near a true branch)")
    axes[0][-1].legend(loc="lower left")
    fig.suptitle("The gt-free support check against the truth: the truth's skeleton (stars) and each method's")
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)


if __name__ == "__main__":
    if len(sys.argv) not in (3, 4):
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2], float(sys.argv[3]) if len(sys.argv) == 4 else 0.9)
