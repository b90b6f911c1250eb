"""Point importance weights (Guo et al. 2018, Eq. 8).

Each point gets its main direction n_i, the eigenvector of the largest eigenvalue of the covariance of its
neighbourhood (PCA), and a weight w_i = #{j : |p_i - p_j| < eps_D and |n_i . n_j| > eps_A}: the number of nearby
points sharing its principal direction (the point itself included, so w_i >= 1). Points on branches, whose
neighbourhoods are elongated along the branch, agree with their neighbours and weigh more than points on leaves,
whose in-plane main directions scatter (Guo et al. 2018, Fig. 6).

The PCA neighbourhood is the same eps_D ball (at least ``min_neighbours`` points) [S: the paper does not give it;
a fixed count of nearest neighbours on a densely sampled branch spans less than its diameter and gives a direction
across the branch, while the eps_D ball spans several diameters of a twig]. Both use one neighbour query of the
``max_neighbours`` nearest points, so dense regions saturate at that count.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["principal_directions", "point_weights", "eq8_weights"]

_CHUNK = 32768
"""Points per block of neighbour queries (bounds the memory of the (block, k, 3) gathers)."""


def _neighbours(tree: cKDTree, q: np.ndarray, k: int, radius: float, min_neighbours: int):
    dist, idx = tree.query(q, k=k, workers=-1)
    if k == 1:
        dist, idx = dist[:, None], idx[:, None]
    rank = np.arange(k)[None, :]
    return dist, idx, (dist < radius) | (rank < min_neighbours)


def principal_directions(points: np.ndarray, radius: float, *, max_neighbours: int = 48, min_neighbours: int = 6,
                         tree: cKDTree | None = None) -> np.ndarray:
    """(n, 3) unit eigenvector of the largest eigenvalue of the covariance of each point's neighbours within
    ``radius`` (at least its ``min_neighbours`` nearest, at most ``max_neighbours``). The sign is arbitrary.

    points : (n, 3) float, n >= 2.
    """
    n = len(points)
    k = int(min(max_neighbours, n))
    tree = tree or cKDTree(points)
    out = np.zeros((n, 3))
    for s in range(0, n, _CHUNK):
        _, idx, use = _neighbours(tree, points[s:s + _CHUNK], k, radius, min_neighbours)
        w = use.astype(np.float64)
        nb = points[idx]                                        # (c, k, 3)
        mean = np.einsum("nk,nki->ni", w, nb) / w.sum(1, keepdims=True)
        d = (nb - mean[:, None, :]) * w[:, :, None]
        cov = np.einsum("nki,nkj->nij", d, d)
        out[s:s + _CHUNK] = np.linalg.eigh(cov)[1][:, :, 2]
    return out


def point_weights(points: np.ndarray, directions: np.ndarray, eps_d: float, eps_a: float, *, max_neighbours: int = 48,
                  tree: cKDTree | None = None) -> np.ndarray:
    """(n,) Eq. 8 weights: neighbours within ``eps_d`` whose |direction . own direction| > ``eps_a``, self included.

    Only the ``max_neighbours`` nearest points are examined, so the weight saturates at that count.
    points : (n, 3) float; directions : (n, 3) unit.
    """
    n = len(points)
    if n == 0:
        return np.zeros(0)
    k = int(min(max_neighbours, n))
    tree = tree or cKDTree(points)
    out = np.zeros(n)
    for s in range(0, n, _CHUNK):
        dist, idx, _ = _neighbours(tree, points[s:s + _CHUNK], k, eps_d, 0)
        valid = dist < eps_d
        dots = np.abs(np.einsum("ni,nki->nk", directions[s:s + _CHUNK], directions[idx]))
        out[s:s + _CHUNK] = np.sum(valid & (dots > eps_a), axis=1)
    return out


def eq8_weights(points: np.ndarray, eps_d: float, eps_a: float, *, max_neighbours: int = 48, min_neighbours: int = 6,
                tree: cKDTree | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`principal_directions` and :func:`point_weights` from one neighbour query (the same results).

    Returns ``directions (n, 3)`` and ``weights (n,)``.
    """
    n = len(points)
    k = int(min(max_neighbours, n))
    tree = tree or cKDTree(points)
    dist = np.zeros((n, k), np.float32)
    idx = np.zeros((n, k), np.int32)
    dirs = np.zeros((n, 3))
    for s in range(0, n, _CHUNK):
        d, i, use = _neighbours(tree, points[s:s + _CHUNK], k, eps_d, min_neighbours)
        dist[s:s + _CHUNK], idx[s:s + _CHUNK] = d, i
        w = use.astype(np.float64)
        nb = points[i]
        mean = np.einsum("nk,nki->ni", w, nb) / w.sum(1, keepdims=True)
        c = (nb - mean[:, None, :]) * w[:, :, None]
        dirs[s:s + _CHUNK] = np.linalg.eigh(np.einsum("nki,nkj->nij", c, c))[1][:, :, 2]
    out = np.zeros(n)
    for s in range(0, n, _CHUNK):
        valid = dist[s:s + _CHUNK] < eps_d
        dots = np.abs(np.einsum("ni,nki->nk", dirs[s:s + _CHUNK], dirs[idx[s:s + _CHUNK]]))
        out[s:s + _CHUNK] = np.sum(valid & (dots > eps_a), axis=1)
    return dirs, out
