"""Separating the plant from the ground: a fitted ground plane, height above it, ground colour, and floaters.

1. RANSAC (3-point samples, normals within ``max_tilt_deg`` of the up axis) finds the plane with the most inliers,
   refined by least squares (SVD) on its inliers, oriented so that its normal points up.
2. Points lower than ``height`` above the plane are ground; points up to ``color_band x height`` whose colour
   matches the ground's (Mahalanobis distance to the inliers' RGB mean and covariance) are ground too (soil
   clumps, shadows on the ground reconstructed slightly above it).
3. Radius-graph connected components much smaller than the largest are floaters and dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plantbench.errors import InputError
from plantbench.plant import check_shape

from .params import GroundParams

__all__ = ["Plane", "fit_ground_plane", "plant_mask", "drop_small_components"]


@dataclass(frozen=True)
class Plane:
    """The plane n . x = offset with unit ``normal`` pointing up (height of x = n . x - offset)."""

    normal: np.ndarray
    offset: float

    def height(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points, float) @ self.normal - self.offset


def fit_ground_plane(
    points: np.ndarray, *, inlier_dist: float, rng: np.random.Generator, up=(0.0, 0.0, 1.0),
    max_tilt_deg: float = 30.0, iterations: int = 500, max_below: float = 0.2, low_fraction: float = 0.2,
) -> tuple[Plane, np.ndarray]:
    """RANSAC + least-squares plane among near-horizontal planes with (almost) nothing below them.

    Half of the 3-point samples are drawn from the lowest ``low_fraction`` of the points along ``up``, where the
    ground is. And since the ground carries the plant, a candidate with more than ``max_below`` of the points lower
    than 3 ``inlier_dist`` under it is not the ground (a dense horizontal layer of a crown). Measurements behind
    both defaults: ``docs/tuning/mvs.md``.

    Parameters
    ----------
    points : (n, 3) float, n >= 3
    inlier_dist : inlier distance
    rng : numpy Generator (the samples)
    up : the up direction
    max_tilt_deg : largest angle between the plane normal and ``up``
    iterations : RANSAC samples
    max_below : largest fraction of points allowed more than 3 ``inlier_dist`` below a candidate (when no candidate
        qualifies, the one with the fewest points below wins)
    low_fraction : half of the samples come from this lowest fraction of the points

    Returns
    -------
    plane : Plane (normal pointing to ``up``'s side)
    inliers : (n,) bool
    """
    pts = check_shape("points", points, (-1, 3), "f")
    if len(pts) < 3:
        raise InputError(f"fit_ground_plane needs at least 3 points, got {len(pts)}")
    up = np.asarray(up, float) / np.linalg.norm(up)
    cos_tilt = np.cos(np.radians(max_tilt_deg))
    sub = pts if len(pts) <= 50_000 else pts[rng.choice(len(pts), 50_000, replace=False)]
    low = np.argsort(sub @ up, kind="stable")[: max(3, int(low_fraction * len(sub)))]
    half = iterations // 2
    tri = np.concatenate([rng.integers(0, len(sub), (iterations - half, 3)), low[rng.integers(0, len(low), (half, 3))]])
    a, b, c = sub[tri[:, 0]], sub[tri[:, 1]], sub[tri[:, 2]]
    nrm = np.cross(b - a, c - a)
    ln = np.linalg.norm(nrm, axis=1)
    good = ln > 1e-12
    nrm[good] /= ln[good, None]
    nrm *= np.sign(nrm @ up)[:, None]
    good &= nrm @ up >= cos_tilt
    if not good.any():
        raise InputError("no near-horizontal plane found in the cloud")
    nrm, a = nrm[good], a[good]
    off = np.einsum("ij,ij->i", nrm, a)
    # score in chunks: |sub @ n - off| < d
    scores = np.zeros(len(nrm), np.int64)
    below = np.zeros(len(nrm), np.int64)
    for s in range(0, len(nrm), 64):
        h = sub @ nrm[s : s + 64].T - off[s : s + 64]
        scores[s : s + 64] = (np.abs(h) < inlier_dist).sum(0)
        below[s : s + 64] = (h < -3.0 * inlier_dist).sum(0)
    ok = below <= max_below * len(sub)
    best = int(np.argmax(np.where(ok, scores, -1))) if ok.any() else int(np.argmin(below))
    n0, o0 = nrm[best], off[best]
    inl = np.abs(pts @ n0 - o0) < inlier_dist
    for _ in range(3):  # least-squares refinement on the inliers
        q = pts[inl]
        centroid = q.mean(0)
        _, _, vt = np.linalg.svd(q - centroid, full_matrices=False)
        n1 = vt[2] * np.sign(vt[2] @ up)
        n0, o0 = n1, float(n1 @ centroid)
        inl = np.abs(pts @ n0 - o0) < inlier_dist
    return Plane(n0, float(o0)), inl


def drop_small_components(points: np.ndarray, radius: float, min_fraction: float) -> np.ndarray:
    """(n,) bool: points in radius-graph components at least ``min_fraction`` the size of the largest."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(points)
    if n == 0:
        return np.zeros(0, bool)
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(g, directed=False)
    sizes = np.bincount(labels)
    return sizes[labels] >= min_fraction * sizes.max()


def plant_mask(
    points: np.ndarray, colours: np.ndarray, *, scale: float, params: GroundParams, rng: np.random.Generator,
    up=(0.0, 0.0, 1.0), component_radius: float | None = None,
) -> tuple[np.ndarray, Plane | None]:
    """(n,) bool mask of plant points, and the ground plane (None when no ground was found).

    ``scale`` is the capture's length scale (distance from the cameras to the scene centre): the inlier and height
    thresholds are fractions of it. ``component_radius`` (default: 2 % of scale) links points into components.
    """
    pts = check_shape("points", points, (-1, 3), "f")
    if len(pts) < 3:
        return np.ones(len(pts), bool), None
    try:
        plane, inl = fit_ground_plane(
            pts, inlier_dist=params.inlier_fraction * scale, rng=rng, up=up,
            max_tilt_deg=params.max_tilt_deg, iterations=params.ransac_iterations,
        )
    except InputError:
        return np.ones(len(pts), bool), None
    hgt = plane.height(pts)
    thr = params.height_fraction * scale
    keep = hgt > thr
    col = np.asarray(colours, np.float64)
    ground_col = col[inl]
    if len(ground_col) > 10:
        mu = ground_col.mean(0)
        cov = np.cov(ground_col.T) + np.eye(3) * 1.0
        diff = col - mu
        maha = np.sqrt(np.einsum("ij,jk,ik->i", diff, np.linalg.inv(cov), diff))
        keep &= ~((hgt < params.color_band * thr) & (maha < params.color_mahalanobis))
    if keep.sum() > 1 and params.cluster_fraction > 0:
        idx = np.flatnonzero(keep)
        radius = component_radius if component_radius is not None else 0.02 * scale
        keep[idx] = drop_small_components(pts[idx], radius, params.cluster_fraction)
    return keep, plane
