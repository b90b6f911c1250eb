"""Bezier leaf fitting (Chaurasia and Beardsley 2017, section 5): recovery under occlusion, the fast model, UV
mapping, weights."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from plantbench.errors import InputError
from plantbench.geometry.leaf import BezierLeaf, leaf_points
from reference_impl.leaves.ellipse import Ellipse
from reference_impl.leaves.fit import LeafModel, fit_leaf, initial_params, uv_mapping
from reference_impl.leaves.params import LeafParams

from .conftest import LAUREL, PEACH, rotation, surface_samples, transform


def _random_pose(rng) -> np.ndarray:
    axis = rng.normal(size=3)
    return transform(rotation(axis, rng.uniform(0, np.pi)), rng.normal(size=3))


def _mean_surface_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric mean nearest-neighbour distance between two dense surface samplings."""
    return 0.5 * (cKDTree(b).query(a)[0].mean() + cKDTree(a).query(b)[0].mean())


@pytest.mark.parametrize("shape", [LAUREL, PEACH], ids=["laurel", "peach"])
@pytest.mark.parametrize("cut", ["side", "oblique"])
def test_occluded_leaf_is_recovered(shape, cut, rng):
    """Acceptance: a generator leaf with 30 % of its points removed is recovered within 3 % of its length."""
    omega, length = shape.vector(), 0.08
    pose = _random_pose(rng)
    u, v = rng.uniform(-1, 1, 1500), rng.uniform(0, 1, 1500)
    local = leaf_points(omega, u, v)
    key = local[:, 1] if cut == "side" else 0.7 * local[:, 0] + 0.7 * local[:, 1]
    keep = key < np.quantile(key, 0.7)  # an occluder hides 30 % of the blade
    pts = (local[keep] * length) @ pose[:3, :3].T + pose[:3, 3] + rng.normal(0, 0.0004, (keep.sum(), 3))
    fit = fit_leaf(pts, rng=rng, up=pose[:3, 2])
    truth = surface_samples(omega, length, pose)
    assert _mean_surface_distance(truth, fit.surface(41, 81)) <= 0.03 * length
    assert 1 <= fit.iterations <= LeafParams().fit_iterations
    # the fitted frame is a rigid transform whose +z faces the same side as the leaf's upper surface
    rot = fit.transform[:3, :3]
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(rot) > 0 and rot[:, 2] @ pose[:3, 2] > 0.9


def test_leaf_model_matches_the_generator(rng):
    u, v = rng.uniform(-1, 1, 200), rng.uniform(0, 1, 200)
    omega = BezierLeaf(axis1_y=0.1, axis2_z=0.1, sil_z2=0.05, f_z1=0.1, g_z3=-0.1).vector()
    batch = omega + rng.normal(0, 0.05, (4, 21))
    model = LeafModel(u, v)
    np.testing.assert_allclose(model(omega), leaf_points(omega, u, v), atol=1e-12)
    np.testing.assert_allclose(model(batch), leaf_points(batch, u, v), atol=1e-12)
    # Jacobian against central differences of the generator's function
    jac = model.jacobian(omega)
    h = 1e-6
    for k in (0, 5, 7, 10, 14, 20):
        e = np.zeros(21)
        e[k] = h
        num = (leaf_points(omega + e, u, v) - leaf_points(omega - e, u, v)).ravel() / (2 * h)
        np.testing.assert_allclose(jac[:, k], num, atol=1e-5)


def test_uv_mapping_on_a_flat_leaf():
    omega = initial_params(0.2)
    u_true = np.array([0.5, -0.5, 1.0, -1.0, 0.25, 0.0])
    v_true = np.array([0.5, 0.5, 0.5, 0.5, 0.5, 0.5])
    pts = leaf_points(omega, u_true, v_true)
    idx, u, v, w = uv_mapping(omega, pts, None, scanlines=21)
    np.testing.assert_array_equal(idx, np.arange(6))
    np.testing.assert_allclose(v, 0.5)
    np.testing.assert_allclose(u, u_true, atol=1e-9)  # per scanline and side, the farthest point is u = +-1
    np.testing.assert_allclose(w, 1.0)
    # the ellipse weights (Eq. 10): a scanline reaching the ellipse weighs 1, one falling short by x_s weighs 1/2
    half = pts[:, 1].max()
    ell = Ellipse(np.array([0.5, 0.0]), np.diag([1 / 0.5**2, 1 / (2 * half) ** 2]))
    _, u2, _, w2 = uv_mapping(omega, pts, ell, scanlines=21)
    np.testing.assert_allclose(w2[np.abs(u2) > 0], 0.5, atol=1e-9)


def test_bad_input():
    with pytest.raises(InputError):
        fit_leaf(np.zeros((5, 3)), rng=np.random.default_rng(0))
    line = np.c_[np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)]
    with pytest.raises(InputError):
        fit_leaf(line, rng=np.random.default_rng(0))


def test_scipy_and_batched_solvers_agree(rng):
    """The batched LM and scipy's MINPACK LM minimise the same energy: both recover the leaf, and each other."""
    omega, length = LAUREL.vector(), 0.08
    local = leaf_points(omega, rng.uniform(-1, 1, 800), rng.uniform(0, 1, 800))
    keep = local[:, 1] < np.quantile(local[:, 1], 0.7)
    pts = local[keep] * length
    truth = surface_samples(omega, length, np.eye(4))
    fits = [fit_leaf(pts, params=LeafParams(lm_backend=b), rng=np.random.default_rng(0)) for b in ("batched", "scipy")]
    for f in fits:
        assert _mean_surface_distance(truth, f.surface(41, 81)) <= 0.03 * length
    assert _mean_surface_distance(fits[0].surface(41, 81), fits[1].surface(41, 81)) <= 0.01 * length


def test_many_leaves_at_once_equal_one_at_a_time(rng):
    from reference_impl.leaves.fit import fit_leaves

    clouds = []
    for shape in (LAUREL, PEACH, BezierLeaf()):
        local = leaf_points(shape.vector(), rng.uniform(-1, 1, 300), rng.uniform(0, 1, 300))
        clouds.append(local * 0.1 @ _random_pose(rng)[:3, :3].T)
    clouds.append(np.zeros((3, 3)))
    together = fit_leaves(clouds, rng=np.random.default_rng(0))
    assert together[3] == "few_points"
    for cloud, f in zip(clouds[:3], together[:3], strict=True):
        alone = fit_leaf(cloud, rng=np.random.default_rng(0))
        np.testing.assert_allclose(f.transform, alone.transform, atol=1e-9)
        np.testing.assert_allclose(f.omega, alone.omega, atol=1e-6)


def test_linear_jacobian_matches_central_differences(rng):
    """lm_batch differentiates parameters 9-20 analytically; they must match the generator's control points."""
    from reference_impl.leaves.fit import NONLINEAR, linear_jacobian

    omega = initial_params(0.2)[None] + rng.normal(0, 0.05, (3, 21))
    jac = linear_jacobian(omega)
    h = 1e-6
    for k in range(NONLINEAR, 21):
        e = np.zeros(21)
        e[k] = h
        num = (LeafModel.controls(omega + e) - LeafModel.controls(omega - e)) / (2 * h)
        np.testing.assert_allclose(jac[:, k - NONLINEAR], num, atol=1e-7)
