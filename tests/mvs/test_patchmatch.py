"""Depth and normals of one view of the analytic scene against its exact depth."""

from __future__ import annotations

import numpy as np
import pytest

from plantbench.errors import InputError
from reference_impl.mvs.neighbours import depth_range, scene_centre
from reference_impl.mvs.params import DepthParams
from reference_impl.mvs.patchmatch import estimate_depth, sweep_depths, to_gray


@pytest.fixture(scope="module")
def estimate(views, ring):
    ref, srcs = 0, [1, 15, 2, 14]
    near, far = depth_range(ring[ref], scene_centre(ring), 1.25)
    dm = estimate_depth(views[ref][0], [views[j][0] for j in srcs], ring[ref], [ring[j] for j in srcs],
                        (near, far), DepthParams(), rng=np.random.default_rng(0))
    sweep_only = estimate_depth(views[ref][0], [views[j][0] for j in srcs], ring[ref], [ring[j] for j in srcs],
                                (near, far), DepthParams(), rng=np.random.default_rng(0), refine=False)
    gt = views[ref][1]
    inside = np.isfinite(gt) & (gt > near) & (gt < far)
    return dm, sweep_only, gt, inside


def test_depth_matches_exact_depth(estimate, views):
    dm, _, gt, inside = estimate
    got = np.isfinite(dm.depth) & inside
    assert got.sum() > 0.6 * inside.sum()  # most textured in-range pixels get a depth
    rel = np.abs(dm.depth[got] - gt[got]) / gt[got]
    # 128 px views: a pixel spans ~1.7 cm at 2.6 m, so 1 % depth error is about one pixel of disparity
    assert np.median(rel) < 0.01
    assert np.mean(rel < 0.02) > 0.7
    on_objects = got & (views[0][2] == 1)
    assert np.median(np.abs(dm.depth[on_objects] - gt[on_objects]) / gt[on_objects]) < 0.005


def test_patchmatch_refines_the_sweep(estimate):
    dm, sweep, gt, inside = estimate
    both = np.isfinite(dm.depth) & np.isfinite(sweep.depth) & inside
    err_pm = np.median(np.abs(dm.depth[both] - gt[both]) / gt[both])
    err_sw = np.median(np.abs(sweep.depth[both] - gt[both]) / gt[both])
    assert err_pm <= err_sw * 1.05


def test_normals_of_the_ground(estimate, views):
    dm, _, gt, inside = estimate
    ground = inside & (views[0][2] == 0) & np.isfinite(dm.depth)
    cosang = dm.normal[ground] @ np.array([0.0, 0.0, 1.0])
    assert np.median(cosang) > np.cos(np.radians(20))


def test_unmatched_pixels_are_nan(estimate):
    dm, _, _, _ = estimate
    assert np.all(np.isnan(dm.normal[np.isnan(dm.depth)]))
    assert dm.depth.dtype == np.float32 and dm.normal.shape == dm.depth.shape + (3,)


def test_sweep_depths_uniform_in_inverse_depth():
    d = sweep_depths(2.0, 8.0, 5)
    assert d[0] == pytest.approx(8.0) and d[-1] == pytest.approx(2.0)
    assert np.allclose(np.diff(1 / d), (1 / 2.0 - 1 / 8.0) / 4)
    with pytest.raises(InputError):
        sweep_depths(3.0, 2.0, 4)


def test_to_gray_weights():
    img = np.zeros((2, 2, 3), np.uint8)
    img[..., 1] = 255
    assert np.allclose(to_gray(img), 0.587, atol=1e-6)


def test_estimate_depth_rejects_bad_input(views, ring):
    with pytest.raises(InputError):
        estimate_depth(views[0][0], [], ring[0], [], (1.0, 4.0), rng=np.random.default_rng(0))
    with pytest.raises(InputError):
        estimate_depth(views[0][0][:64], [views[1][0]], ring[0], [ring[1]], (1.0, 4.0),
                       rng=np.random.default_rng(0))


def test_bilinear_lookup_matches_scipy(rng):
    """The Dr.Jit bilinear lookup of the cost kernels against scipy's map_coordinates (order 1, border replicated),
    including points outside the image and non-finite coordinates (a ray parallel to the plane)."""
    from scipy.ndimage import map_coordinates

    from reference_impl.mvs.patchmatch import _bilinear, _drjit

    dr, jl = _drjit()
    h, w = 37, 53
    img = rng.random((h, w)).astype(np.float32)
    u = np.concatenate([rng.uniform(-3, w + 2, 500), [np.nan, np.inf, -np.inf, 0.0, w - 1.0]]).astype(np.float32)
    v = np.concatenate([rng.uniform(-3, h + 2, 500), [1.0, 2.0, 3.0, np.nan, h - 1.0]]).astype(np.float32)
    val, inside = _bilinear(dr, jl, jl.Float(img.ravel()), w, h, jl.Float(u), jl.Float(v))
    val, inside = np.asarray(val), np.asarray(inside)
    fin = np.isfinite(u) & np.isfinite(v)
    ref = map_coordinates(img, [v[fin], u[fin]], order=1, mode="nearest")
    np.testing.assert_allclose(val[fin], ref, atol=1e-5)
    assert np.all(np.isfinite(val))
    np.testing.assert_array_equal(inside, fin & (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5))
