"""Stava et al. 2014 tree similarity S_T (DESIGN.md section 7; notes/metrics.md section 1.3).

Two skeletons are compared through their *branch graphs*: a node is a maximal unbranched chain of skeleton nodes
(:func:`plantbench.skeletons.branch_chains`), its parent the chain that ends at its first node. The distance has
three parts, each in [0, 1]:

* d_S, shape: 13 crown descriptors (height; for three slabs cut at the crown's mean height and the means of its
  halves, the slab height, the mean radius along the two horizontal principal directions and the terminal-branch
  density);
* d_G, geometry: weighted mean and variance of deformation, straightness and slope (weights b_D b_L and b_D^2 b_L)
  and of sibling and parent angle (weights b_D and b_D^2): 20 descriptors;
* d_T, structure: Zhang's constrained unordered tree edit distance with Stava's split/merge of chains, insert and
  delete cost b_L b_D, assign cost of Stava's Appendix B, normalised by twice the larger whole-tree cost (Eq. 7).

Descriptors are compared with delta = 1 - exp(-(a - b)^2 / (2 sigma^2)), sigma = c min(|a|, |b|), c = 0.5, and
aggregated with the normalised Minkowski mean of order p = 2.5. S_T = 1 - (d_S + d_G + d_T) / 3.

Conventions (documented choices where the paper is silent):

* b_D is the branch's maximal *diameter* 2 r; lengths in metres; angles in radians.
* A chain's initial / final direction (for sibling and parent angles) is the chord over its first / last
  ``min(b_L, chord_radii * r)`` of arc length, r the radius at that end.
* delta = 0 when a == b (also for a == b == 0); delta = 1 when sigma = 0 and a != b (the sigma -> 0 limit).
* A weighted mean or variance with no samples (no branch has a sibling, say) is 0.
* A slab with no crown point has radii 0 and density 0; a density whose slab volume is 0 is 0.
* Several roots (multi-stem shrubs) hang from one virtual root of length 0, so a forest is one tree.
* A prediction with no branch (empty or single-node skeleton) scores S_T = 0 and d_S = d_G = d_T = 1 ("no similarity
  at all", the paper's scale end); a ground truth with no branch raises InputError.
* Split/merge chains hold at most ``max_chain`` branch nodes (Stava bounds them for tractability without a
  number); the default 3 lets one node absorb two consecutive neighbours. ``max_chain = 1`` is plain Zhang
  (the ``stava_nosplit`` metric).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from plantbench.errors import InputError
from plantbench.plant import Skeleton
from plantbench.skeletons import branch_chains

__all__ = [
    "stava_similarities",
    "StavaParams",
    "StavaResult",
    "BranchGraph",
    "branch_graph",
    "descriptor_delta",
    "minkowski_mean",
    "shape_descriptors",
    "geometric_descriptors",
    "assign_cost",
    "tree_edit_distance",
    "stava_similarity",
]

_EPS = 1e-12


@dataclass(frozen=True)
class StavaParams:
    """Parameters of the Stava similarity (defaults are the paper's where it gives them)."""

    c: float = 0.5
    """sigma = c * min(|a|, |b|) in the per-descriptor difference (Eq. 4)."""
    p: float = 2.5
    """Order of the normalised Minkowski mean aggregating deltas."""
    max_chain: int = 3
    """Longest chain of branch nodes a split or merge may fuse (1 = no split/merge, plain Zhang)."""
    chord_radii: float = 5.0
    """Initial/final branch direction: chord over this many radii of arc length (capped at the branch length)."""

    def __post_init__(self) -> None:
        if not self.c > 0 or not self.p >= 1 or int(self.max_chain) < 1 or not self.chord_radii > 0:
            raise InputError(f"invalid Stava parameters {self}")


@dataclass(frozen=True)
class StavaResult:
    """S_T and its components (all in [0, 1]; S_T = 1 - (d_S + d_G + d_T) / 3)."""

    S_T: float
    d_S: float
    d_G: float
    d_T: float

    def as_dict(self) -> dict[str, float]:
        return {"S_T": self.S_T, "d_S": self.d_S, "d_G": self.d_G, "d_T": self.d_T}


# ------------------------------------------------------------------------------------------------ branch graph


@dataclass(frozen=True)
class BranchGraph:
    """Branch graph of a skeleton: one node per unbranched chain, parents first.

    parent : (n,) int, parent branch, -1 for a top-level branch (hanging from the ground / virtual root)
    length : (n,) float, b_L, polyline length
    diameter : (n,) float, b_D, maximal 2 r over the chain
    deformation : (n,) float, b_alpha, sum of turning angles between consecutive segments
    straightness : (n,) float, b_r, end-point distance / b_L (1 for a zero-length branch)
    slope : (n,) float, b_S, signed angle of the end-point chord to the horizontal plane
    start, end : (n, 3) float, first and last chain node
    first_dir, last_dir : (n, 3) float, unit direction of the first / last non-degenerate segment (0 if none)
    init_dir, final_dir : (n, 3) float, unit chord over the first / last few radii (sibling and parent angles)
    crown_points : (m, 3) float, skeleton nodes of terminal branches
    tips : (k, 3) float, end points of terminal branches
    z_range : (2,) float, min and max z over all skeleton nodes
    """

    parent: np.ndarray
    length: np.ndarray
    diameter: np.ndarray
    deformation: np.ndarray
    straightness: np.ndarray
    slope: np.ndarray
    start: np.ndarray
    end: np.ndarray
    first_dir: np.ndarray
    last_dir: np.ndarray
    init_dir: np.ndarray
    final_dir: np.ndarray
    crown_points: np.ndarray
    tips: np.ndarray
    z_range: np.ndarray

    def __len__(self) -> int:
        return len(self.parent)

    def children(self) -> list[list[int]]:
        kids: list[list[int]] = [[] for _ in range(len(self))]
        for i, p in enumerate(self.parent.tolist()):
            if p >= 0:
                kids[p].append(i)
        return kids


def _angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angle between row vectors (0 where either is zero)."""
    cross = np.linalg.norm(np.cross(u, v), axis=-1)
    dot = np.sum(u * v, axis=-1)
    return np.arctan2(cross, dot)


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > _EPS)


def _point_at(points: np.ndarray, cum: np.ndarray, s: float) -> np.ndarray:
    """Point at arc length s along a polyline with cumulative lengths ``cum`` (cum[0] = 0)."""
    i = int(np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(points) - 2))
    seg = cum[i + 1] - cum[i]
    f = 0.0 if seg <= _EPS else (s - cum[i]) / seg
    return points[i] + np.clip(f, 0.0, 1.0) * (points[i + 1] - points[i])


def polyline_properties(points: np.ndarray, radii: np.ndarray, chord_radii: float = 5.0) -> dict:
    """Table-3 properties of one polyline (a branch, or several fused by Stava's join operator).

    points : (m, 3) float, m >= 2; radii : (m,) float
    """
    seg = np.diff(points, axis=0)
    sl = np.linalg.norm(seg, axis=1)
    length = float(sl.sum())
    nz = seg[sl > _EPS] / sl[sl > _EPS, None]
    deformation = float(_angle(nz[:-1], nz[1:]).sum()) if len(nz) > 1 else 0.0
    chord = points[-1] - points[0]
    dse = float(np.linalg.norm(chord))
    straightness = dse / length if length > _EPS else 1.0
    slope = float(np.arcsin(np.clip(chord[2] / dse, -1.0, 1.0))) if dse > _EPS else 0.0
    cum = np.concatenate([[0.0], np.cumsum(sl)])
    a = min(length, chord_radii * float(radii[0]))
    b = min(length, chord_radii * float(radii[-1]))
    init_dir = _unit(_point_at(points, cum, a) - points[0]) if a > _EPS else (nz[0] if len(nz) else np.zeros(3))
    final_dir = _unit(points[-1] - _point_at(points, cum, length - b)) if b > _EPS else \
        (nz[-1] if len(nz) else np.zeros(3))
    return {
        "length": length,
        "diameter": float(2.0 * np.max(radii)),
        "deformation": deformation,
        "straightness": straightness,
        "slope": slope,
        "first_dir": nz[0] if len(nz) else np.zeros(3),
        "last_dir": nz[-1] if len(nz) else np.zeros(3),
        "init_dir": init_dir,
        "final_dir": final_dir,
    }


def branch_graph(skeleton: Skeleton, *, chord_radii: float = 5.0) -> BranchGraph:
    """Branch graph (Stava's tree graph) of a skeleton. See :class:`BranchGraph`."""
    chains = branch_chains(skeleton)
    pos, rad = skeleton.positions, skeleton.radii
    n = len(chains)
    last_to_chain = {int(c[-1]): i for i, c in enumerate(chains)}
    parent = np.array([last_to_chain.get(int(c[0]), -1) for c in chains], np.int64)
    props = [polyline_properties(pos[c], rad[c], chord_radii) for c in chains]

    def col(key: str, shape: tuple = ()) -> np.ndarray:
        return np.array([p[key] for p in props], float).reshape((n, *shape))

    has_child = np.zeros(n, bool)
    has_child[parent[parent >= 0]] = True
    terminal = [c for c, h in zip(chains, has_child) if not h]
    crown = pos[np.unique(np.concatenate(terminal))] if terminal else np.zeros((0, 3))
    tips = pos[[int(c[-1]) for c in terminal]] if terminal else np.zeros((0, 3))
    z = pos[:, 2]
    return BranchGraph(
        parent=parent,
        length=col("length"),
        diameter=col("diameter"),
        deformation=col("deformation"),
        straightness=col("straightness"),
        slope=col("slope"),
        start=pos[[int(c[0]) for c in chains]].reshape(n, 3),
        end=pos[[int(c[-1]) for c in chains]].reshape(n, 3),
        first_dir=col("first_dir", (3,)),
        last_dir=col("last_dir", (3,)),
        init_dir=col("init_dir", (3,)),
        final_dir=col("final_dir", (3,)),
        crown_points=crown,
        tips=tips,
        z_range=np.array([z.min(), z.max()]) if len(z) else np.zeros(2),
    )


# ------------------------------------------------------------------------------------------------ descriptors


def descriptor_delta(a, b, *, c: float = 0.5) -> np.ndarray:
    """Eq. 4: delta = 1 - exp(-(a - b)^2 / (2 sigma^2)), sigma = c min(|a|, |b|); elementwise, in [0, 1]."""
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    diff = a - b
    sigma = c * np.minimum(np.abs(a), np.abs(b))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        d = -np.expm1(-(diff * diff) / (2.0 * sigma * sigma))
    return np.where(diff == 0, 0.0, np.where(sigma > 0, d, 1.0))


def minkowski_mean(deltas, *, p: float = 2.5, axis: int = -1) -> np.ndarray:
    """Normalised Minkowski mean ((1/k) sum delta^p)^(1/p)."""
    d = np.asarray(deltas, float)
    return np.mean(d**p, axis=axis) ** (1.0 / p)


def shape_descriptors(graph: BranchGraph) -> np.ndarray:
    """d_S descriptors (13,): height, then per slab (bottom, middle, top): height, r_max, r_min, density."""
    out = [float(graph.z_range[1] - graph.z_range[0])]
    crown, tips = graph.crown_points, graph.tips
    if len(crown) == 0:
        return np.array(out + [0.0] * 12)
    z = crown[:, 2]
    mu = z.mean()
    upper, lower = z[z >= mu], z[z < mu]
    mu_uh = upper.mean()
    mu_lh = lower.mean() if len(lower) else mu
    bounds = [z.min(), mu_lh, mu_uh, z.max()]
    for i in range(3):
        lo, hi = bounds[i], bounds[i + 1]
        last = i == 2
        sel = (z >= lo) & ((z <= hi) if last else (z < hi))
        h = hi - lo
        xy = crown[sel, :2]
        if len(xy) == 0:
            out += [h, 0.0, 0.0, 0.0]
            continue
        xy = xy - xy.mean(axis=0)
        _, vecs = np.linalg.eigh(xy.T @ xy)
        proj = np.abs(xy @ vecs)  # columns: minor, major
        r_min, r_max = float(proj[:, 0].mean()), float(proj[:, 1].mean())
        tz = tips[:, 2]
        n_tips = int(np.count_nonzero((tz >= lo) & ((tz <= hi) if last else (tz < hi))))
        vol = np.pi * r_min * r_max * h
        out += [h, r_max, r_min, n_tips / vol if vol > _EPS * _EPS else 0.0]
    return np.array(out)


def _weighted_stats(q: np.ndarray, w: np.ndarray) -> list[float]:
    sw = w.sum()
    if len(q) == 0 or sw <= 0:
        return [0.0, 0.0]
    m = float((w * q).sum() / sw)
    return [m, float((w * (q - m) ** 2).sum() / sw)]


def sibling_parent_angles(graph: BranchGraph) -> tuple[np.ndarray, np.ndarray]:
    """(n,) sibling angle b_AS and parent angle b_AP per branch, NaN where undefined."""
    n = len(graph)
    b_as = np.full(n, np.nan)
    b_ap = np.full(n, np.nan)
    par = graph.parent
    has = par >= 0
    b_ap[has] = _angle(graph.init_dir[has], graph.final_dir[par[has]])
    order = np.argsort(par, kind="stable")
    groups = np.split(order, np.flatnonzero(np.diff(par[order])) + 1) if n else []
    for g in groups:
        if len(g) < 2:
            continue
        d = graph.init_dir[g]
        ang = _angle(d[:, None, :], d[None, :, :])
        np.fill_diagonal(ang, np.inf)
        b_as[g] = ang.min(axis=1)
    return b_as, b_ap


def geometric_descriptors(graph: BranchGraph) -> np.ndarray:
    """d_G descriptors (20,): for deformation, straightness, slope, sibling angle, parent angle (in that order):
    mean and variance with weight w', then mean and variance with weight w''."""
    L, D = graph.length, graph.diameter
    b_as, b_ap = sibling_parent_angles(graph)
    out: list[float] = []
    for q in (graph.deformation, graph.straightness, graph.slope):
        out += _weighted_stats(q, D * L) + _weighted_stats(q, D * D * L)
    for q in (b_as, b_ap):
        ok = np.isfinite(q)
        out += _weighted_stats(q[ok], D[ok]) + _weighted_stats(q[ok], D[ok] ** 2)
    return np.array(out)


# --------------------------------------------------------------------------------------------------- d_T


def assign_cost(len1, diam1, shape1, len2, diam2, shape2, *, c: float = 0.5, p: float = 2.5) -> np.ndarray:
    """Stava Appendix B assign cost, elementwise.

    gamma_A = s b_L(short) (b_D1 + b_D2) + (b_L(long) - b_L(short)) b_D(long), s = Minkowski mean of the deltas of
    slope, straightness and deformation. ``shape1``, ``shape2`` : (..., 3) float (slope, straightness, deformation).
    """
    len1, len2, diam1, diam2 = (np.asarray(x, float) for x in (len1, len2, diam1, diam2))
    delta = descriptor_delta(np.asarray(shape1, float), np.asarray(shape2, float), c=c)
    s = minkowski_mean(delta, p=p)
    short_is_1 = len1 <= len2
    lmin = np.minimum(len1, len2)
    lmax = np.maximum(len1, len2)
    d_long = np.where(short_is_1, diam2, diam1)
    return s * lmin * (diam1 + diam2) + (lmax - lmin) * d_long


@dataclass
class _Prepared:
    n: int  # real nodes; index n = virtual root, n + 1 = dummy (empty subtree)
    children: list[list[int]]
    kids_pad: np.ndarray  # (n + 1, kmax) children padded with the dummy
    degree: np.ndarray  # (n + 2,)
    height: np.ndarray  # (n + 1,)
    tcost: np.ndarray  # (n + 2,) whole-subtree delete/insert cost
    fcost: np.ndarray  # (n + 2,) children-forest delete/insert cost
    chain_start: np.ndarray  # (n + 1,)
    chain_count: np.ndarray  # (n + 1,)
    ch_len: np.ndarray
    ch_diam: np.ndarray
    ch_shape: np.ndarray  # (m, 3) slope, straightness, deformation
    ch_side: np.ndarray  # delete cost of the subtrees hanging off the chain
    ch_bottom: np.ndarray


def _prepare(g: BranchGraph, max_chain: int) -> _Prepared:
    n = len(g)
    vroot, dummy = n, n + 1
    kids = g.children() + [[]]
    kids[vroot] = [i for i in range(n) if g.parent[i] < 0]
    # post-order (children before parents): reverse of a BFS from the virtual root
    bfs = [vroot]
    for i in bfs:
        bfs.extend(kids[i])
    length = np.concatenate([g.length, [0.0, 0.0]])
    diam = np.concatenate([g.diameter, [0.0, 0.0]])
    own = length * diam
    tcost = own.copy()
    height = np.zeros(n + 1, np.int64)
    for i in reversed(bfs):
        if kids[i]:
            tcost[i] += tcost[kids[i]].sum()
            height[i] = 1 + height[kids[i]].max()
    fcost = tcost - own
    degree = np.array([len(k) for k in kids] + [0], np.int64)
    kmax = max(1, int(degree.max()))
    kids_pad = np.full((n + 1, kmax), dummy, np.int64)
    for i, k in enumerate(kids):
        kids_pad[i, : len(k)] = k

    # chains: every downward path of at most max_chain real nodes, listed per top node (virtual root: itself only)
    shape = np.stack([g.slope, g.straightness, g.deformation], axis=1) if n else np.zeros((0, 3))
    junction = np.zeros(n)  # turning angle between a branch's parent's last segment and its own first one
    has_parent = g.parent >= 0
    junction[has_parent] = _angle(g.last_dir[g.parent[has_parent]], g.first_dir[has_parent])
    lens, diams, shapes, sides, bottoms = [], [], [], [], []
    start = np.zeros(n + 1, np.int64)
    count = np.zeros(n + 1, np.int64)
    for top in range(n):
        start[top] = len(lens)
        stack = [[top]]
        while stack:
            path = stack.pop()
            bottom = path[-1]
            if len(path) == 1:
                L, D, sh, side = g.length[top], g.diameter[top], shape[top], 0.0
            else:
                L = g.length[path].sum()
                D = g.diameter[path].max()
                alpha = g.deformation[path].sum() + junction[path[1:]].sum()
                chord = g.end[bottom] - g.start[top]
                dse = float(np.linalg.norm(chord))
                straight = dse / L if L > _EPS else 1.0
                slope = float(np.arcsin(np.clip(chord[2] / dse, -1, 1))) if dse > _EPS else 0.0
                sh = np.array([slope, straight, alpha])
                side = sum(fcost[a] - tcost[b] for a, b in zip(path[:-1], path[1:]))
            lens.append(L)
            diams.append(D)
            shapes.append(sh)
            sides.append(side)
            bottoms.append(bottom)
            if len(path) < max_chain:
                stack.extend(path + [k] for k in reversed(kids[bottom]))
        count[top] = len(lens) - start[top]
    start[vroot] = len(lens)
    count[vroot] = 1
    lens.append(0.0)
    diams.append(0.0)
    shapes.append(np.zeros(3))
    sides.append(0.0)
    bottoms.append(vroot)
    return _Prepared(
        n=n, children=kids, kids_pad=kids_pad, degree=degree, height=height, tcost=tcost, fcost=fcost,
        chain_start=start, chain_count=count, ch_len=np.array(lens), ch_diam=np.array(diams),
        ch_shape=np.array(shapes).reshape(-1, 3), ch_side=np.array(sides), ch_bottom=np.array(bottoms, np.int64),
    )


_PERMS = {k: np.array(list(itertools.permutations(range(k))), np.int64) for k in range(1, 5)}
_BLOCK = 1 << 22  # chain pairs evaluated per numpy pass (bounds memory)


def _gamma_outer(a: dict, b: dict, c: float, p: float) -> np.ndarray:
    """Assign cost between every chain of ``a`` (rows) and of ``b`` (columns); same values as assign_cost."""
    acc = None
    k = 2.0 * c * c
    for j in range(3):
        x, y = a["shape"][j][:, None], b["shape"][j][None, :]
        sig = np.minimum(a["abs"][j][:, None], b["abs"][j][None, :])
        den = sig * sig
        den *= k
        np.maximum(den, 1e-300, out=den)
        d = x - y
        d *= d
        d /= den
        np.negative(d, out=d)
        np.expm1(d, out=d)
        np.negative(d, out=d)  # delta in [0, 1]
        if p == 2.5:
            t = np.sqrt(d)
            d *= d
            d *= t
        else:
            d **= p
        acc = d if acc is None else acc.__iadd__(d)
    acc /= 3.0
    acc **= 1.0 / p  # s
    la, lb = a["len"][:, None], b["len"][None, :]
    da, db = a["diam"][:, None], b["diam"][None, :]
    lmin = np.minimum(la, lb)
    acc *= lmin
    acc *= da + db
    longer = np.where(la <= lb, db, da)
    longer *= np.maximum(la, lb) - lmin
    acc += longer
    return acc


def _chain_block(t: _Prepared, nodes: np.ndarray) -> tuple[dict, np.ndarray]:
    """Chain attributes of every chain topped by ``nodes`` (contiguous per node) and each node's first row."""
    cnt = t.chain_count[nodes]
    off = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    idx = np.repeat(t.chain_start[nodes] - off, cnt) + np.arange(int(cnt.sum()))
    shape = t.ch_shape[idx]
    cols = [np.ascontiguousarray(shape[:, j]) for j in range(3)]
    return {"shape": cols, "abs": [np.abs(x) for x in cols], "len": t.ch_len[idx], "diam": t.ch_diam[idx],
            "side": t.ch_side[idx], "bottom": t.ch_bottom[idx]}, off


def _block_matching(T, t1: _Prepared, t2: _Prepared, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(len(A), len(B)) min-cost matching of the child subtrees (unmatched children deleted / inserted)."""
    out = np.zeros((len(A), len(B)))
    k = min(4, max(int(t1.degree[A].max()), int(t2.degree[B].max())))
    if k > 0:
        ka, kb = _pad(t1.kids_pad[A], k, t1.n + 1), _pad(t2.kids_pad[B], k, t2.n + 1)
        cost = {}
        for i in range(k):
            for j in range(k):
                m = T[np.ix_(ka[:, i], kb[:, j])]
                cost[i, j] = np.minimum(m, t1.tcost[ka[:, i]][:, None] + t2.tcost[kb[:, j]][None, :])
        out[:] = np.inf
        for perm in _PERMS[k]:
            tot = cost[0, int(perm[0])].copy()
            for i in range(1, k):
                tot += cost[i, int(perm[i])]
            np.minimum(out, tot, out=out)
    big_a = np.flatnonzero(t1.degree[A] > 4)
    big_b = np.flatnonzero(t2.degree[B] > 4)
    if len(big_a) or len(big_b):
        from scipy.optimize import linear_sum_assignment

        # Rectangular form of the padded assignment: deleting every child of both sides costs the sum of their
        # subtree costs; matching a with b changes that by gain = min(T, ta + tb) - ta - tb <= 0, so the best
        # matching pairs every child of the smaller side (what the padding with empty subtrees allowed).
        pairs = {(i, j) for i in big_a for j in range(len(B))} | {(i, j) for i in range(len(A)) for j in big_b}
        for i, j in pairs:
            c1, c2 = t1.children[A[i]], t2.children[B[j]]
            ta, tb = t1.tcost[c1], t2.tcost[c2]
            total = ta.sum() + tb.sum()
            if c1 and c2:
                gain = T[np.ix_(c1, c2)] - ta[:, None] - tb[None, :]
                np.minimum(gain, 0.0, out=gain)
                if min(gain.shape) == 1:
                    total += gain.min()
                else:
                    r, cc = linear_sum_assignment(gain)
                    total += gain[r, cc].sum()
            out[i, j] = total
    return out


def _pad(kids: np.ndarray, k: int, dummy: int) -> np.ndarray:
    if kids.shape[1] >= k:
        return kids[:, :k]
    return np.concatenate([kids, np.full((len(kids), k - kids.shape[1]), dummy, np.int64)], axis=1)


def _block_skip(M, base, kids, sub, rows, along_cols: bool) -> np.ndarray:
    """Zhang's 'map into one child subtree' option for a block: base + min over children t of (M[.., t] - sub[t]).

    along_cols: rows index the first tree and the children are the second tree's (columns); else transposed.
    """
    best = None
    for t in range(kids.shape[1]):
        kt = kids[:, t]
        v = (M[np.ix_(rows, kt)] - sub[kt][None, :]) if along_cols else (M[np.ix_(kt, rows)] - sub[kt][:, None])
        best = v if best is None else np.minimum(best, v, out=best)
    return best + (base[None, :] if along_cols else base[:, None])


def _group_by(height: np.ndarray) -> list[np.ndarray]:
    order = np.argsort(height, kind="stable")
    return np.split(order, np.searchsorted(height[order], np.arange(1, int(height.max()) + 1)))


def tree_edit_distance(gt: BranchGraph, pred: BranchGraph, *, c: float = 0.5, p: float = 2.5,
                       max_chain: int = 3) -> tuple[float, float]:
    """Zhang's constrained unordered tree edit distance with Stava's split/merge, and its Eq. 7 normaliser.

    Returns ``(d_N, 2 max(delete cost of gt, insert cost of pred))``; d_T = d_N / normaliser.

    Dynamic programme over every node pair (a, b), processed in blocks of equal subtree heights (h1, h2) by
    increasing h1 + h2, so that each block only reads finished entries; inside a block every quantity is a dense
    (|A|, |B|) numpy array. For a pair: the forest distance F of the children (min-cost matching, children padded
    with an empty subtree, or Zhang's mapping of one forest into a child's forest), then the tree distance T:
    the best assignment of a chain from a to a chain from b (chains of at most ``max_chain`` nodes: Stava's
    split and merge, side subtrees deleted / inserted) plus F of the chain ends, or Zhang's mapping of one tree
    into a child subtree of the other.
    """
    t1, t2 = _prepare(gt, max_chain), _prepare(pred, max_chain)
    n1, n2 = t1.n, t2.n
    d1, d2 = n1 + 1, n2 + 1
    # T: tree distance, F: forest distance of the children; the dummy (empty subtree) row and column filled in
    T = np.zeros((n1 + 2, n2 + 2))
    F = np.zeros((n1 + 2, n2 + 2))
    T[d1, :] = t2.tcost
    T[:, d2] = t1.tcost
    F[d1, :] = t2.fcost
    F[:, d2] = t1.fcost
    T[d1, d2] = F[d1, d2] = 0.0
    g1, g2 = _group_by(t1.height), _group_by(t2.height)
    blocks2 = [_chain_block(t2, B) for B in g2]
    for s in range(len(g1) + len(g2) - 1):
        for h in range(max(0, s - len(g2) + 1), min(s, len(g1) - 1) + 1):
            B = g2[s - h]
            cb, offb = blocks2[s - h]
            rows_per = max(1, _BLOCK // max(1, len(cb["len"])))
            nodes1 = g1[h]
            step = max(1, int(rows_per / max(1.0, t1.chain_count[nodes1].mean())))
            for lo in range(0, len(nodes1), step):
                A = nodes1[lo:lo + step]
                _solve_block(T, F, t1, t2, A, B, cb, offb, c, p)
    return float(T[n1, n2]), 2.0 * max(float(t1.tcost[n1]), float(t2.tcost[n2]))


def _solve_block(T, F, t1: _Prepared, t2: _Prepared, A, B, cb, offb, c, p) -> None:
    ka, kb = t1.kids_pad[A], t2.kids_pad[B]
    f = _block_matching(T, t1, t2, A, B)
    np.minimum(f, _block_skip(F, t2.fcost[B], kb, t2.fcost, A, True), out=f)
    np.minimum(f, _block_skip(F, t1.fcost[A], ka, t1.fcost, B, False), out=f)
    F[np.ix_(A, B)] = f
    ca, offa = _chain_block(t1, A)
    cost = _gamma_outer(ca, cb, c, p)
    cost += ca["side"][:, None]
    cost += cb["side"][None, :]
    cost += F[np.ix_(ca["bottom"], cb["bottom"])]
    t = np.minimum.reduceat(np.minimum.reduceat(cost, offa, axis=0), offb, axis=1)
    np.minimum(t, _block_skip(T, t2.tcost[B], kb, t2.tcost, A, True), out=t)
    np.minimum(t, _block_skip(T, t1.tcost[A], ka, t1.tcost, B, False), out=t)
    T[np.ix_(A, B)] = t


# ------------------------------------------------------------------------------------------------ similarity


def stava_similarity(gt: Skeleton, pred: Skeleton, *, params: StavaParams = StavaParams(),
                     split_merge: bool = True) -> StavaResult:
    """Stava et al. 2014 similarity of a predicted skeleton to the ground truth.

    Parameters
    ----------
    gt, pred : Skeleton
    params : StavaParams
    split_merge : bool
        False gives the faster variant without Stava's split/merge (plain Zhang), reported as ``stava_nosplit``.
    """
    return _stava(gt, pred, params, (split_merge,))[0]


def stava_similarities(gt: Skeleton, pred: Skeleton, *, params: StavaParams = StavaParams()
                       ) -> tuple[StavaResult, StavaResult]:
    """:func:`stava_similarity` with and without split/merge, sharing the branch graphs and the d_S and d_G
    descriptors of the two (only d_T differs)."""
    return tuple(_stava(gt, pred, params, (True, False)))


def _stava(gt: Skeleton, pred: Skeleton, params: StavaParams, variants: tuple[bool, ...]) -> list[StavaResult]:
    g1 = branch_graph(gt, chord_radii=params.chord_radii)
    if len(g1) == 0:
        raise InputError("ground-truth skeleton has no branch (needs at least one edge)")
    g2 = branch_graph(pred, chord_radii=params.chord_radii)
    if len(g2) == 0:
        return [StavaResult(0.0, 1.0, 1.0, 1.0) for _ in variants]
    d_s = float(minkowski_mean(descriptor_delta(shape_descriptors(g1), shape_descriptors(g2), c=params.c),
                               p=params.p))
    d_g = float(minkowski_mean(descriptor_delta(geometric_descriptors(g1), geometric_descriptors(g2), c=params.c),
                               p=params.p))
    out = []
    for split_merge in variants:
        dist, norm = tree_edit_distance(g1, g2, c=params.c, p=params.p,
                                        max_chain=int(params.max_chain) if split_merge else 1)
        d_t = float(min(1.0, dist / norm)) if norm > 0 else 0.0
        out.append(StavaResult(1.0 - (d_s + d_g + d_t) / 3.0, d_s, d_g, d_t))
    return out
