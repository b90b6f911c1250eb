"""``plantbench evaluate``: score a method's output folder against a case folder (docs/design.md, On-disk contracts).

:func:`evaluate` reads the files, calls the pure metric functions and returns one flat dict, metric name -> value,
with every registered metric present (see :data:`plantbench.metrics.info.METRICS`). A metric that cannot apply is
None, never NaN; :func:`evaluate_detailed` also returns why:

* no ``plant/`` folder (a real capture): Stava, mesh_to_surface, points, surface and leaf metrics, and the skeleton
  metrics that compare with the ground truth (P/R/F1, ``skeleton.*_error*``); the reconstruction's own traits
  (``skeleton.height_m``, ``branch_count``, ``total_length_m``, ``mean_branch_length_m``, ``dbh_cm``,
  ``crown_area_m2``) are still reported, as are ``mesh_to_scan``, ``reprojection`` and ``support``;
* no ``mesh.ply`` in the output: mesh_to_scan, mesh_to_surface, reprojection, surface;
* no ``scan/scan.ply`` and no ``plant/``: mesh_to_scan (with ``plant/`` but no scan the ground truth is a dense
  area-uniform sample of the plant surface);
* no ``views/cameras.json`` or instance maps: reprojection;
* no ``scan/scan.ply`` and no observed cloud given: the GT-free skeleton support (``support.*``, the share of the
  skeleton's length near an observed point, tolerance a fraction of the observed cloud's height above z = 0, or,
  for ``support.skeleton@spacing``, max(1 % of that height, twice the observed points' median spacing); and the
  reverse, ``support.coverage@spacing``, the share of the observed points within that of the skeleton's surface);
* no ``leaves.json`` in the output: leaf metrics; no ``points.ply``: points metrics; no ``skeleton.ply``: Stava and
  skeleton metrics;
* a ground truth without leaves: the foliage part of the point and surface metrics; a trunk shorter than breast
  height: DBH; fewer than 3 skeleton nodes, or all on one vertical plane: the crown projection area.

Random samples (surface samples) come from a generator seeded by ``options.seed``: the same inputs give the same
numbers.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from plantbench.errors import InputError
from plantbench.metrics.info import METRICS
from plantbench.metrics.stava import StavaParams

__all__ = ["EvaluateOptions", "evaluate", "evaluate_detailed", "format_summary"]


@dataclass(frozen=True)
class EvaluateOptions:
    """Everything that changes a score; invalid values raise :class:`~plantbench.errors.InputError`."""

    seed: int = 0
    """Seed of the area-uniform surface samples (the same seed gives the same samples, so the same scores)."""
    gt_samples: int = 1_000_000
    """Samples of the ground-truth surface, for the point and surface metrics and for mesh_to_scan when the case
    has no scan."""
    recon_samples: int = 200_000
    """Samples of the reconstructed mesh, for the surface metrics and mesh_to_scan.area_D_cm."""
    skeleton_step: float = 0.001
    """Step, in metres, at which both skeletons are resampled along their edges (1 mm, as Smart-Tree)."""
    breast_height: float = 1.3
    """Height above the lowest skeleton node, in metres, at which DBH is measured."""
    max_dist_fraction: float = 0.1
    """Distance cutoff of the DTU-style point metrics, as a fraction of the plant's height."""
    stava: StavaParams = field(default_factory=StavaParams)
    """Parameters of the Stava similarity."""

    def __post_init__(self) -> None:
        if (self.gt_samples < 1 or self.recon_samples < 1 or not self.skeleton_step > 0
                or not self.breast_height >= 0 or not 0 < self.max_dist_fraction <= 1):
            raise InputError(f"invalid evaluation options {self}")


def evaluate(case_dir: str | os.PathLike, recon_dir: str | os.PathLike, *,
             options: EvaluateOptions = EvaluateOptions(), observed: np.ndarray | None = None,
             observed_from: str | None = None) -> dict[str, float | None]:
    """All metrics of one reconstruction: metric name -> value (None where it cannot apply)."""
    return evaluate_detailed(case_dir, recon_dir, options=options, observed=observed, observed_from=observed_from)[0]


def _set(values: dict, reasons: dict, prefix: str, result: dict | None, reason: str | None = None) -> None:
    """Store ``result`` under ``prefix.key``, or mark every registered ``prefix.*`` metric None with ``reason``."""
    if result is None:
        for name in METRICS:
            if name.startswith(prefix + ".") and name not in values:
                values[name] = None
                reasons[name] = reason or "not applicable"
        return
    for k, v in result.items():
        name = f"{prefix}.{k}"
        if name not in METRICS:
            raise AssertionError(f"metric {name} is not registered")
        if v is not None and not np.isfinite(v):
            raise AssertionError(f"metric {name} is not finite ({v})")
        values[name] = None if v is None else float(v)
        if v is None:
            reasons[name] = reason or "undefined for this input (see the metric's docstring)"


def _read_masks(case: Path, cameras: list, images: list[str]) -> list[np.ndarray]:
    from PIL import Image

    folder = case / "views" / "instance"
    files = sorted(p.name for p in folder.glob("*.png"))
    if len(files) != len(cameras):
        raise InputError(f"{len(cameras)} cameras but {len(files)} instance maps (mismatched view counts)",
                         path=folder)
    masks = []
    for cam, name in zip(cameras, images):
        path = folder / Path(name).name
        if not path.is_file():
            raise InputError("instance map missing for a camera", path=path)
        m = np.array(Image.open(path))
        if m.shape != (cam.height, cam.width):
            raise InputError(f"instance map is {m.shape}, camera is {(cam.height, cam.width)}", path=path)
        masks.append(m > 0)
    return masks


def _observed_wood(case: Path, plant, observed_from: str | None) -> tuple[np.ndarray | None, str]:
    """The share of each ground-truth edge the capture observed (:mod:`plantbench.capture.observed`), from the
    views' or the scan's file (``observed_from``; None: the views', else the scan's), or None and why."""
    from plantbench.capture.observed import OBSERVED_FILE, read_observed

    if plant is None:
        return None, "no ground truth (case has no plant/)"
    if observed_from not in (None, "views", "scan"):
        raise InputError(f"observed_from must be 'views' or 'scan', got {observed_from!r}")
    order = [observed_from] if observed_from else ["views", "scan"]
    for part in order:
        path = case / part / OBSERVED_FILE
        if path.is_file():
            return read_observed(path, plant.skeleton), ""
    return None, f"no {' or '.join(f'{p}/{OBSERVED_FILE}' for p in order)} in the capture (made before issue 63?)"


def _breast_height_observed(skeleton, share: np.ndarray, breast_height: float) -> float | None:
    """1 when the capture observed at least half the bark of the ground-truth stem's edge at breast height (above
    its lowest node), else 0; None when the stem does not reach it. A DBH is checked only where this is 1."""
    from plantbench.skeletons import stem_edge_at_height

    if len(skeleton) == 0:
        return None
    edge = stem_edge_at_height(skeleton, float(skeleton.positions[:, 2].min()) + breast_height)
    if edge is None:
        return None
    index = int(np.searchsorted(np.flatnonzero(skeleton.parents >= 0), edge[1]))  # edges are ordered by child
    return 1.0 if share[index] >= 0.5 else 0.0


def _skeleton_metrics(values: dict, reasons: dict, plant, skeleton, samples, options: EvaluateOptions,
                      no_plant: str, gt_observed: tuple[np.ndarray | None, str] = (None, "")) -> None:
    """The ``skeleton.*`` metrics: the reconstruction's own traits (height, branches, lengths, DBH, crown area) with
    or without ground truth; P/R/F1 and the errors against the ground truth only with it. ``samples``: the
    skeleton's (:func:`~plantbench.metrics.skeleton.skeleton_samples`); ``gt_observed``: the share of each
    ground-truth edge the capture observed, or None and why (:func:`_observed_wood`)."""
    from plantbench.metrics.points import tau_label
    from plantbench.metrics.skeleton import (
        STRUCTURE_FRACTION,
        crown_area,
        skeleton_attributes,
        skeleton_prf,
        skeleton_samples,
    )
    from plantbench.metrics.structure import branch_count_log2_error, branch_prf

    if skeleton is None:
        for prefix in ("skeleton", "qsm", "capture"):
            _set(values, reasons, prefix, None, "no skeleton.ply in the output")
        return
    a = skeleton_attributes(skeleton, breast_height=options.breast_height)
    _trait_metrics(values, reasons, skeleton, options)
    area = crown_area(skeleton)
    _set(values, reasons, "skeleton", {"crown_area_m2": area}, "fewer than 3 skeleton nodes, or all in one vertical plane")
    traits = {"branch_count": a["branch_count"], "total_length_m": a["total_length_m"],
              "mean_branch_length_m": a["mean_branch_length_m"], "height_m": a["height_m"],
              "dbh_cm": None if a["dbh_m"] is None else a["dbh_m"] * 100}
    if plant is None:
        _set(values, reasons, "skeleton", traits, "trunk below breast height, or no branch")
        _set(values, reasons, "skeleton", None, no_plant)  # P/R/F1 and every error
        _set(values, reasons, "capture", None, no_plant)
        return
    gt_samples = skeleton_samples(plant.skeleton, options.skeleton_step)
    share, why = gt_observed
    if share is not None:
        w = gt_samples.weights(True)[:gt_samples.edge_samples]
        _set(values, reasons, "capture", {"observed_wood_share": float((w * share[gt_samples.edge]).sum() / w.sum())
                                          if w.sum() > 0 else None}, "the ground truth has no wood")
        _set(values, reasons, "capture", {"breast_height_observed": _breast_height_observed(plant.skeleton, share,
                                                                                            options.breast_height)},
             "the ground-truth stem does not reach breast height")
    else:
        _set(values, reasons, "capture", None, why)
    prf = skeleton_prf(gt_samples, samples, step=options.skeleton_step,
                       height=plant.height if plant.height > 0 else None,
                       gt_observed=share if plant.height > 0 else None)
    if share is None:
        _set(values, reasons, "skeleton", {k.split(".", 1)[1]: None for k in METRICS
                                           if k.startswith(("skeleton.vf1_observed@", "skeleton.vrecall_hidden@"))},
             why)
    a_gt = skeleton_attributes(plant.skeleton, breast_height=options.breast_height)
    structure = {"branch_count_log2_error": branch_count_log2_error(a_gt["branch_count"], a["branch_count"])}
    if plant.height > 0 and a_gt["branch_count"] > 0:
        lab = tau_label(STRUCTURE_FRACTION)
        structure.update({f"{k}@{lab}": v for k, v in
                          branch_prf(plant.skeleton, skeleton, tau=STRUCTURE_FRACTION * plant.height).items()})

    def rel(k):
        return abs(a[k] - a_gt[k]) / a_gt[k] if a_gt[k] else None

    dbh_err = abs(a["dbh_m"] - a_gt["dbh_m"]) * 100 if a["dbh_m"] is not None and a_gt["dbh_m"] is not None \
        else None
    area_gt = crown_area(plant.skeleton)
    _set(values, reasons, "skeleton", {"crown_area_rel_error": abs(area - area_gt) / area_gt if area is not None
                                       and area_gt is not None else None}, "no crown area (here or in the ground truth)")
    _set(values, reasons, "skeleton", {
        **prf, **traits, **structure,
        "branch_count_rel_error": rel("branch_count"), "total_length_rel_error": rel("total_length_m"),
        "height_error_m": abs(a["height_m"] - a_gt["height_m"]), "dbh_error_cm": dbh_err,
    }, "trunk below breast height, or no branch")


def _trait_metrics(values: dict, reasons: dict, skeleton, options: EvaluateOptions) -> None:
    """The forester's traits (:mod:`plantbench.metrics.traits`), from the skeleton (``skeleton.*``) and from its QSM
    cylinder export (``qsm.*``); no ground truth needed."""
    from plantbench.io.qsm import skeleton_to_cylinders
    from plantbench.metrics.traits import cylinder_traits, skeleton_traits

    t = skeleton_traits(skeleton, breast_height=options.breast_height)
    _set(values, reasons, "skeleton", {k: v for k, v in t.items() if f"skeleton.{k}" in METRICS
                                       and k not in ("dbh_cm", "height_m", "total_length_m", "branch_count")},
         "no edge")
    has_edge = len(skeleton) > 0 and bool(np.any(skeleton.parents >= 0))
    _set(values, reasons, "qsm", cylinder_traits(skeleton_to_cylinders(skeleton), breast_height=options.breast_height)
         if has_edge else None, "no edge: no cylinder" if not has_edge else "no stem reaches breast height")


def _support_metrics(values: dict, reasons: dict, samples, observed: np.ndarray | None,
                     options: EvaluateOptions) -> None:
    """``support.*``: the GT-free share of the skeleton's length near an observed point (the scan, or the input
    cloud), tolerances fractions of the observed height above z = 0. ``samples``: the skeleton's
    (:func:`~plantbench.metrics.skeleton.skeleton_samples`), None without a skeleton."""
    from plantbench.geometry.clouds import cloud_height, median_spacing
    from plantbench.metrics.points import tau_label
    from plantbench.metrics.skeleton import HEIGHT_FRACTIONS, skeleton_coverage, skeleton_support

    obs_height = cloud_height(observed) if observed is not None and len(observed) else 0.0
    if samples is None or observed is None or obs_height <= 0:
        _set(values, reasons, "support", None, "no skeleton.ply in the output" if samples is None
             else "no scan/scan.ply or observed cloud above the ground")
        return
    spacing = median_spacing(observed)
    sparse = max(0.01 * obs_height, 2.0 * spacing) if np.isfinite(spacing) else 0.01 * obs_height
    shares = skeleton_support(samples, observed, tolerances=(*(f * obs_height for f in HEIGHT_FRACTIONS), sparse))
    _set(values, reasons, "support", None if shares is None else
         {**{f"skeleton@{tau_label(f)}": v for f, v in zip(HEIGHT_FRACTIONS, shares)}, "skeleton@spacing": shares[-1]},
         "the skeleton has no length")
    _set(values, reasons, "support", {"coverage@spacing": skeleton_coverage(samples, observed, tolerance=sparse)},
         "the skeleton has no sample")
    _set(values, reasons, "support", {"spacing_cm": 100.0 * spacing if np.isfinite(spacing) else None},
         "fewer than 2 observed points")


def _gt_surface_sample(plant, options: EvaluateOptions) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform sample of the ground-truth surface and its labels (0 wood, 1 foliage); the skeleton's nodes
    (wood) for a plant without surface."""
    from plantbench.metrics.surface import sample_surface
    from plantbench.seeding import rng as make_rng

    r = make_rng(options.seed, "metrics", "gt-surface")
    mw = plant.branch_mesh.face_areas().sum() if len(plant.branch_mesh.faces) else 0.0
    ml = plant.leaf_mesh.face_areas().sum() if len(plant.leaf_mesh.faces) else 0.0
    n_w = int(round(options.gt_samples * mw / (mw + ml))) if mw + ml > 0 else 0
    pw, _ = sample_surface(plant.branch_mesh, n_w, r)
    pl, _ = sample_surface(plant.leaf_mesh, options.gt_samples - n_w, r)
    gt_pts = np.concatenate([pw, pl])
    gt_lab = np.concatenate([np.zeros(len(pw), np.int64), np.ones(len(pl), np.int64)])
    if len(gt_pts) == 0:
        gt_pts = plant.skeleton.positions
        gt_lab = np.zeros(len(gt_pts), np.int64)
    return gt_pts, gt_lab


def _reprojection_metrics(values: dict, reasons: dict, case: Path, mesh, scene) -> None:
    """``reprojection.*``: the mesh's silhouettes against the case's instance masks (no ground truth needed).
    ``scene``: the mesh's ray-casting scene (:func:`~plantbench.metrics.surface.raycasting_scene`), or None."""
    from plantbench.cameras import read_cameras
    from plantbench.metrics.reprojection import render_silhouettes, reprojection_error, strided

    cam_path = case / "views" / "cameras.json"
    if mesh is None or not cam_path.is_file() or not (case / "views" / "instance").is_dir():
        _set(values, reasons, "reprojection", None,
             "no mesh.ply in the output" if mesh is None else "no views/cameras.json or views/instance/")
        return
    cameras, images = read_cameras(cam_path)
    masks = _read_masks(case, cameras, images)
    scored = [strided(cam) for cam in cameras]  # large views: a regular subset of their pixels (the module's doc)
    masks = [m[::s, ::s] for m, (_, s) in zip(masks, scored, strict=True)]
    res = reprojection_error(masks, render_silhouettes(mesh, [c for c, _ in scored], scene=scene))
    err = res.per_view_error[np.isfinite(res.per_view_error)]
    _set(values, reasons, "reprojection", {
        "error": res.error, "error_max": float(err.max()) if len(err) else None,
        "iou": res.iou, "iou_min": float(res.per_view_iou.min())}, "every reference mask is empty")


def _leaf_metrics(values: dict, reasons: dict, plant, leaves, no_plant: str) -> None:
    """``leaves.*``: counts and detection (Hungarian and strict matching of centroids) against the ground truth."""
    from plantbench.metrics import leaves as lv

    if plant is None or leaves is None:
        _set(values, reasons, "leaves", None, no_plant if plant is None else "no leaves.json in the output")
        return
    counts = lv.leaf_count_metrics(len(plant.leaves), len(leaves))
    lengths = [leaf.length for leaf in plant.leaves]
    radius = 0.5 * float(np.median(lengths)) if lengths else 1.0
    gt_c = np.array([leaf.centroid for leaf in plant.leaves]).reshape(-1, 3)
    pred_c = np.array([leaf.centroid for leaf in leaves]).reshape(-1, 3)
    det = lv.leaf_detection(gt_c, pred_c, radius=radius)
    det.pop("matched")
    spacing = lv.median_spacing(gt_c) if len(gt_c) > 1 else (plant.leaves[0].length if len(gt_c) else 1.0)
    strict_radius = lv.SPACING_FRACTION * spacing
    strict = lv.leaf_detection(gt_c, pred_c, radius=strict_radius)
    det.update({f"strict_{k}": strict[k] for k in ("precision", "recall", "f1")})
    pairs = lv.leaf_matches(gt_c, pred_c, radius=strict_radius)
    shape, angle = lv.leaf_shape_errors(plant.leaves, leaves, pairs)
    det.update({"strict_matched": float(len(pairs)),
                "shape_error": float(np.median(shape)) if len(pairs) else None,
                "normal_error_deg": float(np.median(angle)) if len(pairs) else None})
    _set(values, reasons, "leaves", {**counts, **det}, "no ground-truth leaf")


def _cloud_scores(values: dict, reasons: dict, plant, points, mesh, gt_sample: tuple, recon_sample,
                  options: EvaluateOptions, no_plant: str) -> None:
    """``points.*`` (the method's points.ply) and ``surface.*`` (``recon_sample``, the sample of its mesh) against
    the ground-truth surface sample ``gt_sample`` (points, labels)."""
    from plantbench.metrics.points import cloud_metrics
    from plantbench.metrics.surface import kdtree

    gt_pts, gt_lab = gt_sample
    height = plant.height if plant is not None else 0.0
    gt_tree = kdtree(gt_pts) if plant is not None and height > 0 else None  # for both cloud scores below
    if points is None:
        _set(values, reasons, "points", None, "no points.ply in the output")
    else:
        values["points.count"] = float(len(points))
        if plant is None or height <= 0:
            _set(values, reasons, "points", None, no_plant)
        else:
            _set(values, reasons, "points", cloud_metrics(gt_pts, gt_lab, points, height=height,
                                                          max_dist_fraction=options.max_dist_fraction,
                                                          gt_tree=gt_tree),
                 "no ground-truth points of this part, or no reconstructed points")
    if mesh is None or plant is None or height <= 0:
        _set(values, reasons, "surface", None, "no mesh.ply in the output" if mesh is None else no_plant)
    else:
        _set(values, reasons, "surface", cloud_metrics(gt_pts, gt_lab, recon_sample, height=height,
                                                       max_dist_fraction=options.max_dist_fraction, gt_tree=gt_tree),
             "no ground-truth points of this part, or an empty reconstructed surface")


def _recon_sample(mesh, options: EvaluateOptions) -> np.ndarray:
    """The area-uniform sample of the reconstructed mesh that mesh_to_scan's area_D and the surface metrics share."""
    from plantbench.metrics.surface import sample_surface
    from plantbench.seeding import rng as make_rng

    return sample_surface(mesh, options.recon_samples, make_rng(options.seed, "metrics", "recon-surface"))[0]


def _mesh_metrics(values: dict, reasons: dict, plant, mesh, scan: np.ndarray | None, recon_sample, scene,
                  no_plant: str) -> None:
    """``mesh_to_scan.*`` against ``scan`` (the case's scan, or the ground-truth surface sample) and
    ``mesh_to_surface.*`` against the ground-truth meshes; ``recon_sample`` and ``scene``: the mesh's shared
    surface sample and ray-casting scene."""
    from plantbench.metrics.surface import distance_stats_cm, mesh_to_scan, point_to_mesh_distances
    from plantbench.plant import TriMesh

    if mesh is None:
        _set(values, reasons, "mesh_to_scan", None, "no mesh.ply in the output")
    elif scan is None or len(scan) == 0:
        _set(values, reasons, "mesh_to_scan", None, "no scan/scan.ply and no ground-truth surface")
    else:
        m2s = mesh_to_scan(scan, mesh, rng=None, area_sample=recon_sample, scene=scene)
        _set(values, reasons, "mesh_to_scan", dict(vars(m2s)), "empty mesh (no vertices or no triangles)")
    gt_mesh = TriMesh.concatenate([plant.branch_mesh, plant.leaf_mesh]) if plant is not None else None
    if mesh is None or gt_mesh is None or len(gt_mesh.faces) == 0:
        _set(values, reasons, "mesh_to_surface", None, "no mesh.ply in the output" if mesh is None else no_plant)
    else:
        D, s = distance_stats_cm(point_to_mesh_distances(gt_mesh, mesh.vertices))
        _set(values, reasons, "mesh_to_surface", {"D_cm": D, "sigma_cm": s}, "empty mesh (no vertices)")


def evaluate_detailed(case_dir: str | os.PathLike, recon_dir: str | os.PathLike, *,
                      options: EvaluateOptions = EvaluateOptions(), observed: np.ndarray | None = None,
                      observed_from: str | None = None) -> tuple[dict[str, float | None], dict[str, str]]:
    """Like :func:`evaluate`, plus metric name -> reason for every None value.

    ``observed`` : (m, 3) float, the points the capture gave for the GT-free skeleton support; None: the case's
    ``scan/scan.ply``. ``observed_from``: 'views' or 'scan', the capture the method read, whose observed wood
    splits the skeleton's recall into observation and inference (``skeleton.vf1_observed@*``,
    ``skeleton.vrecall_hidden@*``, ``capture.observed_wood_share``); None: the views', else the scan's."""
    from plantbench.io.plantio import read_plant, read_reconstruction
    from plantbench.io.ply import read_points
    from plantbench.metrics.skeleton import skeleton_samples
    from plantbench.metrics.stava import stava_similarities
    from plantbench.metrics.surface import raycasting_scene

    case, out = Path(case_dir), Path(recon_dir)
    if not case.is_dir():
        raise InputError("case folder not found", path=case)
    recon = read_reconstruction(out)
    plant = read_plant(case)[0] if (case / "plant").is_dir() else None
    values: dict[str, float | None] = {}
    reasons: dict[str, str] = {}
    no_plant = "no ground truth (case has no plant/)"
    mesh = recon.mesh

    # ---- Stava and skeleton
    if plant is None or recon.skeleton is None:
        for prefix in ("stava", "stava_nosplit"):
            _set(values, reasons, prefix, None, no_plant if plant is None else "no skeleton.ply in the output")
    else:
        both = stava_similarities(plant.skeleton, recon.skeleton, params=options.stava)
        for prefix, res in zip(("stava", "stava_nosplit"), both):
            _set(values, reasons, prefix, res.as_dict())
    samples = skeleton_samples(recon.skeleton, options.skeleton_step) if recon.skeleton is not None else None
    _skeleton_metrics(values, reasons, plant, recon.skeleton, samples, options, no_plant,
                      _observed_wood(case, plant, observed_from))

    # ---- GT-free support of the skeleton by the observed points
    scan_path = case / "scan" / "scan.ply"
    scan_pts = read_points(scan_path)[0] if scan_path.is_file() else None
    _support_metrics(values, reasons, samples, scan_pts if observed is None else observed, options)

    gt_pts, gt_lab = _gt_surface_sample(plant, options) if plant is not None else (None, None)

    # ---- the reconstructed surface: mesh to scan / to the ground-truth surface, reprojection, leaves, clouds
    wanted = mesh is not None and (plant is not None or scan_pts is not None)  # by mesh_to_scan or surface.*
    recon_sample = _recon_sample(mesh, options) if wanted else None
    scene = raycasting_scene(mesh) if mesh is not None and len(mesh.faces) else None  # (its BVH: on first use)
    _mesh_metrics(values, reasons, plant, mesh, scan_pts if scan_pts is not None else gt_pts, recon_sample, scene,
                  no_plant)
    _reprojection_metrics(values, reasons, case, mesh, scene)
    _leaf_metrics(values, reasons, plant, recon.leaves, no_plant)
    _cloud_scores(values, reasons, plant, recon.points, mesh, (gt_pts, gt_lab), recon_sample, options, no_plant)
    missing = set(METRICS) - set(values)
    if missing:
        raise AssertionError(f"evaluate did not set {sorted(missing)}")
    return {k: values[k] for k in METRICS}, reasons


def format_summary(results: dict[str, float | None], reasons: dict[str, str] | None = None):
    """A rich Table of the results: metric, value, unit, direction (and why a value is missing)."""
    from rich.table import Table

    table = Table("metric", "value", "unit", "", title="plantbench evaluate")
    if reasons:
        table.add_column("note")
    for name, value in results.items():
        info = METRICS.get(name)
        arrow = "" if info is None or info.higher_is_better is None else ("↑" if info.higher_is_better else "↓")
        text = "-" if value is None else f"{value:.4g}"
        row = [name, text, info.unit if info else "", arrow]
        if reasons:
            row.append(reasons.get(name, "") if value is None else "")
        table.add_row(*row)
    return table
