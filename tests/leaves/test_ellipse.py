"""Minimum-volume enclosing ellipses against analytic cases."""

from __future__ import annotations

import numpy as np
import pytest

from plantbench.errors import InputError
from reference_impl.leaves.ellipse import ellipse_extent, min_volume_ellipse, min_volume_ellipses


def _rot(a: float) -> np.ndarray:
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def test_rhombus_gives_the_ellipse_through_its_vertices():
    # affine image of a square, whose minimum enclosing ellipse is its circumcircle: x^2/p^2 + y^2/q^2 = 1
    pts = np.array([[2.0, 0.0], [-2.0, 0.0], [0.0, 1.0], [0.0, -1.0]]) + [3.0, 4.0]
    e = min_volume_ellipse(pts)
    np.testing.assert_allclose(e.centre, [3.0, 4.0], atol=1e-6)
    np.testing.assert_allclose(e.semi_axes, (2.0, 1.0), rtol=1e-6)
    ends = sorted(map(tuple, e.major_ends()))
    np.testing.assert_allclose(ends, [(1.0, 4.0), (5.0, 4.0)], atol=1e-6)


def test_points_on_an_ellipse_recover_it(rng):
    t = rng.uniform(0, 2 * np.pi, 400)
    a, b, ang, c = 3.0, 1.2, 0.7, np.array([-1.0, 2.0])
    pts = np.c_[a * np.cos(t), b * np.sin(t)] @ _rot(ang).T + c
    inner = rng.uniform(-0.5, 0.5, (300, 2)) * [a, b] @ _rot(ang).T + c  # interior points change nothing
    e = min_volume_ellipse(np.concatenate([pts, inner]))
    assert e.contains(pts, tol=1e-6).all()
    np.testing.assert_allclose(e.semi_axes, (a, b), rtol=0.02)
    np.testing.assert_allclose(e.centre, c, atol=0.02)
    assert e.area >= np.pi * a * b * (1 - 1e-3)  # never smaller than the true minimum
    major = e.axes[1][:, 0]
    assert abs(abs(major @ [np.cos(ang), np.sin(ang)]) - 1) < 1e-3


def test_batched_equals_one_at_a_time(rng):
    sets = [rng.normal(size=(int(rng.integers(5, 60)), 2)) * [2.0, 0.5] for _ in range(12)]
    batch = min_volume_ellipses(sets)
    for s, e in zip(sets, batch, strict=True):
        one = min_volume_ellipse(s)
        assert e.contains(s, tol=1e-6).all()
        np.testing.assert_allclose(e.area, one.area, rtol=1e-9)


def test_degenerate_sets():
    line = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])
    assert min_volume_ellipses([line, np.zeros((2, 2)), np.ones((1, 2))]) == [None, None, None]
    with pytest.raises(InputError):
        min_volume_ellipse(line)


def test_extent_along_axes():
    e = min_volume_ellipse(np.array([[2.0, 0.0], [-2.0, 0.0], [0.0, 1.0], [0.0, -1.0]]))
    d = ellipse_extent(e, np.zeros((3, 2)), np.array([[1.0, 0.0], [0.0, 1.0], [0.0, -1.0]]))
    np.testing.assert_allclose(d, [2.0, 1.0, 1.0], atol=1e-6)
    # from an interior point towards the boundary; a ray starting outside and pointing away has no extent
    np.testing.assert_allclose(ellipse_extent(e, np.array([[1.0, 0.0]]), np.array([[1.0, 0.0]])), [1.0], atol=1e-6)
    assert ellipse_extent(e, np.array([[5.0, 0.0]]), np.array([[1.0, 0.0]]))[0] == 0.0
