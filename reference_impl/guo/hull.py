"""Occluded crowns (Guo et al. 2018, section 6.1, Fig. 8): extra markers inside the crown's convex hull.

"First, we compute the convex hull of the crown using the reconstructed 3D points. Then we perform Poisson-disk
sampling [66] to generate randomly and uniformly distributed points in the interior of the convex hull. Guided by
these overdispersed points, our rule-based growth creates branches to fill the crown space."

- :func:`crown_mask`: the crown is the cloud above the crown base, the lowest height slab whose horizontal spread
  exceeds a third of the widest slab's (so a bare trunk below the crown does not stretch the hull down to the
  ground) [S: the paper does not say how the crown is delimited].
- :func:`poisson_disk_in_hull`: dart throwing in the hull, vectorised: candidates drawn uniformly in the bounding
  box, kept if inside the hull (behind every facet plane), then rounds of conflict removal (of every pair closer
  than the spacing, the later candidate goes) and refills until a round adds nothing or the cap is reached.
- :func:`shell_ratio`: how much the crown points hug the hull's surface: the median depth (distance inside the
  hull) of the crown points over that of uniform interior samples. About 1 when points fill the crown, small for a
  shell of visible leaves around an empty interior: the 'auto' test for an occluded crown [S].
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

__all__ = ["crown_mask", "poisson_disk_in_hull", "hull_depth", "uniform_in_hull", "shell_ratio"]


def crown_mask(points: np.ndarray, heights: np.ndarray, *, bins: int = 50, spread_fraction: float = 1 / 3
               ) -> np.ndarray:
    """(n,) bool: points at or above the crown base. points : (n, 3); heights : (n,) above the ground."""
    top = float(heights.max())
    if top <= 0:
        return np.ones(len(points), bool)
    b = np.clip((heights / top * bins).astype(np.int64), 0, bins - 1)
    spread = np.zeros(bins)
    for i in np.unique(b):
        q = points[b == i, :2]
        if len(q) >= 3:
            spread[i] = np.percentile(np.linalg.norm(q - q.mean(0), axis=1), 90)
    base_bin = int(np.argmax(spread >= spread_fraction * spread.max()))
    return b >= base_bin


def poisson_disk_in_hull(points: np.ndarray, spacing: float, rng: np.random.Generator, *, max_samples: int = 60_000,
                         rounds: int = 4) -> tuple[np.ndarray, float]:
    """Poisson-disk samples (no two closer than the spacing) inside the convex hull of ``points``.

    points : (n, 3) float. The spacing grows when the hull would need more than ``max_samples`` samples.
    Returns ``samples (m, 3)`` and the spacing used. A flat or degenerate hull gives no samples.
    """
    if len(points) < 4:
        return np.zeros((0, 3)), spacing
    try:
        hull = ConvexHull(points)
    except QhullError:
        return np.zeros((0, 3)), spacing
    volume = float(hull.volume)
    # a maximal Poisson-disk set of spacing s has about 0.7 / s^3 points per unit volume (random close packing)
    if 0.7 * volume / spacing**3 > max_samples:
        spacing = (0.7 * volume / max_samples) ** (1 / 3)
    eq = hull.equations
    lo, hi = points.min(0), points.max(0)
    box = float(np.prod(np.maximum(hi - lo, 1e-12)))
    target = 0.7 * volume / spacing**3
    kept = np.zeros((0, 3))
    for _ in range(rounds):
        need = int(min(4 * target * box / max(volume, 1e-300), 4_000_000))
        cand = lo + rng.random((max(need, 16), 3)) * (hi - lo)
        cand = cand[_inside(eq, cand)]
        if len(kept):
            d, _ = cKDTree(kept).query(cand, k=1, distance_upper_bound=spacing)
            cand = cand[~np.isfinite(d)]
        alive = np.ones(len(cand), bool)
        for _ in range(32):  # conflict removal: the later of every close pair goes
            idx = np.flatnonzero(alive)
            pairs = cKDTree(cand[idx]).query_pairs(spacing, output_type="ndarray")
            if len(pairs) == 0:
                break
            alive[idx[pairs.max(axis=1)]] = False
        new = cand[alive]
        if len(new) == 0:
            break
        kept = np.concatenate([kept, new])
        if len(kept) >= max_samples:
            kept = kept[:max_samples]
            break
    return kept, spacing


def _inside(equations: np.ndarray, query: np.ndarray, chunk: int = 65536) -> np.ndarray:
    """(m,) bool: inside the hull whose facets are ``equations`` (n . x + b <= 0 inside)."""
    out = np.zeros(len(query), bool)
    for s in range(0, len(query), chunk):
        q = query[s:s + chunk]
        out[s:s + chunk] = np.all(q @ equations[:, :3].T + equations[:, 3] <= 0, axis=1)
    return out


def hull_depth(hull_points: np.ndarray, query: np.ndarray) -> np.ndarray:
    """(m,) distance from each query point to the boundary of the convex hull of ``hull_points`` (negative
    outside). hull_points : (n, 3), n >= 4, not coplanar."""
    eq = ConvexHull(hull_points).equations           # n . x + b <= 0 inside, |n| = 1
    return np.min(-(query @ eq[:, :3].T + eq[:, 3]), axis=1)


def uniform_in_hull(points: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """About ``count`` uniform samples inside the convex hull of ``points`` (rejection from the bounding box)."""
    hull = ConvexHull(points)
    lo, hi = points.min(0), points.max(0)
    box = float(np.prod(np.maximum(hi - lo, 1e-12)))
    need = int(min(count * box / max(hull.volume, 1e-300) + 16, 50 * count))
    cand = lo + rng.random((need, 3)) * (hi - lo)
    return cand[_inside(hull.equations, cand)]


def shell_ratio(crown: np.ndarray, rng: np.random.Generator, *, max_points: int = 4000) -> float:
    """Median hull depth of (a subsample of) the crown points over the median depth of uniform samples of the hull.
    1.0 when the hull is degenerate."""
    if len(crown) < 4:
        return 1.0
    sub = crown[rng.choice(len(crown), min(max_points, len(crown)), replace=False)]
    try:
        sam = uniform_in_hull(crown, max_points, rng)
        if len(sam) == 0:
            return 1.0
        d_pts = np.median(hull_depth(crown, sub))
        d_sam = np.median(hull_depth(crown, sam))
    except QhullError:
        return 1.0
    return float(d_pts / d_sam) if d_sam > 0 else 1.0
