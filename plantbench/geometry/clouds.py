"""Point-cloud measures shared by methods and metrics."""

from __future__ import annotations

import numpy as np

from plantbench.errors import InputError
from plantbench.plant import check_shape

__all__ = ["cloud_height", "median_spacing", "HEIGHT_QUANTILE"]

HEIGHT_QUANTILE = 0.999
"""A cloud's height is this quantile of its points' z (above z = 0): a few stray points above the crown (mvs
outliers, a bird in a scan) do not set it."""


def cloud_height(points: np.ndarray) -> float:
    """Height of a cloud (n, 3) above the ground plane z = 0: the :data:`HEIGHT_QUANTILE` quantile of z."""
    pts = check_shape("points", points, (-1, 3), "f")
    if not len(pts):
        raise InputError("the cloud is empty: it has no height")
    return float(np.quantile(pts[:, 2], HEIGHT_QUANTILE))


def median_spacing(points: np.ndarray) -> float:
    """Median distance from each point (n, 3) to its nearest other point, metres (nan with fewer than 2 points)."""
    from scipy.spatial import cKDTree

    pts = check_shape("points", points, (-1, 3), "f")
    if len(pts) < 2:
        return float("nan")
    d, _ = cKDTree(pts).query(pts, k=2)
    return float(np.median(d[:, 1]))
