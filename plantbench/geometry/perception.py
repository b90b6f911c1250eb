"""Perception cones of space colonisation (Palubicki et al. 2009), shared by the generator's growth
(:mod:`plantbench.generate.palubicki`) and point-cloud-guided growth (``reference_impl.guo.growth``).

A bud at ``p`` with unit direction ``d`` perceives a marker ``x`` when ``|x - p| <= radius`` and the angle between
``x - p`` and ``d`` is at most half the cone's opening; a marker perceived by several buds goes to the closest one.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["assign_markers"]


def assign_markers(markers: np.ndarray, bud_pos: np.ndarray, bud_dir: np.ndarray, *, radius: float,
                   cos_half_angle: float, neighbours: int = 8, penalty: np.ndarray | None = None) -> np.ndarray:
    """Each marker's bud: the closest bud within ``radius`` whose perception cone holds the marker, else -1.

    markers : (m, 3) float; bud_pos : (b, 3) float; bud_dir : (b, 3) float unit cone axes
    penalty : (b,) float, optional
        Added to a bud's distance when a marker chooses between the buds that perceive it (a tie-break between
        buds at the same place); default: none, the closest bud wins (the first found on ties).

    Only the ``neighbours`` closest buds of each marker are examined (exact when that many cover the radius).
    returns : (m,) int
    """
    nb = len(bud_pos)
    out = np.full(len(markers), -1, np.int64)
    if nb == 0 or len(markers) == 0:
        return out
    kk = min(neighbours, nb)
    dist, ind = cKDTree(bud_pos).query(markers, k=kk, distance_upper_bound=radius)
    if kk == 1:
        dist, ind = dist[:, None], ind[:, None]
    rows = np.flatnonzero(np.isfinite(dist[:, 0]))  # markers with at least one bud in range
    dist, ind = dist[rows], ind[rows]
    valid = np.isfinite(dist) & (dist > 1e-12)
    safe = np.where(valid, ind, 0)
    vec = markers[rows, None, :] - bud_pos[safe]
    cosang = (vec * bud_dir[safe]).sum(axis=2) / np.where(valid, dist, 1.0)
    ok = valid & (cosang >= cos_half_angle)
    if penalty is None:  # candidates come closest first: the first one whose cone holds the marker
        best = np.argmax(ok, axis=1)
    else:
        best = np.argmin(np.where(ok, dist + penalty[safe], np.inf), axis=1)
    has = ok[np.arange(len(rows)), best]
    out[rows[has]] = safe[has, best[has]]
    return out
