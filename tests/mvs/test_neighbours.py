"""Neighbour selection, depth ranges and the scene centre from cameras alone."""

from __future__ import annotations

import numpy as np
import pytest

from plantbench.cameras import look_at
from plantbench.errors import InputError
from reference_impl.mvs import synthetic
from reference_impl.mvs.neighbours import depth_range, scene_centre, select_neighbours


def test_ring_neighbours_are_adjacent_views():
    cams = synthetic.ring_cameras(20, target=(0.1, -0.2, 0.5))
    assert np.allclose(scene_centre(cams), [0.1, -0.2, 0.5], atol=1e-6)
    nb = select_neighbours(cams)
    assert all(len(n) == 4 for n in nb)
    assert set(nb[0]) == {1, 19, 2, 18}
    assert set(nb[7]) == {6, 8, 5, 9}


def test_depth_range_contains_the_centre():
    cams = synthetic.ring_cameras(8)
    near, far = depth_range(cams[0], scene_centre(cams), 1.25)
    assert 0 < near < 3.0 < far


def test_one_view_is_an_error():
    with pytest.raises(InputError, match="at least 2 views"):
        select_neighbours(synthetic.ring_cameras(1))


def test_views_without_overlap_are_an_error():
    a = look_at((0, 0, 1), (5, 0, 1), fov_x_deg=40, width=64, height=64)
    b = look_at((0, 0.2, 1), (0, 5, 1), fov_x_deg=40, width=64, height=64)
    c = look_at((0, -0.2, 1), (-5, 0, 1), fov_x_deg=40, width=64, height=64)
    with pytest.raises(InputError, match="overlap"):
        select_neighbours([a, b, c])
