"""Structure metrics: does a reconstruction have the plant's branches, no more and no fewer?

The volume-weighted skeleton scores (:mod:`plantbench.metrics.skeleton`) weight every sample by pi r^2 x length, so
the trunk and the main limbs carry them and a twig weighs almost nothing: a skeleton with five times the true branch
count scores as well as the exact one. The metrics here count branches instead.

A *branch* is a Stava chain (:func:`plantbench.skeletons.branch_chains`): a maximal unbranched chain of nodes, from
a root or a fork to the next fork or a tip, the fork it hangs from included. It is the branch of the paper's
|B| (``skeleton.branch_count``).

**Branch-level precision, recall and F1** (:func:`branch_prf`), at a tolerance tau (metres; the evaluation uses
1 % of the ground-truth height). A true branch is *found* when more than half of its length lies within tau of one
single predicted branch; a predicted branch is *correct* when more than half of its length lies within tau of one
single true branch. recall = found true branches / true branches, precision = correct predicted branches /
predicted branches, F1 their harmonic mean. Every branch counts once, whatever its length: an invented twig costs as
much precision as a missing limb costs recall. Matching is many-to-one (two predicted branches along one true
branch are both correct; the true branch is found once). "One single branch" is what makes it a structure metric: a
skeleton whose forks are wrong (a tangle: edges across the gaps between branches) splits and re-joins chains, so a
true branch covered half by one predicted branch and half by another is not found, even though every point of it
lies near the prediction.

The field's practice, and where this definition stands in it: the airway-tree benchmarks (EXACT'09, Lo et al. 2012;
ATM'22, Zhang et al. 2023) report the *branch detected rate*, the share of the reference branches that a
segmentation detects, beside the *tree-length detected rate*, the share of the reference centreline length it covers:
our branch recall and ``skeleton.lrecall`` play those parts. Neuron-tracing metrics (DIADEM, Gillette et al. 2011;
SkeletonMetrics) count *splits* and *merges* of the reference's branches; a split or merged true branch fails the
one-branch majority rule here. Smart-Tree (Dobbs et al. 2023) scores learned tree skeletonisers by sample-wise
precision and recall within a radius-relative tolerance, which :func:`plantbench.metrics.skeleton.skeleton_prf`
reports. The majority (> 1/2) threshold is ours: it makes "found by one predicted branch" unique.

Computation: each skeleton is cut into pieces of at most tau / :data:`SAMPLES_PER_TAU` along its edges, each piece
represented by its midpoint and weighted by its length; a piece lies "within tau of a branch" when a piece midpoint
of that branch lies within tau of its midpoint. The distances are therefore those between midpoints, which differ
from the exact point-to-polyline distances by at most half a piece (tau / 8).

**Branch-count error** (:func:`branch_count_log2_error`): |log2(predicted / true)|, the number of doublings between
the two counts (0 exact, 1 for half or twice as many, 2.32 for five times).

Degenerate cases: an empty prediction (no node, or no branch with length) scores precision = recall = F1 = 0 and a
branch-count error of log2(true), as if it had one branch; a ground truth without a branch raises
:class:`~plantbench.errors.InputError`. A zero-length branch (two nodes at one place) is found, or correct, when one
branch of the other skeleton lies within tau of it.
"""

from __future__ import annotations

import numpy as np

from plantbench.errors import InputError
from plantbench.plant import Skeleton
from plantbench.skeletons import branch_chains

__all__ = ["SAMPLES_PER_TAU", "ChainPieces", "chain_pieces", "branch_matches", "branch_prf", "branch_count_log2_error"]

SAMPLES_PER_TAU = 4
"""Pieces per tolerance length: a piece is at most tau / 4 long, its midpoint within tau / 8 of any of its points."""

_CHUNK = 50_000
"""Pieces whose neighbours are gathered at once (bounds the memory of the pair lists)."""


class ChainPieces:
    """A skeleton cut into pieces of at most ``step`` metres along its edges, each labelled with its branch.

    points : (k, 3) float, the pieces' midpoints; length : (k,) float, their lengths;
    chain : (k,) int, the branch (index into :func:`plantbench.skeletons.branch_chains`) each piece belongs to;
    chain_length : (c,) float, each branch's length; a zero-length branch has one piece of length 0.
    """

    def __init__(self, points: np.ndarray, length: np.ndarray, chain: np.ndarray, chain_length: np.ndarray) -> None:
        self.points, self.length, self.chain, self.chain_length = points, length, chain, chain_length

    @property
    def n_chains(self) -> int:
        return len(self.chain_length)


def chain_pieces(skeleton: Skeleton, step: float) -> ChainPieces:
    """:class:`ChainPieces` of ``skeleton`` with pieces at most ``step`` (> 0) metres long."""
    chains = branch_chains(skeleton)
    if not chains:
        return ChainPieces(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), np.zeros(0))
    pos = skeleton.positions
    sizes = np.array([len(c) - 1 for c in chains])
    a = np.concatenate([c[:-1] for c in chains])
    b = np.concatenate([c[1:] for c in chains])
    edge_chain = np.repeat(np.arange(len(chains)), sizes)
    d = pos[b] - pos[a]
    edge_len = np.linalg.norm(d, axis=1)
    n = np.maximum(1, np.ceil(edge_len / step).astype(np.int64))
    seg = np.repeat(np.arange(len(a)), n)
    t = (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n) + 0.5) / np.repeat(n, n)
    points = pos[a][seg] + t[:, None] * d[seg]
    length = np.repeat(edge_len / n, n)
    chain = edge_chain[seg]
    return ChainPieces(points, length, chain, np.bincount(edge_chain, weights=edge_len, minlength=len(chains)))


def _majority_pairs(src: ChainPieces, dst: ChainPieces, tau: float) -> np.ndarray:
    """Keys src_branch * dst.n_chains + dst_branch (sorted, int64) of the pairs where more than half of the source
    branch's length lies within ``tau`` of the destination branch (a zero-length source branch: one destination
    piece within tau)."""
    from plantbench.metrics.surface import kdtree

    m = np.int64(dst.n_chains)
    if dst.n_chains == 0 or src.n_chains == 0:
        return np.zeros(0, np.int64)
    tree = kdtree(dst.points)
    keys, weights = [], []
    for lo in range(0, len(src.points), _CHUNK):
        hi = min(lo + _CHUNK, len(src.points))
        near = kdtree(src.points[lo:hi]).sparse_distance_matrix(tree, tau, output_type="ndarray")
        if not len(near):
            continue
        # one (source piece, destination branch) pair per destination branch near the piece
        piece_branch = np.unique((near["i"].astype(np.int64) + lo) * m + dst.chain[near["j"]])
        i, j = piece_branch // m, piece_branch % m
        keys.append(src.chain[i] * m + j)
        weights.append(src.length[i])
    if not keys:
        return np.zeros(0, np.int64)
    pair, inv = np.unique(np.concatenate(keys), return_inverse=True)
    covered = np.bincount(inv, weights=np.concatenate(weights))
    length = src.chain_length[pair // m]
    return pair[np.where(length > 0, covered > 0.5 * length, True)]


def branch_matches(gt: Skeleton, pred: Skeleton, *, tau: float) -> tuple[int, int, int]:
    """(matched, true, predicted) branch counts at tolerance ``tau`` (metres, > 0): the size of a maximum one-to-one
    matching of true and predicted branches among the pairs where more than half of each branch lies within tau of
    the other (see the module)."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import maximum_bipartite_matching

    if not tau > 0:
        raise InputError(f"branch matching: tau must be > 0, got {tau}")
    step = tau / SAMPLES_PER_TAU
    g, p = chain_pieces(gt, step), chain_pieces(pred, step)
    if g.n_chains == 0 or p.n_chains == 0:
        return 0, g.n_chains, p.n_chains
    m = np.int64(p.n_chains)
    g_in_p = _majority_pairs(g, p, tau)  # keys t * m + p
    p_in_g = _majority_pairs(p, g, tau)  # keys p * n_true + t
    n = np.int64(g.n_chains)
    mutual = np.intersect1d(g_in_p, (p_in_g % n) * m + p_in_g // n, assume_unique=True)
    if not len(mutual):
        return 0, g.n_chains, p.n_chains
    graph = csr_matrix((np.ones(len(mutual)), (mutual // m, mutual % m)), shape=(g.n_chains, p.n_chains))
    matched = int(np.count_nonzero(maximum_bipartite_matching(graph, perm_type="column") >= 0))
    return matched, g.n_chains, p.n_chains


def branch_prf(gt: Skeleton, pred: Skeleton, *, tau: float) -> dict[str, float]:
    """Branch-level 'branch_precision' (matched / predicted branches), 'branch_recall' (matched / true branches)
    and 'branch_f1' (2 matched / (true + predicted)) at tolerance ``tau`` (metres, > 0): see the module and
    :func:`branch_matches`. ``gt`` must have at least one branch."""
    matched, n_true, n_pred = branch_matches(gt, pred, tau=tau)
    if n_true == 0:
        raise InputError("branch_prf: the ground-truth skeleton has no branch")
    if n_pred == 0:
        return {"branch_precision": 0.0, "branch_recall": 0.0, "branch_f1": 0.0}
    return {"branch_precision": matched / n_pred, "branch_recall": matched / n_true,
            "branch_f1": 2 * matched / (n_true + n_pred)}


def branch_count_log2_error(true_count: int | float, predicted_count: int | float) -> float:
    """|log2(predicted / true)|; a count below 1 counts as 1 (an empty prediction scores log2(true)). Counts must be
    >= 0."""
    if true_count < 0 or predicted_count < 0:
        raise InputError(f"branch_count_log2_error: counts must be >= 0, got {true_count}, {predicted_count}")
    return abs(float(np.log2(max(float(predicted_count), 1.0) / max(float(true_count), 1.0))))
