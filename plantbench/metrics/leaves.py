"""Leaf counting (CVPPP conventions) and leaf detection by centroid matching.

* DiC = N_pred - N_gt, |DiC|, relative error |DiC| / N_gt, accuracy = max(0, 1 - |DiC| / N_gt). With N_gt = 0 the
  relative error is None and the accuracy 1 when N_pred = 0, else 0.
* Detection: ground-truth and predicted leaf centroids are matched one-to-one by the Hungarian algorithm on
  Euclidean distance; a pair counts when its distance is at most ``radius`` (half the median ground-truth leaf
  length in :func:`plantbench.metrics.evaluate.evaluate`). Precision = matches / N_pred, recall = matches / N_gt,
  F1 = 2PR / (P + R); 0 where a denominator is 0 (both empty: 1).
"""

from __future__ import annotations

import numpy as np

from plantbench.errors import InputError
from plantbench.plant import check_shape

__all__ = ["leaf_count_metrics", "leaf_detection"]


def leaf_count_metrics(n_gt: int, n_pred: int) -> dict[str, float | None]:
    """Keys: count_gt, count_pred, dic, abs_dic, rel_error, accuracy."""
    if n_gt < 0 or n_pred < 0:
        raise InputError(f"leaf counts must be >= 0, got {n_gt}, {n_pred}")
    dic = n_pred - n_gt
    if n_gt:
        rel: float | None = abs(dic) / n_gt
        acc = max(0.0, 1.0 - abs(dic) / n_gt)
    else:
        rel, acc = None, 1.0 if n_pred == 0 else 0.0
    return {"count_gt": float(n_gt), "count_pred": float(n_pred), "dic": float(dic), "abs_dic": float(abs(dic)),
            "rel_error": rel, "accuracy": acc}


def leaf_detection(gt_centroids: np.ndarray, pred_centroids: np.ndarray, *, radius: float) -> dict[str, float]:
    """Precision, recall, F1 and number of matches of predicted leaf centroids.

    gt_centroids : (m, 3) float; pred_centroids : (n, 3) float; radius : match distance in metres (> 0)
    """
    from scipy.optimize import linear_sum_assignment
    from scipy.spatial.distance import cdist

    g = check_shape("ground-truth leaf centroids", gt_centroids, (-1, 3), "f")
    p = check_shape("predicted leaf centroids", pred_centroids, (-1, 3), "f")
    if not radius > 0:
        raise InputError(f"leaf_detection: radius must be > 0, got {radius}")
    matched = 0
    if len(g) and len(p):
        d = cdist(g, p)
        cost = np.where(d <= radius, d, 1e6 + d)  # pairs beyond the radius only when nothing better exists
        r, c = linear_sum_assignment(cost)
        matched = int(np.count_nonzero(d[r, c] <= radius))
    if not len(g) and not len(p):
        return {"precision": 1.0, "recall": 1.0, "f1": 1.0, "matched": 0.0}
    prec = matched / len(p) if len(p) else 0.0
    rec = matched / len(g) if len(g) else 0.0
    f1 = 2 * prec * rec / (prec + rec) if prec + rec > 0 else 0.0
    return {"precision": prec, "recall": rec, "f1": f1, "matched": float(matched)}
