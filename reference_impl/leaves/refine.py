"""Scale-invariant refinement of candidate leaves across all views (Chaurasia and Beardsley 2017, section 4.2).

1. Template: the ``template_leaves`` (50) most confident candidates of all views; the template is an ellipse whose
   major-to-minor axis ratio is their median length-to-width ratio (enclosing-ellipse axes), at unit length.
2. Candidates are processed in decreasing confidence (``confidence_bins`` = 25 bins) and, within a bin, decreasing
   size. For each: the template, scaled to the candidate (length = min(major axis, ratio x minor axis): a conjoined
   candidate is too long or too wide, not both; but at least the expected leaf length (the species hint) and the
   median length of the most confident candidates,
   so that a fragment of a leaf grows to the whole leaf instead of becoming a leaf of its own: our leaves are small
   and occluded, and most candidates are fragments) and aligned with its major axis and plane, is registered to the
   candidate's points by rigid point-to-point ICP (Open3D, 300 iterations, correspondence distance delta_plane),
   run from the candidate's points to the template and inverted: each observed point is pulled onto the leaf, and
   the template's unobserved part weighs nothing (a candidate has tens of points, the template tens of thousands:
   wp_conifer's mvs cloud, median 21 against 22.7k);
   the scene points (all views) within ``capture_distance x delta_plane`` of the placed template that no earlier
   leaf claimed form the leaf. This drops spurious geometry and pulls in points from other views.
3. De-duplication: a candidate whose own points were already claimed (``duplicate_fraction``) is the same leaf seen
   from another view, and is skipped as ``duplicate``.
"""

from __future__ import annotations

import numpy as np

from .params import LeafParams
from .segment import Candidate

__all__ = ["template_ratio", "template_points", "processing_order", "points_near", "refine_candidates"]


def template_ratio(candidates: list[Candidate], count: int) -> float:
    """Median length-to-width ratio (major / minor enclosing-ellipse axis) of the ``count`` most confident."""
    if not candidates:
        return 2.0
    conf = np.array([c.confidence for c in candidates])
    top = np.argsort(-conf, kind="stable")[:count]
    return float(np.median([candidates[i].semi_axes[0] / candidates[i].semi_axes[1] for i in top]))


def template_points(ratio: float, spacing: float) -> np.ndarray:
    """(k, 3) grid points filling the unit-length ellipse template (semi-axes 1/2 and 1/(2 ratio)), z = 0, centred
    at the origin, major axis along x; ``spacing`` in leaf lengths."""
    a, b = 0.5, 0.5 / ratio
    xs = np.arange(-a, a + 1e-12, spacing)
    ys = np.arange(-b, b + 1e-12, spacing)
    gx, gy = np.meshgrid(xs, ys - ys.mean())
    inside = (gx / a) ** 2 + (gy / b) ** 2 <= 1.0
    return np.column_stack([gx[inside], gy[inside], np.zeros(inside.sum())])


def processing_order(confidence: np.ndarray, size: np.ndarray, bins: int) -> np.ndarray:
    """Candidate order: confidence binned into ``bins`` equal bins over [0, 1], bins in decreasing confidence,
    within a bin decreasing size."""
    b = np.minimum((np.asarray(confidence) * bins).astype(np.int64), bins - 1)
    return np.lexsort((-np.asarray(size, float), -b))


def points_near(tree, points: np.ndarray, placed: np.ndarray, radius: float) -> np.ndarray:
    """Sorted indices of the ``points`` (indexed by the cKDTree ``tree``) within ``radius`` of any of ``placed``: the
    points in one ball around the placed template that a k-d tree of the template finds within ``radius``, without a
    Python list per template point."""
    from scipy.spatial import cKDTree

    if len(placed) == 0:
        return np.zeros(0, np.int64)
    centre = placed.mean(axis=0)
    reach = float(np.sqrt(((placed - centre) ** 2).sum(axis=1).max())) + radius
    near = np.sort(np.asarray(tree.query_ball_point(centre, reach * (1 + 1e-9) + 1e-12), np.int64))
    hit = cKDTree(placed).query_ball_point(points[near], radius, return_length=True) > 0
    return near[hit]


def refine_candidates(points: np.ndarray, candidates: list[Candidate], *, delta: float, params: LeafParams,
                      leaf_length: float = 0.0) -> tuple[list[np.ndarray], dict[str, int], float]:
    """Leaves from candidates (section 4.2).

    points : (n, 3) float, the scene points of all views (candidates index into it)
    leaf_length : expected leaf length (metres; the species hint), the template's smallest length (0: none)
    returns : one (k_i,) index array per extracted leaf, skipped candidates per reason, the template ratio
    """
    import open3d as o3d
    from scipy.spatial import cKDTree

    skipped = {"duplicate": 0, "few_points_after_icp": 0}
    if not candidates:
        return [], skipped, 2.0
    ratio = template_ratio(candidates, params.template_leaves)
    conf_all = np.array([c.confidence for c in candidates])
    top = np.argsort(-conf_all, kind="stable")[: params.template_leaves]
    typical = max(float(np.median([2 * candidates[i].semi_axes[0] for i in top])), leaf_length)
    radius = params.capture_distance * delta
    order = processing_order(np.array([c.confidence for c in candidates]), np.array([c.area for c in candidates]),
                             params.confidence_bins)
    tree = cKDTree(points)
    claimed = np.zeros(len(points), bool)
    reg = o3d.pipelines.registration
    criteria = reg.ICPConvergenceCriteria(max_iteration=params.icp_iterations)
    estimator = reg.TransformationEstimationPointToPoint()
    leaves: list[np.ndarray] = []
    for k in order:
        cand = candidates[k]
        own = cand.index
        if claimed[own].mean() >= params.duplicate_fraction:
            skipped["duplicate"] += 1
            continue
        a, b = cand.semi_axes
        length = max(min(2 * a, ratio * 2 * b), typical)
        tmpl = template_points(ratio, min(0.5 * radius / length, 0.05)) * length
        inv = np.eye(4)  # world -> template frame: the candidate's points are registered to the template
        inv[:3, :3] = cand.frame
        inv[:3, 3] = -cand.frame @ cand.centre
        src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[own[~claimed[own]]]))
        tgt = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(tmpl))
        res = reg.registration_icp(src, tgt, delta, inv, estimator, criteria)
        tr = np.linalg.inv(np.asarray(res.transformation))
        idx = points_near(tree, points, tmpl @ tr[:3, :3].T + tr[:3, 3], radius)
        idx = idx[~claimed[idx]]
        if len(idx) < params.min_candidate_points:
            skipped["few_points_after_icp"] += 1
            continue
        claimed[idx] = True
        leaves.append(idx)
    return leaves, skipped, ratio
