"""Space colonisation growth: marker perception against brute force, and the grown structure's invariants."""

import numpy as np

from plantbench.generate.palubicki import GrowthParams, assign_markers, grow_space_colonisation, perceive
from plantbench.plant import Skeleton


def _brute_force(markers, bud_pos, bud_dir, radius, cos_half):
    out = np.full(len(markers), -1)
    for i, m in enumerate(markers):
        best, best_d = -1, np.inf
        for b, (p, d) in enumerate(zip(bud_pos, bud_dir)):
            v = m - p
            dist = np.linalg.norm(v)
            if 0 < dist <= radius and v @ d / dist >= cos_half and dist < best_d:
                best, best_d = b, dist
        out[i] = best
    return out


def test_assign_markers_matches_brute_force(rng):
    markers = rng.random((300, 3))
    bud_pos = rng.random((25, 3))
    bud_dir = rng.normal(size=(25, 3))
    bud_dir /= np.linalg.norm(bud_dir, axis=1, keepdims=True)
    cos_half = np.cos(np.radians(45))
    got = assign_markers(markers, bud_pos, bud_dir, radius=0.4, cos_half_angle=cos_half, neighbours=25)
    np.testing.assert_array_equal(got, _brute_force(markers, bud_pos, bud_dir, 0.4, cos_half))


def test_assign_markers_penalty_breaks_ties(rng):
    """Two buds at each place (guo's apical and lateral bud of one node): without a penalty the first found wins;
    a penalty on one of them hands its markers to the other, wherever both perceive them."""
    markers = rng.random((300, 3))
    pos = rng.random((10, 3))
    bud_pos = np.repeat(pos, 2, axis=0)
    bud_dir = np.repeat(rng.normal(size=(10, 3)), 2, axis=0)
    bud_dir /= np.linalg.norm(bud_dir, axis=1, keepdims=True)
    kw = {"radius": 0.5, "cos_half_angle": np.cos(np.radians(60)), "neighbours": 20}
    plain = assign_markers(markers, bud_pos, bud_dir, **kw)
    for lose in (0, 1):
        penalty = np.where(np.arange(20) % 2 == lose, 1e-9, 0.0)
        got = assign_markers(markers, bud_pos, bud_dir, penalty=penalty, **kw)
        np.testing.assert_array_equal(got >= 0, plain >= 0)
        np.testing.assert_array_equal(got[got >= 0] // 2, plain[plain >= 0] // 2)  # the same place
        assert np.all(got[got >= 0] % 2 != lose)


def test_perceive_direction_is_mean_unit_vector():
    bud_pos = np.zeros((1, 3))
    bud_dir = np.array([[0.0, 0.0, 1.0]])
    markers = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 0.0, -1.0]])  # the last is behind the bud
    q, v = perceive(markers, bud_pos, bud_dir, radius=2.0, cos_half_angle=np.cos(np.radians(50)))
    expect = np.array([0, 0, 1]) + np.array([1, 0, 1]) / np.sqrt(2)
    np.testing.assert_allclose(v[0], expect / np.linalg.norm(expect))
    assert q[0] == 1


def _grow(rng, roots=((0.0, 0.0, 0.0),), **kw):
    params = GrowthParams(internode_length=0.05, roll_angle=137.5, branching_angle=40, bud_break=0.5,
                          max_iterations=30, bole_height=0.3, **kw)
    markers = np.column_stack([rng.uniform(-0.4, 0.4, 3000), rng.uniform(-0.4, 0.4, 3000), rng.uniform(0.3, 1.0, 3000)])
    roots = np.asarray(roots, float)
    return grow_space_colonisation(markers, roots, np.tile([0.0, 0.0, 1.0], (len(roots), 1)), params, rng), params


def test_grown_structure_is_a_rooted_tree_of_internodes(rng):
    res, params = _grow(rng)
    n = len(res.positions)
    assert n > 100
    assert np.all(res.parents[1:] < np.arange(1, n))  # parents precede children
    assert np.sum(res.parents < 0) == 1
    seg = np.linalg.norm(res.positions[1:] - res.positions[res.parents[1:]], axis=1)
    np.testing.assert_allclose(seg, params.internode_length)  # every internode has length l
    # at most one main and one lateral child per node
    kids = np.bincount(res.parents[1:], minlength=n)
    assert kids.max() <= 2
    lat_kids = np.bincount(res.parents[1:][res.lateral[1:]], minlength=n)
    assert lat_kids.max() <= 1
    # branch order rises by one at each lateral
    par = res.parents[1:]
    np.testing.assert_array_equal(res.order[1:], res.order[par] + res.lateral[1:])
    assert Skeleton(res.positions, np.ones(n), res.parents).is_forest()
    # growth stays near the envelope: nothing beyond the perception radius around the marker box
    reach = params.perception_radius * params.internode_length
    assert res.positions[:, 2].max() <= 1.0 + reach
    assert np.abs(res.positions[:, :2]).max() <= 0.4 + reach


def test_lateral_bud_leaves_at_the_branching_angle(rng):
    res, params = _grow(rng, noise=0.0, direction_weight=0.0, tropism=0.0)
    lat = np.flatnonzero(res.lateral)
    assert len(lat)
    par = res.parents[lat]
    cosang = np.sum(res.headings[lat] * res.headings[par], axis=1)
    np.testing.assert_allclose(np.degrees(np.arccos(np.clip(cosang, -1, 1))), params.branching_angle, atol=1e-6)


def test_several_roots_compete(rng):
    roots = [(-0.2, 0.0, 0.0), (0.2, 0.0, 0.0), (0.0, 0.25, 0.0)]
    res, _ = _grow(rng, roots=roots)
    root_idx = np.flatnonzero(res.parents < 0)
    assert len(root_idx) == 3
    np.testing.assert_allclose(res.positions[root_idx, 2], 0.0)
    # every root grew its own stem
    owner = np.arange(len(res.parents))
    for i in range(len(owner)):
        if res.parents[i] >= 0:
            owner[i] = owner[res.parents[i]]
    assert all(np.sum(owner == r) > 10 for r in root_idx)


def test_apical_control_makes_the_leader_dominate(rng):
    """Higher lambda (Borchert-Honda apical control) gives fewer laterals for the same markers."""
    low, _ = _grow(np.random.default_rng(3), apical_control=0.45)
    high, _ = _grow(np.random.default_rng(3), apical_control=0.75)
    assert high.lateral.sum() < low.lateral.sum()


def test_heading_turns_at_most_max_turn_per_internode(rng):
    res, _ = _grow(rng, max_turn=7.0, direction_weight=1.5, noise=0.3)
    child = np.flatnonzero((res.parents >= 0) & ~res.lateral)
    child = child[res.parents[child] != 0]  # the root's heading is not an internode's
    cosang = np.sum(res.headings[child] * res.headings[res.parents[child]], axis=1)
    assert np.degrees(np.arccos(np.clip(cosang, -1, 1))).max() <= 7.0 + 1e-6


def test_growable_nodes_keep_rows_and_fill_across_growth():
    """Rows added before a capacity doubling survive it; columns not given keep their fill; alive set on add."""
    from plantbench.geometry.nodes import GrowableNodes

    nodes = GrowableNodes({"pos": ((3,), np.float64, 0.0), "parent": ((), np.int64, -1),
                           "alive": ((), bool, False)}, cap=2)
    a = nodes.add(pos=np.ones((2, 3)))
    b = nodes.add(pos=np.full((3, 3), 2.0), parent=np.array([0, 1, 1]))
    assert list(a) == [0, 1] and list(b) == [2, 3, 4] and nodes.n == 5 and len(nodes.pos) >= 5
    assert np.array_equal(nodes.pos[:5], np.repeat([[1.0], [1.0], [2.0], [2.0], [2.0]], 3, axis=1))
    assert list(nodes.parent[:5]) == [-1, -1, 0, 1, 1] and np.all(nodes.parent[5:] == -1)
    assert nodes.alive[:5].all() and not nodes.alive[5:].any()


def test_alive_rows_renumber_parents_among_the_living():
    from plantbench.geometry.nodes import GrowableNodes

    nodes = GrowableNodes({"pos": ((3,), np.float64, 0.0), "parent": ((), np.int64, -1),
                           "alive": ((), bool, False)})
    nodes.add(pos=np.zeros((5, 3)), parent=np.array([-1, 0, 1, 2, 1]))
    nodes.alive[2] = False  # node 3 hangs from a dead node: it becomes a root
    keep, parents = nodes.alive_rows()
    assert list(keep) == [0, 1, 3, 4] and list(parents) == [-1, 0, -1, 1]
