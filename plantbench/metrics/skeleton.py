"""Skeleton metrics: radius-relative precision / recall / F1 (Smart-Tree protocol, uc-vision/synthetic-trees) and
tree attributes (branch count, total and mean branch length, height, DBH).

Precision / recall: both skeletons are sampled every ``step`` metres along every edge (each sample carries the
linearly interpolated radius). recall(t) = fraction of ground-truth samples g with a predicted sample closer than
t r_g; precision(t) = fraction of predicted samples p whose nearest ground-truth sample g* is closer than t r_g*;
F1 = 2PR / (P + R) (0 when P + R = 0). An empty predicted skeleton scores P = R = F1 = 0; a single-node one is one
sample.

Volume-weighted precision / recall at a height-relative tolerance (the headline skeleton fidelity metric, chosen by
``plantbench calibrate``): the same samples, each weighted by the wood it stands for, pi r^2 x the edge length it
covers (node samples weigh 0), and a tolerance tau = f x the ground-truth plant height (f in :data:`HEIGHT_FRACTIONS`).
vrecall(f) = weight of ground-truth samples with a predicted sample within tau / total ground-truth weight;
vprecision(f) = weight of predicted samples (their own radii) within tau of a ground-truth sample / total predicted
weight; vF1 the harmonic mean. Radius-relative tolerances read ~0 for anything made from images (the exact skeleton
jittered by 0.5 % of the height scores F1@1.0 0.02-0.05) and unweighted height-relative ones are passed by a tree of
the species that looks at nothing (twigs fill the crown); weighting by volume makes the trunk and the main limbs, which
a capture does constrain, carry the score. An empty predicted skeleton scores vprecision = vrecall = vF1 = 0; one
with no length (a single node) or no radius has vprecision 0 and vF1 0, its vrecall being the share of the
ground-truth wood within tau of its nodes.

Length-weighted precision / recall at the same tolerances (lprecision, lrecall, lF1): the same samples and
distances, each sample weighted by the edge length it covers alone. A twig weighs as much per metre as the trunk, so
invented branches cost precision in proportion to their length: the exact skeleton with twigs of total length L'
added to its length L, all farther than tau from it, has lprecision L / (L + L') and lrecall 1. Reported beside the
volume-weighted scores for the structure of the crown (:mod:`plantbench.metrics.structure` counts branches). The
degenerate cases are those of the volume-weighted scores.

DBH: diameter of the trunk at height ``breast_height`` above the lowest skeleton node (1.3 m, as TreeQSM), the trunk
being the path that starts at the thickest root and always follows the thickest child; linear interpolation of the
radius along the edge that crosses that height. None when the trunk does not reach it.

Crown projection area: the area of the 2D convex hull of all the skeleton's nodes projected on the ground plane
(x, y), in m^2. Every node counts: no crown base is guessed (the trunk's nodes usually fall inside the hull of the
crown above them). None for fewer than 3 distinct projections or collinear ones (zero area). It needs no ground
truth.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from plantbench.plant import Skeleton, check_shape
from plantbench.skeletons import branch_chains, stem_at_height

__all__ = ["THRESHOLDS", "HEIGHT_FRACTIONS", "STRUCTURE_FRACTION", "OBSERVED_EDGE", "SkeletonSamples", "skeleton_samples", "sample_skeleton",
           "sample_weights", "skeleton_prf", "skeleton_attributes", "dbh", "skeleton_support", "skeleton_coverage",
           "crown_area"]

THRESHOLDS = (0.5, 1.0, 2.0)
"""Radius-relative tolerances of the Smart-Tree protocol (multiples of the local ground-truth radius)."""
HEIGHT_FRACTIONS = (0.005, 0.01, 0.02)
"""Height-relative tolerances of the volume- and length-weighted scores (fractions of the ground-truth plant height)."""
STRUCTURE_FRACTION = 0.01
"""Tolerance of the branch-level scores (:func:`plantbench.metrics.structure.branch_prf`), a fraction of the
ground-truth plant height."""


@dataclass(frozen=True)
class SkeletonSamples:
    """A skeleton sampled every ``step`` metres along each edge (parent end included), plus every node
    (:func:`skeleton_samples`): what the sample-based skeleton metrics need of it, built once per skeleton.

    points : (k, 3) float; radii : (k,) float, linearly interpolated along the edge
    length : (k,) float, the edge length each sample covers; 0 for the node samples, which come last
    edge_samples : how many samples lie on edges (the first ones)
    edge : (edge_samples,) index into ``Skeleton.edges`` of each edge sample's edge
    """

    points: np.ndarray
    radii: np.ndarray
    length: np.ndarray
    edge_samples: int
    edge: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    @functools.cached_property
    def tree(self):
        """k-d tree over the points (:func:`plantbench.metrics.surface.kdtree`), built on first use."""
        from plantbench.metrics.surface import kdtree

        return kdtree(self.points)

    def weights(self, volume: bool = True) -> np.ndarray:
        """:func:`sample_weights`: the covered length, times pi r^2 when ``volume``; 0 for the node samples."""
        if not volume:
            return self.length
        e = self.edge_samples
        return np.concatenate([self.length[:e] * np.pi * self.radii[:e] ** 2, np.zeros(len(self.length) - e)])


def skeleton_samples(skeleton: Skeleton, step: float = 0.001) -> SkeletonSamples:
    """Samples every ``step`` metres along each edge (parent end included), plus every node: see
    :class:`SkeletonSamples`."""
    if len(skeleton) == 0:
        return SkeletonSamples(np.zeros((0, 3)), np.zeros(0), np.zeros(0), 0)
    e = skeleton.edges
    pos, rad = skeleton.positions, skeleton.radii
    p0, r0 = pos[e[:, 0]], rad[e[:, 0]]
    dp, dr = pos[e[:, 1]] - p0, rad[e[:, 1]] - r0
    length = np.linalg.norm(dp, axis=1)
    n = np.maximum(1, np.ceil(length / step).astype(np.int64))
    seg = np.repeat(np.arange(len(e)), n)
    t = (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n, n)
    pts = p0[seg] + t[:, None] * dp[seg]
    return SkeletonSamples(points=np.concatenate([pts, pos]), radii=np.concatenate([r0[seg] + t * dr[seg], rad]),
                           length=np.concatenate([np.repeat(length / n, n), np.zeros(len(skeleton))]),
                           edge_samples=len(pts), edge=seg)


def _samples(skeleton: Skeleton | SkeletonSamples, step: float) -> SkeletonSamples:
    return skeleton if isinstance(skeleton, SkeletonSamples) else skeleton_samples(skeleton, step)


def sample_skeleton(skeleton: Skeleton, step: float = 0.001) -> tuple[np.ndarray, np.ndarray]:
    """Samples every ``step`` metres along each edge (parent end included), plus every node.

    Returns
    -------
    points : (k, 3) float
    radii : (k,) float
    """
    s = skeleton_samples(skeleton, step)
    return s.points, s.radii


def sample_weights(skeleton: Skeleton, step: float = 0.001, *, volume: bool = True) -> np.ndarray:
    """The weight of each sample of :func:`sample_skeleton` (same order): the edge length it covers, times pi r^2
    when ``volume``; 0 for the node samples."""
    return skeleton_samples(skeleton, step).weights(volume)


def _weighted_share(weights: np.ndarray, inside: np.ndarray) -> float:
    total = float(weights.sum())
    return float(weights[inside].sum()) / total if total > 0 else 0.0


def skeleton_prf(gt: Skeleton | SkeletonSamples, pred: Skeleton | SkeletonSamples, *,
                 thresholds: tuple[float, ...] = THRESHOLDS, step: float = 0.001, height: float | None = None,
                 height_fractions: tuple[float, ...] = HEIGHT_FRACTIONS,
                 gt_observed: np.ndarray | None = None) -> dict[str, float]:
    """Keys 'precision@t', 'recall@t', 'f1@t' for each threshold t (multiples of the local ground-truth radius) and,
    when ``height`` (the ground-truth plant height, metres) is given, 'vprecision@f', 'vrecall@f', 'vf1@f'
    (volume-weighted) and 'lprecision@f', 'lrecall@f', 'lf1@f' (length-weighted) for each height fraction f
    (labelled as :func:`plantbench.metrics.points.tau_label` does: '1%').

    With ``gt_observed`` ((e,) the share of each ground-truth edge the capture observed,
    :mod:`plantbench.capture.observed`) and ``height``, also 'vf1_observed@f' (the volume-weighted precision against
    the whole truth with the recall over the observed edges only, those observed at least :data:`OBSERVED_EDGE`) and
    'vrecall_hidden@f' (the recall over the hidden edges' wood farther than the tolerance from the observed: what the
    method had to infer; None when there is none).

    ``gt`` and ``pred`` may be given as their samples (:func:`skeleton_samples`, when the caller shares them with
    other metrics); ``step`` is then theirs."""
    from plantbench.errors import InputError
    from plantbench.metrics.points import tau_label
    from plantbench.metrics.surface import threshold_distances

    g, p = _samples(gt, step), _samples(pred, step)
    if len(g.points) == 0:
        raise InputError("skeleton_prf: the ground-truth skeleton is empty")
    if height is not None and not height > 0:
        raise InputError(f"skeleton_prf: height must be > 0, got {height}")
    taus = [f * height for f in height_fractions] if height is not None else []
    out: dict[str, float] = {}
    if len(p.points):
        d_p, r_p = _pred_to_gt(g, p, taus, max(thresholds, default=0.0))
        d_g = threshold_distances(p.points, g.points, np.concatenate(
            [np.multiply.outer(g.radii, thresholds), np.broadcast_to(taus, (len(g.points), len(taus)))], axis=1),
            tree=p.tree, query_tree=g.tree)
    for t in thresholds:
        if len(p.points):
            prec = float(np.mean(d_p < t * r_p))
            rec = float(np.mean(d_g < t * g.radii))
        else:
            prec = rec = 0.0
        out[f"precision@{t:.1f}"] = prec
        out[f"recall@{t:.1f}"] = rec
        out[f"f1@{t:.1f}"] = 2 * prec * rec / (prec + rec) if prec + rec > 0 else 0.0
    if height is not None:
        for kind, volume in (("v", True), ("l", False)):
            wg, wp = g.weights(volume), p.weights(volume)
            for f, tau in zip(height_fractions, taus):
                prec = _weighted_share(wp, d_p < tau) if len(p.points) else 0.0
                rec = _weighted_share(wg, d_g < tau) if len(p.points) else 0.0
                lab = tau_label(f)
                out[f"{kind}precision@{lab}"] = prec
                out[f"{kind}recall@{lab}"] = rec
                out[f"{kind}f1@{lab}"] = 2 * prec * rec / (prec + rec) if prec + rec > 0 else 0.0
        if gt_observed is not None:
            out.update(_observed_scores(g, gt_observed, d_g if len(p.points) else None, taus, height_fractions,
                                        out))
    return out


OBSERVED_EDGE = 0.5
"""A ground-truth edge counts as observed when the capture observed at least this share of its bark (the rung that
keeps the observed edges, :func:`plantbench.methods.ladder.cut_to_observed`, uses the same cut)."""


def _observed_scores(g: SkeletonSamples, gt_observed: np.ndarray, d_g: np.ndarray | None, taus: list[float],
                     fractions: tuple[float, ...], scores: dict) -> dict[str, float | None]:
    """'vf1_observed@f' and 'vrecall_hidden@f' of :func:`skeleton_prf`; ``d_g``: (k,) the ground-truth samples'
    distances as thresholded there (None without predicted samples).

    An edge is observed when its share is at least :data:`OBSERVED_EDGE`. The hidden wood a method had to infer is
    the unobserved edges' samples farther than the tolerance (plus the sample spacing, which brings in the observed
    edges' end nodes) from every observed sample: a skeleton that only draws the observed wood recovers none of it,
    and the hidden wood within the tolerance of the observed (a twig's first centimetres beside its observed limb) is
    scored by neither metric's recall."""
    from plantbench.metrics.points import tau_label
    from plantbench.metrics.surface import threshold_distances

    share = np.asarray(gt_observed, float)
    if share.ndim != 1 or len(g.edge) != g.edge_samples or (len(g.edge) and int(g.edge.max()) >= len(share)):
        raise ValueError("gt_observed needs one share per ground-truth edge")
    e = g.edge_samples
    w = g.weights(True)[:e]
    seen = share[g.edge] >= OBSERVED_EDGE
    pts = g.points[:e]
    gap = float(g.length[:e].max(initial=0.0))  # samples lie this close along an edge: its end node is within it
    to_seen = threshold_distances(pts[seen], pts, [t + gap for t in taus]) if seen.any() else np.full(e, np.inf)
    ws = w * seen
    out: dict[str, float | None] = {}
    for f, tau in zip(fractions, taus):
        lab = tau_label(f)
        near = d_g[:e] < tau if d_g is not None else np.zeros(e, bool)
        rec = float(ws[near].sum() / ws.sum()) if ws.sum() > 0 else 0.0
        prec = scores[f"vprecision@{lab}"]
        out[f"vf1_observed@{lab}"] = 2 * prec * rec / (prec + rec) if prec + rec > 0 else 0.0
        wh = w * (~seen & (to_seen >= tau + gap))
        out[f"vrecall_hidden@{lab}"] = float(wh[near].sum() / wh.sum()) if wh.sum() > 1e-12 * w.sum() else None
    return out


def _pred_to_gt(g: SkeletonSamples, p: SkeletonSamples, taus: list[float], factor: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """What :func:`skeleton_prf`'s precision compares with its tolerances, per predicted sample: a distance d and a
    radius r such that ``d < t r`` for every radius factor t up to ``factor`` and ``d < tau`` for every tau in
    ``taus`` (the height-relative tolerances) come out as with the distance to the nearest ground-truth sample and
    that sample's radius.

    A searched sample's answer is exact up to the largest tau; beyond it (inf, 0), and exact near a thick
    ground-truth sample (factor r > the largest tau), where a radius test can still pass. The search stops at the
    largest tau: a far query costs the most, and most far ones cannot pass.

    For many samples (:data:`_SETTLE_MIN`) most are settled without a search of their own, as
    :func:`~plantbench.metrics.surface.threshold_distances` settles its queries: consecutive samples lie along an
    edge, and every ``_SETTLE_EVERY``-th one (an anchor) is searched first. A sample q at distance ``gap`` from its
    anchor a (at most ``_SETTLE_GAP``) lies at a distance within ``gap`` of a's; it is settled when no tau falls in
    that range (d = a's distance is on the same side of every tau) and no ground-truth sample thick enough to pass a
    radius test (radius > (d_a - gap) / factor) lies within d_a + gap of it, checked from the anchor with twice the
    gap (then d_q >= factor r_nearest: every radius test fails, and r = 0 says so). A settled sample's d is its
    anchor's distance, a stand-in on the same side of every tau.
    """
    from plantbench.metrics.surface import _WITHIN_MARGIN, nearest_distances

    within = max(taus, default=None)
    n = len(p.points)
    settled = np.zeros(n, bool)
    d = np.full(n, np.inf)
    i = np.full(n, len(g.points), np.int64)
    if within is not None and n >= _SETTLE_MIN:
        settled, d_s, anchors, d_a, i_a = _settle(g, p, np.asarray(taus, float), factor)
        d[settled] = d_s
        ok = d_a <= within * (1 + _WITHIN_MARGIN)  # the anchors' own answers: as the bounded search gives them
        d[anchors[ok]], i[anchors[ok]] = d_a[ok], i_a[ok]
        rest = ~settled
        rest[anchors] = False
        if rest.any():
            d_r, i_r = nearest_distances(g.points, p.points, tree=g.tree, query_tree=p.tree, within=within,
                                         select=rest)
            d[rest], i[rest] = d_r[rest], i_r[rest]
    else:
        d, i = nearest_distances(g.points, p.points, tree=g.tree, query_tree=p.tree, within=within)
    thick = factor * g.radii > within if within is not None else np.zeros(len(g.points), bool)
    far = np.isinf(d) & ~settled
    if far.any() and thick.any():
        reach = factor * float(g.radii.max())
        near_thick = np.isfinite(nearest_distances(g.points[thick], p.points, query_tree=p.tree, within=reach,
                                                   select=far)[0])
        d_t, i_t = nearest_distances(g.points, p.points, tree=g.tree, query_tree=p.tree, within=reach,
                                     select=near_thick)
        d[near_thick], i[near_thick] = d_t[near_thick], i_t[near_thick]
    return d, np.append(g.radii, 0.0)[i]


_SETTLE_MIN = 100_000
"""Predicted samples from which :func:`_pred_to_gt` settles most of them from anchors."""
_SETTLE_EVERY = 16
"""One anchor per this many consecutive samples: fewer anchors are fewer searches; a sample farther than
:data:`_SETTLE_GAP` from its anchor is searched itself."""
_SETTLE_GAP = 0.02
"""Samples farther than this (metres) from their anchor (across an edge's end) are searched themselves."""


def _settle(g: SkeletonSamples, p: SkeletonSamples, taus: np.ndarray, factor: float):
    """The anchors' searches and the samples they settle (:func:`_pred_to_gt`).

    Returns settled (n,) bool, the settled samples' stand-in distances, the anchors' indices and their distances and
    nearest ground-truth samples (exact up to the largest tau plus the gap bound, else inf and len(g.points)).
    """
    from plantbench.metrics.surface import _WITHIN_MARGIN, nearest_distances

    n, gap_max = len(p.points), _SETTLE_GAP
    anchor = np.minimum((np.arange(n) + _SETTLE_EVERY // 2) // _SETTLE_EVERY * _SETTLE_EVERY, n - 1)
    is_anchor = np.zeros(n, bool)
    is_anchor[anchor] = True
    anchors = np.flatnonzero(is_anchor)
    bound = float(taus.max()) * (1 + _WITHIN_MARGIN) + gap_max  # an anchor beyond it: its samples lie beyond the taus
    d_all, i_all = nearest_distances(g.points, p.points, tree=g.tree, query_tree=p.tree, within=bound,
                                     select=is_anchor)
    d_a, i_a = d_all[anchors], i_all[anchors]
    gap = np.linalg.norm(p.points - p.points[anchor], axis=1)
    mine = d_all[anchor]  # each sample's anchor's distance
    found = np.isfinite(mine)
    slack = 1e-9 * (np.where(found, mine, bound) + gap + 1.0)  # rounding of the computed distances and gaps
    lo = np.where(found, mine, bound) - gap - slack
    hi = np.where(found, mine + gap + slack, np.inf)
    settled = ~is_anchor & (gap <= gap_max) & found
    settled &= ~((taus[None, :] >= lo[:, None]) & (taus[None, :] <= hi[:, None])).any(axis=1)
    # no sample thick enough for a radius test near the sample: per anchor, the samples of radius above a level
    # below (d_a - gap_max) / factor, none within d_a + 2 gap_max of the anchor
    clear = np.zeros(len(anchors), bool) if factor > 0 else np.ones(len(anchors), bool)  # (no radius test: clear)
    live = np.isfinite(d_a)
    r_need = (np.where(live, d_a, 0.0) - gap_max - 1e-9) / max(factor, 1e-300)
    positive = g.radii[g.radii > 0]
    base = float(positive.min()) if len(positive) else 1.0
    level = np.floor(np.log2(np.clip(r_need, base, 1e300) / base)).astype(np.int64)
    level -= base * 2.0 ** level > r_need  # (log2 rounded up: the level must not exceed r_need)
    level[~live | (r_need < base) | (factor <= 0)] = -1  # (a sample can pass against any radius, or not found)
    reach = d_a + 2 * gap_max + 1e-9
    for k in np.unique(level[level >= 0]).tolist():
        sel = np.flatnonzero(level == k)
        thick = g.radii > base * 2.0 ** k
        if not thick.any():
            clear[sel] = True
            continue
        near = nearest_distances(g.points[thick], p.points[anchors[sel]], within=float(reach[sel].max()))[0]
        clear[sel] = near > reach[sel]
    settled &= clear[np.searchsorted(anchors, anchor)]
    return settled, mine[settled], anchors, np.where(d_a <= bound, d_a, np.inf), i_a


def skeleton_support(skeleton: Skeleton | SkeletonSamples, observed: np.ndarray, *, tolerances: tuple[float, ...],
                     step: float = 0.001) -> list[float] | None:
    """Share of the skeleton's length within each of ``tolerances`` (metres) of an observed point: the GT-free check.

    skeleton : the reconstruction (or its samples, :func:`skeleton_samples`; ``step`` is then theirs);
    observed : (m, 3) float, the points the capture gave (the scan, or the input cloud).
    A branch through empty space counts against the method although there is no ground truth. Returns one share per
    tolerance (the distances only as far as the tolerances tell them apart), or None when the skeleton has no
    length or there is no observed point.
    """
    from plantbench.metrics.surface import threshold_distances

    obs = check_shape("observed points", observed, (-1, 3), "f")
    if not all(t > 0 for t in tolerances):
        from plantbench.errors import InputError

        raise InputError(f"skeleton_support: tolerances must be > 0, got {tolerances}")
    s = _samples(skeleton, step)
    w = s.weights(volume=False)
    if not len(obs) or not w.sum() > 0:
        return None
    d = threshold_distances(obs, s.points, tolerances, query_tree=s.tree)
    return [_weighted_share(w, d <= t) for t in tolerances]


def skeleton_coverage(skeleton: Skeleton | SkeletonSamples, observed: np.ndarray, *, tolerance: float,
                      step: float = 0.001, neighbours: int = 8) -> float | None:
    """Share of the observed points within ``tolerance`` (metres) of the skeleton's surface: the reverse of
    :func:`skeleton_support`, what of the scan the reconstruction explains (TreeQSM's coverage, the cylinder model's
    fit to the cloud). A point's distance to the surface is, over its ``neighbours`` nearest axis samples (each
    sample at most ``tolerance`` + the largest radius away), the smallest distance to the sample minus the sample's
    radius (the distance to a cylinder's axis minus its radius); a point with no sample that near is not covered.
    A skeleton that leaves part of the crown out leaves those points uncovered, however well what it drew lies on
    the scan. None when the skeleton has no sample or there is no observed point."""
    obs = check_shape("observed points", observed, (-1, 3), "f")
    if not tolerance > 0:
        from plantbench.errors import InputError

        raise InputError(f"skeleton_coverage: tolerance must be > 0, got {tolerance}")
    s = _samples(skeleton, step)
    if not len(obs) or not len(s.points):
        return None
    reach = float(tolerance) + float(s.radii.max(initial=0.0))
    k = min(int(neighbours), len(s.points))
    d, i = s.tree.query(obs, k=k, distance_upper_bound=reach * (1 + 1e-9))
    d, i = d.reshape(len(obs), k), i.reshape(len(obs), k)
    found = np.isfinite(d)
    surface = np.where(found, d - np.append(s.radii, 0.0)[np.where(found, i, len(s.points))], np.inf)
    return float(np.mean(surface.min(axis=1) <= tolerance))


def dbh(skeleton: Skeleton, *, breast_height: float = 1.3) -> float | None:
    """Trunk diameter (m) at ``breast_height`` above the lowest node; None if the trunk does not reach it."""
    if len(skeleton) == 0:
        return None
    at = stem_at_height(skeleton, float(skeleton.positions[:, 2].min()) + breast_height)
    return None if at is None else 2 * at[2]


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


def crown_area(skeleton: Skeleton) -> float | None:
    """Crown projection area (m^2): area of the convex hull of the nodes' (x, y); None for fewer than 3 nodes or
    collinear projections (see the module)."""
    from scipy.spatial import ConvexHull, QhullError

    xy = np.unique(np.asarray(skeleton.positions, float)[:, :2], axis=0)
    if len(xy) < 3:
        return None
    try:
        area = float(ConvexHull(xy).volume)  # in 2D, the hull's "volume" is its area
    except QhullError:  # every point on one line
        return None
    return area if area > 0 else None
