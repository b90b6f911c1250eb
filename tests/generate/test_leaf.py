"""The Bezier leaf (Chaurasia and Beardsley 2017, Eq. 1-6) against analytic and independent computations."""

import numpy as np
import pytest

from plantbench.geometry.leaf import (
    PARAM_NAMES,
    BezierLeaf,
    bezier,
    leaf_grid,
    leaf_points,
    max_half_width,
    silhouette_outline,
    tessellate,
)


def test_twenty_one_parameters_round_trip():
    assert len(PARAM_NAMES) == 21
    leaf = BezierLeaf(sil_x2=0.4, f_z1=0.05)
    assert BezierLeaf.from_vector(leaf.vector()) == leaf


def test_bezier_matches_de_casteljau(rng):
    ctrl = rng.random((5, 3))
    t = np.linspace(0, 1, 11)

    def casteljau(points, s):
        pts = points.copy()
        while len(pts) > 1:
            pts = (1 - s) * pts[:-1] + s * pts[1:]
        return pts[0]

    expect = np.array([casteljau(ctrl, s) for s in t])
    np.testing.assert_allclose(bezier(ctrl, t), expect, atol=1e-12)


def test_base_apex_axis_and_margin():
    omega = BezierLeaf(axis1_z=0.1, sil_z2=0.05, f_z2=0.02).vector()
    pts = leaf_points(omega, np.array([0.0, 0.7, -0.3, 0.0, 1.0]), np.array([0.0, 0.0, 0.0, 1.0, 1.0]))
    np.testing.assert_allclose(pts[0], 0, atol=1e-12)  # base
    np.testing.assert_allclose(pts[1], 0, atol=1e-12)  # the whole v = 0 row collapses on the base
    np.testing.assert_allclose(pts[3], [1, 0, 0], atol=1e-12)  # apex
    np.testing.assert_allclose(pts[4], [1, 0, 0], atol=1e-12)
    # u = 0 is the axis A(v), u = 1 the silhouette S(v)
    v = np.linspace(0, 1, 9)
    axis_ctrl = np.array([[0, 0, 0], [1 / 3, 0, 0.1], [2 / 3, 0, 0], [1, 0, 0]])
    np.testing.assert_allclose(leaf_points(omega, np.zeros(9), v), bezier(axis_ctrl, v), atol=1e-12)
    outline = silhouette_outline(omega, 9)
    np.testing.assert_allclose(leaf_points(omega, np.ones(9), v), outline, atol=1e-12)


def test_symmetric_halves_for_a_straight_axis():
    omega = BezierLeaf(sil_z1=0.03, g_z3=-0.02).vector()
    u = np.linspace(0, 1, 7)
    v = np.linspace(0, 1, 7)
    right = leaf_points(omega, u, v)
    left = leaf_points(omega, -u, v)
    np.testing.assert_allclose(left * [1, -1, 1], right, atol=1e-12)


def test_batched_evaluation_equals_single(rng):
    omegas = np.stack([BezierLeaf().vector() + 0.02 * rng.normal(size=21) for _ in range(4)])
    u, v, _ = leaf_grid((3, 5))
    batch = leaf_points(omegas, u, v)
    for i in range(4):
        np.testing.assert_allclose(batch[i], leaf_points(omegas[i], u, v), atol=1e-12)


@pytest.mark.parametrize("shape", [BezierLeaf(), BezierLeaf(sil_v1=0.05, sil_x1=0.5, sil_x2=0.55, sil_x3=0.2)])
def test_flat_leaf_area_matches_outline_integral(shape):
    """A flat, straight leaf covers exactly the region inside its silhouettes: area = 2 x shoelace(S)."""
    length = 0.12
    mesh = tessellate(shape, length, (24, 96))
    s = silhouette_outline(shape.vector(), 20000)[:, :2] * length
    x, y = s[:, 0], s[:, 1]
    area_outline = 2 * 0.5 * abs(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    assert mesh.face_areas().sum() == pytest.approx(area_outline, rel=2e-3)
    # the width agrees with the sampled half width
    assert 2 * np.abs(mesh.vertices[:, 1]).max() == pytest.approx(2 * max_half_width(shape.vector()) * length, rel=1e-2)


def test_grid_faces_face_up_and_resolution_counts():
    mesh = tessellate(BezierLeaf(), 1.0, (3, 6))
    a, b, c = (mesh.vertices[mesh.faces[:, i]] for i in range(3))
    nz = np.cross(b - a, c - a)[:, 2]
    assert np.all(nz > 0)
    # 6 columns x 6 rows of quads, two triangles each, minus the collapsed triangles at base and apex
    assert len(mesh.faces) == 2 * 6 * 6 - 2 * 6
    with pytest.raises(ValueError):
        leaf_grid((0, 4))
