"""Point-cloud measures shared by methods and metrics."""

from __future__ import annotations

import numpy as np

from plantbench.errors import InputError
from plantbench.plant import check_shape

__all__ = ["cloud_height", "cloud_base", "BASE_QUANTILE", "median_spacing", "HEIGHT_QUANTILE", "canonical_order",
           "CANONICAL_CELL"]

BASE_QUANTILE = 0.1
"""A cloud's base is read on its lowest tenth (by z): :func:`cloud_base`."""

CANONICAL_CELL = 1e-3
"""Cell of :func:`canonical_order`, metres: far above a coordinate's round-off (a 1e-6 m move changes a point's cell
only within 1e-6 m of a cell face, about 0.6 % of the points), far below any method's neighbourhood."""

HEIGHT_QUANTILE = 0.999
"""A cloud's height is this quantile of its points' z (above z = 0): a few stray points above the crown (mvs
outliers, a bird in a scan) do not set it."""


def cloud_height(points: np.ndarray) -> float:
    """Height of a cloud (n, 3) above the ground plane z = 0: the :data:`HEIGHT_QUANTILE` quantile of z."""
    pts = check_shape("points", points, (-1, 3), "f")
    if not len(pts):
        raise InputError("the cloud is empty: it has no height")
    return float(np.quantile(pts[:, 2], HEIGHT_QUANTILE))


def cloud_base(points: np.ndarray) -> np.ndarray:
    """Where a cloud (n, 3) stands on the ground plane z = 0: the median x and y of its lowest :data:`BASE_QUANTILE`
    of points (by z), at z = 0. A rule any method can apply to its input (the no-data prior stands its stem there):
    it does not know the true root, and a stray point or a leaning stem moves it little."""
    pts = check_shape("points", points, (-1, 3), "f")
    if not len(pts):
        raise InputError("the cloud is empty: it has no base")
    low = pts[pts[:, 2] <= np.quantile(pts[:, 2], BASE_QUANTILE)]
    return np.array([float(np.median(low[:, 0])), float(np.median(low[:, 1])), 0.0])


def median_spacing(points: np.ndarray) -> float:
    """Median distance from each point (n, 3) to its nearest other point, metres (nan with fewer than 2 points)."""
    from scipy.spatial import cKDTree

    pts = check_shape("points", points, (-1, 3), "f")
    if len(pts) < 2:
        return float("nan")
    d, _ = cKDTree(pts).query(pts, k=2)
    return float(np.median(d[:, 1]))


def canonical_order(points: np.ndarray, cell: float = CANONICAL_CELL) -> np.ndarray:
    """An order of the points (n, 3) that depends on where they are, not on the order they came in: by their
    :data:`CANONICAL_CELL` cell (x, then y, then z), and within a cell by exact coordinates. A method that reads its
    cloud in this order gives the same result for any permutation of it (up to exact duplicates, which are
    interchangeable); a move of every point by round-off swaps only points that are neighbours in space, so what a
    method draws by index (RANSAC samples) stays near what it drew. Returns the index array."""
    pts = np.asarray(points, np.float64)
    q = np.floor(pts / cell)
    return np.lexsort((pts[:, 2], pts[:, 1], pts[:, 0], q[:, 2], q[:, 1], q[:, 0]))
