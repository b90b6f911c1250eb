"""Reading and checking a points method's input cloud (plantbench.methods.api: ``capture_dir/points.ply``) and
splitting it at the ground plane."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from plantbench.errors import InputError
from plantbench.methods.inputs import check_cloud, read_input_points
from reference_impl.common.ground import Ground, GroundParams, remove_ground

__all__ = ["MIN_POINTS", "load_points", "check_points", "split_ground", "plant_height"]

MIN_POINTS = 10
"""Fewer points than this cannot describe a stem (a graph, a root and a direction); refused with InputError."""


def check_points(points: np.ndarray, *, what: str = "points") -> np.ndarray:
    """Validate an (n, 3) finite cloud with at least :data:`MIN_POINTS` points; returns float64."""
    return check_cloud(points, min_points=MIN_POINTS, what=what)


def load_points(capture_dir: str | Path) -> np.ndarray:
    """The coordinates of ``capture_dir/points.ply`` (extra columns ignored), validated by :func:`check_points`, in
    their canonical order (:func:`plantbench.geometry.clouds.canonical_order`): a method that reads them here gives
    the same reconstruction for the cloud's points in any order."""
    from plantbench.geometry.clouds import canonical_order

    pts = read_input_points(capture_dir, min_points=MIN_POINTS)
    return pts[canonical_order(pts)]


def split_ground(points: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, Ground, np.ndarray]:
    """The checked cloud (:func:`check_points`), its ground (:func:`reference_impl.common.ground.remove_ground` with
    the default parameters) and the plant points above the ground band."""
    pts = check_points(points)
    ground = remove_ground(pts, rng, GroundParams())
    return pts, ground, pts[ground.keep]


def plant_height(plant: np.ndarray, ground: Ground) -> tuple[np.ndarray, float]:
    """(m,) height of each plant point above the ground plane and the plant's height (their maximum), metres.

    Raises InputError for fewer than :data:`MIN_POINTS` plant points or a plant with no height above the plane.
    """
    if len(plant) < MIN_POINTS:
        raise InputError(f"only {len(plant)} points above the ground; at least {MIN_POINTS} are needed")
    hgt = ground.height(plant)
    height = float(hgt.max())
    if not height > 0:
        raise InputError("the cloud has no height above the ground plane")
    return hgt, height
