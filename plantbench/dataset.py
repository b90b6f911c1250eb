"""Frozen datasets: a suite's cases (ground truth and captures) packed once with a sha256 manifest, and run from.

``plantbench dataset pack --suite NAME --out DIR`` writes::

    DIR/manifest.json     format, suite (name and full config), plantbench version and git SHA, code hashes of the
                          generator and the capture, Dr.Jit target, Mitsuba variant, licence, and per case its id,
                          species, family, seed and files; per file its sha256 and size
    DIR/DATASHEET.md      what is in it and how it was made
    DIR/cases/<case>/     plant/, views/, scan/ as in a case folder (docs/design.md, On-disk contracts)

``plantbench run --suite NAME --dataset DIR`` verifies every file against the manifest first (a missing, altered or
unlisted file is an :class:`InputError` naming it) and runs the methods on the frozen captures instead of generating
and capturing again; run.json records the manifest's sha256. Nothing is half-written: the pack is assembled in a
temporary folder beside ``DIR`` and renamed into place. The manifest itself (reading, verifying, hashing), which the runner needs, is
:mod:`plantbench.io.manifest`, below the runner; this module packs, which runs a suite, above it.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path

from plantbench.errors import InputError
from plantbench.io.atomic import atomic_write, write_json
from plantbench.io.manifest import (
    CASE_PARTS,
    DATASET_FORMAT,
    LICENCE,
    DatasetCase,
    Manifest,
    case_files,
    file_sha256,
    manifest_sha256,
    open_dataset,
    verify_dataset,
)

__all__ = ["DatasetCase", "Manifest", "pack_suite", "verify_dataset", "open_dataset", "file_sha256", "manifest_sha256",
           "DATASET_FORMAT", "LICENCE"]

def _datasheet(manifest: Manifest) -> str:
    cfg = manifest.suite_config
    cap = cfg.get("capture", {})
    species = sorted({c.species for c in manifest.cases})
    return f"""# Datasheet: plantbench suite `{manifest.suite}`

**What it is.** {len(manifest.cases)} synthetic plants ({", ".join(species)}) with exact ground truth and their
captures, as the plantbench suite `{manifest.suite}` defines them: {cfg.get("description", "")}.

**Per case** (`cases/<species>-<seed>/`, layout of docs/design.md): `plant/` the ground truth (skeleton with
radii, branch and leaf meshes, per-leaf parameters); `views/` {cap.get("views")} rendered views at
{cap.get("width")}x{cap.get("height")} px ({cap.get("spp")} spp, Mitsuba 3 `{manifest.mitsuba_variant}`) with exact
z-depth and instance maps (ground truth), cameras as OpenCV, COLMAP and transforms.json; `scan/` a simulated
terrestrial laser scan ({cap.get("stations")} station(s)) whose labels are ground truth.

**How it was made.** `plantbench dataset pack --suite {manifest.suite}` with plantbench {manifest.plantbench_version}
(git {manifest.git_sha}), generator code {manifest.code.get("generate")}, capture code {manifest.code.get("capture")},
Dr.Jit code generation `{manifest.llvm_target}`, on {manifest.created}. Every random draw is seeded from the suite's
root seed ({cfg.get("root_seed")}) and the case; the same code and target give the same bytes.

**Use.** `plantbench run --suite {manifest.suite} --dataset <this folder>` checks every file against `manifest.json`
(sha256) and runs the methods on these captures; the results record the manifest's sha256. A method may read only
what a real capture gives (images with cameras, the scan's coordinates); `plant/`, the exact depth and instance
maps and the scan's labels are for scoring.

**Licence.** {manifest.licence}. The plants are procedural (no third-party models or textures).

**Known limits.** Synthetic plants and renders: no wind, no real sensor model beyond the path tracer's noise and the
scan's range noise and dropout.
"""


def pack_suite(suite, out: str | os.PathLike, *, cache: str | os.PathLike = "runs/cache", workers: int = 1,
               force: bool = False, progress=None) -> Manifest:
    """Generate and capture every case of ``suite`` (through the run cache: finished cases are reused) and write
    the dataset folder ``out``; returns its manifest. ``out`` must not exist unless ``force``."""
    from plantbench import __version__
    from plantbench.backend import llvm_target_id, select_variant
    from plantbench.runner.execute import execute_plan
    from plantbench.runner.plan import Plan, code_hash, make_plan
    from plantbench.runner.run import git_sha
    from plantbench.runner.worker import job_folder

    out, cache = Path(out), Path(cache)
    if out.exists() and not force:
        raise InputError("already exists (pass --force to replace it)", path=out)
    # the suite's plan with one method gives one cell per case (its id, species, capture key); only the plant and
    # capture jobs run
    full = make_plan(suite, ["gt"])
    plan = Plan(suite, {k: j for k, j in full.jobs.items() if j.kind in ("plant", "capture")})
    records, _ = execute_plan(plan, cache, workers=workers, progress=progress)
    failed = [k for k, r in records.items() if r["status"] != "ok"]
    if failed:
        raise InputError(f"{len(failed)} plant/capture job(s) failed: {records[failed[0]].get('error')}",
                         path=job_folder(cache, plan.jobs[failed[0]].kind, failed[0]))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        cases, seen = [], set()
        for cell in full.cells:
            if cell.case in seen:
                continue
            seen.add(cell.case)
            src = job_folder(cache, "capture", cell.case_key)
            for part in CASE_PARTS:
                if (src / part).exists():
                    shutil.copytree(src / part, tmp / "cases" / cell.case / part, symlinks=False)
            cases.append(DatasetCase(id=cell.case, species=cell.species, family=cell.family, seed=cell.seed,
                                     capture_key=cell.case_key))
        files = {str(p.relative_to(tmp)): file_sha256(p) for p in case_files(tmp)}
        manifest = Manifest(
            suite=suite.name, suite_config=suite.model_dump(mode="json"), plantbench_version=__version__,
            git_sha=git_sha(), code={"generate": code_hash("plantbench/generate"),
                                      "capture": code_hash("plantbench/capture")},
            llvm_target=llvm_target_id(), mitsuba_variant=select_variant(),
            created=time.strftime("%Y-%m-%dT%H:%M:%S%z"), cases=cases, files=files,
            bytes=sum((tmp / f).stat().st_size for f in files))
        write_json(tmp / "manifest.json", manifest.model_dump(mode="json"))
        with atomic_write(tmp / "DATASHEET.md", "w") as fh:
            fh.write(_datasheet(manifest))
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return manifest
