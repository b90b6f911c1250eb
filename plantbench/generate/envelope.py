"""Crown envelopes: Weber-Penn shape ratios and uniform markers inside the envelope."""

from __future__ import annotations

import numpy as np

__all__ = ["shape_ratio", "envelope_radius", "sample_markers", "envelope_volume"]


def shape_ratio(shape: str, r: np.ndarray) -> np.ndarray:
    """Weber and Penn's ShapeRatio(shape, r), r in [0, 1] (1 at the crown base, 0 at the top).

    r : (n,) float; returns (n,) float in [0, 1].
    """
    r = np.clip(np.asarray(r, dtype=np.float64), 0.0, 1.0)
    if shape == "conical":
        return 0.2 + 0.8 * r
    if shape == "spherical":
        return 0.2 + 0.8 * np.sin(np.pi * r)
    if shape == "hemispherical":
        return 0.2 + 0.8 * np.sin(0.5 * np.pi * r)
    if shape == "cylindrical":
        return np.ones_like(r)
    if shape == "tapered_cylindrical":
        return 0.5 + 0.5 * r
    if shape == "flame":
        return np.where(r <= 0.7, r / 0.7, (1.0 - r) / 0.3)
    if shape == "inverse_conical":
        return 1.0 - 0.8 * r
    if shape == "tend_flame":
        return np.where(r <= 0.7, 0.5 + 0.5 * r / 0.7, 0.5 + 0.5 * (1.0 - r) / 0.3)
    raise ValueError(f"unknown envelope shape {shape!r}")


def envelope_radius(z: np.ndarray, *, height: float, crown_base: float, radius: float, shape: str) -> np.ndarray:
    """(n,) crown radius at heights z (0 outside [crown_base * height, height])."""
    z = np.asarray(z, dtype=np.float64)
    z0 = crown_base * height
    r = (height - z) / max(height - z0, 1e-12)
    inside = (z >= z0) & (z <= height)
    return np.where(inside, radius * shape_ratio(shape, r), 0.0)


def envelope_volume(*, height: float, crown_base: float, radius: float, shape: str, n: int = 2001) -> float:
    """Volume of the envelope (numerical quadrature of pi R(z)^2), cubic metres."""
    z = np.linspace(crown_base * height, height, n)
    rad = envelope_radius(z, height=height, crown_base=crown_base, radius=radius, shape=shape)
    return float(np.trapezoid(np.pi * rad**2, z))


def sample_markers(rng: np.random.Generator, count: int, *, height: float, crown_base: float, radius: float,
                   shape: str, offset: float = 0.0, centre: np.ndarray | None = None) -> np.ndarray:
    """``count`` points uniformly distributed in the envelope (rejection sampling in the bounding cylinder).

    offset : markers closer than ``offset * radius`` to the vertical axis are rejected (hollow crowns).
    returns : (count, 3) float
    """
    centre = np.zeros(2) if centre is None else np.asarray(centre, dtype=np.float64)[:2]
    out: list[np.ndarray] = []
    have = 0
    z0 = crown_base * height
    while have < count:
        m = max(2 * (count - have), 1024)
        p = rng.random((m, 3))
        x = (2 * p[:, 0] - 1) * radius
        y = (2 * p[:, 1] - 1) * radius
        z = z0 + p[:, 2] * (height - z0)
        rho = np.hypot(x, y)
        keep = (rho <= envelope_radius(z, height=height, crown_base=crown_base, radius=radius, shape=shape)) & (
            rho >= offset * radius
        )
        pts = np.stack([x + centre[0], y + centre[1], z], 1)[keep]
        out.append(pts)
        have += len(pts)
    return np.concatenate(out)[:count]
