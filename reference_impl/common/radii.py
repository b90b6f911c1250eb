"""Branch radii from allometry, anchored on a trunk radius measured in the cloud.

- :func:`pipe_model_radii`: Shinozaki's pipe model on supported length, r = r_root (w / w_root)^(1/2) (cross-section
  area proportional to the branch length a node supports), the Livny-style choice.
- :func:`wbe_murray_radii`: Xu et al. 2007 section 5.2: a tip-to-root pass for the supported lengths, then a
  root-to-tip pass with Eq. 4 (one child: r_c = r_p (l_c / l_p)^(3/2), the simplified WBE model) and Eq. 5 (several
  children: r_ci = r_p (l_ci / sum_j l_cj)^(1/2.49), Murray's exponent).
- :func:`murray_angle`: Eq. 3, the branching angle Murray (1926) predicts from the parent and child radii.
- :func:`fit_trunk_radius`: a circle fitted (algebraic Kasa fit, then two Huber-reweighted refits) to the points
  around the base of a stem, projected on the plane perpendicular to the stem axis; works on the half-circle arc a
  single scan station sees.
"""

from __future__ import annotations

import numpy as np

from plantbench.geometry import vectors
from reference_impl.common.graph import children_csr, subtree_lengths

__all__ = ["pipe_model_radii", "wbe_murray_radii", "murray_angle", "fit_circle", "fit_trunk_radius"]


def pipe_model_radii(weights: np.ndarray, parents: np.ndarray, root_radius: float | np.ndarray, *,
                     exponent: float = 0.5, min_radius: float = 0.0) -> np.ndarray:
    """(n,) r = r_root (w / w_root)^exponent, with w_root the weight of each node's own root.

    weights : (n,) supported lengths (> 0); root_radius : scalar or (n_roots,) in the order of ``parents < 0``.
    Children are never thicker than their parents.
    """
    parents = np.asarray(parents, np.int64)
    levels = vectors.levels(parents)
    root_of = np.arange(len(parents))
    for idx in levels:
        c = idx[parents[idx] >= 0]
        root_of[c] = root_of[parents[c]]
    roots = np.flatnonzero(parents < 0)
    rr = np.zeros(len(parents))
    rr[roots] = np.broadcast_to(np.asarray(root_radius, float), roots.shape)
    w = np.maximum(np.asarray(weights, float), 1e-12)
    r = rr[root_of] * (w / w[root_of]) ** exponent
    r = np.maximum(r, min_radius)
    for idx in levels:
        c = idx[parents[idx] >= 0]
        r[c] = np.minimum(r[c], r[parents[c]])
    return r


def wbe_murray_radii(positions: np.ndarray, parents: np.ndarray, root_radius: float | np.ndarray, *,
                     wbe_exponent: float = 1.5, murray_exponent: float = 2.49, min_radius: float = 0.0) -> np.ndarray:
    """Xu et al. 2007 Eq. 4 (single child) and Eq. 5 (split), applied root to tip.

    positions : (n, 3) float; parents : (n,) int; root_radius : scalar or (n_roots,) (roots in index order).
    The supported length of a node counts its incoming edge (so a tip's is its twig length, never 0).
    """
    parents = np.asarray(parents, np.int64)
    n = len(parents)
    sup = np.maximum(subtree_lengths(positions, parents), 1e-12)
    ptr, _ = children_csr(parents)
    nkids = np.diff(ptr)
    roots = np.flatnonzero(parents < 0)
    r = np.zeros(n)
    r[roots] = np.broadcast_to(np.asarray(root_radius, float), roots.shape)
    # sum of the siblings' supported lengths, per parent
    child = np.flatnonzero(parents >= 0)
    sib_sum = np.zeros(n)
    np.add.at(sib_sum, parents[child], sup[child])
    for idx in vectors.levels(parents)[1:]:
        p = parents[idx]
        single = nkids[p] == 1
        ratio_single = np.minimum(sup[idx] / sup[p], 1.0) ** wbe_exponent        # Eq. 4
        ratio_split = (sup[idx] / sib_sum[p]) ** (1.0 / murray_exponent)          # Eq. 5
        r[idx] = np.maximum(r[p] * np.where(single, ratio_single, ratio_split), min_radius)
    return r


def murray_angle(r_parent: np.ndarray, r_child: np.ndarray) -> np.ndarray:
    """Xu et al. 2007 Eq. 3 (Murray 1926): angle (radians) between the parent and a child of radius r_c <= r_p."""
    rp = np.asarray(r_parent, float)
    rc = np.minimum(np.asarray(r_child, float), rp)
    num = rp**4 + rc**4 - np.maximum(rp**3 - rc**3, 0.0) ** (4.0 / 3.0)
    cos = num / np.maximum(2.0 * rp**2 * rc**2, 1e-300)
    return np.arccos(np.clip(cos, -1.0, 1.0))


def fit_circle(xy: np.ndarray, *, iterations: int = 2) -> tuple[np.ndarray, float]:
    """Least-squares circle (Kasa algebraic fit, then Huber-reweighted refits): ``(centre (2,), radius)``.

    xy : (n, 2) float, n >= 3. Raises ValueError on a degenerate (collinear) configuration.
    """
    xy = np.asarray(xy, float)
    w = np.ones(len(xy))
    centre, radius = None, None
    for it in range(iterations + 1):
        a = np.c_[2 * xy, np.ones(len(xy))] * w[:, None]
        b = (xy**2).sum(1) * w
        sol, *_ = np.linalg.lstsq(a, b, rcond=None)
        centre = sol[:2]
        r2 = sol[2] + centre @ centre
        if not np.isfinite(r2) or r2 <= 0:
            raise ValueError("degenerate circle fit")
        radius = float(np.sqrt(r2))
        if it < iterations:
            res = np.abs(np.linalg.norm(xy - centre, axis=1) - radius)
            s = 1.4826 * np.median(res) + 1e-12
            w = np.minimum(1.0, 1.345 * s / np.maximum(res, 1e-12))  # Huber weights
    return centre, radius


def fit_trunk_radius(points: np.ndarray, base: np.ndarray, axis: np.ndarray, *, length: float,
                     max_radius: float, strict: bool = False) -> tuple[float, np.ndarray]:
    """Radius and axis point of a stem from the points within ``length`` above ``base`` along ``axis``.

    points : (n, 3); base : (3,); axis : (3,) (normalised here); max_radius : the search radius around the axis and
    the upper bound of the answer. Falls back to the median distance to the axis when the circle fit fails or
    leaves [0, max_radius] (``strict``: returns NaN instead). Returns ``(radius, centre (3,))`` with the centre at
    the base height.
    """
    axis = np.asarray(axis, float) / max(np.linalg.norm(axis), 1e-12)
    rel = points - base
    t = rel @ axis
    perp = rel - t[:, None] * axis
    sel = (t >= 0) & (t <= length) & (np.linalg.norm(perp, axis=1) <= max_radius)
    if sel.sum() < 3:
        return float("nan"), np.asarray(base, float)
    u = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    xy = np.c_[perp[sel] @ u, perp[sel] @ v]
    try:
        c, r = fit_circle(xy)
        ok = 0 < r <= max_radius and np.linalg.norm(c) <= max_radius
    except ValueError:
        ok = False
    if not ok:
        if strict:
            return float("nan"), np.asarray(base, float)
        c = np.median(xy, axis=0)
        r = float(np.median(np.linalg.norm(xy - c, axis=1)))
    centre = np.asarray(base, float) + c[0] * u + c[1] * v
    return float(r), centre
