"""What the methods do with a sparse real scan: a stem cut off from its crown by a gap, crown fragments across gaps,
skeleton vertices pulled off the data (reference_impl.common.roots, reference_impl.livny.bsg)."""

import numpy as np
from scipy.spatial import cKDTree

from reference_impl.common.graph import knn_graph, median_spacing
from reference_impl.common.roots import find_roots, stem_radii
from reference_impl.livny.bsg import _route_bridges, _stay_near, _unbridged


def _stem_and_crown(rng, stem_xy=(0.0, 0.0)):
    """A 1 m stem (a ring of 6 bark points every 4 cm: 150 points, 3.6 % of the scan, as sparse as AdTree's tree13),
    nothing between 1 and 2 m, a crown ball of radius 1.5 m at 3.5 m over the origin."""
    z = np.repeat(np.arange(0.0, 1.0, 0.04), 6)
    a = np.tile(np.linspace(0, 2 * np.pi, 6, endpoint=False), len(z) // 6)
    stem = np.c_[stem_xy[0] + 0.05 * np.cos(a), stem_xy[1] + 0.05 * np.sin(a), z]
    d = rng.normal(size=(4000, 3))
    crown = np.array([0.0, 0.0, 3.5]) + 1.5 * d / np.linalg.norm(d, axis=1, keepdims=True) * rng.random((4000, 1)) ** (
        1 / 3)
    return np.concatenate([stem, crown]), len(stem)


def _roots(points):
    graph = knn_graph(points, 10, max_edge=3 * median_spacing(points))
    return find_roots(points, points[:, 2], graph, slab=0.02 * 5.0, group_cell=0.05 * 5.0)


def test_a_stem_cut_off_from_its_crown_roots_the_tree(rng):
    points, n_stem = _stem_and_crown(rng)
    roots = _roots(points)
    # the stem, too small to count as a plant of its own (under 5 % of the points), is joined to the crown above it,
    # and the root is at its base, not 2 m up at the crown's bottom
    assert len(roots) == 1
    assert roots[0] < n_stem and points[roots[0], 2] < 0.02


def test_a_post_beside_the_crown_is_not_taken_for_its_stem(rng):
    points, n_stem = _stem_and_crown(rng, stem_xy=(3.0, 0.0))
    roots = _roots(points)
    assert all(r >= n_stem for r in roots)
    assert points[roots, 2].min() > 1.9


def _bridged_tree():
    """A chain of 20 vertices 1 apart on the x axis; a 2-vertex fragment hung 5 away from its end (own length 1), a
    10-vertex fragment hung 4 away from its start (own length 9), itself carrying a 1-vertex fragment 6 away."""
    main = np.c_[np.arange(20.0), np.zeros(20), np.zeros(20)]
    small = np.array([[24.0, 0, 0], [25.0, 0, 0]])
    big = np.c_[np.zeros(10), np.full(10, 4.0), np.arange(10.0)]
    lone = np.array([[0.0, 10.0, 9.0]])
    cloud = np.concatenate([main, small, big, lone])
    parents = np.r_[-1, np.arange(19), 19, 20, 0, np.arange(22, 31), 31]
    return cloud, parents


def test_fragments_smaller_than_their_bridge_are_dropped():
    cloud, parents = _bridged_tree()
    keep = _unbridged(cloud, parents, max_edge=1.5, support=1.0)
    # naive: a bridge (edge > 1.5) is kept when the subtree below it has at least as much non-bridge length
    expect = np.ones(len(cloud), bool)
    expect[20:22] = False  # own 1 < bridge 5
    expect[32] = False  # own 0 < bridge 6
    np.testing.assert_array_equal(keep, expect)
    # a stricter rule (fragments 3x their bridge) drops the 9-long fragment behind its 4-long bridge too
    assert not _unbridged(cloud, parents, max_edge=1.5, support=0.3)[22:].any()


def test_livny_bridges_step_through_the_dropped_scraps():
    cloud, parents = _bridged_tree()
    keep = _unbridged(cloud, parents, max_edge=1.5, support=1.0)
    kept = np.flatnonzero(keep)
    par = parents[kept]
    par = np.where(par >= 0, np.searchsorted(kept, np.maximum(par, 0)), -1)
    # scraps dropped before the bridging: two on the way of the 4-long bridge (0,0,0) -> (0,4,0), one beside it
    scraps = np.array([[0.0, 2.6, 0.1], [0.0, 1.2, -0.1], [3.0, 2.0, 0.0]])
    cloud2 = np.concatenate([cloud, scraps])
    keep2 = np.r_[keep, False, False, False]
    new_keep, new_par, added = _route_bridges(cloud2, keep2, par, max_edge=1.5)
    assert added == 2
    np.testing.assert_array_equal(new_keep, np.r_[keep, True, True, False])
    pos = cloud2[new_keep]
    # a tree still, with the fragment's base now hung from the chain 0 -> (0,1.2) -> (0,2.6) -> fragment
    assert (new_par < 0).sum() == 1 and np.all(new_par < len(pos))
    chain = [int(np.flatnonzero(np.all(pos == [0.0, 4.0, 0.0], axis=1))[0])]
    while new_par[chain[-1]] >= 0:
        chain.append(int(new_par[chain[-1]]))
    np.testing.assert_allclose(pos[chain], [[0, 4, 0], [0, 2.6, 0.1], [0, 1.2, -0.1], [0, 0, 0]])
    # every other vertex keeps its parent
    old = {tuple(cloud[k]): (tuple(cloud[parents[k]]) if parents[k] >= 0 else None) for k in kept}
    for v, p in enumerate(new_par):
        if tuple(pos[v]) in old and tuple(pos[v]) != (0.0, 4.0, 0.0):
            assert (tuple(pos[p]) if p >= 0 else None) == old[tuple(pos[v])]


def test_stay_near_pulls_far_vertices_back_to_the_limit(rng):
    cloud = rng.random((500, 3))
    pos = rng.random((200, 3)) * 3 - 1
    limit = rng.uniform(0.05, 0.2, 200)
    tree = cKDTree(cloud)
    d0, i0 = tree.query(pos)
    out = _stay_near(tree, cloud, pos, limit)
    d1, _ = tree.query(out)
    assert np.all(d1 <= limit + 1e-9)
    near = d0 <= limit
    np.testing.assert_array_equal(out[near], pos[near])
    # a far vertex moves straight towards its nearest cloud point, to the limit
    far = ~near
    np.testing.assert_allclose(np.linalg.norm(out[far] - cloud[i0[far]], axis=1), limit[far])
    cross = np.cross(out[far] - cloud[i0[far]], pos[far] - cloud[i0[far]])
    np.testing.assert_allclose(cross, 0, atol=1e-9)


def test_stem_radii_keeps_the_candidate_circle_on_the_bark():
    # a trunk of radius 0.3 m (a bark band 2 cm thick, seen all round); the root lies inside the ring, off its axis
    r = np.random.default_rng(3)
    a = r.uniform(0, 2 * np.pi, 4000)
    rad = 0.3 + r.normal(0, 0.02, 4000)
    points = np.c_[rad * np.cos(a), rad * np.sin(a), r.uniform(-0.1, 0.6, 4000)]
    root = np.array([[-0.25, 0.05, 0.0]])
    skewed = np.array([[0.2, 0.2, 1.0]]) / np.linalg.norm([0.2, 0.2, 1.0])
    up = np.array([[0.0, 0.0, 1.0]])
    kw = dict(offset=0.08, length=0.55, max_radius=1.1, fallback=0.01, min_radius=0.001)
    # along the skewed axis the nested windows close a circle on a patch of the band
    assert stem_radii(points, root, skewed, **kw)[0] < 0.15
    for axes in ([skewed, up], [up, skewed]):
        assert abs(stem_radii(points, root, axes, **kw)[0] - 0.3) < 0.03
    # no candidate fits (no points near the root): the fallback
    assert stem_radii(points + [5.0, 0, 0], root, [up], **kw)[0] == 0.01


def _trunk_gap_and_limb_scraps(rng):
    """tree33's case: a trunk seen sparsely from 0 to 1.5 m (a ring of 4 bark points every 4 cm, under 5 % of the
    scan: the stem base of the plant above), nothing up to 2.2 m, then on up to 4 m (a ring of 8 every 2 cm) inside a
    crown disc (z 2.4-4 m, x -1 to 2 m); under the crown's right edge a low limb seen as scraps: 3-point clusters about
    0.25 m apart from the trunk's top out to x = 2 m and up to the crown (each too small to count, and nearer its
    neighbours than the trunk's two parts are to each other)."""
    zl, zu = np.repeat(np.arange(0.0, 1.5, 0.04), 4), np.repeat(np.arange(2.2, 4.0, 0.02), 8)
    al = np.tile(np.linspace(0, 2 * np.pi, 4, endpoint=False), len(zl) // 4)
    au = np.tile(np.linspace(0, 2 * np.pi, 8, endpoint=False), len(zu) // 8)
    trunk = np.c_[0.05 * np.cos(np.r_[al, au]), 0.05 * np.sin(np.r_[al, au]), np.r_[zl, zu]]
    crown = np.c_[rng.uniform(-1.0, 2.0, 3000), rng.normal(0, 0.05, 3000), rng.uniform(2.4, 4.0, 3000)]
    steps = np.linspace(0.0, 1.0, 8)[1:]
    centres = np.c_[0.3 + 1.7 * steps, np.zeros(7), 1.5 + 0.75 * steps ** 3]
    scraps = np.concatenate([c + rng.normal(0, 0.01, (3, 3)) for c in centres])
    return np.concatenate([trunk, crown, scraps]), scraps


def _trunk_path_x(bridge_scraps: bool, min_component_voxels: int, rng):
    """Largest |x| on the tree's path from the trunk's top (the kept vertex nearest (0, 0, 3.9)) down to its root,
    and how many of the scraps' points lie within 5 cm of a kept vertex."""
    from reference_impl.common.ground import Ground
    from reference_impl.livny.bsg import LivnyParams, _shortest_path_forest

    points, scraps = _trunk_gap_and_limb_scraps(rng)
    ground = Ground(np.zeros(3), np.ones(len(points), bool), True)
    params = LivnyParams(bridge_scraps=bridge_scraps, min_component_voxels=min_component_voxels, bridge_waypoints=False,
                         bridge_support=0.0)
    keep, parents, _ = _shortest_path_forest(points, ground, 4.0, 0.02, params)
    cloud = points[keep]
    tree = cKDTree(cloud)
    node = int(tree.query([0.0, 0.0, 3.9])[1])
    path = []
    while node >= 0:
        path.append(node)
        node = int(parents[node])
    near = int((tree.query(scraps)[0] < 0.05).sum())
    return float(np.abs(cloud[path, 0]).max()), near


def test_scraps_bridged_in_after_the_trunk_keep_it_straight(rng):
    # every component bridged at once: the scraps join the trunk's parts, and the way up turns out along the limb
    x_all, near_all = _trunk_path_x(False, 0, rng)
    # the large components joined first: the trunk crosses its gap straight, and the scraps hang from the tree
    x_after, near_after = _trunk_path_x(True, 20, np.random.default_rng(12345))
    # the default drops the scraps
    _, near_drop = _trunk_path_x(False, 20, np.random.default_rng(12345))
    assert x_all > 1.0
    assert x_after < 0.1
    assert near_after == near_all == 21 and near_drop == 0
