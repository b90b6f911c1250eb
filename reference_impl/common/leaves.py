"""Leaf placement from unexplained crown points, shared by the baselines.

:func:`skeleton_distance` measures each point's distance to the skeleton's tubes (edges sampled densely);
:func:`foliage_cells` groups the points that the branches do not explain into cells of one leaf size and returns,
per cell, its centroid, its points' PCA normal and the skeleton node it hangs from.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from plantbench.geometry.vectors import unit

__all__ = ["sample_edges", "skeleton_distance", "foliage_cells"]


def sample_edges(positions: np.ndarray, parents: np.ndarray, radii: np.ndarray, step: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points along every edge at most ``step`` apart: ``samples (m, 3)``, ``node (m,)`` (the edge's child, or the
    node itself for isolated roots) and ``radius (m,)`` (interpolated)."""
    child = np.flatnonzero(parents >= 0)
    pts, node, rad = [positions], [np.arange(len(parents))], [radii]
    if len(child):
        a, b = positions[parents[child]], positions[child]
        ln = np.linalg.norm(b - a, axis=1)
        k = np.maximum(np.ceil(ln / step).astype(np.int64), 1)
        e = np.repeat(np.arange(len(child)), k - 1)
        t = (np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k))
        t = t[t > 0] / np.repeat(k, k - 1)  # interior fractions
        pts.append(a[e] + t[:, None] * (b[e] - a[e]))
        node.append(child[e])
        rad.append(radii[parents[child]][e] * (1 - t) + radii[child][e] * t)
    return np.concatenate(pts), np.concatenate(node), np.concatenate(rad)


def skeleton_distance(points: np.ndarray, positions: np.ndarray, parents: np.ndarray, radii: np.ndarray, step: float
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each point's distance to the nearest skeleton sample, that sample's node and local radius."""
    s, node, rad = sample_edges(positions, parents, radii, step)
    d, j = cKDTree(s).query(points, k=1, workers=-1)
    return d, node[j], rad[j]


def foliage_cells(points: np.ndarray, node: np.ndarray, cell: float, *, min_points: int = 3
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Group foliage points into cubic cells of edge ``cell``.

    points : (n, 3) foliage points; node : (n,) the skeleton node nearest each.
    Returns per kept cell (>= ``min_points`` points): ``centroid (k, 3)``, ``normal (k, 3)`` (smallest principal
    direction, pointing up), ``node (k,)`` (the most common nearest node) and ``count (k,)``.
    """
    if len(points) == 0:
        z = np.zeros((0, 3))
        return z, z, np.zeros(0, np.int64), np.zeros(0, np.int64)
    key = np.floor((points - points.min(0)) / cell).astype(np.int64)
    _, lab, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    lab = lab.ravel()
    m = len(cnt)
    mean = np.zeros((m, 3))
    np.add.at(mean, lab, points)
    mean /= cnt[:, None]
    d = points - mean[lab]
    cov = np.zeros((m, 3, 3))
    np.add.at(cov, lab, d[:, :, None] * d[:, None, :])
    _, vec = np.linalg.eigh(cov + 1e-12 * np.eye(3))
    normal = vec[:, :, 0]
    normal = np.where(normal[:, 2:3] < 0, -normal, normal)
    # most common nearest node per cell
    pair = lab * (int(node.max()) + 1) + node
    up, upc = np.unique(pair, return_counts=True)
    cell_of = up // (int(node.max()) + 1)
    order = np.lexsort((-upc, cell_of))
    first = np.ones(len(order), bool)
    first[1:] = cell_of[order][1:] != cell_of[order][:-1]
    cell_node = np.zeros(m, np.int64)
    cell_node[cell_of[order][first]] = (up % (int(node.max()) + 1))[order][first]
    keep = cnt >= min_points
    return mean[keep], unit(normal[keep]), cell_node[keep], cnt[keep]
