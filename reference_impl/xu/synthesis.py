"""Xu, Gossett, Chen 2007 section 4.3 (leaf locations, supported/feasible, triangle-matching branch synthesis,
implementation in section 7.2) and the twig pruning of section 4.4."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from plantbench.geometry.vectors import levels, similarity_transform, unit
from reference_impl.common.graph import children_csr, empty_segments, subtree_sums

__all__ = ["leaf_locations", "node_directions", "axil_angles", "support", "triangle_table", "triangle_angles",
           "similarity_transform", "section_nodes", "synthesize", "prune_bare_twigs", "SynthesisResult"]


def leaf_locations(points: np.ndarray, cell: float, density_range: float) -> tuple[np.ndarray, np.ndarray]:
    """Group unattached points into leaf locations (one per occupied cell of edge ``cell``: the paper's sphere of
    leaf size) and their density (the number of other locations within ``density_range``)."""
    if len(points) == 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    key = np.floor((points - points.min(0)) / cell).astype(np.int64)
    _, lab, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    lab = lab.ravel()
    loc = np.zeros((len(cnt), 3))
    np.add.at(loc, lab, points)
    loc /= cnt[:, None]
    dens = cKDTree(loc).query_ball_point(loc, density_range, return_length=True, workers=-1) - 1
    return loc, np.asarray(dens, np.int64)


def _kth_ancestor(parents: np.ndarray, k: int) -> np.ndarray:
    anc = np.arange(len(parents))
    for _ in range(k):
        anc = np.where(parents[anc] >= 0, parents[anc], anc)
    return anc


def _main_descendant(parents: np.ndarray, k: int) -> np.ndarray:
    """(n,) the node reached by following the child with the largest subtree ``k`` times (or the last one)."""
    n = len(parents)
    size = subtree_sums(np.ones(n), parents)
    child = np.flatnonzero(parents >= 0)
    main = np.arange(n)
    if len(child):
        order = np.lexsort((child, -size[child], parents[child]))
        c = child[order]
        first = np.ones(len(c), bool)
        first[1:] = parents[c][1:] != parents[c][:-1]
        main[parents[c[first]]] = c[first]
    out = np.arange(n)
    for _ in range(k):
        out = main[out]
    return out


def node_directions(positions: np.ndarray, parents: np.ndarray, reach: int = 3) -> np.ndarray:
    """(n, 3) unit direction pointing to each node from its parent, measured over ``reach`` edges (from the
    reach-th ancestor) so that bin noise does not dominate [S: the paper uses the parent; our nodes are one bin
    apart]; roots take the direction to their main descendant (or +Z)."""
    anc = _kth_ancestor(parents, reach)
    d = positions - positions[anc]
    desc = _main_descendant(parents, reach)
    roots = np.flatnonzero(anc == np.arange(len(parents)))
    d[roots] = positions[desc[roots]] - positions[roots]
    bad = np.linalg.norm(d, axis=1) < 1e-12
    d[bad] = np.array([0.0, 0.0, 1.0])
    return unit(d)


def axil_angles(positions: np.ndarray, parents: np.ndarray, reach: int = 3) -> np.ndarray:
    """Section 4.3, Fig. 5(a): at every split node (>= 2 children, not a root) the largest angle between a child's
    direction and the node's own direction, degrees. Directions span ``reach`` edges (see node_directions)."""
    ptr, kids = children_csr(parents)
    d = node_directions(positions, parents, reach)
    desc = _main_descendant(parents, max(reach - 1, 0))
    split = np.flatnonzero((np.diff(ptr) >= 2) & (parents >= 0))
    out = np.zeros(len(split))
    for i, v in enumerate(split):
        c = desc[kids[ptr[v]:ptr[v + 1]]]
        cos = unit(positions[c] - positions[v]) @ d[v]
        out[i] = np.degrees(np.arccos(np.clip(cos.min(), -1, 1)))
    return out


def _connection_ok(loc: np.ndarray, node_pos: np.ndarray, node_dir: np.ndarray, lo: float, hi: float) -> np.ndarray:
    cos = np.sum(unit(loc - node_pos) * node_dir, axis=-1)
    ang = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    return (ang >= lo) & (ang <= hi)


def support(locations: np.ndarray, positions: np.ndarray, parents: np.ndarray, *, d0: float, interval: tuple,
            k: int = 32) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every leaf location: its nearest feasible node (connection angle in ``interval`` degrees) among the ``k``
    nearest nodes (-1 if none), that node's distance, and ``supported`` (a feasible node within ``d0``)."""
    m = len(locations)
    if m == 0 or len(positions) == 0:
        return np.full(m, -1), np.full(m, np.inf), np.zeros(m, bool)
    kk = min(k, len(positions))
    dist, idx = cKDTree(positions).query(locations, k=kk, workers=-1)
    dist, idx = dist.reshape(m, kk), idx.reshape(m, kk)
    d = node_directions(positions, parents)
    ok = _connection_ok(locations[:, None, :], positions[idx], d[idx], *interval)
    first = np.argmax(ok, axis=1)
    has = ok[np.arange(m), first]
    node = np.where(has, idx[np.arange(m), first], -1)
    nd = np.where(has, dist[np.arange(m), first], np.inf)
    return node, nd, nd <= d0


def triangle_angles(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 3) interior angles (degrees) at O, A, B of the triangles OAB."""
    def ang(p, q, r):
        return np.degrees(np.arccos(np.clip(np.sum(unit(q - p) * unit(r - p), -1), -1, 1)))

    return np.stack([ang(o, a, b), ang(a, b, o), ang(b, o, a)], -1)


@dataclass(frozen=True)
class TriangleTable:
    """Section 7.2: every candidate triangle (O', A', B') of the skeleton as a 3D point of angles, stored twice
    ((alpha, beta, gamma) and (alpha, gamma, beta)), in a KD-tree."""

    tree: cKDTree | None
    o: np.ndarray
    a: np.ndarray
    b: np.ndarray
    detail: np.ndarray
    """Number of skeleton nodes in the section spanned by the triangle (the paper's tie-break: more fine detail)."""


def triangle_table(positions: np.ndarray, parents: np.ndarray, *, per_child: int = 6) -> TriangleTable:
    """Triangles O' (a split node), A' and B' (offspring in two different child subtrees of O'): for each child
    subtree, the first ``per_child`` junctions and tips below it in breadth-first order [S: bounds the table]."""
    ptr, kids = children_csr(parents)
    nk = np.diff(ptr)
    size = subtree_sums(np.ones(len(parents)), parents)  # nodes per subtree
    os_, as_, bs_, det = [], [], [], []
    for o in np.flatnonzero(nk >= 2):
        groups = []
        for c in kids[ptr[o]:ptr[o + 1]]:
            found, frontier = [], [int(c)]
            for _ in range(64):  # breadth-first, bounded
                if not frontier or len(found) >= per_child:
                    break
                nxt = []
                for v in frontier:
                    if nk[v] != 1:
                        found.append(v)
                    nxt.extend(kids[ptr[v]:ptr[v + 1]].tolist())
                frontier = nxt
            groups.append(found[:per_child])
        for i in range(len(groups)):
            for j in range(i + 1, len(groups)):
                for a in groups[i]:
                    for b in groups[j]:
                        os_.append(o)
                        as_.append(a)
                        bs_.append(b)
                        det.append(size[kids[ptr[o]:ptr[o + 1]]].sum())
    if not os_:
        return TriangleTable(None, *(np.zeros(0, np.int64),) * 3, np.zeros(0))
    o, a, b = np.asarray(os_), np.asarray(as_), np.asarray(bs_)
    ang = triangle_angles(positions[o], positions[a], positions[b])
    pts = np.concatenate([ang, ang[:, [0, 2, 1]]])
    return TriangleTable(cKDTree(pts), np.concatenate([o, o]), np.concatenate([a, b]), np.concatenate([b, a]),
                         np.concatenate([det, det]))


def _path_up(parents: np.ndarray, start: int, stop: int) -> list[int]:
    """Nodes from ``start`` up to (excluding) ``stop``; bounded by the node count."""
    out, v = [], start
    for _ in range(len(parents)):
        if v == stop or v < 0:
            break
        out.append(v)
        v = int(parents[v])
    return out


def section_nodes(parents: np.ndarray, o: int, a: int, b: int) -> np.ndarray:
    """Sorted nodes of the section defined by the triangle O'A'B' (section 4.3: "the skeleton structure from O' to
    A' and B' is copied"): the paths from A' and from B' up to O', O' excluded. The side branches hanging from the
    paths are not part of it [an earlier reading of ours copied their parts within the ball around O' reaching A'
    and B' too: on the multiview suite's mvs clouds the final skeletons had 1.04-2.08x the branch chains they have
    with the paths alone, at the same skeleton vF1@1% (0.579 and 0.582 over the 10 plants)]."""
    return np.asarray(sorted(set(_path_up(parents, a, o)) | set(_path_up(parents, b, o))), np.int64)


@dataclass
class SynthesisResult:
    positions: np.ndarray
    parents: np.ndarray
    synthetic: np.ndarray
    """(n,) bool: node was synthesised (not from the scan)."""
    iterations: int
    branches: int
    refused: int = 0
    """Copies refused because an edge crossed empty space."""


def _section_copy(table, pos: np.ndarray, par: np.ndarray, po: np.ndarray, pa: np.ndarray, pb: np.ndarray):
    """The section O'A'B' of the scanned triangle most similar to OAB (Eq. 6; ties within 1 degree to the one with
    more nodes), mapped onto OAB by the similarity transform. Returns the mapped positions, each copied node's
    parent's index within the copy (its nodes are sorted) and whether that parent is in the copy (else it hangs
    from O)."""
    ang = triangle_angles(po, pa, pb)
    dd, ii = table.tree.query(ang, k=min(8, len(table.o)))
    dd, ii = np.atleast_1d(dd), np.atleast_1d(ii)
    close = ii[dd <= dd[0] + 1.0]
    t = int(close[np.argmax(table.detail[close])])
    o2, a2, b2 = int(table.o[t]), int(table.a[t]), int(table.b[t])
    nodes = section_nodes(par, o2, a2, b2)
    s, rot, tr = similarity_transform(pos[[o2, a2, b2]], np.stack([po, pa, pb]))
    mapped = (s * (rot @ pos[nodes].T)).T + tr
    up = np.minimum(np.searchsorted(nodes, par[nodes]), len(nodes) - 1)
    return mapped, up, nodes[up] == par[nodes]


def synthesize(positions: np.ndarray, parents: np.ndarray, locations: np.ndarray, density: np.ndarray, *,
               d0: float, interval: tuple, group: float, iterations: int,
               max_nodes: int, cloud: cKDTree | None = None, tolerance: float | None = None,
               max_reach: float = np.inf) -> SynthesisResult:
    """Section 4.3: up to ``iterations`` rounds; each round associates every unsupported leaf location with its
    nearest feasible node, and at each node O with associations picks A (highest density) and B (highest density
    among the far half, farther than ``group`` from A), finds the most similar skeleton triangle O'A'B' (Eq. 6,
    KD-tree over angle triples; ties within 1 degree go to the triangle with more nodes), and copies the section
    O'A'B' (its two paths, :func:`section_nodes`) with the similarity transform mapping O'A'B' onto OAB, hung from
    O. A node whose associated locations hold no two separate ones (a single location, or all within ``group`` of
    A) gets nothing, as the paper synthesises from a triangle OAB only [an earlier straight twig O -> A of ours made
    70-92 % of the synthesised branches on the multiview suite's mvs clouds, each a chain of its own]. The table
    holds the scanned skeleton's triangles (computed once, as the paper pre-calculates them). Stops early when
    everything is supported or at ``max_nodes`` [S: memory bound].

    Two limits of ours (issue 25: synthesis copies only where the cloud lacks branch points, never across the crown,
    and leaves no edge through empty space) [S]: a location is associated only with a feasible node within
    ``max_reach`` of it; and with ``cloud`` (a cKDTree of the input points) and ``tolerance``, a copy any of whose
    edges (the one hanging it from O included) crosses empty space (:func:`~reference_impl.common.graph.
    empty_segments`) is refused; ``SynthesisResult.refused`` counts them (a refused copy's locations stay
    unsupported and may be reached from another node in the next round).
    """
    pos = np.asarray(positions, float)
    par = np.asarray(parents, np.int64)
    synth = np.zeros(len(par), bool)
    table = triangle_table(pos, par)
    branches = refused = 0
    it = 0

    def crosses_empty(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        if cloud is None or tolerance is None:
            return np.zeros(len(a), bool)
        return empty_segments(a, b, cloud, tolerance)

    for it in range(1, iterations + 1):
        node, nd, sup = support(locations, pos, par, d0=d0, interval=interval)
        todo = np.flatnonzero(~sup & (node >= 0) & (nd <= max_reach))
        if len(todo) == 0 or len(pos) >= max_nodes:
            it -= 1
            break
        new_pos, new_par = [], []
        base = len(pos)
        order = np.argsort(node[todo], kind="stable")
        todo = todo[order]
        splits = np.flatnonzero(np.diff(node[todo])) + 1
        for grp in np.split(todo, splits):
            if base + len(new_pos) >= max_nodes:
                break
            o = int(node[grp[0]])
            po = pos[o]
            a_i = grp[np.argmax(density[grp])]
            pa = locations[a_i]
            dist = np.linalg.norm(locations[grp] - po, axis=1)
            far = grp[(dist >= np.median(dist)) & (np.linalg.norm(locations[grp] - pa, axis=1) > group)]
            if len(far) == 0 or table.tree is None:
                continue  # no two separate locations A and B (or no triangle to copy): nothing to synthesise
            pb = locations[far[np.argmax(density[far])]]
            mapped, up, inside = _section_copy(table, pos, par, po, pa, pb)
            if crosses_empty(np.where(inside[:, None], mapped[up], po), mapped).any():
                refused += 1
                continue
            new_par.extend(np.where(inside, base + len(new_pos) + up, o).tolist())
            new_pos.extend(mapped)
            branches += 1
        if not new_pos:
            break
        pos = np.concatenate([pos, np.asarray(new_pos)])
        par = np.concatenate([par, np.asarray(new_par, np.int64)])
        synth = np.concatenate([synth, np.ones(len(new_pos), bool)])
    return SynthesisResult(pos, par, synth, it, branches, refused)


def prune_bare_twigs(positions: np.ndarray, parents: np.ndarray, synthetic: np.ndarray, supporting: np.ndarray,
                     keep_fraction: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Section 4.4: twigs of synthesised branches (terminal chains of synthetic nodes) that support no leaf location
    are removed, except a random ``keep_fraction`` of them. supporting : (n,) bool, node is the supporting node of
    a leaf location. Returns the keep mask and the bare twigs kept (their tip nodes)."""
    n = len(parents)
    ptr, _ = children_csr(parents)
    nk = np.diff(ptr)
    keep = np.ones(n, bool)
    tips = np.flatnonzero((nk == 0) & synthetic)
    bare_chains = []
    for tip in tips:
        chain, v, ok = [], int(tip), False
        for _ in range(n):
            if v < 0 or not synthetic[v] or (nk[v] > 1 and v != tip):
                break
            chain.append(v)
            ok |= bool(supporting[v])
            v = int(parents[v])
        if chain and not ok:
            bare_chains.append(chain)
    kept_tips = []
    if bare_chains:
        keep_mask = rng.random(len(bare_chains)) < keep_fraction
        for chain, k in zip(bare_chains, keep_mask):
            if k:
                kept_tips.append(chain[0])
            else:
                keep[chain] = False
    # a removed node's descendants go too (a chain ends at a junction, so there are none, but stay safe)
    for idx in levels(parents):
        c = idx[parents[idx] >= 0]
        keep[c] &= keep[parents[c]]
    return keep, np.asarray(kept_tips, np.int64)
