"""reference_impl.common.graph against brute-force computations."""

import itertools

import numpy as np
import pytest
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from plantbench.errors import InputError
from plantbench.geometry.vectors import depths
from reference_impl.common.graph import (
    bridge_components,
    bridge_waypoints,
    children_csr,
    knn_graph,
    radius_graph,
    shortest_path_tree,
    subtree_lengths,
    voxel_downsample,
)


def test_voxel_downsample_matches_naive_grouping(rng):
    pts = rng.random((500, 3))
    cen, lab, cnt = voxel_downsample(pts, 0.2)
    groups = {}
    cell = np.floor((pts - pts.min(0)) / 0.2).astype(int)
    for p, c in zip(pts, map(tuple, cell)):
        groups.setdefault(c, []).append(p)
    assert len(cen) == len(groups) == cnt.size and cnt.sum() == len(pts)
    for key, members in groups.items():
        i = lab[np.flatnonzero((cell == key).all(1))[0]]
        assert np.allclose(cen[i], np.mean(members, axis=0))
    with pytest.raises(InputError):
        voxel_downsample(pts, 0.0)


def test_knn_and_radius_graphs_match_brute_force(rng):
    pts = rng.random((80, 3))
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    g = knn_graph(pts, 4).toarray()
    assert np.allclose(g, g.T)
    order = np.argsort(d, axis=1)[:, 1:5]
    want = np.zeros_like(d, bool)
    want[np.repeat(np.arange(80), 4), order.ravel()] = True
    want |= want.T
    assert np.array_equal(g > 0, want)
    assert np.allclose(g[want], d[want])
    r = radius_graph(pts, 0.25).toarray()
    want_r = (d < 0.25) & ~np.eye(80, dtype=bool)
    assert np.array_equal(r > 0, want_r) and np.allclose(r[want_r], d[want_r])
    capped = knn_graph(pts, 4, max_edge=0.1).toarray()
    assert capped.max() <= 0.1


def test_bridge_components_joins_blobs_with_their_closest_pair(rng):
    a = rng.normal(0, 0.05, (60, 3))
    b = rng.normal(0, 0.05, (60, 3)) + [1.0, 0, 0]
    c = rng.normal(0, 0.05, (60, 3)) + [0, 2.0, 0]
    pts = np.concatenate([a, b, c])
    g = knn_graph(pts, 6)
    assert csgraph.connected_components(g)[0] == 3
    g2, added = bridge_components(pts, g)
    assert csgraph.connected_components(g2)[0] == 1
    assert added == 2
    # the a-b bridge is the closest a-b pair (brute force)
    dab = np.linalg.norm(a[:, None] - b[None], axis=2)
    assert np.isclose(g2[:60, 60:120].max(), dab.min())


def _cheapest_by_enumeration(a, b, pts):
    """Every ordered subset of ``pts`` as a path from a to b, the one with the least sum of squared steps."""
    best, best_path = np.sum((b - a) ** 2), ()
    for k in range(1, len(pts) + 1):
        for path in itertools.permutations(range(len(pts)), k):
            xyz = np.concatenate([a[None], pts[list(path)], b[None]])
            cost = np.sum(np.diff(xyz, axis=0) ** 2)
            if cost < best - 1e-12:
                best, best_path = cost, path
    return best_path


def test_bridge_waypoints_match_an_enumeration_of_every_path(rng):
    a, b = np.zeros(3), np.array([1.0, 0, 0])
    hits = 0
    for _ in range(30):
        pts = rng.uniform([-0.1, -0.4, -0.4], [1.1, 0.4, 0.4], (7, 3))
        free = rng.random(7) < 0.8
        got = bridge_waypoints(pts, cKDTree(pts), free, a, b)
        free_idx = np.flatnonzero(free & (np.linalg.norm(pts - [0.5, 0, 0], axis=1) <= 0.5))
        expect = free_idx[list(_cheapest_by_enumeration(a, b, pts[free_idx]))]
        np.testing.assert_array_equal(got, expect)
        hits += len(got) > 1
    assert hits > 5  # multi-step paths were compared, not only jumps


def test_bridge_waypoints_step_through_a_gap_in_order(rng):
    a, b = np.zeros(3), np.array([0.0, 0, 1.0])
    on_axis = np.c_[rng.normal(0, 0.01, (5, 2)), [0.8, 0.2, 0.6, 0.4, 0.9]]
    aside = np.array([[0.45, 0, 0.5], [0, 0, 1.3]])  # off the way, and outside the ball
    pts = np.concatenate([on_axis, aside])
    got = bridge_waypoints(pts, cKDTree(pts), np.ones(len(pts), bool), a, b)
    np.testing.assert_array_equal(got, [1, 3, 2, 0, 4])  # z 0.2, 0.4, 0.6, 0.8, 0.9
    assert len(bridge_waypoints(pts, cKDTree(pts), np.zeros(len(pts), bool), a, b)) == 0
    assert len(bridge_waypoints(pts, cKDTree(pts), np.ones(len(pts), bool), a, a)) == 0


def test_shortest_path_tree_is_consistent(rng):
    pts = rng.random((200, 3))
    g = knn_graph(pts, 8)
    g, _ = bridge_components(pts, g)
    dist, par, src = shortest_path_tree(g, np.array([0, 5]))
    assert par[0] == -1 and par[5] == -1 and set(np.unique(src)) <= {0, 5}
    ch = np.flatnonzero(par >= 0)
    assert np.allclose(dist[ch], dist[par[ch]] + np.linalg.norm(pts[ch] - pts[par[ch]], axis=1))
    full = csgraph.dijkstra(g, indices=[0, 5]).min(0)
    assert np.allclose(dist, full)


def _naive_depth_and_length(pos, par):
    n = len(par)
    depth = np.zeros(n, int)
    for v in range(n):
        u = v
        while par[u] >= 0:
            depth[v] += 1
            u = par[u]
    inc = np.array([np.linalg.norm(pos[v] - pos[par[v]]) if par[v] >= 0 else 0.0 for v in range(n)])
    total = np.zeros(n)
    for v in range(n):
        u = v
        while u >= 0:
            total[u] += inc[v]
            u = par[u]
    return depth, total


def test_depths_and_subtree_lengths_match_naive(rng):
    n = 300
    par = np.array([-1] + [int(rng.integers(0, i)) for i in range(1, n)])
    perm = rng.permutation(n)  # parents need not precede children
    inv = np.argsort(perm)
    par_p = np.where(par[perm] >= 0, inv[np.maximum(par[perm], 0)], -1)
    pos = rng.random((n, 3))
    depth, total = _naive_depth_and_length(pos, par_p)
    assert np.array_equal(depths(par_p), depth)
    assert np.allclose(subtree_lengths(pos, par_p), total)
    ptr, kids = children_csr(par_p)
    for v in range(0, n, 37):
        assert sorted(kids[ptr[v]:ptr[v + 1]]) == sorted(np.flatnonzero(par_p == v))
