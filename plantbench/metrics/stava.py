"""Stava et al. 2014 tree similarity S_T (docs/design.md, Metrics).

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

import functools
import itertools
import math
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
    """``v`` normalised along its last axis, 0 where its norm is <= _EPS: a chord of a chain that folds back to
    within _EPS of where it started has no direction (:func:`plantbench.geometry.vectors.unit` normalises every
    norm above 1e-15 and leaves smaller vectors as they are)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > _EPS)


def _point_at(points: np.ndarray, cum: np.ndarray, s: float) -> np.ndarray:
    """Point at arc length s along a polyline with cumulative lengths ``cum`` (cum[0] = 0)."""
    i = min(max(int(np.searchsorted(cum, s, side="right")) - 1, 0), len(points) - 2)
    seg = cum[i + 1] - cum[i]
    f = 0.0 if seg <= _EPS else (s - cum[i]) / seg
    return points[i] + min(max(f, 0.0), 1.0) * (points[i + 1] - points[i])


def polyline_properties(points: np.ndarray, radii: np.ndarray, chord_radii: float = 5.0) -> dict:
    """Table-3 properties of one polyline (a branch, or several fused by Stava's join operator).

    points : (m, 3) float, m >= 2; radii : (m,) float
    """
    props = _polylines(points, radii, [np.arange(len(points))], chord_radii)
    return {k: (float(v[0]) if v.ndim == 1 else v[0]) for k, v in props.items()}


def _polylines(pos: np.ndarray, rad: np.ndarray, chains: list[np.ndarray], chord_radii: float) -> dict:
    """:func:`polyline_properties` of several polylines (index arrays into ``pos`` and ``rad``, each of at least
    two points) at once: a dict of arrays, one row per polyline.

    Elementwise steps run on all polylines together; sums, the chord norm, the slope and the arc-length lookups run
    per polyline on the same numpy calls as for a single one, so that the values are the same to the last bit.
    """
    n = len(chains)
    idx = np.concatenate(chains) if n else np.zeros(0, np.int64)
    pts = pos[idx]
    cnt = np.array([len(c) for c in chains], np.int64)
    first = np.cumsum(cnt) - cnt  # polyline i: pts[first[i]:last[i] + 1]
    last = first + cnt - 1
    keep = np.ones(max(len(pts) - 1, 0), bool)
    keep[last[:-1]] = False  # no difference across two polylines
    seg = (pts[1:] - pts[:-1])[keep]
    sl = np.linalg.norm(seg, axis=1)
    s0 = first - np.arange(n)  # polyline i: segments s0[i]:s0[i] + cnt[i] - 1
    ok = sl > _EPS
    nz = seg[ok] / sl[ok, None]
    z0 = np.concatenate([[0], np.cumsum(ok)])[np.append(s0, len(sl))]  # polyline i: nz[z0[i]:z0[i + 1]]
    has = z0[1:] > z0[:-1]
    same = np.ones(max(len(nz) - 1, 0), bool)
    cut = z0[1:-1]
    same[cut[(cut > 0) & (cut < len(nz))] - 1] = False  # no angle across two polylines
    ang = _angle(nz[:-1][same], nz[1:][same])
    a0 = np.concatenate([[0], np.cumsum(np.maximum(np.diff(z0) - 1, 0))])  # polyline i: ang[a0[i]:a0[i + 1]]
    out = {k: np.zeros(n) for k in ("length", "deformation", "straightness", "slope")}
    out["diameter"] = 2.0 * np.maximum.reduceat(rad[idx], first) if n else np.zeros(0)
    out["first_dir"] = np.zeros((n, 3))
    out["last_dir"] = np.zeros((n, 3))
    out["first_dir"][has] = nz[z0[:-1][has]]
    out["last_dir"][has] = nz[z0[1:][has] - 1]
    raw = np.zeros((2, n, 3))  # init / final chord vectors, normalised together below
    use = np.zeros((2, n), bool)
    for i in range(n):
        P = pts[first[i]:last[i] + 1]
        sli = sl[s0[i]:s0[i] + cnt[i] - 1]
        length = float(sli.sum())
        if a0[i + 1] > a0[i]:
            out["deformation"][i] = float(ang[a0[i]:a0[i + 1]].sum())
        chord = P[-1] - P[0]
        dse = float(np.linalg.norm(chord))
        out["length"][i] = length
        out["straightness"][i] = dse / length if length > _EPS else 1.0
        out["slope"][i] = float(np.arcsin(min(max(chord[2] / dse, -1.0), 1.0))) if dse > _EPS else 0.0
        cum = np.concatenate([[0.0], np.cumsum(sli)])
        a = min(length, chord_radii * float(rad[idx[first[i]]]))
        b = min(length, chord_radii * float(rad[idx[last[i]]]))
        if a > _EPS:
            raw[0, i], use[0, i] = _point_at(P, cum, a) - P[0], True
        if b > _EPS:
            raw[1, i], use[1, i] = P[-1] - _point_at(P, cum, length - b), True
    unit = _unit(raw)
    out["init_dir"] = np.where(use[0, :, None], unit[0], out["first_dir"])
    out["final_dir"] = np.where(use[1, :, None], unit[1], out["last_dir"])
    return out


def branch_graph(skeleton: Skeleton, *, chord_radii: float = 5.0) -> BranchGraph:
    """Branch graph (Stava's tree graph) of a skeleton. See :class:`BranchGraph`."""
    chains = branch_chains(skeleton)
    pos, rad = skeleton.positions, skeleton.radii
    n = len(chains)
    last_to_chain = {int(c[-1]): i for i, c in enumerate(chains)}
    parent = np.array([last_to_chain.get(int(c[0]), -1) for c in chains], np.int64)
    props = _polylines(pos, rad, chains, chord_radii)

    has_child = np.zeros(n, bool)
    has_child[parent[parent >= 0]] = True
    terminal = [c for c, h in zip(chains, has_child) if not h]
    crown = pos[np.unique(np.concatenate(terminal))] if terminal else np.zeros((0, 3))
    tips = pos[[int(c[-1]) for c in terminal]] if terminal else np.zeros((0, 3))
    z = pos[:, 2]
    return BranchGraph(
        parent=parent,
        length=props["length"],
        diameter=props["diameter"],
        deformation=props["deformation"],
        straightness=props["straightness"],
        slope=props["slope"],
        start=pos[[int(c[0]) for c in chains]].reshape(n, 3),
        end=pos[[int(c[-1]) for c in chains]].reshape(n, 3),
        first_dir=props["first_dir"],
        last_dir=props["last_dir"],
        init_dir=props["init_dir"],
        final_dir=props["final_dir"],
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
    start, count, ch = _chains(g, shape, junction, fcost, tcost, max_chain)
    start, count = np.append(start, len(ch["len"])), np.append(count, 1)
    ch = {k: np.concatenate([v, np.zeros((1, *v.shape[1:]), v.dtype)]) for k, v in ch.items()}
    ch["bottom"][-1] = vroot
    return _Prepared(
        n=n, children=kids, kids_pad=kids_pad, degree=degree, height=height, tcost=tcost, fcost=fcost,
        chain_start=start, chain_count=count, ch_len=ch["len"], ch_diam=ch["diam"], ch_shape=ch["shape"],
        ch_side=ch["side"], ch_bottom=ch["bottom"],
    )


def _chains(g: BranchGraph, shape: np.ndarray, junction: np.ndarray, fcost: np.ndarray, tcost: np.ndarray,
            max_chain: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """Every downward path of at most ``max_chain`` branches, in depth-first pre-order per top branch: the first
    path and number of paths per top, and each path's length, diameter, shape (slope, straightness, deformation),
    side cost (subtrees hanging off it, deleted) and bottom branch.

    A path of several branches is Stava's join: lengths and deformations summed (with the turning angles at the
    joints), the largest diameter, straightness and slope of the chord from the top's start to the bottom's end.
    Sums run from the top down, as np.sum does for fewer than 8 terms; the chord norm is np.linalg.norm's (a dot
    product).
    """
    n = len(g)
    anc = [np.arange(n)]  # anc[j]: the j-th ancestor of each branch (-1: none)
    for _ in range(max_chain - 1):
        anc.append(np.where(anc[-1] >= 0, g.parent[np.maximum(anc[-1], 0)], -1))
    paths = []
    for m in range(1, max_chain + 1):
        ok = anc[m - 1] >= 0
        rows = np.full((int(ok.sum()), max_chain), -1, np.int64)
        for j in range(m):  # column j: the j-th branch from the top
            rows[:, j] = anc[m - 1 - j][ok]
        paths.append(rows)
    P = np.concatenate(paths) if paths else np.zeros((0, max_chain), np.int64)
    P = P[np.lexsort(P.T[::-1])]  # by top, then by each next branch (children in index order): pre-order
    top, size = P[:, 0], np.count_nonzero(P >= 0, axis=1)
    bottom = P[np.arange(len(P)), size - 1]
    length, diam, alpha = g.length[top].copy(), g.diameter[top].copy(), g.deformation[top].copy()
    junc, side = np.zeros(len(P)), np.zeros(len(P))
    for j in range(1, max_chain):
        v, b, a = P[:, j] >= 0, P[P[:, j] >= 0, j], P[P[:, j] >= 0, j - 1]
        length[v] += g.length[b]
        diam[v] = np.maximum(diam[v], g.diameter[b])
        alpha[v] += g.deformation[b]
        junc[v] = junction[b] if j == 1 else junc[v] + junction[b]
        side[v] = fcost[a] - tcost[b] if j == 1 else side[v] + (fcost[a] - tcost[b])
    chord = g.end[bottom] - g.start[top]
    dse = np.sqrt(np.array([c.dot(c) for c in chord])) if len(P) else np.zeros(0)
    with np.errstate(divide="ignore", invalid="ignore"):
        straight = np.where(length > _EPS, dse / length, 1.0)
        slope = np.where(dse > _EPS, np.arcsin(np.clip(chord[:, 2] / dse, -1, 1)), 0.0)
    joined = np.stack([slope, straight, alpha + junc], axis=1)
    single = size == 1
    joined[single] = shape[top[single]]
    ch = {"len": length, "diam": diam, "shape": joined.reshape(-1, 3), "side": side, "bottom": bottom}
    return np.searchsorted(top, np.arange(n)), np.bincount(top, minlength=n), ch


_BLOCK = 1 << 19  # node pairs per block (bounds memory)
_CHUNK = 1 << 15  # chain pairs per pass of the chain costs (temporaries that stay in cache)
_TEMP = 1 << 21  # elements of one child-matching temporary (bounds memory)
_MAX_MAPS = 720  # child matchings with more candidate maps are solved pair by pair with a linear assignment


def _relabel(t: _Prepared) -> _Prepared:
    """The same tree with its nodes renumbered by subtree height, then degree, then parent: every height group is a
    contiguous range of indices, sorted by degree, and the children of neighbouring nodes are near each other (the
    virtual root, the only node of the largest height, stays at n)."""
    n = t.n
    parent = np.full(n + 1, n, np.int64)
    parent[t.kids_pad[t.kids_pad <= n]] = np.nonzero(t.kids_pad <= n)[0]
    start = np.searchsorted(np.sort(t.height), np.arange(int(t.height.max()) + 1))
    inv = np.empty(n + 2, np.int64)  # old -> new index
    inv[n:] = n, n + 1
    for h in range(int(t.height.max()) - 1, -1, -1):  # parents (greater heights) first
        nodes = np.flatnonzero(t.height == h)
        nodes = nodes[np.lexsort((inv[parent[nodes]], t.degree[nodes]))]
        inv[nodes] = start[h] + np.arange(len(nodes))
    order = np.empty(n + 1, np.int64)
    order[inv[: n + 1]] = np.arange(n + 1)
    ext = np.append(order, n + 1)
    return _Prepared(
        n=n, children=[inv[t.children[i]].tolist() for i in order.tolist()], kids_pad=inv[t.kids_pad[order]],
        degree=t.degree[ext], height=t.height[order], tcost=t.tcost[ext], fcost=t.fcost[ext],
        chain_start=t.chain_start[order], chain_count=t.chain_count[order], ch_len=t.ch_len, ch_diam=t.ch_diam,
        ch_shape=t.ch_shape, ch_side=t.ch_side, ch_bottom=inv[t.ch_bottom],
    )


@dataclass
class _Group:
    """What every block of the dynamic programme needs about nodes lo:hi of one relabelled tree, built once.

    The nodes are sorted by degree (:func:`_relabel`): each degree class (0; 1-2; 3-4; 5-8; ...) is a contiguous
    run, the leaves come first and the nodes of the tree's largest degree last.
    """

    sl: slice  # lo:hi
    tcost: np.ndarray
    fcost: np.ndarray
    ksum: np.ndarray  # cost of the children's subtrees together (all of them deleted / inserted)
    leaves: int  # the first ``leaves`` nodes have no child
    full: int  # nodes full: (relative to lo) have the tree's largest degree (no dummy among their padded children)
    runs: list  # (lo, hi, kids (hi - lo, k)) per degree class >= 1, relative to lo; kids padded with the dummy
    pairs: int  # nodes leaves:leaves + pairs have one or two children
    kid: np.ndarray  # the children of the nodes with children, node after node; two each (one twice) for ``pairs``
    kid_off: np.ndarray  # first entry in kid[2 * pairs:] of each node after those
    kid_t: np.ndarray  # tcost[kid]
    kid_f: np.ndarray  # fcost[kid]
    ch: dict  # chain attributes (:func:`_chain_block`)

    def __len__(self) -> int:
        return self.sl.stop - self.sl.start


def _group(t: _Prepared, lo: int, hi: int, c: float) -> _Group:
    nodes = np.arange(lo, hi)
    deg = t.degree[lo:hi]
    cls = np.where(deg > 0, np.maximum(1, np.ceil(np.log2(np.maximum(deg, 1)))), 0).astype(np.int64)
    leaves = int(np.count_nonzero(deg == 0))
    runs = []
    for k in np.unique(cls[leaves:]).tolist():
        a, b = (int(x) for x in np.searchsorted(cls, [k, k + 1]))
        runs.append((a, b, t.kids_pad[lo + a:lo + b, : int(deg[b - 1])]))
    pairs = int(np.searchsorted(deg, 3)) - leaves
    two = t.kids_pad[lo + leaves:lo + leaves + pairs][:, [0, min(1, t.kids_pad.shape[1] - 1)]]
    two[:, 1] = np.where(deg[leaves:leaves + pairs] == 1, two[:, 0], two[:, 1])
    rest = deg[leaves + pairs:]
    width = int(deg[-1])
    kid = np.concatenate([two.ravel(), t.kids_pad[lo + leaves + pairs:hi, :width][np.arange(width) < rest[:, None]]])
    return _Group(sl=slice(lo, hi), tcost=t.tcost[lo:hi], fcost=t.fcost[lo:hi],
                  ksum=t.tcost[t.kids_pad[lo:hi]].sum(axis=1), leaves=leaves,
                  full=int(np.searchsorted(deg, t.kids_pad.shape[1])), runs=runs, pairs=pairs, kid=kid,
                  kid_off=np.concatenate([[0], np.cumsum(rest)[:-1]]).astype(np.int64), kid_t=t.tcost[kid],
                  kid_f=t.fcost[kid], ch=_chain_block(t, nodes, c))


def _chain_block(t: _Prepared, nodes: np.ndarray, c: float) -> dict:
    """Attributes of every chain topped by ``nodes`` (contiguous per node; "off": each node's first chain).

    "nden" holds -max(2 c^2 |x|^2, 1e-300) per shape descriptor x (rows: slope, straightness, deformation):
    rounding is monotone, so the elementwise maximum of two of these is exactly the negated denominator
    -max(2 c^2 min(|x|, |y|)^2, 1e-300) of descriptor_delta.
    """
    cnt = t.chain_count[nodes]
    off = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    idx = np.repeat(t.chain_start[nodes] - off, cnt) + np.arange(int(cnt.sum()))
    shape = np.ascontiguousarray(t.ch_shape[idx].T)
    nden = -np.maximum((np.abs(shape) * np.abs(shape)) * (2.0 * c * c), 1e-300)
    return {"shape": shape, "nden": nden, "len": t.ch_len[idx], "diam": t.ch_diam[idx], "side": t.ch_side[idx],
            "bottom": t.ch_bottom[idx], "off": off}


def _gamma_outer(a: dict, r: slice, b: dict, p: float) -> np.ndarray:
    """Assign cost between the chains ``r`` of ``a`` (rows) and every chain of ``b`` (columns); same values as
    assign_cost."""
    acc = None
    for j in range(3):
        d = np.subtract.outer(a["shape"][j, r], b["shape"][j])
        d *= d
        d /= np.maximum.outer(a["nden"][j, r], b["nden"][j])  # -(a - b)^2 / (2 sigma^2)
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
    la, lb, da, db = a["len"][r], b["len"], a["diam"][r], b["diam"]
    acc *= np.minimum.outer(la, lb)
    acc *= np.add.outer(da, db)
    # (b_L(long) - b_L(short)) b_D(long): fl(la - lb) is exact in sign and |fl(la - lb)| = fl(lmax - lmin)
    diff = np.subtract.outer(la, lb)
    longer = diff * da[:, None]
    np.negative(diff, out=diff)
    diff *= db[None, :]
    np.maximum(longer, diff, out=longer)
    acc += longer
    return acc


@functools.cache
def _maps(k_rows: int, k_cols: int) -> tuple[np.ndarray, np.ndarray]:
    """Injective maps of the shorter side of a (k_rows, k_cols) matrix into the longer: per map, the flat entry
    (row * k_cols + column) taken for each element of the shorter side, and the longer side's indices left over."""
    small, large = sorted((k_rows, k_cols))
    maps = list(itertools.permutations(range(large), small))
    if k_rows <= k_cols:
        sel = [[i * k_cols + m[i] for i in range(small)] for m in maps]
    else:
        sel = [[m[i] * k_cols + i for i in range(small)] for m in maps]
    left = np.array([[j for j in range(large) if j not in m] for m in maps], np.int64).reshape(len(maps), -1)
    return np.array(sel, np.int64).reshape(len(maps), small), left


def _block_matching(T, t1: _Prepared, t2: _Prepared, ga: _Group, gb: _Group) -> np.ndarray:
    """(V, |A|, |B|) min-cost matching of the child subtrees (unmatched children deleted / inserted), per pair of
    degree-class runs: enumerating the injective maps of the fewer children into the more, or with a linear
    assignment per pair where there are more than _MAX_MAPS of them."""
    out = np.empty((len(T), len(ga), len(gb)))
    out[:, : ga.leaves] = gb.ksum
    out[:, :, : gb.leaves] = ga.ksum[:, None]
    for lo_a, hi_a, ka in ga.runs:
        for lo_b, hi_b, kb in gb.runs:
            block = (slice(None), slice(lo_a, hi_a), slice(lo_b, hi_b))
            k_small, k_large = sorted((ka.shape[1], kb.shape[1]))
            if math.perm(k_large, k_small) <= _MAX_MAPS:
                out[block] = _match_runs(T, t1, t2, ka, kb, *_maps(ka.shape[1], kb.shape[1]))
                continue
            A = range(ga.sl.start + lo_a, ga.sl.start + hi_a)
            B = range(gb.sl.start + lo_b, gb.sl.start + hi_b)
            for v in range(len(T)):
                out[v, lo_a:hi_a, lo_b:hi_b] = _match_lsa(T[v], t1, t2, A, B)
    return out


def _match_runs(T, t1: _Prepared, t2: _Prepared, ka: np.ndarray, kb: np.ndarray, sel: np.ndarray,
                left: np.ndarray) -> np.ndarray:
    """Child matching of every pair of a run of ``ka`` (children padded with the dummy) and one of ``kb``.

    Entry cost c = min(T, t_a + t_b) (a dummy row or column gives the other child's subtree cost, exactly, or 0);
    the best over every injective map of the shorter side's children into the longer side's, the longer side's
    children left over deleted / inserted: the same optimum as the padded square assignment.
    """
    kA, kB = ka.shape[1], kb.shape[1]
    ka, kb = ka.T, kb.T  # (kA, |A|), (kB, |B|)
    ta, tb = t1.tcost[ka], t2.tcost[kb]
    rest = tb[left].sum(axis=1)[:, None, :] if kA <= kB else ta[left].sum(axis=1)[:, :, None]  # maps first
    out = np.empty((len(T), ka.shape[1], kb.shape[1]))
    step = max(1, _TEMP // (len(T) * kb.shape[1] * max(kA * kB, len(sel))))
    for lo in range(0, ka.shape[1], step):
        sl = slice(lo, lo + step)
        cost = T[:, ka[:, None, sl, None], kb[None, :, None, :]]  # (V, kA, kB, |A|, |B|)
        np.minimum(cost, ta[:, None, sl, None] + tb[None, :, None, :], out=cost)
        cost = cost.reshape(len(T), kA * kB, *cost.shape[3:])
        tot = cost[:, sel[:, 0]]
        for i in range(1, sel.shape[1]):
            tot += cost[:, sel[:, i]]
        if left.shape[1]:
            tot += rest if kA <= kB else rest[:, sl]
        np.minimum.reduce(tot, axis=1, out=out[:, sl])
    return out


def _match_lsa(T, t1: _Prepared, t2: _Prepared, A: range, B: range) -> np.ndarray:
    """Child matching pair by pair for many children on both sides.

    Rectangular form of the padded assignment: deleting every child of both sides costs the sum of their subtree
    costs; matching a with b changes that by gain = min(T, ta + tb) - ta - tb <= 0, so the best matching pairs every
    child of the smaller side (what the padding with empty subtrees allowed).
    """
    from scipy.optimize import linear_sum_assignment

    out = np.empty((len(A), len(B)))
    for i, a in enumerate(A):
        c1 = t1.children[a]
        ta = t1.tcost[c1]
        for j, b in enumerate(B):
            c2 = t2.children[b]
            tb = t2.tcost[c2]
            gain = T[np.ix_(c1, c2)] - ta[:, None] - tb[None, :]
            np.minimum(gain, 0.0, out=gain)
            r, cc = linear_sum_assignment(gain)
            out[i, j] = ta.sum() + tb.sum() + gain[r, cc].sum()
    return out


def _block_skip(M, ga: _Group, gb: _Group, along_b: bool, forest: bool) -> np.ndarray:
    """Zhang's 'map into one child subtree' option for a block, (V, |A|, |B|): base + min over the children t of
    (M[.., t] - sub[t]), M the forest (``forest``) or the tree distance, sub and base the delete / insert costs.

    along_b: the children are the second tree's; else the first's. The dummy child (an empty subtree, where the
    degree is below the tree's largest) gives M[.., dummy] - 0, the same for every node of the block: broadcast.
    """
    g = gb if along_b else ga
    out = np.empty((len(M), len(ga), len(gb)))
    ax = 2 if along_b else 1  # the children's parents
    sub, base = (g.kid_f, g.fcost) if forest else (g.kid_t, g.tcost)
    if along_b:
        v = np.empty((len(M), len(ga), len(gb.kid)))
        for m, w in zip(M, v):  # (np.take copies a non-contiguous input)
            np.take(m[ga.sl], gb.kid, axis=1, out=w)
        dummy = M[:, ga.sl, -1].copy()[..., None]  # the dummy is the last row / column
        v -= sub
    else:
        v = M[:, ga.kid, gb.sl]
        dummy = M[:, -1, None, gb.sl]
        v -= sub[:, None]
    m, mid = 2 * g.pairs, g.leaves + g.pairs

    def part(x, a, b, step=None):  # x[..., a:b:step] along the parents' axis
        return x[:, :, a:b:step] if along_b else x[:, a:b:step]

    if g.pairs:
        np.minimum(part(v, 0, m, 2), part(v, 1, m, 2), out=part(out, g.leaves, mid))  # (faster than reduceat)
    if mid < len(g):
        np.minimum.reduceat(part(v, m, None), g.kid_off, axis=ax, out=part(out, mid, None))
    part(out, 0, g.leaves)[...] = dummy
    np.minimum(part(out, g.leaves, g.full), dummy, out=part(out, g.leaves, g.full))
    out += base if along_b else base[:, None]
    return out


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
    into a child subtree of the other. The nodes are renumbered so that every height group is a range of rows or
    columns of T and F; what a block needs about its nodes (:class:`_Group`) is built once and reused.
    """
    return _tree_edit_distances(gt, pred, c, p, max_chain, False)[0]


def _tree_edit_distances(gt: BranchGraph, pred: BranchGraph, c: float, p: float, max_chain: int,
                         also_plain: bool) -> list[tuple[float, float]]:
    """:func:`tree_edit_distance` with ``max_chain``, and if ``also_plain`` with max_chain = 1 too, in one pass
    over the blocks (tables stacked along a first axis; the plain variant's assign costs are those of the single
    branch chains, a part of the others)."""
    t1, t2 = _relabel(_prepare(gt, max_chain)), _relabel(_prepare(pred, max_chain))
    n1, n2 = t1.n, t2.n
    d1, d2 = n1 + 1, n2 + 1
    V = 2 if also_plain and max_chain > 1 else 1
    # T: tree distance, F: forest distance of the children (per variant); the dummy (empty subtree) row and column
    T, F = np.zeros((V, n1 + 2, n2 + 2)), np.zeros((V, n1 + 2, n2 + 2))
    for M, cost1, cost2 in ((T, t1.tcost, t2.tcost), (F, t1.fcost, t2.fcost)):
        M[:, d1, :] = cost2
        M[:, :, d2] = cost1
        M[:, d1, d2] = 0.0
    g1 = np.searchsorted(t1.height, np.arange(int(t1.height[-1]) + 2)).tolist()  # group h: g1[h]:g1[h + 1]
    g2 = np.searchsorted(t2.height, np.arange(int(t2.height[-1]) + 2)).tolist()
    h1, h2 = len(g1) - 1, len(g2) - 1
    groups2 = [_group(t2, g2[h], g2[h + 1], c) for h in range(h2)]
    groups1: dict[tuple[int, int], _Group] = {}
    for s in range(h1 + h2 - 1):
        for h in range(max(0, s - h2 + 1), min(s, h1 - 1) + 1):
            gb = groups2[s - h]
            lo, hi = g1[h], g1[h + 1]
            step = max(1, _BLOCK // len(gb))
            for a in range(lo, hi, step):
                ga = groups1.get((a, min(a + step, hi)))
                if ga is None:
                    ga = groups1[a, min(a + step, hi)] = _group(t1, a, min(a + step, hi), c)
                _solve_block(T, F, t1, t2, ga, gb, p)
    norm = 2.0 * max(float(t1.tcost[n1]), float(t2.tcost[n2]))
    out = [(float(T[v, n1, n2]), norm) for v in range(V)]
    return out + out if also_plain and V == 1 else out


def _solve_block(T, F, t1: _Prepared, t2: _Prepared, ga: _Group, gb: _Group, p: float) -> None:
    f = _block_matching(T, t1, t2, ga, gb)
    np.minimum(f, _block_skip(F, ga, gb, True, True), out=f)
    np.minimum(f, _block_skip(F, ga, gb, False, True), out=f)
    F[:, ga.sl, gb.sl] = f
    t = _chain_costs(F, f, ga, gb, p)
    np.minimum(t, _block_skip(T, ga, gb, True, False), out=t)
    np.minimum(t, _block_skip(T, ga, gb, False, False), out=t)
    T[:, ga.sl, gb.sl] = t


def _chain_costs(F, f: np.ndarray, ga: _Group, gb: _Group, p: float) -> np.ndarray:
    """(V, |A|, |B|): best over the pair's chains of assign cost + side subtrees deleted / inserted + F of the
    chain ends (variant 1, if any: single-branch chains only), in passes over a few of A's nodes at a time
    (cache-sized temporaries). ``f``: F of the block itself."""
    ca, cb = ga.ch, gb.ch
    off, offb = ca["off"], cb["off"]
    end = np.append(off[1:], len(ca["len"]))  # each node's chains: rows off[i]:end[i]
    # one chain per node on both sides: no side subtree, the chain ends are the nodes themselves
    single = len(ca["len"]) == len(ga) and len(offb) == len(cb["len"])
    out = np.empty(f.shape)
    F0 = F[0].reshape(-1)  # a view; flat indices gather faster than a pair of index arrays
    per = max(1, _CHUNK // len(cb["len"]))  # chain rows per pass
    lo = 0
    while lo < len(off):
        hi = max(lo + 1, int(np.searchsorted(end, off[lo] + per, side="right")))
        r = slice(int(off[lo]), int(end[hi - 1]))
        cost = _gamma_outer(ca, r, cb, p)
        if single:
            np.add(cost, f[:, lo:hi], out=out[:, lo:hi])
            lo = hi
            continue
        if len(f) > 1:  # the plain variant: single-branch chains, the first of each node
            np.add(np.take(cost[off[lo:hi] - off[lo]], offb, axis=1), f[1, lo:hi], out=out[1, lo:hi])
        cost += ca["side"][r, None]
        cost += cb["side"][None, :]
        cost += F0.take(np.add.outer(ca["bottom"][r] * F.shape[2], cb["bottom"]))  # F[0, bottom, bottom]
        if r.stop - r.start > hi - lo:  # some node has several chains
            cost = np.minimum.reduceat(cost, off[lo:hi] - off[lo], axis=0)
        out[0, lo:hi] = np.minimum.reduceat(cost, offb, axis=1) if len(offb) < cost.shape[1] else cost
        lo = hi
    return out


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
    if variants == (True, False):  # both in one pass
        dists = _tree_edit_distances(g1, g2, params.c, params.p, int(params.max_chain), True)
    else:
        dists = [tree_edit_distance(g1, g2, c=params.c, p=params.p,
                                    max_chain=int(params.max_chain) if split_merge else 1) for split_merge in variants]
    out = []
    for dist, norm in dists:
        d_t = float(min(1.0, dist / norm)) if norm > 0 else 0.0
        out.append(StavaResult(1.0 - (d_s + d_g + d_t) / 3.0, d_s, d_g, d_t))
    return out
