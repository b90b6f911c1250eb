"""Minimum-volume enclosing ellipses (Khachiyan 1996; Chaurasia and Beardsley 2017, refs. [23, 26]), batched
over point sets.

Chaurasia and Beardsley 2017 use the 2D minimum-volume enclosing ellipse of a leaf's points three times: the candidate
confidence (fraction of the ellipse the leaf fills, section 4.1), the base and apex (its major-axis ends, section 5.1)
and the scanline occlusion weights (Eq. 10).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plantbench.errors import InputError
from plantbench.plant import check_shape

__all__ = ["Ellipse", "khachiyan", "min_volume_ellipse", "min_volume_ellipses", "ellipse_extent", "ray_extent"]


@dataclass(frozen=True)
class Ellipse:
    """The ellipse ``(x - centre)^T A (x - centre) <= 1`` in 2D.

    centre : (2,) float; A : (2, 2) float, symmetric positive definite
    """

    centre: np.ndarray
    A: np.ndarray

    @property
    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Semi-axis lengths (2,) (major first) and their unit directions as columns (2, 2)."""
        w, v = np.linalg.eigh(self.A)  # ascending eigenvalues: the smallest is the major axis
        return 1.0 / np.sqrt(w), v

    @property
    def semi_axes(self) -> tuple[float, float]:
        ax, _ = self.axes
        return float(ax[0]), float(ax[1])

    @property
    def area(self) -> float:
        return float(np.pi / np.sqrt(np.linalg.det(self.A)))

    def major_ends(self) -> tuple[np.ndarray, np.ndarray]:
        """The two ends of the major axis, (2,) each."""
        ax, v = self.axes
        d = v[:, 0] * ax[0]
        return self.centre - d, self.centre + d

    def contains(self, points: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        d = np.asarray(points, float) - self.centre
        return np.einsum("ni,ij,nj->n", d, self.A, d) <= 1.0 + tol


def khachiyan(points: np.ndarray, weights_mask: np.ndarray | None = None, *, tol: float = 1e-2,
              max_iter: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """Khachiyan's barycentric coordinate ascent for minimum-volume enclosing ellipsoids, batched.

    points : (b, n, d) float, ``b`` point sets of ``n`` points (pad a smaller set by repeating its own points:
        duplicates do not change the ellipsoid)
    weights_mask : (b, n) bool, points taking part (default all); excluded points get weight 0 throughout
    tol : stop when every set is ``tol``-optimal (all ``m_j <= (d + 1)(1 + tol)`` and ``>= (d + 1)(1 - tol)`` on the
        support; Todd and Yildirim's toward/away-step variant of Khachiyan's algorithm, which converges much faster)
    returns : centres (b, d) and shape matrices A (b, d, d) with ``(x - c)^T A (x - c) <= 1`` (the ellipsoid is
        exact to ``(1 + tol)``-ish in volume; a final rescale makes every point lie inside)
    """
    p = np.asarray(points, float)
    b, n, d = p.shape
    mask = np.ones((b, n), bool) if weights_mask is None else np.asarray(weights_mask, bool)
    cnt = mask.sum(1)
    q = np.concatenate([p, np.ones((b, n, 1))], axis=2)  # (b, n, d+1)
    u = np.where(mask, 1.0 / np.maximum(cnt, 1)[:, None], 0.0)
    active = np.ones(b, bool)
    for _ in range(max_iter):
        idx = np.flatnonzero(active)
        if not len(idx):
            break
        qa, ua, ma = q[idx], u[idx], mask[idx]
        x = np.matmul((qa * ua[..., None]).transpose(0, 2, 1), qa)
        xinv = np.linalg.inv(x + 1e-14 * np.eye(d + 1))
        m = (np.matmul(qa, xinv) * qa).sum(-1)
        rows = np.arange(len(idx))
        jp = np.argmax(np.where(ma, m, -np.inf), axis=1)
        jm = np.argmin(np.where(ma & (ua > 0), m, np.inf), axis=1)
        mp, mm = m[rows, jp], m[rows, jm]
        eps_p, eps_m = mp / (d + 1.0) - 1.0, 1.0 - mm / (d + 1.0)
        toward = eps_p >= eps_m  # Todd-Yildirim: a toward step on the worst point, or an away step
        j = np.where(toward, jp, jm)
        mj = np.where(toward, mp, mm)
        step = (mj - d - 1.0) / ((d + 1.0) * np.maximum(mj - 1.0, 1e-12))
        uj = ua[rows, j]
        step = np.where(toward, np.clip(step, 0.0, 1.0), np.maximum(step, -uj / np.maximum(1.0 - uj, 1e-12)))
        unew = ua * (1.0 - step)[:, None]
        unew[rows, j] += step
        u[idx] = np.maximum(unew, 0.0)
        active[idx] = np.maximum(eps_p, eps_m) > tol
    centre = np.einsum("bn,bnd->bd", u, p)
    diff = p - centre[:, None, :]
    cov = np.einsum("bn,bni,bnj->bij", u, diff, diff)
    A = np.linalg.inv(cov + 1e-18 * np.eye(d)) / d
    # Khachiyan stops near the optimum: scale A so the farthest point lies exactly on the boundary.
    r = np.einsum("bni,bij,bnj->bn", diff, A, diff)
    r = np.where(mask, r, 0.0).max(1)
    A = A / np.maximum(r, 1e-300)[:, None, None]
    return centre, A


def _hull_padded(sets: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Convex-hull vertices of each 2D set, padded to one array; also which sets are degenerate."""
    from scipy.spatial import ConvexHull, QhullError

    hulls, degenerate = [], np.zeros(len(sets), bool)
    for i, s in enumerate(sets):
        try:
            h = s[ConvexHull(s).vertices] if len(s) >= 3 else s
        except (QhullError, ValueError):  # collinear or repeated points
            h = s[:0]
        if len(h) < 3:
            degenerate[i] = True
        hulls.append(h)
    nmax = max(max(len(h) for h in hulls), 3)
    arr = np.zeros((len(sets), nmax, 2))
    mask = np.zeros((len(sets), nmax), bool)
    for i, h in enumerate(hulls):
        if len(h):
            arr[i, : len(h)] = h
            arr[i, len(h):] = h[0]
            mask[i, : len(h)] = True
    return arr, mask, degenerate


def min_volume_ellipses(sets: list[np.ndarray], *, tol: float = 1e-2, min_axis: float = 0.0
                        ) -> list[Ellipse | None]:
    """Minimum-area enclosing ellipse of each 2D point set (on its convex hull), all sets at once.

    sets : list of (n_i, 2) float
    min_axis : a set whose minor semi-axis is not above this (or whose points are collinear) is degenerate
    returns : one :class:`Ellipse` per set, None for a degenerate set (fewer than 3 non-collinear points)
    """
    if not sets:
        return []
    sets = [check_shape("ellipse points", s, (-1, 2), "f") for s in sets]
    arr, mask, degenerate = _hull_padded(sets)
    # centre and scale each set for conditioning
    mu = np.where(mask[..., None], arr, 0).sum(1) / np.maximum(mask.sum(1), 1)[:, None]
    rel = arr - mu[:, None]
    scale = np.sqrt((np.where(mask[..., None], rel, 0) ** 2).sum((1, 2)) / np.maximum(mask.sum(1), 1))
    scale = np.where(scale > 0, scale, 1.0)
    good = ~degenerate
    out: list[Ellipse | None] = [None] * len(sets)
    if not good.any():
        return out
    c, A = khachiyan(rel[good] / scale[good, None, None], mask[good], tol=tol)
    for k, i in enumerate(np.flatnonzero(good)):
        Ai = A[k] / scale[i] ** 2
        w = np.linalg.eigvalsh(Ai)
        if not np.all(np.isfinite(w)) or w[0] <= 0 or 1.0 / np.sqrt(w[-1]) <= max(min_axis, 1e-12 * scale[i]):
            continue
        out[i] = Ellipse(mu[i] + c[k] * scale[i], Ai)
    return out


def min_volume_ellipse(points: np.ndarray, *, tol: float = 1e-2) -> Ellipse:
    """Minimum-area enclosing ellipse of one 2D point set; raises InputError when it is degenerate."""
    e = min_volume_ellipses([points], tol=tol)[0]
    if e is None:
        raise InputError("degenerate point set: no enclosing ellipse (fewer than 3 non-collinear points)")
    return e


def ellipse_extent(ellipse: Ellipse, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Distance from each origin along its unit direction to the ellipse boundary (the positive root; 0 when the
    ray misses the ellipse or starts outside it beyond the boundary).

    origins, directions : (n, 2) float
    returns : (n,) float
    """
    return ray_extent(ellipse.centre, ellipse.A, origins, directions)


def ray_extent(centre: np.ndarray, A: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """:func:`ellipse_extent` for one ellipse per ray: centre (n, 2) or (2,), A (n, 2, 2) or (2, 2)."""
    o = np.asarray(origins, float) - centre
    dvec = np.asarray(directions, float)
    A = np.broadcast_to(np.asarray(A, float), o.shape[:-1] + (2, 2))
    a = np.einsum("ni,nij,nj->n", dvec, A, dvec)
    b = 2 * np.einsum("ni,nij,nj->n", o, A, dvec)
    c = np.einsum("ni,nij,nj->n", o, A, o) - 1.0
    disc = b * b - 4 * a * c
    t = (-b + np.sqrt(np.maximum(disc, 0.0))) / (2 * a)
    return np.where(disc >= 0, np.maximum(t, 0.0), 0.0)
