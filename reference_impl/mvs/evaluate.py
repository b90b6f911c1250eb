"""Acceptance measures of the multi-view stage against a capture's ground truth (for tests, benchmarks and the
closing note; the suite's official point metrics live in plantbench.metrics, whose surface helpers these use).

- accuracy: distance from every cloud point to the ground-truth plant surface (branches + leaves), exact
  point-to-triangle distances (:func:`plantbench.metrics.surface.point_to_mesh_distances`);
- completeness: of the ground-truth surface samples (:func:`plantbench.metrics.surface.sample_surface`) visible in
  >= 2 views (visibility from the exact depth maps), the fraction with a cloud point within ``tau`` (a fraction of
  the plant height).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from plantbench.cameras import Camera, read_cameras
from plantbench.metrics.surface import nearest_distances, point_to_mesh_distances, sample_surface
from plantbench.plant import TriMesh, check_shape

__all__ = ["visible_counts", "evaluate_cloud"]


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
