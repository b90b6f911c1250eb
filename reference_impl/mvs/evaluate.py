"""Acceptance measures of the multi-view stage against a capture's ground truth (for tests, benchmarks and the
closing note; the suite's official point metrics live in plantbench.metrics, whose surface helpers these use).

- accuracy: distance from every cloud point to the ground-truth plant surface (branches + leaves), exact
  point-to-triangle distances (:func:`plantbench.metrics.surface.point_to_mesh_distances`);
- completeness: of the ground-truth surface samples (:func:`plantbench.metrics.surface.sample_surface`) visible in
  >= 2 views (visibility from the exact depth maps), the fraction with a cloud point within ``tau`` (a fraction of
  the plant height);
- leaf depth (:func:`leaf_depth_accuracy`): per view, the share of the leaf pixels (instance map) whose estimated
  depth is within ``tol`` x the plant height of the exact depth (a pixel without an estimate counts as wrong), and
  the share with an estimate.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from plantbench.cameras import Camera, read_cameras
from plantbench.metrics.surface import nearest_distances, point_to_mesh_distances, sample_surface
from plantbench.plant import TriMesh, check_shape

__all__ = ["visible_counts", "evaluate_cloud", "leaf_depth_accuracy"]


def visible_counts(points: np.ndarray, cameras: list[Camera], depths: list[np.ndarray], rel_tol: float = 0.01) -> np.ndarray:
    """(n,) number of views in which each point is visible: it projects inside the image and its depth agrees with
    the exact depth map at the nearest pixel within ``rel_tol``."""
    count = np.zeros(len(points), np.int64)
    for cam, depth in zip(cameras, depths, strict=True):
        uv, z = cam.project(points)
        u = np.round(uv[:, 0]).astype(np.int64)
        v = np.round(uv[:, 1]).astype(np.int64)
        ok = (z > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        idx = np.flatnonzero(ok)
        d = depth[v[idx], u[idx]]
        vis = np.isfinite(d) & (np.abs(d - z[idx]) < rel_tol * z[idx])
        count[idx[vis]] += 1
    return count


def evaluate_cloud(case_dir: str | Path, points: np.ndarray, *, tau: float = 0.01, samples: int = 200_000,
                   seed: int = 0) -> dict:
    """Accuracy and completeness of ``points`` against a case's ground truth.

    Returns
    -------
    dict with height, median/mean/p90 accuracy (absolute and / height), completeness at ``tau`` x height over the
    samples visible in >= 2 views, and the number of such samples
    """
    from plantbench.io.plantio import read_plant

    case = Path(case_dir)
    plant, meta = read_plant(case)
    mesh = TriMesh.concatenate([plant.branch_mesh, plant.leaf_mesh])
    height = float(meta.height)
    pts = check_shape("points", points, (-1, 3), "f")
    dist = point_to_mesh_distances(mesh, pts)
    cams, names = read_cameras(case / "views" / "cameras.json")
    depths = [np.load(case / "views" / "depth" / f"{Path(n).stem}.npy") for n in names]
    rng = np.random.Generator(np.random.PCG64(seed))
    gt, _ = sample_surface(mesh, samples, rng)
    vis = visible_counts(gt, cams, depths) >= 2
    near, _ = nearest_distances(pts, gt[vis])
    return {
        "height": height,
        "points": len(pts),
        "accuracy_median": float(np.median(dist)),
        "accuracy_median_rel": float(np.median(dist) / height),
        "accuracy_mean_rel": float(np.mean(dist) / height),
        "accuracy_p90_rel": float(np.percentile(dist, 90) / height),
        "completeness": float(np.mean(near < tau * height)),
        "tau_rel": tau,
        "visible_samples": int(vis.sum()),
    }


def leaf_depth_accuracy(case_dir: str | Path, depth_dir: str | Path, *, tol: float = 0.01) -> dict:
    """How well per-view depth maps (``depth_dir/STEM.npz``, key ``depth``, NaN where rejected: the mvs stage's
    output; or ``STEM.npy``) hold the leaves of a capture with ground truth.

    Per view with leaf pixels (instance >= 2): ``within`` = leaf pixels whose depth is within ``tol`` x plant height
    of the exact depth / leaf pixels; ``kept`` = leaf pixels with a finite depth / leaf pixels.

    Returns
    -------
    dict: height, tol, views, leaf_pixels (all views), within and kept pooled over the views' leaf pixels,
    within_median and kept_median over the views, within_of_kept (pooled, among the pixels with a depth)
    """
    from PIL import Image

    from plantbench.io.plantio import read_plant

    case = Path(case_dir)
    _, meta = read_plant(case)
    height = float(meta.height)
    _, names = read_cameras(case / "views" / "cameras.json")
    from reference_impl.leaves.pipeline import load_depth_dir

    estimated = load_depth_dir(depth_dir, names)
    n_leaf = n_kept = n_within = 0
    per_within, per_kept = [], []
    for name, est in zip(names, estimated, strict=True):
        stem = Path(name).stem
        leaf = np.array(Image.open(case / "views" / "instance" / f"{stem}.png")) >= 2
        if not leaf.any():
            continue
        exact = np.load(case / "views" / "depth" / f"{stem}.npy").astype(np.float64)
        est = np.full(exact.shape, np.nan) if est is None else est
        kept = leaf & np.isfinite(est)
        within = kept & (np.abs(np.where(kept, est, 0.0) - exact) <= tol * height)
        n_leaf, n_kept, n_within = n_leaf + leaf.sum(), n_kept + kept.sum(), n_within + within.sum()
        per_within.append(within.sum() / leaf.sum())
        per_kept.append(kept.sum() / leaf.sum())
    if not n_leaf:
        return {"height": height, "tol": tol, "views": 0, "leaf_pixels": 0, "within": None, "kept": None,
                "within_median": None, "kept_median": None, "within_of_kept": None}
    return {"height": height, "tol": tol, "views": len(per_within), "leaf_pixels": int(n_leaf),
            "within": float(n_within / n_leaf), "kept": float(n_kept / n_leaf),
            "within_median": float(np.median(per_within)), "kept_median": float(np.median(per_kept)),
            "within_of_kept": float(n_within / n_kept) if n_kept else None}
