"""Roots and trunk diameters (Guo et al. 2018, section 5.3 and Fig. 9).

"We project the point cloud onto a 2D ground plane along the vertical axis, and measure the density of the
projected points. Then we form a cluster of the points with higher density, and select the cluster centroid as the
root point." For a multi-stem shrub, "we compute k roots by selecting the top k cluster centroids according to
their density". The trunk diameter d_root comes from the points near the root projected on the plane perpendicular
to the stem axis; we fit a circle (reference_impl.common.radii, Kasa fit with Huber reweighting) where the paper
fits a B-spline [65]: the circle's diameter is what Eq. 5 needs.

Density map: a 2D histogram of the lowest slab of the cloud (``GuoParams.root_slab``), smoothed with a Gaussian of
one cell. A cluster "of the points with higher density" is a connected region of the cells whose smoothed density is
at least ``min_density`` times the map's highest; its density is its highest cell, its centroid the mean of its slab
points. So a thick trunk, whose surface projects to a ring wider than a few cells, gives one cluster centred on its
axis (a window around the ring's densest cell put the root on the bark: 30 cm off the 44 cm-radius wp_oak trunk).

The stem axis and trunk radius: a cross-section circle fitted about the vertical through the root first, then the
axis through the points within twice that radius of it (so low leaves beside a thin stem do not tilt it: 43 deg on
the laurel's exact-depth cloud, fitted from everything within 10 % of the height), then the circle again about
that axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from reference_impl.common.roots import half_gaps, stem_radius

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
                  max_roots: int = 32) -> RootCluster:
    """Root positions from the ground-plane density of projected points.

    xy : (m, 2) float, m >= 1; cell : map cell edge, metres (> 0); k : number of roots (None: every cluster, at most
    ``max_roots``); min_density : a cluster is a connected region of cells at least this fraction of the densest.
    Clusters come densest first; fewer than k clusters give fewer roots.
    """
    xy = np.asarray(xy, float)
    lo = xy.min(0) - 2 * cell
    ij = np.floor((xy - lo) / cell).astype(np.int64)
    shape = tuple(ij.max(0) + 3)
    grid = np.zeros(shape)
    np.add.at(grid, (ij[:, 0], ij[:, 1]), 1.0)
    smooth = ndimage.gaussian_filter(grid, 1.0, mode="constant")
    regions, n = ndimage.label(smooth >= min_density * smooth.max(), structure=np.ones((3, 3), bool))
    dens = np.asarray(ndimage.maximum(smooth, regions, np.arange(1, n + 1)), float).reshape(-1)
    order = np.argsort(-dens, kind="stable")[: max(int(k), 1) if k is not None else max_roots]
    point_region = regions[ij[:, 0], ij[:, 1]]  # 0: below the threshold
    lab = np.full(len(xy), -1, np.int64)
    cent = np.zeros((len(order), 2))
    for c, r in enumerate(order):
        members = point_region == r + 1
        lab[members] = c
        cent[c] = xy[members].mean(0) if members.any() else \
            lo + (np.argwhere(regions == r + 1).mean(0) + 0.5) * cell
    return RootCluster(cent, dens[order], lab, smooth)


def root_axes_and_radii(points: np.ndarray, heights: np.ndarray, roots_xy: np.ndarray, ground_z: np.ndarray, *,
                        height: float, fit_height: float, fallback: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stem axis and trunk radius at each root (cross-section circle fit).

    points : (n, 3) plant points; heights : (n,) their height above the ground; roots_xy : (k, 2);
    ground_z : (k,) ground height under each root; height : plant height; fit_height : the fit uses the points
    between 1 % and this fraction of the height; fallback : radius when no circle fits. The root is a density
    centroid, inside the stem's cross-section: the fit is tried about the centre of the widest window's circle too
    (:func:`reference_impl.common.roots.stem_radius`'s ``in_stem``).
    Returns ``base (k, 3)`` (the root on the ground, moved onto the fitted axis), ``axis (k, 3)`` (unit, upward) and
    ``radius (k,)``.
    """
    k = len(roots_xy)
    base = np.c_[roots_xy, ground_z]
    half_gap = half_gaps(roots_xy)
    axes = np.tile([0.0, 0.0, 1.0], (k, 1))
    radii = np.full(k, float(fallback))
    lowband = (heights > 0.01 * height) & (heights < fit_height * height)
    up = np.array([0.0, 0.0, 1.0])
    length = (fit_height - 0.01) * height
    for r in range(k):
        reach = min(0.1 * height, half_gap[r])
        fit = stem_radius(points, base[r] + up * 0.01 * height, up, length=length, max_radius=reach, fallback=None,
                          in_stem=True)
        if fit is None:  # no circle: a vertical stem of the fallback radius
            continue
        rad, centre = fit
        # stem axis: the line through the centroids of the lower and upper halves of the band, from the points
        # within twice the fitted radius of the vertical
        near = lowband & (np.linalg.norm(points[:, :2] - centre[:2], axis=1) < 2.0 * rad)
        if near.sum() >= 8:
            q = points[near]
            hq = heights[near]
            mid = np.median(hq)
            a, b = q[hq <= mid].mean(0), q[hq > mid].mean(0)
            ax = b - a
            if np.linalg.norm(ax) > 1e-9 and ax[2] > 0.5 * np.linalg.norm(ax):
                axes[r] = ax / np.linalg.norm(ax)
                start = np.r_[centre[:2], base[r, 2]]
                rad, centre = stem_radius(points, start + axes[r] * 0.01 * height, axes[r], length=length,
                                          max_radius=reach, fallback=fallback, in_stem=True)
        radii[r] = rad
        # the root sits on the ground under the fitted axis
        c = centre - axes[r] * 0.01 * height
        base[r, :2] = c[:2] - axes[r, :2] * (c[2] - ground_z[r]) / max(axes[r, 2], 1e-6)
    return base, axes, radii
