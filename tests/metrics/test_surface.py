"""Mesh-to-scan: against brute-force distances on small inputs; exact point-to-triangle distance against a
plane-projection-or-nearest-edge closest point; area-uniform sampling."""

from __future__ import annotations

import numpy as np
import pytest

from plantbench.errors import InputError
from plantbench.metrics.surface import kdtree, mesh_to_scan, nearest_distances, point_to_mesh_distances, sample_surface
from plantbench.plant import TriMesh

from .synth import cylinder


def closest_on_segment(p, a, b):
    length2 = (b - a) @ (b - a)
    t = np.clip((p - a) @ (b - a) / length2, 0.0, 1.0) if length2 > 0 else 0.0
    return a + t * (b - a)


def closest_on_triangle(p, a, b, c):
    """One point, one triangle, without Ericson's region tests: the foot of the perpendicular on the triangle's plane
    when it falls inside the triangle, else the nearest of the closest points on the three edges."""
    n = np.cross(b - a, c - a)
    if n @ n > 0:  # a degenerate triangle is its edges
        foot = p - (p - a) @ n / (n @ n) * n
        u, v = np.linalg.lstsq(np.stack([b - a, c - a], axis=1), foot - a, rcond=None)[0]
        if u >= 0 and v >= 0 and u + v <= 1:
            return foot
    return min((closest_on_segment(p, s, e) for s, e in ((a, b), (b, c), (c, a))), key=lambda q: np.linalg.norm(p - q))


def brute_point_mesh(mesh, pts):
    return np.array([min(np.linalg.norm(p - closest_on_triangle(p, *mesh.vertices[f])) for f in mesh.faces)
                     for p in pts])


@pytest.mark.parametrize("n_query", [500, 30_000])
def test_nearest_distances_match_brute_force(rng, n_query):
    """Small query sets go straight to the tree, large ones in the order of a tree over them: both give every
    query its own nearest reference point, in the input order."""
    ref = rng.random((400, 3))
    query = rng.random((n_query, 3)) * 1.2 - 0.1
    d, i = nearest_distances(ref, query)
    for lo in range(0, n_query, 5000):
        q = query[lo:lo + 5000]
        full = np.sqrt(((q[:, None] - ref[None]) ** 2).sum(-1))
        np.testing.assert_allclose(d[lo:lo + 5000], full.min(1), rtol=1e-12, atol=1e-15)
        np.testing.assert_array_equal(i[lo:lo + 5000], full.argmin(1))
    d2, i2 = nearest_distances(ref, query, tree=kdtree(ref), query_tree=kdtree(query))
    np.testing.assert_array_equal(d2, d)
    np.testing.assert_array_equal(i2, i)


def test_mesh_to_scan_matches_brute_force(rng):
    mesh = TriMesh(rng.random((40, 3)), rng.integers(0, 40, (30, 3)))
    scan = rng.random((300, 3))
    res = mesh_to_scan(scan, mesh, rng=np.random.default_rng(0), n_area_samples=500)
    d = np.sqrt(((mesh.vertices[:, None, :] - scan[None, :, :]) ** 2).sum(-1)).min(axis=1)
    assert res.D_cm == pytest.approx(d.mean() * 100, rel=1e-12)
    assert res.sigma_cm == pytest.approx(d.std() * 100, rel=1e-12)
    rev = brute_point_mesh(mesh, scan)
    assert res.reverse_D_cm == pytest.approx(rev.mean() * 100, rel=1e-5)  # Open3D works in float32
    assert res.reverse_sigma_cm == pytest.approx(rev.std() * 100, rel=1e-4)
    area, _ = sample_surface(mesh, 500, np.random.default_rng(0))
    da = np.sqrt(((area[:, None, :] - scan[None, :, :]) ** 2).sum(-1)).min(axis=1)
    assert res.area_D_cm == pytest.approx(da.mean() * 100, rel=1e-12)
    assert res.symmetric_cm == pytest.approx(0.5 * (res.area_D_cm + res.reverse_D_cm))


def test_point_to_mesh_exact_on_cylinder(rng):
    # points on the axis at mid height are exactly the polygon's apothem away from a 64-gon cylinder
    mesh = cylinder(radius=0.2, height=1.0, n_around=64, n_up=4)
    pts = np.array([[0, 0, 0.3], [0, 0, 0.7]])
    apothem = 0.2 * np.cos(np.pi / 64)
    assert point_to_mesh_distances(mesh, pts) == pytest.approx([apothem, apothem], abs=1e-6)
    q = rng.normal(size=(50, 3))
    assert point_to_mesh_distances(mesh, q) == pytest.approx(brute_point_mesh(mesh, q), abs=1e-5)


def test_sample_surface_area_uniform(rng):
    # two triangles with areas 1 : 3 receive samples in that ratio, and samples lie on their triangle
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [5, 0, 0], [8, 0, 0], [5, 4, 0]], float)
    mesh = TriMesh(v, np.array([[0, 1, 2], [3, 4, 5]]))
    pts, face = sample_surface(mesh, 40000, rng)
    assert np.mean(face == 1) == pytest.approx(6 / 7, abs=0.01)
    assert np.all(pts[face == 0, 0] + pts[face == 0, 1] / 2 <= 1 + 1e-12)
    assert sample_surface(TriMesh.empty(), 10, rng)[0].shape == (0, 3)


def test_degenerate_inputs(rng):
    scan = rng.random((10, 3))
    r = mesh_to_scan(scan, TriMesh.empty(), rng=rng)
    assert (r.D_cm, r.sigma_cm, r.reverse_D_cm, r.area_D_cm, r.symmetric_cm) == (None,) * 5
    pts_only = TriMesh(rng.random((5, 3)), np.zeros((0, 3), np.int64))
    r = mesh_to_scan(scan, pts_only, rng=rng)
    assert r.D_cm is not None and r.reverse_D_cm is None and r.area_D_cm is None
    with pytest.raises(InputError, match="empty"):
        mesh_to_scan(np.zeros((0, 3)), cylinder(), rng=rng)
    bad = scan.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InputError, match="NaN"):
        mesh_to_scan(bad, cylinder(), rng=rng)
    with pytest.raises(InputError, match="NaN"):
        TriMesh(np.array([[0, 0, np.nan]] * 3), np.array([[0, 1, 2]]))
