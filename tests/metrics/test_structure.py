"""Structure metrics (branch-level matching, branch-count error, length-weighted skeleton scores) against hand
computations and a brute-force matcher."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from plantbench.errors import InputError
from plantbench.metrics.skeleton import skeleton_prf
from plantbench.metrics.structure import branch_count_log2_error, branch_matches, branch_prf
from plantbench.plant import Skeleton
from plantbench.skeletons import branch_chains

from .synth import random_tree


def _polyline_tree(rows: list[tuple[int, tuple[float, float, float]]]) -> Skeleton:
    """A skeleton from (parent index, position) rows, in order."""
    par = np.array([p for p, _ in rows])
    pos = np.array([x for _, x in rows], float)
    return Skeleton(pos, np.full(len(pos), 0.01), par)


# a Y: trunk (0,0,0) -> (0,0,1) in four edges, two limbs from its top; three branches
Y = _polyline_tree([(-1, (0, 0, 0)), (0, (0, 0, 0.25)), (1, (0, 0, 0.5)), (2, (0, 0, 0.75)), (3, (0, 0, 1.0)),
                    (4, (0.5, 0, 1.5)), (4, (-0.5, 0, 1.5))])
TAU = 0.015


def test_identical_empty_and_degenerate():
    assert branch_prf(Y, Y, tau=TAU) == {"branch_precision": 1.0, "branch_recall": 1.0, "branch_f1": 1.0}
    empty = Skeleton(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64))
    single = Skeleton(np.zeros((1, 3)), np.full(1, 0.01), np.array([-1]))
    for pred in (empty, single):  # no branch with length
        assert branch_prf(Y, pred, tau=TAU) == {"branch_precision": 0.0, "branch_recall": 0.0, "branch_f1": 0.0}
    with pytest.raises(InputError, match="no branch"):
        branch_prf(single, Y, tau=TAU)
    with pytest.raises(InputError, match="tau"):
        branch_prf(Y, Y, tau=0.0)


def test_missing_limbs_split_and_merged_branches_by_hand():
    # only the trunk: 1 of 3 true branches matched; the one predicted branch is right
    trunk = Skeleton(Y.positions[:5], Y.radii[:5], Y.parents[:5])
    assert branch_prf(Y, trunk, tau=TAU) == {"branch_precision": 1.0, "branch_recall": pytest.approx(1 / 3),
                                             "branch_f1": pytest.approx(2 * 1 / (3 + 1))}
    # a far twig at z = 0.25 splits the trunk into 0.25 m and 0.75 m: the longer piece matches the trunk (more than
    # half of each lies along the other), the shorter piece and the twig do not: 3 matches of 3 true, 5 predicted
    split = Skeleton(np.vstack([Y.positions, [[0.6, 0, 0.25]]]), np.full(8, 0.01), np.append(Y.parents, 1))
    assert len(branch_chains(split)) == 5
    assert branch_matches(Y, split, tau=TAU) == (3, 3, 5)
    # the trunk and one limb merged into one branch (the other limb missing): it lies along the trunk for 1 of
    # 1.71 m and covers all of it, but the limb covers less than half of it: one match
    merged = Skeleton(Y.positions[:6], Y.radii[:6], Y.parents[:6])
    assert branch_matches(Y, merged, tau=TAU) == (1, 3, 1)
    # two predicted branches along one true branch: one match, one error (matching is one-to-one)
    double = Skeleton(np.vstack([Y.positions, Y.positions[5] + [0, 0.005, 0]]), np.full(8, 0.01),
                      np.append(Y.parents, 4))
    assert branch_matches(Y, double, tau=TAU) == (3, 3, 4)


def _naive_matches(gt: Skeleton, pred: Skeleton, tau: float, step: float = 0.0005) -> int:
    """Brute force: every branch sampled every 0.5 mm, exact point-to-segment distances to every segment of the
    other branch, mutual majority, then the largest one-to-one matching by trying every assignment."""

    def samples(sk, chain):
        p = sk.positions[chain]
        out, w = [], []
        for a, b in zip(p[:-1], p[1:]):
            n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
            t = (np.arange(n) + 0.5) / n
            out.append(a + t[:, None] * (b - a))
            w.append(np.full(n, np.linalg.norm(b - a) / n))
        return np.concatenate(out), np.concatenate(w)

    def dist(q, sk, chain):
        p = sk.positions[chain]
        a, b = p[:-1], p[1:]
        ab = b - a
        t = np.clip(np.einsum("qsk,sk->qs", q[:, None] - a[None], ab) / np.maximum((ab * ab).sum(1), 1e-300), 0, 1)
        return np.linalg.norm(q[:, None] - (a[None] + t[..., None] * ab[None]), axis=2).min(axis=1)

    def majority(src, ci, dst, cj):
        q, w = samples(src, ci)
        return w[dist(q, dst, cj) <= tau].sum() > 0.5 * w.sum()

    gc, pc = branch_chains(gt), branch_chains(pred)
    ok = {(i, j) for i, a in enumerate(gc) for j, b in enumerate(pc) if majority(gt, a, pred, b) and majority(pred, b, gt, a)}
    best = 0
    for k in range(min(len(gc), len(pc)), 0, -1):
        if any(len({j for _, j in combo}) == k and len({i for i, _ in combo}) == k
               for combo in itertools.combinations(sorted(ok), k)):
            best = k
            break
    return best


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_a_brute_force_matcher(seed):
    r = np.random.Generator(np.random.PCG64(seed))
    gt = random_tree(r, 4, trunk_segments=8)
    # the prediction: the tree moved by a little noise, one lateral dropped, one far twig added
    pos = gt.positions + r.normal(0, 0.002, gt.positions.shape)
    par = gt.parents.copy()
    keep = np.ones(len(gt), bool)
    tips = np.flatnonzero(gt.children_counts() == 0)
    drop = tips[-1]
    while par[drop] >= 0 and gt.children_counts()[par[drop]] == 1:
        keep[drop] = False
        drop = par[drop]
    keep[drop] = False
    idx = np.cumsum(keep) - 1
    pred = Skeleton(np.vstack([pos[keep], pos[5] + [0.3, 0.0, 0.0]]), np.full(keep.sum() + 1, 0.01),
                    np.append(np.where(par[keep] >= 0, idx[np.maximum(par[keep], 0)], -1), idx[5]))
    tau = 0.01
    matched, n_true, n_pred = branch_matches(gt, pred, tau=tau)
    assert (n_true, n_pred) == (len(branch_chains(gt)), len(branch_chains(pred)))
    assert matched == _naive_matches(gt, pred, tau)
    assert 0 < matched < n_true


def test_branch_count_error():
    assert branch_count_log2_error(100, 100) == 0.0
    assert branch_count_log2_error(100, 200) == pytest.approx(1.0)
    assert branch_count_log2_error(100, 50) == pytest.approx(1.0)
    assert branch_count_log2_error(100, 500) == pytest.approx(np.log2(5))
    assert branch_count_log2_error(64, 0) == pytest.approx(6.0)  # an empty prediction counts as one branch
    with pytest.raises(InputError):
        branch_count_log2_error(-1, 3)


def test_length_weighted_scores_by_hand():
    # GT: a vertical 1 m stem; prediction: the stem and a horizontal 0.5 m twig from its middle. tau = 1 % of 1 m:
    # the twig's first centimetre lies within tau of the stem, the rest does not -> lprecision (1 + 0.01) / 1.5,
    # lrecall 1; weighted by volume, the 1 mm twig weighs (0.5 - 0.01) pi 0.001^2 against the 1 cm stem's
    # pi 0.01^2 (wood precision about 0.995)
    gt = Skeleton(np.array([[0, 0, 0], [0, 0, 0.5], [0, 0, 1.0]]), np.full(3, 0.01), np.array([-1, 0, 1]))
    pred = Skeleton(np.vstack([gt.positions, [[0.5, 0, 0.5]]]), np.array([0.01, 0.01, 0.01, 0.001]),
                    np.array([-1, 0, 1, 1]))
    twig_radius = np.array([0.01, 0.001])  # the twig tapers from the stem's radius to 1 mm: integrate pi r(x)^2
    out = skeleton_prf(gt, pred, height=1.0, thresholds=(1.0,), step=0.0005)
    assert out["lrecall@1%"] == pytest.approx(1.0)
    assert out["lprecision@1%"] == pytest.approx(1.01 / 1.5, abs=2e-3)
    x = np.linspace(0, 0.5, 100_001)
    r = twig_radius[0] + (twig_radius[1] - twig_radius[0]) * x / 0.5
    twig_far = np.trapezoid(np.pi * r[x > 0.01] ** 2, x[x > 0.01])
    total = 1.0 * np.pi * 0.01**2 + np.trapezoid(np.pi * r**2, x)
    assert out["vprecision@1%"] == pytest.approx(1 - twig_far / total, abs=2e-3)
    assert out["lf1@1%"] == pytest.approx(2 * out["lprecision@1%"] / (1 + out["lprecision@1%"]))
