"""Synthetic test plants for the baselines: a known skeleton whose tube surfaces are sampled with noise."""

from __future__ import annotations

import numpy as np

from plantbench.plant import Skeleton


def _rotate(v: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    return v * np.cos(angle) + np.cross(axis, v) * np.sin(angle) + axis * (axis @ v) * (1 - np.cos(angle))


def random_tree(rng: np.random.Generator, *, height: float = 2.0, levels: int = 3, segment: float = 0.05,
                base: tuple[float, float] = (0.0, 0.0)) -> Skeleton:
    """A trunk with ``levels`` orders of laterals, nodes every ``segment`` metres, pipe-model radii."""
    pos, par = [np.array([base[0], base[1], 0.0])], [-1]

    def grow(start: int, direction: np.ndarray, length: float, level: int) -> None:
        n = max(int(round(length / segment)), 2)
        prev = start
        d = direction / np.linalg.norm(direction)
        chain = []
        for _ in range(n):
            d = d + rng.normal(0, 0.03, 3)
            d = d / np.linalg.norm(d)
            pos.append(pos[prev] + d * segment)
            par.append(prev)
            prev = len(pos) - 1
            chain.append(prev)
        if level >= levels:
            return
        nlat = 4 if level == 0 else 3
        spots = np.linspace(0.35, 0.85, nlat)
        for i, s in enumerate(spots):
            at = chain[int(s * (len(chain) - 1))]
            ref = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
            side = _rotate(ref, d, i * np.radians(137.5) + rng.uniform(0, 0.3))
            lat = np.cos(np.radians(50)) * d + np.sin(np.radians(50)) * side / np.linalg.norm(side)
            grow(at, lat, length * (0.45 - 0.15 * s), level + 1)

    grow(0, np.array([0.0, 0.0, 1.0]), height, 0)
    pos, par = np.asarray(pos), np.asarray(par)
    # pipe model radii on supported length
    from reference_impl.common.graph import subtree_lengths

    w = subtree_lengths(pos, par)
    r = 0.02 * height * np.sqrt(w / w[0])
    return Skeleton(pos, np.maximum(r, 0.002), par)


def sample_surface(rng: np.random.Generator, skeleton: Skeleton, n: int, *, noise: float = 0.001,
                   one_sided: bool = False, ground: int = 0, ground_radius: float = 1.5) -> np.ndarray:
    """``n`` points on the tubes (area-uniform), Gaussian noise; ``one_sided`` keeps the half facing -y (a single
    scanner at -y); ``ground`` points on the disc z = 0 of radius ``ground_radius``."""
    p, par, r = skeleton.positions, skeleton.parents, skeleton.radii
    c = np.flatnonzero(par >= 0)
    a, b = p[par[c]], p[c]
    ra, rb = r[par[c]], r[c]
    ln = np.linalg.norm(b - a, axis=1)
    area = 2 * np.pi * 0.5 * (ra + rb) * ln
    e = rng.choice(len(c), size=n * (2 if one_sided else 1), p=area / area.sum())
    t = rng.random(len(e))
    axis = (b - a)[e] / ln[e, None]
    u = np.cross(axis, np.array([1.0, 0.0, 0.0]))
    bad = np.linalg.norm(u, axis=1) < 1e-6
    u[bad] = np.cross(axis[bad], np.array([0.0, 1.0, 0.0]))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(axis, u)
    th = rng.uniform(0, 2 * np.pi, len(e))
    radial = np.cos(th)[:, None] * u + np.sin(th)[:, None] * v
    rad = (ra[e] * (1 - t) + rb[e] * t)[:, None]
    pts = a[e] + t[:, None] * (b - a)[e] + rad * radial
    if one_sided:
        pts = pts[radial[:, 1] < 0][:n]
    pts = pts + rng.normal(0, noise, pts.shape)
    if ground:
        rr = ground_radius * np.sqrt(rng.random(ground))
        ang = rng.uniform(0, 2 * np.pi, ground)
        g = np.c_[rr * np.cos(ang), rr * np.sin(ang), rng.normal(0, noise, ground)]
        pts = np.concatenate([pts, g])
    return pts


def skeleton_samples(skeleton: Skeleton, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` along the edges with their interpolated radius."""
    from reference_impl.common.leaves import sample_edges

    s, _, r = sample_edges(skeleton.positions, skeleton.parents, skeleton.radii, step)
    return s, r
