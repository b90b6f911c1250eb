"""reference_impl.common.skeleton_ops on hand-built skeletons with known answers."""

import numpy as np

from reference_impl.common import skeleton_ops as ops


def test_remove_nodes_reattaches_to_nearest_kept_ancestor(rng):
    n = 200
    par = np.array([-1] + [int(rng.integers(0, i)) for i in range(1, n)])
    keep = rng.random(n) < 0.5
    keep[0] = True
    new_par, index = ops.remove_nodes(par, keep)
    for v in np.flatnonzero(keep):
        u = par[v]
        while u >= 0 and not keep[u]:
            u = par[u]
        assert new_par[index[v]] == (index[u] if u >= 0 else -1)


def _y_tree(side_len: float):
    """A trunk 0..10 along z (1 m steps) with a side branch of ``side_len`` at node 5, and a top fork."""
    pos = [[0, 0, z] for z in range(11)]
    par = [-1] + list(range(10))
    prev = 5
    for i in range(1, int(side_len) + 1):
        pos.append([i, 0, 5])
        par.append(prev)
        prev = len(pos) - 1
    return np.asarray(pos, float), np.asarray(par)


def test_prune_by_ratio_drops_small_and_keeps_large_subtrees():
    pos, par = _y_tree(4)
    assert ops.prune_by_ratio(pos, par, 0.02).all()
    # a 0.1 m twig on node 2 is below 2 % of what node 2 supports (8 + 4 m)
    pos2 = np.vstack([pos, [0.1, 0, 2]])
    par2 = np.append(par, 2)
    keep = ops.prune_by_ratio(pos2, par2, 0.02)
    assert not keep[-1] and keep[:-1].all()


def test_prune_short_tips_removes_spurs_only():
    pos, par = _y_tree(4)
    pos2 = np.vstack([pos, [0.05, 0, 7]])
    par2 = np.append(par, 7)
    keep = ops.prune_short_tips(pos2, par2, 0.5)
    assert not keep[-1] and keep[:-1].all()
    # a lone stem is never removed, however short
    assert ops.prune_short_tips(np.array([[0, 0, 0], [0, 0, 0.01]]), np.array([-1, 0]), 1.0).all()


def test_spatial_merge_fuses_parallel_paths():
    # two chains from the root running 1 mm apart: one path after merging at 5 cm
    z = np.linspace(0.05, 1.0, 20)
    a = np.c_[np.zeros(20), np.zeros(20), z]
    b = a + [0.001, 0, 0]
    pos = np.vstack([[0, 0, 0], a, b])
    par = np.concatenate([[-1, 0], np.arange(1, 20), [0], np.arange(21, 40)])
    mpos, mpar, mass, index = ops.spatial_merge(pos, par, np.ones(len(par)), 0.05)
    assert np.all(index[1:21] == index[21:41])
    assert (mpar < 0).sum() == 1 and np.bincount(mpar[mpar >= 0]).max() == 1  # a single chain
    assert np.isclose(mass.sum(), len(par))


def test_merge_siblings_by_angle():
    pos = np.array([[0, 0, 0], [0, 0, 1], [np.sin(0.1), 0, 1 + np.cos(0.1)], [np.sin(-0.1), 0, 1 + np.cos(-0.1)],
                    [1, 0, 1]], float)
    par = np.array([-1, 0, 1, 1, 1])
    w = np.array([4.0, 3.0, 1.0, 1.0, 1.0])
    mpos, mpar, index = ops.merge_siblings(pos, par, w, max_angle_deg=25)
    assert len(mpos) == 4 and index[2] == index[3]
    assert np.allclose(mpos[index[2]], [0, 0, 1 + np.cos(0.1)])  # the weight-averaged position
    assert mpar[index[4]] == index[1]


def test_remove_degree2_keeps_corners():
    line = np.c_[np.zeros(11), np.zeros(11), np.linspace(0, 1, 11)]
    corner = np.c_[np.linspace(0.1, 1, 10), np.zeros(10), np.ones(10)]
    pos = np.vstack([line, corner])
    par = np.concatenate([[-1], np.arange(10), [10], np.arange(11, 20)])
    alive, new_par = ops.remove_degree2(pos, par, np.full(len(par), 0.01))
    kept = np.flatnonzero(alive)
    assert set(kept) == {0, 10, 20}
    assert list(new_par) == [-1, 0, 1]


def test_hermite_smooth_rounds_a_right_angle():
    pos = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 2], [1, 0, 2]], float)
    par = np.array([-1, 0, 1, 2])
    spos, spar, origin = ops.hermite_smooth(pos, par, min_angle_deg=30)
    # the corner node 2 is gone, replaced by a curve from node 1 to node 3
    assert 2 not in origin and {0, 1, 3} <= set(origin[origin >= 0])
    new = np.flatnonzero(origin < 0)
    assert 2 <= len(new) <= 8
    curve = spos[new]
    # the analytic Hermite curve between A = (0,0,1) and B = (1,0,2) with tangents |AB| z and |AB| x
    a, b = np.array([0, 0, 1.0]), np.array([1, 0, 2.0])
    s = np.arange(1, len(new) + 1) / (len(new) + 1)
    m = np.sqrt(2)
    want = ((2 * s**3 - 3 * s**2 + 1)[:, None] * a + (s**3 - 2 * s**2 + s)[:, None] * m * np.array([0, 0, 1.0])
            + (-2 * s**3 + 3 * s**2)[:, None] * b + (s**3 - s**2)[:, None] * m * np.array([1, 0, 0.0]))
    order = np.argsort(curve[:, 0])
    assert np.allclose(curve[order], want, atol=1e-12)
    # connectivity: 1 -> samples -> 3
    i3 = int(np.flatnonzero(origin == 3)[0])
    chain, v = [], i3
    while spar[v] >= 0:
        chain.append(v)
        v = spar[v]
    assert len(chain) == len(new) + 2  # 3, the samples, 1 (then the root 0)


def test_merge_close_forks_joins_forks_a_short_chain_apart():
    """A stem forking at z = 2 and again 5 cm higher: the second fork merges into the first (its children hang from
    it), one fork instead of two and one branch fewer; a chain from the root is never merged; forks farther apart
    than the length stay."""
    from plantbench.plant import Skeleton
    from plantbench.skeletons import branch_chains
    from reference_impl.common.skeleton_ops import merge_close_forks, remove_nodes

    pos = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 2], [0, 0, 2.05], [1, 0, 2], [1, 0, 2.05], [0, 0, 3]], float)
    par = np.array([-1, 0, 1, 2, 2, 3, 3])
    keep = merge_close_forks(pos, par, 0.1)
    assert keep.tolist() == [True, True, True, False, True, True, True]
    new_par, index = remove_nodes(par, keep)
    assert new_par[index[5]] == index[2] and new_par[index[6]] == index[2]  # the children of the merged fork
    before = len(branch_chains(Skeleton(pos, np.ones(7), par)))
    after = len(branch_chains(Skeleton(pos[keep], np.ones(int(keep.sum())), new_par)))
    assert (before, after) == (5, 4)
    assert merge_close_forks(pos, par, 0.04).all()  # 5 cm apart: not shorter than 4 cm
    # a root with two children close to a fork: the root's chain is the stem's base and stays
    pos2 = np.array([[0, 0, 0], [0, 0, 0.01], [1, 0, 0.01], [0, 0, 1], [0, 1, 0.01]], float)
    par2 = np.array([-1, 0, 1, 1, 1])
    assert merge_close_forks(pos2, par2, 0.5).all()


def test_trim_unsupported_tips_cuts_back_to_the_data_only():
    """A Y: a trunk 0-1-2 forking at 2 into a left branch 3-4-5 whose last two nodes grew past the data and a right
    branch 6-7 with no data at all, plus a supported twig 8 on node 4. Distances to the data are given per node: 5
    goes, 4 stays though far (twig 8 hangs from it), the right branch goes back to the fork, which stays (the left
    branch hangs from it); a root is never removed. Checked against a naive fixed point on a random tree."""
    par = np.array([-1, 0, 1, 2, 3, 4, 2, 6, 4])
    far = 1.0
    dist = np.array([0.0, 0.0, 0.0, 0.0, 2.0, 3.0, 2.0, 2.0, 0.0])
    keep = ops.trim_unsupported_tips(par, dist, far)
    assert keep.tolist() == [True, True, True, True, True, False, False, False, True]
    # without the supported twig, node 4 is a far tip once 5 is gone, and goes too
    keep = ops.trim_unsupported_tips(par[:8], dist[:8], far)
    assert keep.tolist() == [True, True, True, True, False, False, False, False]
    # every node far: back to the root, which stays
    assert ops.trim_unsupported_tips(np.array([-1, 0, 1]), np.full(3, 5.0), far).tolist() == [True, False, False]
    # a naive per-tip walk agrees on a random tree
    rng = np.random.default_rng(3)
    n = 300
    par = np.r_[-1, [rng.integers(0, i) for i in range(1, n)]]
    dist = rng.uniform(0, 2, n)
    keep = ops.trim_unsupported_tips(par, dist, far)
    naive = np.ones(n, bool)
    changed = True
    while changed:  # remove any non-root node that is far and has no kept child, until none is left
        changed = False
        for v in range(1, n):
            if naive[v] and dist[v] > far and not np.any(naive & (par == v)):
                naive[v] = False
                changed = True
    assert keep.tolist() == naive.tolist()
