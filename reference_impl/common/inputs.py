"""Reading and checking a points method's input cloud (plantbench.methods.api: ``capture_dir/points.ply``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from plantbench.errors import InputError
from plantbench.plant import check_shape

__all__ = ["MIN_POINTS", "load_points", "check_points"]

MIN_POINTS = 10
"""Fewer points than this cannot describe a stem (a graph, a root and a direction); refused with InputError."""


def check_points(points: np.ndarray, *, what: str = "points") -> np.ndarray:
    """Validate an (n, 3) finite cloud with at least :data:`MIN_POINTS` points; returns float64."""
    pts = check_shape(what, points, (-1, 3), "f")
    if len(pts) < MIN_POINTS:
        raise InputError(f"{what}: {len(pts)} points; at least {MIN_POINTS} are needed to build a skeleton")
    if np.ptp(pts, axis=0).max() <= 0:
        raise InputError(f"{what}: all points coincide")
    return pts


def load_points(capture_dir: str | Path) -> np.ndarray:
    """The coordinates of ``capture_dir/points.ply`` (extra columns ignored), validated by :func:`check_points`."""
    from plantbench.io.ply import read_points

    path = Path(capture_dir) / "points.ply"
    if not path.exists():
        raise InputError("no points.ply (a points method reads the scan or the mvs cloud)", path=path)
    pts, _ = read_points(path)
    try:
        return check_points(pts)
    except InputError as exc:
        raise InputError(str(exc), path=path) from None
