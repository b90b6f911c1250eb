"""Tables and figure of reports/leaves from the three leaves runs (issue 23).

usage: python scripts/leaves_report.py RUNS_DIR OUT_DIR
RUNS_DIR holds the runs of the leaves, leaves_procedural and leaves_oracle suites made with the same --out (one
cache); writes OUT_DIR/leaves.csv (one row per configuration and plant), depth.csv (the mvs depth of the leaf
pixels, per plant), tables.md (the tables per species, the summary and the acceptance checks) and
figures/leaves.png.
"""

import sys
from pathlib import Path

import numpy as np

from plantbench.report.leaves import depth_rows, leaf_rows
from plantbench.report.report import leaf_figure

CONFIGS = [
    ("gt", "leaves", "gt"),
    ("prior (no data)", "leaves", "prior"),
    ("leaves, mvs depth", "leaves", "leaves"),
    ("leaves, exact depth (oracle)", "leaves_oracle", "leaves"),
    ("guo, image leaves (mvs depth)", "leaves", "guo"),
    ("guo, image leaves (exact depth, oracle)", "leaves_oracle", "guo"),
    ("guo, procedural leaves", "leaves_procedural", "guo"),
]


def fmt(v, digits=3) -> str:
    if v is None or (isinstance(v, float) and np.isnan(v)):
        return "-"
    return f"{v:.{digits}f}" if isinstance(v, float) and not float(v).is_integer() else f"{v:.0f}"


def markdown(df) -> str:
    head = "| " + " | ".join(df.columns) + " |\n|" + "---|" * len(df.columns) + "\n"
    return head + "".join("| " + " | ".join(fmt(v) if not isinstance(v, str) else v for v in row) + " |\n"
                          for row in df.itertuples(index=False))


def main() -> None:
    runs, out = Path(sys.argv[1]), Path(sys.argv[2])
    out.mkdir(parents=True, exist_ok=True)
    rows = leaf_rows([(label, runs / suite, method) for label, suite, method in CONFIGS if (runs / suite).is_dir()])
    rows.to_csv(out / "leaves.csv", index=False)
    depth = depth_rows(runs / "leaves")
    depth.to_csv(out / "depth.csv", index=False)
    parts = ["## mvs depth of the leaf pixels, per plant\n\n" + markdown(depth)]
    summary = rows.pivot_table(index="config", columns="species", values="F1", sort=False)
    parts.append("## Strict leaf F1 per species\n\n" + markdown(summary.reset_index()))
    for species, sub in rows.groupby("species", sort=False):
        parts.append(f"## {species}\n\n" + markdown(sub.drop(columns=["species", "case"])))
    f1 = rows.pivot_table(index="species", columns="config", values="F1")
    shape = rows.set_index(["config", "species"])["shape err."]
    mvs, prior = "leaves, mvs depth", "prior (no data)"
    checks = [
        f"- leaves (mvs depth) F1 >= 0.7 on {int((f1[mvs] >= 0.7).sum())} of {len(f1)} species (needed: 3)",
        f"- leaves (mvs depth) F1 - prior F1 >= 0.3 on {int((f1[mvs] - f1[prior] >= 0.3).sum())} of {len(f1)} "
        f"species (needed: all); smallest margin {(f1[mvs] - f1[prior]).min():.3f}",
        "- median shape error of matched leaves (mvs depth), per species: "
        + ", ".join(f"{s} {shape[(mvs, s)]:.3f}" for s in f1.index) + " (needed: <= 0.10)",
    ]
    if "guo, procedural leaves" in f1:
        diff = f1["guo, image leaves (mvs depth)"] - f1["guo, procedural leaves"]
        checks.append("- guo image leaves - guo procedural leaves, F1: " +
                      ", ".join(f"{s} {d:+.3f}" for s, d in diff.items()) + f" (mean {diff.mean():+.3f})")
    parts.append("## Acceptance checks\n\n" + "\n".join(checks) + "\n")
    (out / "tables.md").write_text("\n".join(parts))
    leaf_figure(runs / "leaves", out / "figures" / "leaves.png")
    print("\n".join(parts))


if __name__ == "__main__":
    main()
