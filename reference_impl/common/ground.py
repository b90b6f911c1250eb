"""Ground removal for scans (docs/design.md, Conventions: Z up, ground plane at z = 0).

A simulated scan's ``points.ply`` holds raw coordinates, ground hits included; the ``mvs`` stage has already removed
the ground. :func:`remove_ground` handles both: it fits a near-horizontal plane to the lowest slab of the cloud with
RANSAC (seeded) and removes the points within ``tolerance`` of it. A plane counts as ground only when its inliers
spread over more than half the cloud's horizontal extent and fill at least 30 % of it (cells of 1/16 of the extent);
otherwise (no ground in the cloud) the plane is the contract's z = 0 and only points far below it are dropped.
Methods root their skeletons on the plane. Parameter values are our choices (no paper prescribes them), scaled by
the plant height.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GroundParams", "Ground", "remove_ground"]


@dataclass(frozen=True)
class GroundParams:
    slab_fraction: float = 0.05
    """Height of the lowest slab searched for the ground, as a fraction of the cloud's height."""
    inlier_fraction: float = 0.004
    """RANSAC inlier distance, fraction of the cloud's height (4 mm for a 1 m plant; above typical range noise)."""
    tolerance_fraction: float = 0.012
    """Points closer than this to the plane (fraction of height) are removed as ground; also at least 4 robust
    standard deviations of the inliers' residuals, so noisy ground goes too."""
    max_tilt_deg: float = 10.0
    """Largest angle between a candidate plane's normal and +Z (the contract's ground is horizontal)."""
    iterations: int = 200
    """RANSAC plane hypotheses."""
    fill_grid: int = 16
    """The inliers' extent is cut into cells of 1/16 of its longer side ..."""
    fill_fraction: float = 0.3
    """... and the plane is ground only if the inliers occupy at least this fraction of them (a sheet, not the rings
    of stem bases)."""


@dataclass(frozen=True)
class Ground:
    """A fitted ground plane ``z = a x + b y + c`` and the removal result."""

    coef: np.ndarray
    """(3,) float: a, b, c."""
    keep: np.ndarray
    """(n,) bool: points above the ground band."""
    found: bool
    """True when a sheet of ground points was found (else the plane sits at the stems' base)."""

    def height(self, points: np.ndarray) -> np.ndarray:
        """(n,) signed height of points above the plane (vertical distance)."""
        return points[:, 2] - (self.coef[0] * points[:, 0] + self.coef[1] * points[:, 1] + self.coef[2])

    def project(self, points: np.ndarray) -> np.ndarray:
        """Points moved vertically onto the plane."""
        out = np.array(points, float, copy=True)
        out[:, 2] = self.coef[0] * out[:, 0] + self.coef[1] * out[:, 1] + self.coef[2]
        return out


def _plane_z(p: np.ndarray) -> np.ndarray | None:
    """Plane z = a x + b y + c through three points, or None if degenerate/vertical."""
    a = np.c_[p[:, :2], np.ones(3)]
    if abs(np.linalg.det(a)) < 1e-12:
        return None
    return np.linalg.solve(a, p[:, 2])


def remove_ground(points: np.ndarray, rng: np.random.Generator, params: GroundParams = GroundParams()) -> Ground:
    """Fit the ground plane and flag the points above it.

    points : (n, 3) float, n >= 1. Returns a :class:`Ground`; ``points[ground.keep]`` is the plant.
    """
    z = points[:, 2]
    # the 5th lowest point (robust to a few stray returns below the ground; a percentile is not: a thin trunk holds
    # far less than 1 % of a crown's points) and the 99.5th percentile
    zlo = float(np.partition(z, min(5, len(z) - 1))[min(5, len(z) - 1)])
    zhi = float(np.percentile(z, 99.5))
    height = max(zhi - zlo, 1e-6)
    slab = np.flatnonzero(z < zlo + params.slab_fraction * height)
    if len(slab) < 3:
        slab = np.argsort(z)[: min(len(z), 3)]
    sp = points[slab]
    thr = params.inlier_fraction * height
    max_tilt = np.tan(np.radians(params.max_tilt_deg))
    best, best_count = np.array([0.0, 0.0, float(np.min(z))]), -1
    if len(sp) >= 3:
        for _ in range(params.iterations):
            coef = _plane_z(sp[rng.choice(len(sp), 3, replace=False)])
            if coef is None or np.hypot(coef[0], coef[1]) > max_tilt:
                continue
            count = int(np.sum(np.abs(sp[:, 2] - sp[:, :2] @ coef[:2] - coef[2]) < thr))
            if count > best_count:
                best, best_count = coef, count
    res = sp[:, 2] - sp[:, :2] @ best[:2] - best[2]
    inl = np.abs(res) < thr
    if inl.sum() >= 3:  # least-squares refinement on the inliers
        a = np.c_[sp[inl, :2], np.ones(inl.sum())]
        ref = np.linalg.lstsq(a, sp[inl, 2], rcond=None)[0]
        if np.hypot(ref[0], ref[1]) <= max_tilt:
            best = ref
        res = sp[:, 2] - sp[:, :2] @ best[:2] - best[2]
        inl = np.abs(res) < thr
    mad = 1.4826 * float(np.median(np.abs(res[inl]))) if inl.any() else 0.0
    tol = max(params.tolerance_fraction * height, 4.0 * mad)
    # a ground sheet spreads wide and fills its extent; the bases of stems do neither (rings, however far apart)
    found = False
    if inl.sum() >= 20:
        xy = sp[inl, :2]
        ext_in = np.ptp(xy, axis=0)
        ext_all = np.ptp(points[:, :2], axis=0).max()
        if ext_in.max() > 0.5 * ext_all:
            cells = np.floor((xy - xy.min(0)) / (ext_in.max() / params.fill_grid + 1e-12)).astype(np.int64)
            occupied = len(np.unique(cells, axis=0))
            side = ext_in.max() / params.fill_grid + 1e-12
            possible = np.prod(np.minimum(np.ceil(ext_in / side), params.fill_grid))
            found = bool(occupied >= params.fill_fraction * max(possible, 1))
    if not found:
        # no ground sheet (e.g. the mvs stage removed it): the contract's plane z = 0, unless the cloud sits clearly
        # elsewhere; keep everything except points far below it
        best = np.array([0.0, 0.0, 0.0 if abs(zlo) < params.slab_fraction * height else float(zlo)])
        hgt = points[:, 2] - best[2]
        return Ground(best, hgt > -tol, False)
    hgt = points[:, 2] - points[:, :2] @ best[:2] - best[2]
    return Ground(np.asarray(best, float), hgt > tol, True)
