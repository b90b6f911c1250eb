"""Small vector and tree utilities shared by the generator, the metrics and the reconstruction methods.

Vectors are numpy arrays with coordinates on the last axis; trees are parent arrays (``parents[i]`` the parent of
node ``i``, -1 at a root).
"""

from __future__ import annotations

import numpy as np

__all__ = ["unit", "perpendicular", "rotate", "similarity_transform", "depths", "levels", "levels_of"]


def unit(v: np.ndarray) -> np.ndarray:
    """``v`` (..., 3) normalised along its last axis; zero vectors (norm <= 1e-15) stay as they are."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 1e-15, n, 1.0)


def perpendicular(d: np.ndarray) -> np.ndarray:
    """(n, 3) unit vectors perpendicular to the unit vectors ``d`` (n, 3): ``d`` x X, or ``d`` x Y where ``d`` is
    close to X."""
    a = np.where(np.abs(d[:, [0]]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    return unit(np.cross(d, a))


def rotate(v: np.ndarray, axis: np.ndarray, angle: float | np.ndarray) -> np.ndarray:
    """Rodrigues rotation of ``v`` (n, 3) about the unit ``axis`` (n, 3) by ``angle`` radians (a scalar or (n,))."""
    c = np.cos(angle)
    s = np.sin(angle)
    if np.ndim(c):
        c = c[:, None]
        s = s[:, None]
    return v * c + np.cross(axis, v) * s + axis * np.sum(axis * v, axis=1, keepdims=True) * (1 - c)


def similarity_transform(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Umeyama (1991): scale s, rotation R, translation t minimising sum |s R src_i + t - dst_i|^2 (src, dst : (k, 3))."""
    ms, md = src.mean(0), dst.mean(0)
    xs, xd = src - ms, dst - md
    cov = xd.T @ xs / len(src)
    u, sig, vt = np.linalg.svd(cov)
    s_ = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        s_[2, 2] = -1
    rot = u @ s_ @ vt
    var = (xs**2).sum() / len(src)
    scale = float(np.trace(np.diag(sig) @ s_) / max(var, 1e-300))
    return scale, rot, md - scale * rot @ ms


def depths(parents: np.ndarray) -> np.ndarray:
    """(n,) int number of edges from each node to its root (parents need not precede children; -1 for a node on a
    cycle, which a forest has none of). Pointer doubling: log2(n) vectorised passes, however deep the tree."""
    parents = np.asarray(parents, np.int64)
    n = len(parents)
    if n == 0:
        return np.zeros(0, np.int64)
    is_root = parents < 0
    anc = np.where(is_root, np.arange(n), parents)
    depth = np.where(is_root, 0, 1).astype(np.int64)
    for _ in range(int(np.ceil(np.log2(n))) + 2):
        depth = depth + np.where(is_root[anc], 0, depth[anc])
        anc = anc[anc]
    return np.where(is_root[anc], depth, -1)


def levels_of(depth: np.ndarray) -> list[np.ndarray]:
    """Node indices grouped by ``depth`` (n,), shallowest first, each group in index order; negative depths (nodes
    on a cycle) are left out."""
    depth = np.asarray(depth)
    order = np.argsort(depth, kind="stable")
    order = order[depth[order] >= 0]
    if len(order) == 0:
        return []
    return np.split(order, np.flatnonzero(np.diff(depth[order])) + 1)


def levels(parents: np.ndarray) -> list[np.ndarray]:
    """Node indices of the tree ``parents`` grouped by depth, roots first (each group in index order)."""
    return levels_of(depths(parents))
