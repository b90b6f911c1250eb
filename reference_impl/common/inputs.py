"""Reading and checking a points method's input cloud (plantbench.methods.api: ``capture_dir/points.ply``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from plantbench.methods.inputs import check_cloud, read_input_points

__all__ = ["MIN_POINTS", "load_points", "check_points"]

MIN_POINTS = 10
"""Fewer points than this cannot describe a stem (a graph, a root and a direction); refused with InputError."""


def check_points(points: np.ndarray, *, what: str = "points") -> np.ndarray:
    """Validate an (n, 3) finite cloud with at least :data:`MIN_POINTS` points; returns float64."""
    return check_cloud(points, min_points=MIN_POINTS, what=what)


def load_points(capture_dir: str | Path) -> np.ndarray:
    """The coordinates of ``capture_dir/points.ply`` (extra columns ignored), validated by :func:`check_points`."""
    return read_input_points(capture_dir, min_points=MIN_POINTS)
