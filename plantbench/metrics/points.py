"""Point-cloud and surface accuracy: DTU accuracy / completeness / Chamfer and Tanks-and-Temples precision /
recall / F-score at thresholds tau given as fractions of the plant height, for the whole plant and for wood and
foliage separately.

Definitions (distances d in metres, reported in cm):

* accuracy = mean over reconstructed points of min(d(r, GT), max_dist); completeness = mean over ground-truth points of
  min(d(g, R), max_dist); Chamfer = (accuracy + completeness) / 2, unsquared (DTU; distances are *clipped* at
  ``max_dist`` instead of dropped, so far-away junk cannot vanish from the score).
* precision(tau) = fraction of reconstructed points within tau of the ground truth; recall(tau) = fraction of
  ground-truth points within tau of the reconstruction; F = 2PR / (P + R), 0 when P + R = 0 (Tanks and Temples).
* Per part (wood, foliage): ground-truth points carry a label; a reconstructed point belongs to the part of its
  nearest ground-truth point. Precision and accuracy use the reconstructed points of that part, recall and
  completeness the ground-truth points of that part.

Degenerate input: no reconstructed point (in a part): precision = recall = F = 0, accuracy None, completeness =
max_dist, Chamfer None. A part absent from the ground truth: all its values None.
"""

from __future__ import annotations

import numpy as np

from plantbench.errors import InputError
from plantbench.metrics.surface import kdtree, nearest_distances
from plantbench.plant import check_shape

__all__ = ["TAU_FRACTIONS", "tau_label", "cloud_metrics"]

TAU_FRACTIONS = (0.005, 0.01, 0.02)
PARTS = {"wood": 0, "foliage": 1}


def tau_label(fraction: float) -> str:
    """0.005 -> '0.5%', 0.01 -> '1%'."""
    return f"{fraction * 100:g}%"


def _prf(d_pred: np.ndarray, d_gt: np.ndarray, tau: float) -> tuple[float, float, float]:
    p = float(np.mean(d_pred < tau)) if len(d_pred) else 0.0
    r = float(np.mean(d_gt < tau)) if len(d_gt) else 0.0
    f = 2 * p * r / (p + r) if p + r > 0 else 0.0
    return p, r, f


def cloud_metrics(gt_points: np.ndarray, gt_labels: np.ndarray, pred_points: np.ndarray, *, height: float,
                  tau_fractions: tuple[float, ...] = TAU_FRACTIONS, max_dist_fraction: float = 0.1,
                  gt_tree=None) -> dict[str, float | None]:
    """Accuracy, completeness, Chamfer and P/R/F at each tau for 'all', 'wood' and 'foliage'.

    Parameters
    ----------
    gt_points : (m, 3) float, dense sample of the ground-truth surface (m >= 1)
    gt_labels : (m,) int, 0 wood, 1 foliage
    pred_points : (n, 3) float, reconstructed points (or samples of the reconstructed surface)
    height : ground-truth plant height in metres (> 0); tau = fraction * height, max_dist = max_dist_fraction * height
    gt_tree : a k-d tree over ``gt_points`` (:func:`~plantbench.metrics.surface.kdtree`) when the caller scores
        several reconstructions against them; built here otherwise

    Returns
    -------
    dict with keys '{part}.accuracy_cm', '{part}.completeness_cm', '{part}.chamfer_cm', '{part}.precision@{tau}',
    '{part}.recall@{tau}', '{part}.fscore@{tau}' (tau as in :func:`tau_label`).
    """
    gt = check_shape("ground-truth points", gt_points, (-1, 3), "f")
    labels = check_shape("ground-truth labels", gt_labels, (len(gt),), "i")
    pred = check_shape("reconstructed points", pred_points, (-1, 3), "f")
    if len(gt) == 0:
        raise InputError("cloud_metrics: the ground-truth point set is empty")
    if not height > 0:
        raise InputError(f"cloud_metrics: plant height must be > 0, got {height}")
    max_dist = max_dist_fraction * height
    gt_tree = kdtree(gt) if gt_tree is None else gt_tree  # each set's tree answers the other's queries, orders its own
    pred_tree = kdtree(pred) if len(pred) else None
    d_pred, nearest = nearest_distances(gt, pred, tree=gt_tree, query_tree=pred_tree)
    # completeness clips at max_dist and recall compares with tau: a ground-truth point beyond both may stop early
    d_gt = nearest_distances(pred, gt, tree=pred_tree, query_tree=gt_tree,
                             within=max([max_dist] + [t * height for t in tau_fractions]))[0] if len(pred) \
        else np.full(len(gt), np.inf)
    out: dict[str, float | None] = {}
    for part, sel_gt, sel_pred in [("all", slice(None), slice(None))] + [
        (name, labels == lab, labels[nearest] == lab if len(pred) else np.zeros(0, bool))
        for name, lab in PARTS.items()
    ]:
        dg, dp = d_gt[sel_gt], d_pred[sel_pred]
        keys = ["accuracy_cm", "completeness_cm", "chamfer_cm"] + [
            f"{k}@{tau_label(t)}" for t in tau_fractions for k in ("precision", "recall", "fscore")]
        if len(dg) == 0:
            out.update({f"{part}.{k}": None for k in keys})
            continue
        acc = float(np.minimum(dp, max_dist).mean() * 100) if len(dp) else None
        comp = float(np.minimum(dg, max_dist).mean() * 100)
        out[f"{part}.accuracy_cm"] = acc
        out[f"{part}.completeness_cm"] = comp
        out[f"{part}.chamfer_cm"] = 0.5 * (acc + comp) if acc is not None else None
        for t in tau_fractions:
            p, r, f = _prf(dp, dg, t * height)
            lab = tau_label(t)
            out[f"{part}.precision@{lab}"], out[f"{part}.recall@{lab}"], out[f"{part}.fscore@{lab}"] = p, r, f
    return out
