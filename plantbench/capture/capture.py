"""``capture_case``: render the views and simulate the scan of one case (docs/design.md, On-disk contracts, Capture).

Writes ``CASE/views/`` (images/NNNN.png, depth/NNNN.npy, instance/NNNN.png, foliage/NNNN.png, optional
normal/NNNN.npy, cameras.json, colmap/, transforms.json, observed_wood.npz, capture.json) and, when scanning,
``CASE/scan/`` (scan.ply, stations.json, observed_wood.npz: :mod:`plantbench.capture.observed`).

Crash safety: both folders are built in hidden temporary siblings; only when both are complete are the old folders
removed and the new ones renamed into place, scan/ first and views/ last. ``views/capture.json`` is therefore the
mark of a complete capture: a crash leaves either the previous capture, or no views/ folder at all.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np

from plantbench.cameras import Camera, write_cameras
from plantbench.capture.formats import Tracks, visible_tracks, write_colmap_text, write_transforms
from plantbench.capture.raycast import RayCaster
from plantbench.capture.scan import median_spacing, scan_plant
from plantbench.capture.settings import CaptureOptions, as_options
from plantbench.capture.views import (
    exact_maps,
    ground_truth_caster,
    ground_truth_mesh,
    place_cameras,
    render_colour,
    to_srgb8,
)
from plantbench.errors import InputError
from plantbench.io.atomic import write_json
from plantbench.io.plantio import read_plant
from plantbench.io.ply import write_points
from plantbench.plant import Plant
from plantbench.seeding import derive_seed, rng

__all__ = ["CAPTURE_FORMAT", "LEAF_RESOLVED_PX", "capture_case", "leaf_pixels", "sample_surface", "is_complete"]

CAPTURE_FORMAT = "plantbench.capture/1"
_MAX_LEAF_ID = 65535 - 2  # instance maps are uint16 with leaves at 2 + id

LEAF_RESOLVED_PX = 200
"""A leaf is resolved in a view where it covers at least this many pixels (the leaves suite's criterion)."""


def leaf_pixels(instances: list[np.ndarray], n_leaves: int, *, resolved_px: int = LEAF_RESOLVED_PX) -> dict:
    """How large the leaves appear: the pixels each leaf covers in each view where it is visible (instance maps,
    leaves at 2 + id), summarised.

    Keys: ``leaves``; ``visible`` (leaves seen in at least one view) and ``resolved_2_views`` (leaves covering at
    least ``resolved_px`` pixels in at least two views); ``median_px``, ``p25_px``, ``p75_px`` (over the (leaf, view)
    pairs where the leaf is visible; None when none is); ``resolved_px``.
    """
    per_view = np.zeros((len(instances), n_leaves), np.int64)
    for v, inst in enumerate(instances):
        ids = inst[inst >= 2].astype(np.int64) - 2
        per_view[v] = np.bincount(ids[ids < n_leaves], minlength=n_leaves)
    seen = per_view[per_view > 0]
    q = np.percentile(seen, [25, 50, 75]) if len(seen) else [None] * 3
    return {"leaves": int(n_leaves), "visible": int(np.count_nonzero((per_view > 0).any(0))),
            "resolved_2_views": int(np.count_nonzero((per_view >= resolved_px).sum(0) >= 2)),
            "median_px": None if q[1] is None else float(q[1]),
            "p25_px": None if q[0] is None else float(q[0]), "p75_px": None if q[2] is None else float(q[2]),
            "resolved_px": int(resolved_px)}


def sample_surface(plant: Plant, n: int, rng_: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``n`` area-uniform samples on the branch and leaf surfaces and their instance ids (1 wood, 2 + k leaf).

    Returns
    -------
    points : (n, 3) float; instance : (n,) int
    """
    gt = ground_truth_mesh(plant, ground=False)
    if n == 0 or not len(gt.faces):
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    a, b, c = (gt.vertices[gt.faces[:, i]] for i in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    face = rng_.choice(len(area), size=n, p=area / area.sum())
    r1, r2 = rng_.random(n), rng_.random(n)
    s = np.sqrt(r1)
    w0, w1, w2 = 1 - s, s * (1 - r2), s * r2
    pts = w0[:, None] * a[face] + w1[:, None] * b[face] + w2[:, None] * c[face]
    return pts, gt.instance[face]


def is_complete(case_dir: str | os.PathLike) -> bool:
    """True when ``case_dir`` holds a finished capture (views/capture.json exists)."""
    return (Path(case_dir) / "views" / "capture.json").is_file()


def _versions() -> dict[str, str | None]:
    out = {}
    for name in ("plantbench", "mitsuba", "drjit", "numpy", "open3d-cpu", "pillow"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = None
    return out


def add_grey_noise(image: np.ndarray, levels: int, generator: np.random.Generator) -> np.ndarray:
    """``image`` (uint8) plus independent integer noise uniform in [-levels, levels] per pixel and channel, clipped
    to [0, 255]: sensor noise below what any method should notice (the variability study's +-1 grey level)."""
    noise = generator.integers(-levels, levels + 1, size=image.shape, dtype=np.int16)
    return np.clip(image.astype(np.int16) + noise, 0, 255).astype(np.uint8)


def _save_png(path: Path, array: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray(array).save(path, optimize=False, compress_level=6)


CONVENTIONS = {
    "depth": "float32 z-depth along the optical axis, metres, one ray through each pixel centre; inf where "
             "the ray hits nothing (sky); the ground plane has finite depth and instance 0",
    "instance": "uint16: 0 ground or sky, 1 wood, 2 + k leaf k",
    "foliage": "uint8 mask, 255 where the pixel shows a leaf (instance >= 2)",
    "cameras.json": "OpenCV pinhole, world-to-camera R, t; pixel (u, v) centred at integer (u, v)",
    "colmap": "PINHOLE, pixel centres at +0.5 (cx, cy = OpenCV + 0.5); points3D are ground-truth surface "
              "samples seen in >= 2 views",
    "transforms.json": "nerfstudio: camera-to-world, OpenGL axes (+X right, +Y up, +Z back); cx, cy = "
                       "OpenCV + 0.5 (pixel centres at index + 0.5)",
    "mitsuba": "perspective sensor to_world = [R^T diag(-1, -1, 1) | C]",
}
"""What each file of a view capture holds, written into capture.json."""


def capture_case(case_dir: str | os.PathLike, settings: Any = None, *, seed: int) -> Path:
    """Capture ``case_dir/plant/`` into ``case_dir/views/`` and (when ``settings.scan``) ``case_dir/scan/``.

    Parameters
    ----------
    case_dir : folder holding ``plant/`` (a missing or corrupt plant raises :class:`InputError`)
    settings : :class:`CaptureOptions`, a suite's :class:`plantbench.suites.CaptureSettings`, a dict of their
        fields, or None for the defaults
    seed : root seed; textures, render noise, scan noise and dropout and the COLMAP points all derive from it

    Returns
    -------
    the ``views/`` folder
    """
    options = as_options(settings)
    if not isinstance(seed, int | np.integer) or seed < 0:
        raise InputError(f"capture seed must be a non-negative integer, got {seed!r}")
    case = Path(case_dir)
    plant, plant_json = read_plant(case)
    if not len(plant.branch_mesh.faces) and not len(plant.leaf_mesh.faces):
        raise InputError("the plant has no branch or leaf triangles to capture", path=case / "plant")
    if len(plant.leaf_mesh_ids) and (plant.leaf_mesh_ids.min() < 0 or plant.leaf_mesh_ids.max() > _MAX_LEAF_ID):
        raise InputError(f"leaf ids must lie in [0, {_MAX_LEAF_ID}] for uint16 instance maps", path=case / "plant")

    from plantbench.backend import dispatch_seen, llvm_target_id, load_mitsuba
    from plantbench.capture.scene import scene_dict

    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    mi = load_mitsuba()
    surface = np.concatenate([plant.branch_mesh.vertices, plant.leaf_mesh.vertices])
    cameras = place_cameras(surface, options.views, elevation=options.elevation, fov_x_deg=options.fov_deg,
                            width=options.width, height=options.height, fill=options.fill)
    d = scene_dict(plant, cameras, options, rng(seed, "capture", "scene"), mi=mi)
    scene = mi.load_dict(d)
    gt = ground_truth_mesh(plant)
    caster = ground_truth_caster(plant, scene=scene, scene_dict=d)  # reuses the render scene's BVH (llvm)
    timings["setup"] = time.perf_counter() - t0

    tmp_views = Path(tempfile.mkdtemp(prefix=".views.", suffix=".tmp", dir=case))
    tmp_scan = Path(tempfile.mkdtemp(prefix=".scan.", suffix=".tmp", dir=case)) if options.scan else None
    try:
        scan_summary = None
        if tmp_scan is not None:
            t0 = time.perf_counter()
            scan_summary = _write_scan(tmp_scan, plant, options, seed, caster, plant_json.species)
            timings["scan"] = time.perf_counter() - t0
        leaves, observed = _write_views(tmp_views, plant, cameras, scene, gt, caster, options, seed, mi, timings)
        doc = {
            "format": CAPTURE_FORMAT,
            "settings": options.model_dump(mode="json"),
            "seed": int(seed),
            "plant": {"species": plant_json.species, "seed": plant_json.seed, "height": plant_json.height},
            "mitsuba_variant": mi.variant(),
            "llvm_target": llvm_target_id() if mi.variant().startswith("llvm") else None,
            "dispatch": dispatch_seen(),
            "ray_caster": caster.backend,
            "versions": _versions(),
            "images": [f"{i:04d}.png" for i in range(len(cameras))],
            "scan": scan_summary,
            "leaf_pixels": leaves,
            "observed_wood_share": observed,
            "conventions": CONVENTIONS,
        }
        write_json(tmp_views / "capture.json", doc)
        _swap_in(case, tmp_views, tmp_scan)
    except BaseException:
        shutil.rmtree(tmp_views, ignore_errors=True)
        if tmp_scan is not None:
            shutil.rmtree(tmp_scan, ignore_errors=True)
        raise
    return case / "views"


def _swap_in(case: Path, tmp_views: Path, tmp_scan: Path | None) -> None:
    """Remove the old capture (views/ first: it marks completeness), then rename scan/ and views/ into place."""
    for name in ("views", "scan"):
        old = case / name
        if old.exists() or old.is_symlink():
            trash = case / f".{name}.old"
            shutil.rmtree(trash, ignore_errors=True)
            os.replace(old, trash)
            shutil.rmtree(trash, ignore_errors=True)
    if tmp_scan is not None:
        os.replace(tmp_scan, case / "scan")
    os.replace(tmp_views, case / "views")


def _write_scan(folder: Path, plant: Plant, options: CaptureOptions, seed: int, caster: RayCaster,
                species: str) -> dict:
    # the misregistration stream is the species' own, so that the plants of a suite (which share their seed) do not
    # share one draw of station errors
    scan = scan_plant(plant, options, rng(seed, "capture", "scan"), caster,
                      registration_rng=rng(seed, "capture", "scan", "registration", species))
    write_points(folder / "scan.ply", scan.points,
                 {"label": scan.label, "leaf_id": scan.leaf_id, "station": scan.station})
    stations = [{k: v for k, v in st.items() if k != "misregistration"} for st in scan.stations]
    truth = {st["id"]: st["misregistration"] for st in scan.stations if "misregistration" in st}
    if truth:  # ground truth: not copied into a method's input (plantbench.methods.inputs copies scan.ply and
        # stations.json only)
        write_json(folder / "registration.json", {"format": "plantbench.registration/1", "stations": truth,
                                                  "registration_error": options.registration_error})
    doc = {
        "format": "plantbench.scan/1",
        "stations": stations,
        "angular_step_deg": options.angular_step_deg if options.scan_spacing is None
        else scan.stations[0]["angular_step_deg"],
        "scan_spacing": options.scan_spacing,
        "median_spacing": median_spacing(scan.points),
        "registration_error": options.registration_error,
        "max_range": options.max_range,
        "range_noise": options.range_noise,
        "range_noise_per_m": options.range_noise_per_m,
        "dropout": options.dropout,
        "scanner_height": options.scanner_height,
        "labels": {"0": "wood", "1": "leaf"},
        "notes": "beams swept over the plant's angular window; the ground is not scanned",
        "points": len(scan.points),
    }
    write_json(folder / "stations.json", doc)
    observed = _write_observed_scan(folder, plant, scan.points, scan.label)
    return {"points": len(scan.points), "stations": len(scan.stations), "median_spacing": doc["median_spacing"],
            "observed_wood_share": observed}


def _write_views(folder: Path, plant: Plant, cameras: list[Camera], scene, gt, caster: RayCaster,
                 options: CaptureOptions, seed: int, mi, timings: dict[str, float]) -> dict:
    """Writes the views and the wood they observed (``observed_wood.npz``); returns :func:`leaf_pixels` of their
    instance maps and the observed share of the wood."""
    for sub in ("images", "depth", "instance", "foliage") + (("normal",) if options.normals else ()):
        (folder / sub).mkdir()
    names = [f"{i:04d}.png" for i in range(len(cameras))]
    images, depths, instances = [], [], []
    t_render = t_maps = 0.0
    from plantbench.capture.scene import GUIDES_INTEGRATOR

    guides = mi.load_dict(GUIDES_INTEGRATOR) if options.denoise else None
    for i, cam in enumerate(cameras):
        t0 = time.perf_counter()
        rgb = to_srgb8(render_colour(scene, i, spp=options.spp, seed=derive_seed(seed, "capture", "render", i) % 2**32,
                                     mi=mi, guides=guides))
        if options.image_noise:
            noise_rng = rng(seed, "capture", "image_noise", options.image_noise_seed, i)
            rgb = add_grey_noise(rgb, options.image_noise, noise_rng)
        _save_png(folder / "images" / names[i], rgb)
        t1 = time.perf_counter()
        maps = exact_maps(cam, gt, caster, normals=options.normals)
        np.save(folder / "depth" / f"{i:04d}.npy", maps.depth)
        _save_png(folder / "instance" / names[i], maps.instance)
        _save_png(folder / "foliage" / names[i], (maps.foliage * np.uint8(255)).astype(np.uint8))
        if maps.normal is not None:
            np.save(folder / "normal" / f"{i:04d}.npy", maps.normal)
        t_render += t1 - t0
        t_maps += time.perf_counter() - t1
        images.append(rgb)
        depths.append(maps.depth)
        instances.append(maps.instance)
    timings["render"], timings["maps"] = t_render, t_maps
    write_cameras(folder / "cameras.json", cameras, names)
    pts, inst = sample_surface(plant, options.colmap_points, rng(seed, "capture", "colmap"))
    tracks: Tracks = visible_tracks(pts, inst, cameras, depths, instances, images)
    write_colmap_text(folder / "colmap", cameras, names, tracks)
    write_transforms(folder / "transforms.json", cameras, names)
    observed = _write_observed_views(folder, plant, cameras, depths, instances)
    return leaf_pixels(instances, len(plant.leaves)), observed


def _write_observed_views(folder: Path, plant: Plant, cameras: list[Camera], depths: list[np.ndarray],
                          instances: list[np.ndarray]) -> float:
    """``folder/observed_wood.npz``: the share of each ground-truth edge's bark the views observed
    (:mod:`plantbench.capture.observed`); returns the volume-weighted share of the wood."""
    import plantbench.capture.observed as ob

    samples = ob.wood_samples(plant.skeleton, step=ob.STEP_FRACTION * plant.height)
    seen = ob.observed_in_views(samples, cameras, depths, instances)
    share = ob.edge_shares(samples, seen, len(plant.skeleton.edges))
    ob.write_observed(folder / ob.OBSERVED_FILE, plant.skeleton, share,
                      {"depth_tolerance": ob.DEPTH_TOLERANCE, "min_views": ob.MIN_VIEWS,
                       "min_diameter_px": ob.MIN_DIAMETER_PX})
    return ob.observed_share(plant.skeleton, share)


def _write_observed_scan(folder: Path, plant: Plant, points: np.ndarray, label: np.ndarray) -> float:
    """``folder/observed_wood.npz``: the share of each ground-truth edge's bark within twice the scan's median
    spacing of a wood return; returns the volume-weighted share of the wood."""
    import plantbench.capture.observed as ob

    tolerance = 2.0 * float(median_spacing(points)) if len(points) > 1 else 0.0
    samples = ob.wood_samples(plant.skeleton, step=ob.STEP_FRACTION * plant.height)
    seen = ob.observed_in_scan(samples, points[label == 0], tolerance)
    share = ob.edge_shares(samples, seen, len(plant.skeleton.edges))
    ob.write_observed(folder / ob.OBSERVED_FILE, plant.skeleton, share, {"tolerance_m": tolerance})
    return ob.observed_share(plant.skeleton, share)
