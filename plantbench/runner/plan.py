"""Expand a suite into content-addressed jobs: plant -> capture -> (points) -> reconstruction -> metrics.

Every job's key is a SHA-256 over what determines its output: its parameters, the keys of the jobs it reads, and
a hash of the source code of the stage that computes it. A finished job's folder is reused by any run whose plan
contains the same key, so a re-run, a resumed run or another suite sharing a plant recomputes nothing finished,
and editing a stage's code invalidates exactly the stages downstream of it.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import importlib.util
import inspect
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from plantbench.methods.api import ORACLE_CLOUD, ExternalCommand, method_from_spec, split_cloud
from plantbench.paths import project_root
from plantbench.seeding import derive_seed
from plantbench.suites import Suite, apply_override

__all__ = ["Job", "Cell", "Plan", "make_plan", "content_hash", "code_hash", "TYPICAL_SECONDS"]


def content_hash(obj: Any) -> str:
    """SHA-256 (24 hex digits) of the canonical JSON of ``obj``."""
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


@functools.cache
def code_hash(*paths: str) -> str:
    """Hash of the Python sources under ``paths`` (files or folders, relative to the project root or absolute) and
    of every module of the same packages or of plantbench that they import, directly or not, so that editing a
    shared helper invalidates every stage that uses it. Stage code (methods, and plantbench's generate, capture and
    metrics packages) is followed into its function-level imports too, where it imports lazily; plantbench's
    framework modules (registry, species, runner, I/O) only into their module-level ones: their lazy imports are
    hooks such as the metric registry's loader, which would tie every stage to the metrics code."""
    roots = [Path(p) if Path(p).is_absolute() else project_root() / p for p in paths]
    start = [f for r in roots for f in (sorted(r.rglob("*.py")) if r.is_dir() else [r] if r.exists() else [])]
    follow = {"plantbench"} | {_module_name(f).split(".")[0] for f in start}
    h = hashlib.sha256()
    for f in sorted(_import_closure(tuple(start), frozenset(follow)), key=_module_name):
        h.update(_module_name(f).encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def _module_name(file: Path) -> str:
    """Dotted module name of a source file, from the chain of packages (folders with __init__.py) holding it."""
    parts = [] if file.name == "__init__.py" else [file.stem]
    folder = file.parent
    while (folder / "__init__.py").exists():
        parts.insert(0, folder.name)
        folder = folder.parent
    return ".".join(parts)


def _module_file(name: str) -> Path | None:
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, AttributeError, ValueError):
        return None
    return Path(spec.origin) if spec is not None and spec.origin and spec.origin.endswith(".py") else None


STAGE_PACKAGES = ("plantbench.generate", "plantbench.geometry", "plantbench.capture", "plantbench.metrics")
"""plantbench packages that are stage code: :func:`code_hash` follows their function-level imports."""


def _module_level(tree: ast.Module):
    """The nodes of a module outside its function and class bodies."""
    for node in tree.body:
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            yield from ast.walk(node)


def _imported_names(file: Path) -> set[str]:
    """Modules a source file imports (absolute names; ``from a import b`` also yields ``a.b``, which may be a
    submodule): all of them in stage code, the module-level ones in plantbench's framework modules."""
    module = _module_name(file)
    package = module if file.name == "__init__.py" else module.rpartition(".")[0]
    tree = ast.parse(file.read_bytes(), filename=str(file))
    stage = module.split(".")[0] != "plantbench" or module.startswith(STAGE_PACKAGES)
    names: set[str] = set()
    for node in ast.walk(tree) if stage else _module_level(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([node.module] if node.module else []))
            names.add(base)
            names.update(f"{base}.{a.name}" for a in node.names)
    return names


def _import_closure(start: tuple[Path, ...], follow: frozenset[str]) -> set[Path]:
    """The files in ``start`` and every module of the ``follow`` packages they import, transitively (each package's
    __init__.py on the way included, as Python runs it)."""
    seen: set[Path] = set()
    todo = [f.resolve() for f in start]
    while todo:
        f = todo.pop()
        if f in seen:
            continue
        seen.add(f)
        for name in _imported_names(f):
            parts = name.split(".")
            if parts[0] not in follow:
                continue
            for i in range(1, len(parts) + 1):  # importing a.b.c runs a/__init__.py and a/b/__init__.py too
                dep = _module_file(".".join(parts[:i]))
                if dep is not None and dep.resolve() not in seen:
                    todo.append(dep.resolve())
    return seen


def _method_code_hash(method: Any) -> str:
    if isinstance(method, ExternalCommand):
        return content_hash(method.argv)
    module = inspect.getmodule(type(method))
    src = Path(inspect.getfile(module)) if module else None
    if src is None:
        return "unknown"
    # the method's whole package and everything it imports from its own project and from plantbench
    root = src.parent if src.name == "__init__.py" else src
    return code_hash(str(root.parent if root.is_file() and (root.parent / "__init__.py").exists() else root))


LEAVE_DEFAULT = "default"
"""A sweep's linked value that leaves its setting alone at that level (the suite's own value, else the default):
a level added for one setting keeps the other levels' settings, and so their cache keys, as they were. Applied here
rather than in :mod:`plantbench.suites`, whose code is part of every capture's key."""

TYPICAL_SECONDS = {"plant": 5.0, "capture": 15.0, "points": 1.0, "metrics": 20.0, "method": 10.0,
                   "mvs": 60.0, "leaves": 60.0, "guo": 30.0, "gt": 1.0}
"""Rough seconds of a job per kind (and per shipped method) on a quick-suite case: scheduling priorities only."""


@dataclass(frozen=True)
class Job:
    """One unit of work, run in its own process.

    kind : 'plant' | 'capture' | 'points' | 'method' | 'metrics'
    key : content hash; the job's folder is ``cache/<kind>/<key>``
    params : what the worker needs (JSON-serialisable)
    deps : keys of jobs that must be finished first
    """

    kind: str
    key: str
    params: dict
    deps: tuple[str, ...] = ()
    timeout_s: float | None = None


@dataclass(frozen=True)
class Cell:
    """One (case, method) cell of the results table."""

    case: str
    species: str
    family: str
    seed: int
    method: str
    sweep_value: Any
    recon_key: str
    metrics_key: str
    case_key: str


@dataclass
class Plan:
    suite: Suite
    jobs: dict[str, Job] = field(default_factory=dict)
    cells: list[Cell] = field(default_factory=list)

    def add(self, job: Job) -> str:
        self.jobs.setdefault(job.key, job)
        return job.key

    def children(self) -> dict[str, list[str]]:
        """Job key -> keys of the jobs that read its output."""
        out: dict[str, list[str]] = {k: [] for k in self.jobs}
        for k, job in self.jobs.items():
            for d in job.deps:
                out[d].append(k)
        return out

    def priorities(self) -> dict[str, float]:
        """Job key -> estimated seconds on the longest chain from the job to the end of the run (the job
        included): the list-scheduling priority (a job on the critical path starts first). The estimates are
        :data:`TYPICAL_SECONDS`; only their ratios matter."""
        children = self.children()
        level: dict[str, float] = {}
        for k in reversed(list(self.jobs)):  # jobs are added after their dependencies: a topological order
            job = self.jobs[k]
            cost = TYPICAL_SECONDS.get(job.params.get("method", job.kind), TYPICAL_SECONDS[job.kind])
            level[k] = cost + max((level[c] for c in children[k]), default=0.0)
        return level


def make_plan(suite: Suite, methods: list[str] | None = None, *, dataset: tuple[Path, Any] | None = None) -> Plan:
    """Expand ``suite`` (and its sweep) into jobs and cells. Unknown species or methods raise before any work.

    ``dataset`` (folder, :class:`plantbench.dataset.Manifest`, verified): each case's capture is the dataset's copy
    (a job that copies it into the cache, keyed by the files' sha256) instead of a generated and rendered one.
    A case folder of the suite (``path``) is copied into the cache the same way, keyed by its files' sha256."""
    from plantbench.backend import dispatch_id, llvm_target_id
    from plantbench.errors import InputError

    method_names = methods or suite.methods
    resolved = {name: _resolve(name, suite) for name in method_names}
    variants = [(None, suite)]
    if suite.sweep is not None:
        variants = [(v, apply_override(suite, {k: x for k, x in level.items() if x != LEAVE_DEFAULT}))
                    for v, level in suite.sweep.levels()]
    plan = Plan(suite)
    version_code = {
        "plant": code_hash("plantbench/generate"),
        "capture": code_hash("plantbench/capture"),
        "metrics": code_hash("plantbench/metrics"),
        # the worker and what prepares a method's input folder (it imports them lazily)
        "runner": code_hash("plantbench/runner/worker.py", "plantbench/methods/inputs.py", "plantbench/hints.py"),
        # Dr.Jit's code generation changes renders and mvs depth: part of every key downstream of the capture
        "llvm": llvm_target_id(),
        # OpenBLAS's and numpy's kernels change plants, cameras and everything after (backend.pin_dispatch)
        "dispatch": dispatch_id(),
        # the variability study's perturbation of a points method's input cloud (methods.inputs.PERTURB_ENV)
        "inputs": _input_perturbation_spec(),
    }
    seen: set[str] = set()
    for sweep_value, s in variants:
        for case_set in s.cases:
            if case_set.path is not None:
                cases = [_folder_case(plan, s, case_set, sweep_value, version_code)]
            elif case_set.scan is not None:
                cases = [_scan_case(plan, s, case_set, sweep_value)]
            else:
                cases = _generated_cases(plan, s, case_set, sweep_value, version_code, dataset)
            for case in cases:
                if case.id in seen:
                    raise InputError(f"suite {s.name}: two cases named {case.id!r} (case folders are named by their "
                                     "folder's name: rename one)")
                seen.add(case.id)
                _method_jobs(plan, s, resolved, case, sweep_value, version_code)
    return plan


def _input_perturbation_spec() -> str:
    from plantbench.methods.inputs import input_perturbation

    p = input_perturbation()
    return "" if p is None else p.spec()


def method_options(suite: Suite, name: str) -> dict:
    """The suite's ``[method_options]`` of a method entry: its own, or for ``NAME@oracle`` those of NAME."""
    return suite.method_options.get(name, suite.method_options.get(split_cloud(name)[0], {}))


def _resolve(name: str, suite: Suite):
    """The method of a suite's method entry; ``NAME@oracle`` only for a point-cloud method of a views suite."""
    from plantbench.errors import InputError

    spec, oracle_cloud = split_cloud(name)
    method = method_from_spec(spec)
    if oracle_cloud and (method.inputs != "points" or suite.source == "scan"):
        why = (f"{spec} reads {method.inputs}, not a point cloud" if method.inputs != "points"
               else f"suite {suite.name} reconstructs from the scan")
        raise InputError(f"method {name!r}: {ORACLE_CLOUD} runs a point-cloud method on the mvs stage's oracle "
                         f"cloud; {why}")
    return method


@dataclass(frozen=True)
class _Case:
    """A case of the plan, its capture job added: what its method and metrics jobs and its cells need."""

    id: str
    species: str  # the results table's species column
    family: str
    seed: int
    key: str  # the capture job
    hint_species: str | None  # the species hint the methods receive
    hint: str | None  # sha256 of the hint file


def _generated_cases(plan: Plan, s: Suite, case_set, sweep_value, version_code: dict, dataset):
    """The generated (or frozen-dataset) cases of one species: adds their plant and capture jobs as it yields."""
    from plantbench.species import load_species, species

    spec = load_species(case_set.species)
    species_bytes = species.get(case_set.species).read_bytes()
    hint = _hint_hash(case_set.species)
    for seed in case_set.seeds:
        case_id = f"{case_set.species}-{seed}" + (f"@{sweep_value}" if sweep_value is not None else "")
        if dataset is not None:
            case_key = plan.add(_dataset_job(dataset, case_id, s, version_code))
        else:
            plant_key = plan.add(Job("plant", content_hash(
                ["plant", case_set.species, hashlib.sha256(species_bytes).hexdigest(), seed, case_set.scale,
                 version_code["plant"], version_code["dispatch"]]), {"species": case_set.species, "seed": seed, "scale": case_set.scale},
                timeout_s=s.timeout_s))
            capture = s.capture.model_dump(mode="json")
            # each case its own capture stream (textures, render and scan noise), the same in every suite that
            # captures this plant with these settings (so their caches share it)
            capture_seed = derive_seed(s.root_seed, "capture", case_set.species, seed)
            case_key = plan.add(Job("capture", content_hash(
                ["capture", plant_key, capture, s.root_seed, capture_seed, version_code["capture"],
                 version_code["llvm"], version_code["dispatch"]]),
                {"plant": plant_key, "settings": capture, "seed": capture_seed, "root_seed": s.root_seed},
                deps=(plant_key,), timeout_s=s.timeout_s))
        yield _Case(case_id, case_set.species, spec.family, seed, case_key, case_set.species, hint)


def _dataset_job(dataset: tuple[Path, Any], case_id: str, s: Suite, version_code: dict) -> Job:
    """The capture job of a case of a frozen dataset: copies ``cases/<case_id>/`` into the cache."""
    from plantbench.errors import InputError

    folder, manifest = dataset
    prefix = f"cases/{case_id}/"
    files = {rel: digest for rel, digest in manifest.files.items() if rel.startswith(prefix)}
    if not files:
        raise InputError(f"case {case_id} of suite {s.name} is not in the dataset", path=Path(folder) / "manifest.json")
    return Job("capture", content_hash(["dataset", files, version_code["runner"]]),
               {"dataset": str(Path(folder).resolve()), "case": case_id}, timeout_s=s.timeout_s)


CASE_PARTS = ("plant", "views", "scan", "case.json")
"""What a case folder's capture job copies into the cache (those present)."""
REAL_FAMILY = "real"
"""The family column of a case folder's cells (a real capture: no generator family)."""


def _folder_case(plan: Plan, s: Suite, case_set, sweep_value, version_code: dict) -> _Case:
    """A suite's case folder (``path``): a capture job that copies it into the cache, keyed by the sha256 of its
    files, so that editing one re-runs everything downstream. Case id: the folder's name; seed 0; species: the
    hint's, or 'unknown' without one."""
    from plantbench.io.manifest import file_sha256

    folder = Path(case_set.path)
    case_id = folder.name + (f"@{sweep_value}" if sweep_value is not None else "")
    files = {}
    for part in CASE_PARTS:
        if (folder / part).is_file():
            files[part] = file_sha256(folder / part)
        for root, _, names in os.walk(folder / part, followlinks=True):
            for name in names:
                path = Path(root) / name
                files[path.relative_to(folder).as_posix()] = file_sha256(path)
    key = plan.add(Job("capture", content_hash(["folder", files, version_code["runner"]]),
                       {"folder": str(folder), "parts": list(CASE_PARTS)}, timeout_s=s.timeout_s))
    hint = _hint_hash(case_set.species) if case_set.species else None
    return _Case(case_id, case_set.species or "unknown", REAL_FAMILY, 0, key, case_set.species, hint)


def scan_case_id(scan: str | os.PathLike) -> str:
    """The case id of a scan file: its name without its suffixes (``tree1`` for ``tree1.xyz.gz``)."""
    return Path(scan).name.split(".")[0]


def _scan_case(plan: Plan, s: Suite, case_set, sweep_value) -> _Case:
    """A suite's scan file (``scan``): a capture job that imports it (``plantbench import scan``, with the case's
    units and up axis), keyed by the file's sha256, the options and the importer's code. Case id: the file's name
    without its suffixes; seed 0; species: the hint's, or 'unknown' without one."""
    from plantbench.io.manifest import file_sha256

    case_id = scan_case_id(case_set.scan) + (f"@{sweep_value}" if sweep_value is not None else "")
    key = plan.add(Job("capture", content_hash(
        ["scan", file_sha256(Path(case_set.scan)), case_set.units, case_set.up,
         code_hash("plantbench/capture/importers.py")]),
        {"scan": case_set.scan, "units": case_set.units, "up": case_set.up}, timeout_s=s.timeout_s))
    hint = _hint_hash(case_set.species) if case_set.species else None
    return _Case(case_id, case_set.species or "unknown", REAL_FAMILY, 0, key, case_set.species, hint)


def _method_jobs(plan: Plan, s: Suite, resolved: dict, case: _Case, sweep_value, version_code: dict) -> None:
    """Each method's job on ``case`` (after the shared points job its 'points' methods read), its metrics job and
    its cell."""
    points_keys: dict[bool, str] = {}  # oracle cloud? -> its points job
    for name, method in resolved.items():
        spec, oracle_cloud = split_cloud(name)
        deps = [case.key]
        points_key = None
        if method.inputs == "points":
            if oracle_cloud not in points_keys:
                points_keys[oracle_cloud] = _points_job(plan, s, case.key, case.seed, case.hint_species, version_code,
                                                        case.hint, oracle_cloud=oracle_cloud)
            points_key = points_keys[oracle_cloud]
            deps.append(points_key)
        options = method_options(s, name)
        # keyed by the method spec: 'livny@oracle' here and 'livny' of a suite whose mvs stage is the oracle share it
        recon_key = plan.add(Job("method", content_hash(
            ["method", spec, _method_code_hash(method), deps, options, case.seed, case.hint_species, case.hint,
             version_code["runner"], version_code["llvm"], version_code["dispatch"], version_code["inputs"]]),
            {"method": spec, "case": case.key, "points": points_key,
             "seed": case.seed, "species": case.hint_species, "options": options},
            deps=tuple(deps), timeout_s=s.timeout_s))
        # the wood the method's capture observed: a scan suite's points methods (and its oracles) read the scan
        observed_from = "scan" if method.inputs == "scan" or s.source == "scan" else None  # (None: views, else scan)
        metrics_key = plan.add(Job("metrics", content_hash(
            ["metrics", recon_key, version_code["metrics"], observed_from]),
            {"case": case.key, "recon": recon_key, "observed_from": observed_from}, deps=(recon_key,),
            timeout_s=s.timeout_s))
        plan.cells.append(Cell(case.id, case.species, case.family, case.seed, name, sweep_value,
                               recon_key, metrics_key, case.key))


def _hint_hash(species: str) -> str:
    """sha256 of the species' published hint (scenes/hints; validated: a species without one is an error here)."""
    from plantbench.hints import hints, load_hint

    load_hint(species)
    return hashlib.sha256(hints.get(species).read_bytes()).hexdigest()[:16]


def _points_job(plan: Plan, s: Suite, case_key: str, seed: int, species: str, version_code: dict, hint: str,
                *, oracle_cloud: bool = False) -> str:
    """The point cloud that 'points' methods reconstruct from: the mvs cloud of the views, or the scan;
    ``oracle_cloud``: the mvs stage's oracle cloud (its options with ``depth = "oracle"``)."""
    if s.source == "scan":
        return plan.add(Job("points", content_hash(["points", "scan", case_key, version_code["runner"]]),
                            {"source": "scan", "case": case_key}, deps=(case_key,), timeout_s=s.timeout_s))
    mvs = method_from_spec("mvs")
    options = s.method_options.get("mvs", {})
    if oracle_cloud:
        options = {**options, "depth": "oracle"}
    recon = plan.add(Job("method", content_hash(
        ["method", "mvs", _method_code_hash(mvs), [case_key], options, seed, species, hint, version_code["runner"],
         version_code["llvm"], version_code["dispatch"]]),
        {"method": "mvs", "case": case_key, "points": None, "seed": seed, "species": species, "options": options},
        deps=(case_key,), timeout_s=s.timeout_s))
    return plan.add(Job("points", content_hash(["points", "views", recon, version_code["runner"]]),
                        {"source": "views", "case": case_key, "recon": recon}, deps=(case_key, recon),
                        timeout_s=s.timeout_s))
