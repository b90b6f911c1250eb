"""Roots and trunk diameters (Guo et al. 2018, section 5.3 and Fig. 9).

"We project the point cloud onto a 2D ground plane along the vertical axis, and measure the density of the
projected points. Then we form a cluster of the points with higher density, and select the cluster centroid as the
root point." For a multi-stem shrub, "we compute k roots by selecting the top k cluster centroids according to
their density". The trunk diameter d_root comes from the points near the root projected on the plane perpendicular
to the stem axis; we fit a circle (reference_impl.common.radii, Kasa fit with Huber reweighting) where the paper
fits a B-spline [65]: the circle's diameter is what Eq. 5 needs.

Density map: a 2D histogram of the lowest slab of the cloud (``GuoParams.root_slab``), smoothed with a Gaussian of
one cell; peaks are local maxima over a window of ``2 * separation + 1`` cells; each peak's cluster is the set of
slab points closer to it than to any other kept peak and within ``separation`` cells.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from reference_impl.common.roots import stem_radius

__all__ = ["RootCluster", "density_roots", "root_axes_and_radii"]


@dataclass(frozen=True)
class RootCluster:
    centroids: np.ndarray
    """(k, 2) float: cluster centroids on the ground plane (x, y)."""
    density: np.ndarray
    """(k,) float: smoothed peak density (points per cell), decreasing."""
    labels: np.ndarray
    """(m,) int: each slab point's cluster, -1 for none."""
    grid: np.ndarray
    """The smoothed density map (for figures)."""


def density_roots(xy: np.ndarray, cell: float, *, k: int | None = None, min_density: float = 0.25,
                  separation: int = 3, max_roots: int = 32) -> RootCluster:
    """Root positions from the ground-plane density of projected points.

    xy : (m, 2) float, m >= 1; cell : map cell edge, metres (> 0); k : number of roots (None: every peak above
    ``min_density`` times the highest, at most ``max_roots``). Fewer than k peaks give fewer roots.
    """
    xy = np.asarray(xy, float)
    lo = xy.min(0) - 2 * cell
    ij = np.floor((xy - lo) / cell).astype(np.int64)
    shape = tuple(ij.max(0) + 3)
    grid = np.zeros(shape)
    np.add.at(grid, (ij[:, 0], ij[:, 1]), 1.0)
    smooth = ndimage.gaussian_filter(grid, 1.0, mode="constant")
    peak = (smooth == ndimage.maximum_filter(smooth, size=2 * separation + 1, mode="constant")) & (smooth > 0)
    pi, pj = np.nonzero(peak)
    dens = smooth[pi, pj]
    order = np.argsort(-dens, kind="stable")
    pi, pj, dens = pi[order], pj[order], dens[order]
    # plateaus give several equal maxima next to each other: keep the first of each window
    keep: list[int] = []
    for a in range(len(pi)):
        if all(max(abs(pi[a] - pi[b]), abs(pj[a] - pj[b])) > separation for b in keep):
            keep.append(a)
    sel = np.asarray(keep, np.int64)
    if k is not None:
        sel = sel[: max(int(k), 1)]
    else:
        sel = sel[dens[sel] >= min_density * dens[sel[0]]][:max_roots]
    centres = lo + (np.stack([pi[sel], pj[sel]], 1) + 0.5) * cell
    d, lab = cKDTree(centres).query(xy, k=1)
    lab = np.where(d <= (separation + 0.5) * cell, lab, -1)
    cent = np.array([xy[lab == c].mean(0) if np.any(lab == c) else centres[c] for c in range(len(sel))])
    return RootCluster(cent.reshape(-1, 2), dens[sel], lab, smooth)


def root_axes_and_radii(points: np.ndarray, heights: np.ndarray, roots_xy: np.ndarray, ground_z: np.ndarray, *,
                        height: float, fit_height: float, fallback: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stem axis and trunk radius at each root (cross-section circle fit).

    points : (n, 3) plant points; heights : (n,) their height above the ground; roots_xy : (k, 2);
    ground_z : (k,) ground height under each root; height : plant height; fit_height : the fit uses the points
    between 1 % and this fraction of the height; fallback : radius when the fit has too few points.
    Returns ``base (k, 3)`` (the root on the ground, moved onto the fitted axis), ``axis (k, 3)`` (unit, upward) and
    ``radius (k,)``.
    """
    k = len(roots_xy)
    base = np.c_[roots_xy, ground_z]
    if k > 1:
        dd, _ = cKDTree(roots_xy).query(roots_xy, k=2)
        half_gap = 0.5 * dd[:, 1]
    else:
        half_gap = np.full(k, np.inf)
    axes = np.tile([0.0, 0.0, 1.0], (k, 1))
    radii = np.full(k, float(fallback))
    lowband = (heights > 0.01 * height) & (heights < fit_height * height)
    for r in range(k):
        reach = min(0.1 * height, half_gap[r])
        near = lowband & (np.linalg.norm(points[:, :2] - roots_xy[r], axis=1) < reach)
        if near.sum() >= 8:
            q = points[near]
            # stem axis: the line through the centroids of the lower and upper halves of the band
            hq = heights[near]
            mid = np.median(hq)
            a, b = q[hq <= mid].mean(0), q[hq > mid].mean(0)
            ax = b - a
            if np.linalg.norm(ax) > 1e-9 and ax[2] > 0.5 * np.linalg.norm(ax):
                axes[r] = ax / np.linalg.norm(ax)
        rad, centre = stem_radius(points, base[r] + axes[r] * 0.01 * height, axes[r],
                                  length=(fit_height - 0.01) * height, max_radius=reach, fallback=fallback)
        radii[r] = rad
        # the root sits on the ground under the fitted axis
        c = centre - axes[r] * 0.01 * height
        base[r, :2] = c[:2] - axes[r, :2] * (c[2] - ground_z[r]) / max(axes[r, 2], 1e-6)
    return base, axes, radii
