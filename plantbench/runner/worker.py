"""Body of one job, run in its own process: ``python -m plantbench.runner.worker CACHE KIND KEY FOLDER PARAMS``.

The worker writes its outputs and a ``status.json`` into FOLDER (a temporary folder the parent renames into the
cache when the process ends). An exception becomes ``status: failed`` (or ``invalid`` for a method whose output
breaks the contract) with the traceback in the job log; a process that dies or runs past its timeout is recorded
by the parent.
"""

from __future__ import annotations

import json
import os
import sys
import time
import traceback
from pathlib import Path

from plantbench.io.atomic import write_json

__all__ = ["run_job", "job_folder"]


def job_folder(cache: Path, kind: str, key: str) -> Path:
    return Path(cache) / kind / key


def _link(target: Path, link: Path) -> None:
    """Relative symlink ``link`` -> ``target``."""
    link.symlink_to(os.path.relpath(target, link.parent), target_is_directory=target.is_dir())


class InvalidOutput(Exception):
    """A method returned but its output folder breaks the contract."""


MIN_SKELETON_NODES = 10
"""A skeleton with fewer nodes is degenerate (no plant is drawn with fewer)."""
MIN_HEIGHT_SHARE = 0.5
"""A skeleton spanning less than this share of its input cloud's height is degenerate: the method lost the tree."""


def _validate_reconstruction(folder: Path, cloud: Path | None = None) -> None:
    """The output contract (readable files, no empty skeleton, cloud or mesh), and, when ``cloud`` (the method's
    input points.ply) is given, a skeleton that is not degenerate: at least :data:`MIN_SKELETON_NODES` nodes and a
    vertical extent of at least :data:`MIN_HEIGHT_SHARE` of the cloud's height. A degenerate skeleton is an invalid
    output, a failed cell with its reason, not a score."""
    from plantbench.io.plantio import read_reconstruction

    try:
        rec = read_reconstruction(folder)
    except Exception as exc:  # noqa: BLE001 - any reading problem is an invalid output
        raise InvalidOutput(str(exc)) from None
    if rec.skeleton is not None and len(rec.skeleton) == 0:
        raise InvalidOutput("skeleton.ply has no vertices")
    if rec.skeleton is None and len(rec.points) == 0:
        raise InvalidOutput("points.ply has no points")
    if rec.mesh is not None and len(rec.mesh.faces) == 0:
        raise InvalidOutput("mesh.ply has no faces")
    if rec.skeleton is not None and cloud is not None and cloud.is_file():
        from plantbench.geometry.clouds import cloud_height
        from plantbench.io.ply import read_points

        sk = rec.skeleton
        height = cloud_height(read_points(cloud)[0])
        extent = float(sk.positions[:, 2].max() - sk.positions[:, 2].min())
        if len(sk) < MIN_SKELETON_NODES or extent < MIN_HEIGHT_SHARE * height:
            raise InvalidOutput(f"degenerate skeleton: {len(sk)} nodes spanning {extent:.2f} m of the input cloud's "
                                f"{height:.2f} m (a skeleton needs >= {MIN_SKELETON_NODES} nodes and "
                                f">= {MIN_HEIGHT_SHARE:g} of the height)")


def run_job(cache: Path, kind: str, key: str, folder: Path, params: dict) -> dict:
    """Execute one job into ``folder``; return the status record (also written to folder/status.json)."""
    cache, folder = Path(cache), Path(folder)
    t0 = time.perf_counter()
    status, error = "ok", None
    try:
        if kind == "plant":
            from plantbench.generate import generate_case

            generate_case(params["species"], params["seed"], folder, scale=params["scale"])
        elif kind == "capture" and ("dataset" in params or "folder" in params):
            _copy_case(folder, params)
        elif kind == "capture" and "scan" in params:
            from plantbench.capture.importers import import_scan

            imported = import_scan(params["scan"], folder / "imported", units=params["units"], up=params["up"]).case
            for part in ("scan", "case.json"):  # (the job folder already holds its log)
                (imported / part).rename(folder / part)
            imported.rmdir()
        elif kind == "capture":
            from plantbench.capture import capture_case

            _link(job_folder(cache, "plant", params["plant"]) / "plant", folder / "plant")
            capture_case(folder, params["settings"], seed=params["seed"])
        elif kind == "points":
            _points(cache, folder, params)
        elif kind == "method":
            _method(cache, folder, params)
            _validate_reconstruction(folder, job_folder(cache, "points", params["points"]) / "points.ply"
                                     if params.get("points") else None)
        elif kind == "metrics":
            from plantbench.metrics.evaluate import evaluate

            results = evaluate(job_folder(cache, "capture", params["case"]), job_folder(cache, "method", params["recon"]),
                               observed_from=params.get("observed_from"))
            write_json(folder / "metrics.json", results)
        else:
            raise ValueError(f"unknown job kind {kind!r}")
    except InvalidOutput as exc:
        status, error = "invalid", f"invalid output: {exc}"
    except Exception as exc:  # noqa: BLE001 - a crashing stage becomes a failed job, never a lost run
        traceback.print_exc()
        status, error = "failed", f"{type(exc).__name__}: {exc}"
    record = {"status": status, "error": error, "seconds": time.perf_counter() - t0, "kind": kind, "key": key}
    write_json(folder / "status.json", record)
    return record


def _copy_case(folder: Path, params: dict) -> None:
    """A capture that is a copy: a frozen dataset's case (verified before the run) or a suite's case folder (a real
    capture: hashed when the run was planned)."""
    import shutil

    if "dataset" in params:
        src, parts = Path(params["dataset"]) / "cases" / params["case"], ("plant", "views", "scan")
    else:
        src, parts = Path(params["folder"]), params["parts"]
    for part in parts:
        if (src / part).is_dir():
            shutil.copytree(src / part, folder / part)
        elif (src / part).is_file():
            shutil.copyfile(src / part, folder / part)


def _method(cache: Path, folder: Path, params: dict) -> None:
    """Run a method on an input folder that holds only what its ``inputs`` allow, outside the cache
    (:func:`plantbench.methods.inputs.run_isolated`); its outputs end in ``folder``."""
    from plantbench.methods.api import method_from_spec
    from plantbench.methods.inputs import run_isolated

    points = job_folder(cache, "points", params["points"]) if params["points"] else None
    run_isolated(method_from_spec(params["method"]), job_folder(cache, "capture", params["case"]), folder,
                 seed=params["seed"], species=params["species"], options=params["options"], points_dir=points)


def _points(cache: Path, folder: Path, params: dict) -> None:
    """Input folder of a 'points' method: points.ply (coordinates only) and, for view captures, views/ (and depth/
    when the mvs stage wrote its depth maps)."""
    import shutil

    from plantbench.io.ply import read_points, write_points

    case = job_folder(cache, "capture", params["case"])
    if params["source"] == "scan":
        pts, _ = read_points(case / "scan" / "scan.ply")  # labels are ground truth: not passed on
        write_points(folder / "points.ply", pts)
    else:
        src = job_folder(cache, "method", params["recon"]) / "points.ply"
        if not src.exists():
            raise FileNotFoundError(f"the mvs stage wrote no points.ply ({src})")
        shutil.copyfile(src, folder / "points.ply")
        _link(case / "views", folder / "views")
        if (src.parent / "depth").is_dir():  # the mvs stage's depth maps (write_depth), for leaf segmentation
            _link(src.parent / "depth", folder / "depth")


def main(argv: list[str]) -> int:
    cache, kind, key, folder, params = argv
    record = run_job(Path(cache), kind, key, Path(folder), json.loads(params))
    return 0 if record["status"] == "ok" else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
