"""Ground plane fit and plant/ground separation on a synthetic cloud."""

from __future__ import annotations

import numpy as np
import pytest

from plantbench.errors import InputError
from reference_impl.mvs.ground import drop_small_components, fit_ground_plane, plant_mask
from reference_impl.mvs.params import GroundParams


def _cloud(rng, tilt_deg=4.0):
    """Tilted noisy ground (brown), a 'plant' column above it (green) and a few floaters."""
    n = np.array([np.sin(np.radians(tilt_deg)), 0.0, np.cos(np.radians(tilt_deg))])
    xy = rng.uniform(-2, 2, (20000, 2))
    z = -(n[0] * xy[:, 0]) / n[2] + 0.1 + rng.normal(0, 0.003, 20000)
    ground = np.column_stack([xy, z])
    h = rng.uniform(0.2, 1.5, 6000)
    ang = rng.uniform(0, 2 * np.pi, 6000)
    plant = np.column_stack([0.05 * np.cos(ang), 0.05 * np.sin(ang), 0.1 + h])
    crown = rng.normal([0, 0, 1.3], 0.2, (6000, 3))
    floaters = rng.uniform([1.5, 1.5, 1.0], [2, 2, 2.0], (5, 3)) * rng.choice([-1, 1], (5, 1)) * [1, 1, -1] * -1
    pts = np.concatenate([ground, plant, crown, floaters])
    col = np.concatenate([np.tile([120, 90, 60], (20000, 1)), np.tile([60, 150, 40], (12000, 1)),
                          np.tile([60, 150, 40], (5, 1))]).astype(np.uint8)
    col = np.clip(col + rng.normal(0, 8, col.shape), 0, 255).astype(np.uint8)
    label = np.r_[np.zeros(20000), np.ones(12000), np.full(5, 2)]
    return pts, col, label, n


def test_plane_fit_recovers_the_ground(rng):
    pts, _, label, n = _cloud(rng)
    plane, inl = fit_ground_plane(pts, inlier_dist=0.01, rng=rng)
    assert np.degrees(np.arccos(plane.normal @ n)) < 0.5
    assert abs(plane.offset - 0.1 * n[2]) < 0.005
    assert inl[label == 0].mean() > 0.95 and inl[label == 1].mean() < 0.05


def test_plane_fit_refuses_vertical_only_clouds(rng):
    wall = np.column_stack([rng.random(300), np.zeros(300), rng.random(300)])
    with pytest.raises(InputError):
        fit_ground_plane(wall, inlier_dist=0.01, rng=rng, max_tilt_deg=20)


def test_plant_mask_keeps_plant_removes_ground_and_floaters(rng):
    pts, col, label, _ = _cloud(rng)
    keep, plane = plant_mask(pts, col, scale=2.0, params=GroundParams(), rng=rng, component_radius=0.1)
    assert plane is not None
    assert keep[label == 0].mean() < 0.01
    # the plant's lowest 2 cm (height threshold 1 % of scale) go with the ground; the rest stays
    assert keep[label == 1].mean() > 0.95
    assert not keep[label == 2].any()


def test_small_components_dropped(rng):
    big = rng.normal(0, 0.05, (500, 3))
    small = rng.normal(5, 0.01, (3, 3))
    keep = drop_small_components(np.concatenate([big, small]), 0.1, 0.05)
    assert keep[:500].all() and not keep[500:].any()


def test_plane_fit_finds_a_sparse_ground_under_a_dense_crown(rng):
    """The ground is 3 % of the cloud (barely reconstructed); the crown above it holds a dense horizontal layer
    with more points than the ground (it would win the inlier count) and a trunk reaching down to the ground."""
    ground = np.column_stack([rng.uniform(-2, 2, (600, 2)), rng.normal(0, 0.003, 600)])
    layer = np.column_stack([rng.uniform(-1, 1, (6000, 2)), 1.5 + rng.normal(0, 0.003, 6000)])
    crown = rng.normal([0, 0, 1.6], [0.6, 0.6, 0.4], (12000, 3))
    trunk = np.column_stack([rng.normal(0, 0.02, (2000, 2)), rng.uniform(0, 1.5, 2000)])
    pts = np.concatenate([ground, layer, crown, trunk])
    plane, inl = fit_ground_plane(pts, inlier_dist=0.01, rng=rng)
    assert np.degrees(np.arccos(plane.normal[2])) < 1.0 and abs(plane.offset) < 0.01
    assert inl[:600].mean() > 0.9
    # without the constraint on points below, the dense layer is the plane with the most inliers
    wrong, _ = fit_ground_plane(pts, inlier_dist=0.01, rng=rng, max_below=1.0)
    assert abs(wrong.offset - 1.5) < 0.02
