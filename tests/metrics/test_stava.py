"""Stava similarity: exact identity, symmetry, invariances, monotone decrease, and the tree edit distance against a
textbook recursive implementation (Zhang's recursion with scipy's assignment, Stava's split/merge written as the
paper's recursion on explicitly fused polylines)."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from plantbench.errors import InputError
from plantbench.metrics import stava
from plantbench.metrics.stava import (
    StavaParams,
    assign_cost,
    branch_graph,
    descriptor_delta,
    minkowski_mean,
    polyline_properties,
    shape_descriptors,
    stava_similarities,
    stava_similarity,
    tree_edit_distance,
)
from plantbench.plant import Skeleton
from plantbench.skeletons import branch_chains

from .synth import bend, prune_terminal, random_tree, rotate_z, scaled


def naive_tree_distance(s1: Skeleton, s2: Skeleton, max_chain: int, c: float = 0.5, p: float = 2.5) -> float:
    """Recursive reference: d_N on chains (tuples of branch ids), d_F by a square LSA cost matrix."""
    trees = []
    for s in (s1, s2):
        g = branch_graph(s)
        chains = branch_chains(s)
        kids = [tuple(k) for k in g.children()]
        own = g.length * g.diameter
        tsum = own.copy()
        for i in reversed(range(len(g))):  # parents come first in branch_chains order
            tsum[i] += sum(tsum[k] for k in kids[i])
        tops = tuple(i for i in range(len(g)) if g.parent[i] < 0)
        trees.append((s, chains, kids, own, tsum, tops))

    @cache
    def props(t: int, path: tuple) -> tuple:
        s, chains, *_ = trees[t]
        idx = np.concatenate([chains[path[0]]] + [chains[q][1:] for q in path[1:]])
        pr = polyline_properties(s.positions[idx], s.radii[idx])
        return pr["length"], pr["diameter"], (pr["slope"], pr["straightness"], pr["deformation"])

    def gamma(A, B):
        la, da, sa = props(0, A)
        lb, db, sb = props(1, B)
        return float(assign_cost(la, da, sa, lb, db, sb, c=c, p=p))

    K1, K2 = trees[0][2], trees[1][2]
    T1, T2 = trees[0][4], trees[1][4]

    @cache
    def dN(A: tuple, B: tuple) -> float:
        a, b = A[-1], B[-1]
        best = gamma(A, B) + dF(K1[a], K2[b])
        if len(A) < max_chain:  # merge a's last node with one of its children, delete the others
            for ch in K1[a]:
                best = min(best, sum(T1[k] for k in K1[a]) - T1[ch] + dN(A + (ch,), B))
        if len(B) < max_chain:  # split
            for ch in K2[b]:
                best = min(best, sum(T2[k] for k in K2[b]) - T2[ch] + dN(A, B + (ch,)))
        if len(A) == 1 and len(B) == 1:  # Zhang: map one tree into a child subtree of the other
            for ch in K2[b]:
                best = min(best, T2[b] + dN(A, (ch,)) - T2[ch])
            for ch in K1[a]:
                best = min(best, T1[a] + dN((ch,), B) - T1[ch])
        return best

    @cache
    def dF(X: tuple, Y: tuple) -> float:
        n, m = len(X), len(Y)
        big = 1e18
        M = np.zeros((n + m, n + m))
        M[:n, m:] = big
        M[n:, :m] = big
        for i, x in enumerate(X):
            M[i, m + i] = T1[x]
            for j, y in enumerate(Y):
                M[i, j] = dN((x,), (y,))
        for j, y in enumerate(Y):
            M[n + j, j] = T2[y]
        r, cc = linear_sum_assignment(M)
        best = float(M[r, cc].sum())
        for y in Y:  # Zhang: X maps into the children forest of one tree y of Y
            best = min(best, sum(T2[k] for k in Y) - sum(T2[k] for k in K2[y]) + dF(X, K2[y]))
        for x in X:
            best = min(best, sum(T1[k] for k in X) - sum(T1[k] for k in K1[x]) + dF(K1[x], Y))
        return best

    return dF(trees[0][5], trees[1][5])


@pytest.mark.parametrize("max_chain", [1, 2, 3])
def test_tree_edit_distance_matches_recursive_reference(max_chain):
    for seed in range(6):
        rng = np.random.default_rng(seed)
        a = random_tree(rng, int(rng.integers(2, 6)), trunk_segments=6)
        b = random_tree(rng, int(rng.integers(2, 6)), trunk_segments=6)
        if seed % 3 == 0:
            b = prune_terminal(a, 0.5, rng)  # near-identical pair: split/merge matters
        got, _ = tree_edit_distance(branch_graph(a), branch_graph(b), max_chain=max_chain)
        want = naive_tree_distance(a, b, max_chain)
        assert got == pytest.approx(want, rel=1e-9, abs=1e-12)


def whorl_tree(rng: np.random.Generator, whorls: int, per_whorl: tuple[int, int]) -> Skeleton:
    """A trunk with whorls of 2-7 laterals at one node each (a conifer's habit): branch-graph nodes of degree > 4,
    the case the tree edit distance solves with a linear assignment instead of enumerating permutations."""
    pos, rad, par = [np.zeros(3)], [0.03], [-1]
    for w in range(whorls):
        top = len(pos) - 1
        for _ in range(2):  # two trunk segments up to the whorl node
            pos.append(pos[top] + [0.0, 0.0, 0.1 + 0.02 * rng.random()])
            rad.append(0.03 * (1 - 0.15 * (w + 1)))
            par.append(top)
            top = len(pos) - 1
        for _ in range(int(rng.integers(*per_whorl))):
            a = rng.uniform(0, 2 * np.pi)
            d = np.array([np.cos(a), np.sin(a), rng.uniform(-0.3, 0.6)])
            node = top
            for i in range(int(rng.integers(1, 4))):
                pos.append(pos[node] + 0.06 * d / np.linalg.norm(d) + rng.normal(0, 0.005, 3))
                rad.append(0.01 * (1 - 0.2 * i))
                par.append(node)
                node = len(pos) - 1
    return Skeleton(np.array(pos), np.array(rad), np.array(par))


@pytest.mark.parametrize("max_chain", [1, 3])
def test_tree_edit_distance_with_high_degree_nodes_matches_recursive_reference(max_chain):
    for seed in range(4):
        rng = np.random.default_rng(100 + seed)
        a = whorl_tree(rng, 2, (5, 8))
        b = whorl_tree(rng, 2, (2, 8)) if seed % 2 else prune_terminal(a, 0.4, rng)
        g1, g2 = branch_graph(a), branch_graph(b)
        assert max(len(k) for k in g1.children()) > 4
        got, _ = tree_edit_distance(g1, g2, max_chain=max_chain)
        assert got == pytest.approx(naive_tree_distance(a, b, max_chain), rel=1e-9, abs=1e-12)


def bushy_tree(rng: np.random.Generator, n: int) -> Skeleton:
    """A random recursive tree (each node hangs from a random earlier one): branch-graph nodes of many degrees, also
    within one subtree height."""
    pos, rad, par = [np.zeros(3)], [0.03], [-1]
    for i in range(1, n):
        p = int(rng.integers(0, i))
        d = rng.normal(0, 1, 3) + [0, 0, 1.5]
        pos.append(pos[p] + 0.05 * d / np.linalg.norm(d))
        rad.append(0.6 * rad[p] + 0.002)
        par.append(p)
    return Skeleton(np.array(pos), np.array(rad), np.array(par))


@pytest.mark.parametrize("small_limits", [False, True])
def test_tree_edit_distance_matches_recursive_reference_on_larger_trees(monkeypatch, small_limits):
    """Trees with several height groups, degree classes 1-2, 3-4, 5-8 and 9-16 (conifers with 3-5 against 6-9
    laterals per whorl: more child maps than enumerated, the linear-assignment fallback; bushy trees: several degrees
    in one class and height) and chains of 1-3 branches, both variants at once as stava_similarities computes them.

    With small_limits, blocks hold a few node pairs, chain costs take several passes, child matchings are split, and
    every matching with more than two children on a side goes through the linear assignment."""
    if small_limits:
        monkeypatch.setattr(stava, "_BLOCK", 6)
        monkeypatch.setattr(stava, "_CHUNK", 40)
        monkeypatch.setattr(stava, "_TEMP", 16)
        monkeypatch.setattr(stava, "_MAX_MAPS", 2)
    rng = np.random.default_rng(7)
    a = random_tree(rng, 14)
    pairs = [(a, prune_terminal(a, 0.3, rng)), (a, random_tree(rng, 12)),
             (whorl_tree(rng, 3, (3, 6)), whorl_tree(rng, 3, (6, 10))), (bushy_tree(rng, 40), bushy_tree(rng, 36))]
    for x, y in pairs:
        g1, g2 = branch_graph(x), branch_graph(y)
        got = stava._tree_edit_distances(g1, g2, 0.5, 2.5, 3, True)
        for (d, _), max_chain in zip(got, (3, 1)):
            assert d == pytest.approx(naive_tree_distance(x, y, max_chain), rel=1e-9, abs=1e-12)
        d2, _ = tree_edit_distance(g1, g2, max_chain=2)
        assert d2 == pytest.approx(naive_tree_distance(x, y, 2), rel=1e-9, abs=1e-12)


def test_stava_similarities_is_both_variants(rng):
    a = random_tree(rng, 8)
    b = bend(prune_terminal(a, 0.3, rng), 10.0, rng)
    both = stava_similarities(a, b)
    assert both == (stava_similarity(a, b, split_merge=True), stava_similarity(a, b, split_merge=False))
    assert both[0].d_T <= both[1].d_T and both[0].d_S == both[1].d_S


def test_split_merge_never_costs_more_and_helps_on_missing_side_branches(rng):
    a = random_tree(rng, 12)
    b = prune_terminal(a, 0.3, np.random.default_rng(3))
    g1, g2 = branch_graph(a), branch_graph(b)
    d = [tree_edit_distance(g1, g2, max_chain=k)[0] for k in (1, 2, 3)]
    assert d[0] > d[1] >= d[2]


def test_identical_trees_exactly_one(rng):
    t = random_tree(rng, 25)
    for split in (True, False):
        r = stava_similarity(t, t, split_merge=split)
        assert (r.S_T, r.d_S, r.d_G, r.d_T) == (1.0, 0.0, 0.0, 0.0)


def test_symmetric(rng):
    a, b = random_tree(rng, 20), random_tree(rng, 15)
    ab, ba = stava_similarity(a, b), stava_similarity(b, a)
    for x, y in zip(ab.as_dict().values(), ba.as_dict().values()):
        assert x == pytest.approx(y, abs=1e-12)
    assert 0 < ab.S_T < 1


def test_invariant_to_translation_and_rotation_about_z(rng):
    a, b = random_tree(rng, 20), random_tree(rng, 20)
    base = stava_similarity(a, b).S_T
    for angle, off in ((0.7, (1.0, -2.0, 0.5)), (2.5, (0.0, 0.0, 0.0)), (0.0, (3.0, 3.0, 3.0))):
        moved = stava_similarity(rotate_z(a, angle, off), rotate_z(b, angle, off)).S_T
        assert moved == pytest.approx(base, abs=1e-9)
    assert stava_similarity(a, rotate_z(a, 1.1, (0.3, 0.2, 0.1))).S_T == pytest.approx(1.0, abs=1e-9)


@pytest.mark.parametrize("split", [True, False])
def test_strictly_decreasing_under_pruning_scaling_bending(rng, split):
    t = random_tree(rng, 30)
    pruned = [stava_similarity(t, prune_terminal(t, f, np.random.default_rng(7)), split_merge=split).S_T
              for f in (0.0, 0.1, 0.3, 0.5)]
    grown = [stava_similarity(t, scaled(t, s), split_merge=split).S_T for s in (1.0, 1.1, 1.5, 2.0)]
    bent = [stava_similarity(t, bend(t, m, np.random.default_rng(7)), split_merge=split).S_T
            for m in (0.0, 5.0, 15.0, 30.0)]
    for seq in (pruned, grown, bent):
        assert seq[0] == 1.0
        assert all(x > y for x, y in zip(seq, seq[1:])), seq


def test_scaling_d_T_closed_form(rng):
    # same topology and shape, every length and diameter times k: gamma_A = (k - 1) L D per branch, so
    # d_T = sum (k - 1) L D / (2 k^2 sum L D) ... = (k - 1) / (2 k) with the normaliser k^2 sum L D.
    t = random_tree(rng, 10)
    for k in (1.5, 2.0):
        r = stava_similarity(t, scaled(t, k))
        assert r.d_T == pytest.approx((k - 1) / (2 * k), rel=1e-9)
        assert r.d_G == pytest.approx(0.0, abs=1e-9)  # angles and ratios do not change with scale


def test_delta_and_minkowski():
    assert descriptor_delta(2.0, 2.0) == 0.0
    assert descriptor_delta(0.0, 0.0) == 0.0
    assert descriptor_delta(0.0, 1.0) == 1.0
    # sigma = 0.5 * 1 -> 1 - exp(-0.1^2 / 0.5)
    assert descriptor_delta(1.0, 1.1) == pytest.approx(1 - np.exp(-0.01 / 0.5))
    assert minkowski_mean([0.0, 1.0], p=2.5) == pytest.approx(0.5 ** 0.4)


def test_shape_descriptors_by_hand():
    # trunk 0 -> (0,0,1), two straight laterals with tips at z = 1.5 and 2.0: crown = nodes of terminal branches
    pos = np.array([[0, 0, 0], [0, 0, 1], [1, 0, 1.5], [0, 0, 2.0]], float)
    s = Skeleton(pos, np.full(4, 0.01), np.array([-1, 0, 1, 1]))
    d = shape_descriptors(branch_graph(s))
    assert d[0] == pytest.approx(2.0)
    assert len(d) == 13
    # crown z = {1, 1.5, 2}: mean 1.5, upper half {1.5, 2} -> 1.75, lower {1} -> 1: slabs [1,1), [1,1.75), [1.75,2]
    assert d[1] == pytest.approx(0.0) and d[5] == pytest.approx(0.75) and d[9] == pytest.approx(0.25)


def test_degenerate_inputs(rng):
    t = random_tree(rng, 5)
    empty = Skeleton(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64))
    single = Skeleton(np.zeros((1, 3)), np.ones(1), np.array([-1]))
    for bad in (empty, single):
        r = stava_similarity(t, bad)
        assert (r.S_T, r.d_S, r.d_G, r.d_T) == (0.0, 1.0, 1.0, 1.0)
        with pytest.raises(InputError, match="no branch"):
            stava_similarity(bad, t)
    with pytest.raises(InputError):
        StavaParams(max_chain=0)
    # a planar tree (zero minor radius) gives finite descriptors, no NaN
    flat = Skeleton(np.array([[0, 0, 0], [0, 0, 1], [1, 0, 2], [-1, 0, 2]], float), np.full(4, 0.01),
                    np.array([-1, 0, 1, 1]))
    r = stava_similarity(flat, t)
    assert all(np.isfinite(v) for v in r.as_dict().values())


def test_multi_root_forest(rng):
    a = random_tree(rng, 6)
    b = random_tree(rng, 6)
    both = Skeleton(np.concatenate([a.positions, b.positions + [1, 0, 0]]), np.concatenate([a.radii, b.radii]),
                    np.concatenate([a.parents, np.where(b.parents >= 0, b.parents + len(a), -1)]))
    assert stava_similarity(both, both).S_T == 1.0
    assert stava_similarity(both, a).S_T < 1.0
