"""Skeleton metrics: radius-relative precision / recall / F1 (Smart-Tree protocol, uc-vision/synthetic-trees) and
tree attributes (branch count, total and mean branch length, height, DBH).

Precision / recall: both skeletons are sampled every ``step`` metres along every edge (each sample carries the
linearly interpolated radius). recall(t) = fraction of ground-truth samples g with a predicted sample closer than
t r_g; precision(t) = fraction of predicted samples p whose nearest ground-truth sample g* is closer than t r_g*;
F1 = 2PR / (P + R) (0 when P + R = 0). An empty predicted skeleton scores P = R = F1 = 0; a single-node one is one
sample.

DBH: diameter of the trunk at height ``breast_height`` above the lowest skeleton node (1.3 m, as TreeQSM), the trunk
being the path that starts at the thickest root and always follows the thickest child; linear interpolation of the
radius along the edge that crosses that height. None when the trunk does not reach it.
"""

from __future__ import annotations

import numpy as np

from plantbench.plant import Skeleton
from plantbench.skeletons import branch_chains, children_lists

__all__ = ["THRESHOLDS", "sample_skeleton", "skeleton_prf", "skeleton_attributes", "dbh"]

THRESHOLDS = (0.5, 1.0, 2.0)


def sample_skeleton(skeleton: Skeleton, step: float = 0.001) -> tuple[np.ndarray, np.ndarray]:
    """Samples every ``step`` metres along each edge (parent end included), plus every node.

    Returns
    -------
    points : (k, 3) float
    radii : (k,) float
    """
    if len(skeleton) == 0:
        return np.zeros((0, 3)), np.zeros(0)
    e = skeleton.edges
    p0, p1 = skeleton.positions[e[:, 0]], skeleton.positions[e[:, 1]]
    r0, r1 = skeleton.radii[e[:, 0]], skeleton.radii[e[:, 1]]
    n = np.maximum(1, np.ceil(np.linalg.norm(p1 - p0, axis=1) / step).astype(np.int64))
    seg = np.repeat(np.arange(len(e)), n)
    t = (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n, n)
    pts = p0[seg] + t[:, None] * (p1[seg] - p0[seg])
    rad = r0[seg] + t * (r1[seg] - r0[seg])
    return np.concatenate([pts, skeleton.positions]), np.concatenate([rad, skeleton.radii])


def skeleton_prf(gt: Skeleton, pred: Skeleton, *, thresholds: tuple[float, ...] = THRESHOLDS, step: float = 0.001
                 ) -> dict[str, float]:
    """Keys 'precision@t', 'recall@t', 'f1@t' for each threshold t (multiples of the local ground-truth radius)."""
    from plantbench.metrics.surface import kdtree, nearest_distances

    g, rg = sample_skeleton(gt, step)
    p, _ = sample_skeleton(pred, step)
    out: dict[str, float] = {}
    if len(g) == 0:
        from plantbench.errors import InputError

        raise InputError("skeleton_prf: the ground-truth skeleton is empty")
    if len(p):
        tg, tp = kdtree(g), kdtree(p)
        d_p, nearest = nearest_distances(g, p, tree=tg, query_tree=tp)
        d_g, _ = nearest_distances(p, g, tree=tp, query_tree=tg)
    for t in thresholds:
        if len(p):
            prec = float(np.mean(d_p < t * rg[nearest]))
            rec = float(np.mean(d_g < t * rg))
        else:
            prec = rec = 0.0
        out[f"precision@{t:.1f}"] = prec
        out[f"recall@{t:.1f}"] = rec
        out[f"f1@{t:.1f}"] = 2 * prec * rec / (prec + rec) if prec + rec > 0 else 0.0
    return out


def dbh(skeleton: Skeleton, *, breast_height: float = 1.3) -> float | None:
    """Trunk diameter (m) at ``breast_height`` above the lowest node; None if the trunk does not reach it."""
    if len(skeleton) == 0:
        return None
    pos, rad = skeleton.positions, skeleton.radii
    z0 = float(pos[:, 2].min())
    kids = children_lists(skeleton)
    roots = skeleton.roots
    node = int(roots[np.argmax(rad[roots])])
    target = z0 + breast_height
    while len(kids[node]):
        nxt = int(kids[node][np.argmax(rad[kids[node]])])
        za, zb = pos[node, 2], pos[nxt, 2]
        if (za - target) * (zb - target) <= 0 and za != zb:
            f = (target - za) / (zb - za)
            return float(2 * (rad[node] + f * (rad[nxt] - rad[node])))
        node = nxt
    return None


def skeleton_attributes(skeleton: Skeleton, *, breast_height: float = 1.3) -> dict[str, float | None]:
    """branch_count (Stava chains), total_length_m, mean_branch_length_m, height_m (max z - min z), dbh_m."""
    if len(skeleton) == 0:
        return {"branch_count": 0.0, "total_length_m": 0.0, "mean_branch_length_m": None, "height_m": 0.0,
                "dbh_m": None}
    e = skeleton.edges
    total = float(np.linalg.norm(skeleton.positions[e[:, 1]] - skeleton.positions[e[:, 0]], axis=1).sum())
    n_branch = len(branch_chains(skeleton))
    z = skeleton.positions[:, 2]
    return {
        "branch_count": float(n_branch),
        "total_length_m": total,
        "mean_branch_length_m": total / n_branch if n_branch else None,
        "height_m": float(z.max() - z.min()),
        "dbh_m": dbh(skeleton, breast_height=breast_height),
    }
