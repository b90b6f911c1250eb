"""Acceptance measurements of the mvs stage (issue 6) on real captures.

usage: python scripts/mvs_acceptance.py CASE_DIR OUT_DIR [key=value ...]
Runs the mvs method on CASE_DIR (options as key=value, e.g. poses=sfm), then prints one JSON line with accuracy
(median distance to the ground-truth surface / plant height), completeness (GT surface samples visible in >= 2 views
with a cloud point within 1 % of plant height), SfM registration and timings.
"""

import ast
import json
import sys
import time
from pathlib import Path

from plantbench.io.ply import read_points
from reference_impl.mvs import MVS
from reference_impl.mvs.evaluate import evaluate_cloud


def main() -> None:
    case, out = Path(sys.argv[1]), Path(sys.argv[2])
    options = {}
    for kv in sys.argv[3:]:
        k, v = kv.split("=", 1)
        try:
            options[k] = ast.literal_eval(v)
        except (ValueError, SyntaxError):
            options[k] = v
    t0 = time.perf_counter()
    cpu0 = time.process_time()
    MVS().reconstruct(case, out, seed=0, **options)
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    pts, _ = read_points(out / "points.ply")
    stats = json.loads((out / "mvs.json").read_text())
    row = {"case": case.name, "options": options, "wall_s": wall, "cpu_s": cpu, **evaluate_cloud(case, pts)}
    row["sfm"] = stats.get("sfm")
    row["timings"] = stats["timings"]
    print(json.dumps(row))


if __name__ == "__main__":
    main()
