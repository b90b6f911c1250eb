"""A method's input folder: only what a real capture gives (docs/design.md), in a fresh folder of its own.

The runner and ``plantbench reconstruct`` copy into a new temporary folder, outside the job cache, what the method's
``inputs`` allow:

- ``views``: ``views/images/``, ``views/cameras.json``, ``views/transforms.json``, ``views/colmap/`` with the
  cameras and images but no points (the capture's points3D.txt holds exact ground-truth surface samples, which no
  real capture has; a method that wants sparse points triangulates them) and ``views/capture.json`` without the
  ground-truth plant summary; never ``views/depth``, ``views/instance``, ``views/foliage`` or ``views/normal``
  (exact maps, ground truth);
- ``scan``: ``scan/scan.ply`` with x, y, z and station only (a real scanner gives no wood/leaf label or leaf id)
  and ``scan/stations.json``;
- ``points``: ``points.ply`` (coordinates), plus for a view capture the views as above and the mvs stage's own
  depth maps (``depth/``).

and the species hint as ``hint.json`` when the run gives one (:mod:`plantbench.hints`). Files are copied, not
linked, so no path inside the folder leads back to the cache or to ``plant/``. A method that declares itself an
oracle (``oracle = True``, or ``is_oracle(options)`` for one whose options make it one) gets the whole capture,
ground truth included (unless it declares ``reads_ground_truth = False``).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from plantbench.errors import InputError

__all__ = ["PERTURB_ENV", "InputPerturbation", "input_perturbation", "perturb_points", "prepare_inputs",
           "run_isolated", "is_oracle", "reads_ground_truth", "check_cloud", "read_input_points", "VIEW_ENTRIES",
           "GROUND_TRUTH"]

VIEW_ENTRIES = ("images", "cameras.json", "transforms.json")
"""What a method reading views gets of ``views/`` as it is (besides colmap/ and capture.json, filtered)."""

GROUND_TRUTH = ("plant", "views/depth", "views/instance", "views/foliage", "views/normal", "views/observed_wood.npz",
                "scan/observed_wood.npz")
"""Ground truth inside a capture: only oracles read it (and the scan's label, leaf_id columns)."""

_CAPTURE_GROUND_TRUTH_KEYS = ("plant", "scan", "leaf_pixels", "observed_wood_share")
"""Keys of views/capture.json that describe the ground truth (the plant's species, seed and height; the scan's
label counts; the leaves' pixel counts; the share of the wood the views observed): dropped from a method's copy."""


PERTURB_ENV = "PLANTBENCH_PERTURB_INPUT"
"""A perturbation of every points method's input cloud that carries no meaning, for the variability study:
``order:SEED`` (the points in another order) or ``jitter:AMPLITUDE:SEED`` (every coordinate moved by a uniform draw
in [-AMPLITUDE, AMPLITUDE] metres). Unset: the cloud as the point stage wrote it. Part of every method job's key."""


@dataclass(frozen=True)
class InputPerturbation:
    kind: str  # 'order' or 'jitter'
    seed: int
    amplitude: float = 0.0

    def spec(self) -> str:
        return f"order:{self.seed}" if self.kind == "order" else f"jitter:{self.amplitude:g}:{self.seed}"


def input_perturbation() -> InputPerturbation | None:
    """The perturbation :data:`PERTURB_ENV` asks for, or None; a malformed value is an InputError."""
    value = os.environ.get(PERTURB_ENV, "").strip()
    if not value:
        return None
    parts = value.split(":")
    try:
        if parts[0] == "order" and len(parts) == 2:
            return InputPerturbation("order", int(parts[1]))
        if parts[0] == "jitter" and len(parts) == 3 and float(parts[1]) > 0:
            return InputPerturbation("jitter", int(parts[2]), float(parts[1]))
    except ValueError:
        pass
    raise InputError(f"{PERTURB_ENV} must be 'order:SEED' or 'jitter:AMPLITUDE:SEED', got {value!r}")


def perturb_points(points: np.ndarray, perturbation: InputPerturbation | None, *keys,
                   columns: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """(points, columns) under ``perturbation`` (the same draw for the same seed and ``keys``); None: unchanged.
    ``columns`` (one value per point, e.g. the scan's station, or None) follow their points in a new order and are
    never jittered."""
    if perturbation is None:
        return points, columns
    from plantbench.seeding import rng

    gen = rng(perturbation.seed, "input-perturbation", perturbation.kind, *keys)
    if perturbation.kind == "order":
        order = gen.permutation(len(points))
        return points[order], (None if columns is None else np.asarray(columns)[order])
    return points + gen.uniform(-perturbation.amplitude, perturbation.amplitude, size=points.shape), columns


def is_oracle(method, options: dict | None = None) -> bool:
    """Whether ``method`` reads ground truth with these options: its ``is_oracle(options)`` when it has one; else
    whether one of the options named in its ``oracle_when`` mapping (option -> value) has that value (mvs with
    ``oracle_when = {"depth": "oracle"}``); else its ``oracle`` attribute (False when absent)."""
    options = dict(options or {})
    check = getattr(method, "is_oracle", None)
    if callable(check):
        return bool(check(options))
    when = getattr(method, "oracle_when", None) or {}
    return any(options.get(k) == v for k, v in when.items()) or bool(getattr(method, "oracle", False))


def reads_ground_truth(method, options: dict | None = None) -> bool:
    """Whether ``method``'s input folder holds the whole capture, ground truth included: an oracle, unless it
    declares ``reads_ground_truth = False`` (the no-data prior: an oracle of the generative model, not of the case)."""
    return is_oracle(method, options) and bool(getattr(method, "reads_ground_truth", True))


def _copy_views(src: Path, dest: Path) -> None:
    if not (src / "cameras.json").exists():
        raise InputError("no views/cameras.json: not a view capture", path=src)
    dest.mkdir(parents=True)
    for name in VIEW_ENTRIES:
        s = src / name
        if s.is_dir():
            shutil.copytree(s, dest / name)
        elif s.is_file():
            shutil.copyfile(s, dest / name)
    if (src / "colmap").is_dir():
        from plantbench.cameras import read_cameras
        from plantbench.capture.formats import write_colmap_text

        cameras, names = read_cameras(src / "cameras.json")
        write_colmap_text(dest / "colmap", cameras, names)  # the same cameras and images, no ground-truth points
    cap = src / "capture.json"
    if cap.is_file():
        try:
            doc = json.loads(cap.read_text())
        except ValueError as exc:
            raise InputError(f"malformed JSON ({exc})", path=cap) from None
        for key in _CAPTURE_GROUND_TRUTH_KEYS:
            doc.pop(key, None)
        (dest / "capture.json").write_text(json.dumps(doc, indent=1, sort_keys=True))


def _copy_scan(src: Path, dest: Path) -> None:
    from plantbench.io.ply import read_points, write_points

    ply = src / "scan.ply"
    if not ply.is_file():
        raise InputError("no scan/scan.ply: not a scan capture", path=src)
    pts, fields = read_points(ply)
    dest.mkdir(parents=True)
    pts, station = perturb_points(pts, input_perturbation(), "scan", columns=fields.get("station"))
    write_points(dest / "scan.ply", pts, None if station is None else {"station": station})
    if (src / "stations.json").is_file():
        shutil.copyfile(src / "stations.json", dest / "stations.json")


def prepare_inputs(dest: str | os.PathLike, capture_dir: str | os.PathLike, inputs: str, *,
                   points_dir: str | os.PathLike | None = None, hint=None, oracle: bool = False) -> Path:
    """Fill the new folder ``dest`` with what a method whose ``inputs`` are 'views', 'scan' or 'points' may read.

    Parameters
    ----------
    dest : folder to create (must not exist)
    capture_dir : the case (a capture: views/ and/or scan/, plant/ when it has ground truth)
    inputs : the method's ``inputs``
    points_dir : for 'points' methods, the point stage's folder (points.ply, and depth/ of the mvs stage); None:
        the coordinates of the capture's scan
    hint : a :class:`plantbench.hints.SpeciesHint` written as hint.json, or None
    oracle : give the whole capture, ground truth included (an oracle method)

    Returns
    -------
    ``dest``
    """
    dest, capture = Path(dest), Path(capture_dir)
    if inputs not in ("views", "scan", "points"):
        raise InputError(f"method inputs must be 'views', 'scan' or 'points', got {inputs!r}")
    dest.mkdir(parents=True)
    if oracle:
        for entry in sorted(capture.iterdir()):
            if entry.name in ("views", "scan", "plant"):
                shutil.copytree(entry, dest / entry.name)
    elif inputs == "views":
        _copy_views(capture / "views", dest / "views")
    elif inputs == "scan":
        _copy_scan(capture / "scan", dest / "scan")
    if inputs == "points":
        from plantbench.io.ply import read_points, write_points

        cloud = capture / "scan" / "scan.ply" if points_dir is None else Path(points_dir) / "points.ply"
        if not cloud.is_file():
            raise InputError("a points method needs a point cloud: the mvs stage's points.ply or the capture's scan",
                             path=cloud)
        pts, _ = read_points(cloud)  # coordinates only: the scan's labels are ground truth
        write_points(dest / "points.ply", perturb_points(pts, input_perturbation(), "points")[0])
        if not oracle and (capture / "views" / "cameras.json").exists():
            _copy_views(capture / "views", dest / "views")
        if points_dir is not None and (Path(points_dir) / "depth").is_dir():  # the mvs stage's own depth maps
            shutil.copytree(Path(points_dir) / "depth", dest / "depth")
    if hint is not None:
        from plantbench.hints import write_hint

        write_hint(dest, hint)
    return dest


def run_isolated(method, capture_dir: str | os.PathLike, out_dir: str | os.PathLike, *, seed: int,
                 species: str | None = None, options: dict | None = None,
                 points_dir: str | os.PathLike | None = None) -> None:
    """Run ``method`` on a fresh input folder (:func:`prepare_inputs`, with the published hint of ``species``) and
    a fresh output folder, both in a temporary folder outside the cache, then move its outputs into ``out_dir``
    (created; an entry of the same name is replaced). What the runner's method jobs and ``plantbench reconstruct``
    both do."""
    from plantbench.hints import load_hint

    options = dict(options or {})
    hint = load_hint(species) if species else None
    with tempfile.TemporaryDirectory(prefix="plantbench-job-") as tmp:
        inputs = prepare_inputs(Path(tmp) / "input", capture_dir, method.inputs, points_dir=points_dir, hint=hint,
                                oracle=reads_ground_truth(method, options))
        result = Path(tmp) / "output"
        result.mkdir()
        method.reconstruct(inputs, result, seed=seed, species=species, **options)
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        for item in sorted(result.iterdir()):
            target = out / item.name
            if target.is_dir():
                shutil.rmtree(target)
            shutil.move(str(item), str(target))


def check_cloud(points, *, min_points: int, what: str = "points", method: str = "a points method",
                why: str = "") -> np.ndarray:
    """Validate a points method's cloud: (n, 3), finite, at least ``min_points`` points, not all coincident;
    returns float64. Too few points: 'WHAT: n points; METHOD needs at least MIN (WHY)'."""
    from plantbench.plant import check_shape

    pts = check_shape(what, points, (-1, 3), "f")
    if len(pts) < min_points:
        raise InputError(f"{what}: {len(pts)} points; {method} needs at least {min_points}" + (f" ({why})" if why
                                                                                            else ""))
    if np.ptp(pts, axis=0).max() <= 0:
        raise InputError(f"{what}: all points coincide")
    return pts


def read_input_points(folder: str | os.PathLike, *, min_points: int, method: str = "a points method",
                      why: str = "") -> np.ndarray:
    """The coordinates of a points method's input, ``folder/points.ply`` (extra columns ignored), checked by
    :func:`check_cloud`; every error names the file. For reference and third-party methods alike."""
    from plantbench.io.ply import read_points

    path = Path(folder) / "points.ply"
    if not path.is_file():
        raise InputError(f"no points.ply ({method} reads the scan or the mvs cloud)", path=path)
    pts, _ = read_points(path)
    try:
        return check_cloud(pts, min_points=min_points, method=method, why=why)
    except InputError as exc:
        raise InputError(str(exc), path=path) from None
