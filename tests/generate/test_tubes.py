"""Radii (Eq. 5 on supported length) and generalised-cylinder tubes."""

import numpy as np
import pytest

from plantbench.geometry.tubes import (
    depths,
    main_child_mask,
    node_frames,
    supported_length_radii,
    supported_lengths,
    tube_mesh,
)


def _y_tree():
    # trunk 0-1-2, then a fork at 2 into 3-4 (main) and 5 (lateral)
    pos = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 2], [0, 0, 3], [0, 0, 4], [1, 0, 3]], float)
    parents = np.array([-1, 0, 1, 2, 3, 2])
    return pos, parents


def _naive_supported(pos, parents):
    n = len(parents)
    kids = [[c for c in range(n) if parents[c] == i] for i in range(n)]

    def sub(i):
        inc = np.linalg.norm(pos[i] - pos[parents[i]]) if parents[i] >= 0 else 0.0
        return inc + sum(sub(c) for c in kids[i])

    return np.array([sub(i) for i in range(n)])


def test_supported_length_against_recursion(rng):
    n = 200
    parents = np.array([-1] + [int(rng.integers(0, i)) for i in range(1, n)])
    pos = rng.random((n, 3))
    np.testing.assert_allclose(supported_lengths(pos, parents), _naive_supported(pos, parents))
    assert depths(parents)[0] == 0
    d = depths(parents)
    np.testing.assert_array_equal(d[1:], d[parents[1:]] + 1)


def test_radii_follow_eq5_and_never_grow(rng):
    pos, parents = _y_tree()
    r = supported_length_radii(pos, parents, gamma=0.5, tip_radius=0.01, internode_length=1.0)
    sup = _naive_supported(pos, parents)
    np.testing.assert_allclose(r, 0.01 * sup**0.5)
    # Eq. 5 at the fork: d_c / d_c' = (l_c / l_c')^gamma
    assert r[3] / r[5] == pytest.approx((sup[3] / sup[5]) ** 0.5)
    assert np.all(r[1:] <= r[parents[1:]])


def test_main_child_defaults_to_thickest():
    pos, parents = _y_tree()
    r = supported_length_radii(pos, parents, gamma=0.5, tip_radius=0.01, internode_length=1.0)
    main = main_child_mask(parents, r)
    np.testing.assert_array_equal(main, [False, True, True, True, True, False])


def test_frames_are_orthonormal_and_continuous():
    t = np.linspace(0, 2, 40)
    pos = np.column_stack([np.sin(t), np.cos(t) - 1, t])  # a helix-like chain
    parents = np.arange(-1, 39)
    main = parents >= 0
    tangent, normal, _, _ = node_frames(pos, parents, main)
    np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1)
    np.testing.assert_allclose(np.sum(tangent * normal, axis=1), 0, atol=1e-12)
    # parallel transport: successive normals turn no more than the tangent does
    turn_n = np.arccos(np.clip(np.sum(normal[1:] * normal[:-1], 1), -1, 1))
    turn_t = np.arccos(np.clip(np.sum(tangent[1:] * tangent[:-1], 1), -1, 1))
    assert np.all(turn_n <= turn_t + 1e-9)


def test_straight_tube_is_a_cylinder_with_outward_normals():
    pos = np.column_stack([np.zeros(5), np.zeros(5), np.linspace(0, 1, 5)])
    parents = np.arange(-1, 4)
    radii = np.full(5, 0.1)
    mesh = tube_mesh(pos, parents, radii, parents >= 0, max_sides=8, min_sides=8)
    side = mesh.vertices[:-1]  # last vertex is the tip cap apex
    np.testing.assert_allclose(np.hypot(side[:, 0], side[:, 1]), 0.1)
    assert len(mesh.faces) == 4 * 8 * 2 + 8
    a, b, c = (mesh.vertices[mesh.faces[:, i]] for i in range(3))
    normal = np.cross(b - a, c - a)
    centre = (a + b + c) / 3
    radial = centre - np.column_stack([np.zeros(len(centre)), np.zeros(len(centre)), centre[:, 2]])
    assert np.all(np.sum(normal * radial, axis=1) > 0)
    # the lateral surface area is that of the cylinder, up to the polygon
    area = mesh.face_areas()[: 4 * 8 * 2].sum()
    assert area == pytest.approx(8 * 2 * 0.1 * np.sin(np.pi / 8) * 1.0, rel=1e-9)


def test_lateral_tube_starts_inside_its_parent():
    pos, parents = _y_tree()
    r = supported_length_radii(pos, parents, gamma=0.5, tip_radius=0.05, internode_length=1.0)
    main = main_child_mask(parents, r)
    mesh = tube_mesh(pos, parents, r, main, max_sides=6, min_sides=6)
    # the start ring of the lateral (node 5) is centred on node 2 and lies within node 2's radius
    start_ring = mesh.vertices[6 * 6: 6 * 7]
    assert np.all(np.linalg.norm(start_ring - pos[2], axis=1) <= r[2] + 1e-12)
