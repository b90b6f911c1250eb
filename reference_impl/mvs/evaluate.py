"""Acceptance measures of the multi-view stage against a capture's ground truth (for tests, benchmarks and the
closing note; the suite's official point metrics live in plantbench.metrics).

- accuracy: distance from every cloud point to the ground-truth plant surface (branches + leaves), exact
  point-to-triangle distances (open3d RaycastingScene);
- completeness: of the ground-truth surface samples visible in >= 2 views (visibility from the exact depth maps),
  the fraction with a cloud point within ``tau`` (a fraction of the plant height).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from plantbench.cameras import Camera
from plantbench.plant import TriMesh, check_shape

__all__ = ["surface_distance", "sample_surface", "visible_counts", "evaluate_cloud"]


def surface_distance(mesh: TriMesh, points: np.ndarray) -> np.ndarray:
    """(n,) exact distance from ``points`` (n, 3) to the triangle mesh."""
    import open3d as o3d

    pts = check_shape("points", points, (-1, 3), "f")
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh.vertices.astype(np.float32), mesh.faces.astype(np.uint32))
    return scene.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy().astype(np.float64)


def sample_surface(mesh: TriMesh, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) points uniform by area on the mesh."""
    area = mesh.face_areas()
    f = rng.choice(len(area), n, p=area / area.sum())
    a, b, c = (mesh.vertices[mesh.faces[f, i]] for i in range(3))
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    return (1 - s)[:, None] * a + (s * (1 - r2))[:, None] * b + (s * r2)[:, None] * c


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
    from plantbench.cameras import read_cameras
    from plantbench.io.plantio import read_plant

    case = Path(case_dir)
    plant, meta = read_plant(case)
    mesh = TriMesh.concatenate([plant.branch_mesh, plant.leaf_mesh])
    height = float(meta.height)
    pts = check_shape("points", points, (-1, 3), "f")
    dist = surface_distance(mesh, pts)
    cams, names = read_cameras(case / "views" / "cameras.json")
    depths = [np.load(case / "views" / "depth" / f"{Path(n).stem}.npy") for n in names]
    rng = np.random.Generator(np.random.PCG64(seed))
    gt = sample_surface(mesh, samples, rng)
    vis = visible_counts(gt, cams, depths) >= 2
    from scipy.spatial import cKDTree

    near, _ = cKDTree(pts).query(gt[vis], workers=-1)
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
