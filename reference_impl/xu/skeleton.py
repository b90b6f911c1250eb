"""Xu, Gossett, Chen 2007 section 4.1-4.2: the main skeleton from geodesic bins and its extension by
bi-directional probing. Pure functions over arrays; see :mod:`reference_impl.xu` for the parameters."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from plantbench.geometry.vectors import unit
from reference_impl.common.graph import bridge_waypoints

__all__ = ["BinSkeleton", "bin_skeleton", "probe_extend"]


@dataclass
class BinSkeleton:
    """A skeleton from geodesic bins: node centroids, parents, mean geodesic distance, and for every member point
    its node (``point_node``, -1 for points outside the processed subgraph)."""

    positions: np.ndarray
    parents: np.ndarray
    geodesic: np.ndarray
    point_node: np.ndarray


def bin_skeleton(points: np.ndarray, graph: sp.csr_matrix, members: np.ndarray, roots: np.ndarray,
                 width: float) -> BinSkeleton:
    """Section 4.1 on the subgraph induced by ``members`` (indices into ``points``) from ``roots`` (indices into
    ``points``, members themselves).

    Shortest paths from the roots (Dijkstra), path lengths quantised in bins of ``width``, each bin split into the
    connected components of the edges inside it (as Brostow et al. 2004); each component's centroid is a skeleton
    node whose parent is the component holding the shortest-path predecessors of most of its points (so parents lie
    in strictly lower bins and the result is a forest rooted in the roots' bin-0 components). Unreachable members
    get no node.
    """
    members = np.asarray(members, np.int64)
    n = len(points)
    local = np.full(n, -1, np.int64)
    local[members] = np.arange(len(members))
    sub = graph[members][:, members].tocsr()
    dist, pred, _ = csgraph.dijkstra(sub, directed=False, indices=local[np.asarray(roots, np.int64)],
                                  return_predecessors=True, min_only=True)
    reach = np.isfinite(dist)
    bins = np.where(reach, np.floor(dist / width), -1).astype(np.int64)
    coo = sub.tocoo()
    same = (bins[coo.row] == bins[coo.col]) & reach[coo.row]
    m = len(members)
    inbin = sp.coo_matrix((np.ones(same.sum()), (coo.row[same], coo.col[same])), shape=(m, m))
    _, comp = csgraph.connected_components(inbin, directed=False)
    comp = np.where(reach, comp, -1)
    ids, comp_r = np.unique(comp[reach], return_inverse=True)
    k = len(ids)
    node = np.full(m, -1, np.int64)
    node[reach] = comp_r
    cnt = np.bincount(comp_r, minlength=k).astype(float)
    pos = np.zeros((k, 3))
    np.add.at(pos, comp_r, points[members[reach]])
    pos /= cnt[:, None]
    geo = np.zeros(k)
    np.add.at(geo, comp_r, dist[reach])
    geo /= cnt
    # parent: majority component of predecessors lying in other components
    src = np.flatnonzero(reach & (pred >= 0))
    a, b = node[src], node[pred[src]]
    diff = a != b
    a, b = a[diff], b[diff]
    parents = np.full(k, -1, np.int64)
    if len(a):
        pair = a * k + b
        up, upc = np.unique(pair, return_counts=True)
        child, par = up // k, up % k
        order = np.lexsort((-upc, child))
        first = np.ones(len(order), bool)
        first[1:] = child[order][1:] != child[order][:-1]
        parents[child[order][first]] = par[order][first]
    point_node = np.full(n, -1, np.int64)
    point_node[members] = node
    return BinSkeleton(pos, parents, geo, point_node)


def _cone_hits(origin: np.ndarray, axis: np.ndarray, cand: np.ndarray, half_angle: float, reach: float
               ) -> np.ndarray:
    """Mask of candidate points inside the cone (apex ``origin``, unit ``axis``, half-angle, length ``reach``)."""
    v = cand - origin
    d = np.linalg.norm(v, axis=1)
    cos = (v @ axis) / np.maximum(d, 1e-15)
    return (d <= reach) & (d > 1e-12) & (cos >= np.cos(half_angle))


def _probe(tree: cKDTree, points: np.ndarray, labels: np.ndarray, attached: np.ndarray, rejected: np.ndarray,
           apex: np.ndarray, axis: np.ndarray, half_angle: float, gap: float) -> int:
    """Forward probe: the nearest point inside the cone (``apex``, ``axis``, ``half_angle``, length ``gap``) that
    belongs to a subgraph neither attached nor rejected; -1 for none."""
    near = np.asarray(tree.query_ball_point(apex, gap), np.int64)
    near = near[~attached[near] & ~rejected[labels[near]]]
    if len(near) == 0:
        return -1
    hit = near[_cone_hits(apex, axis, points[near], half_angle, gap)]
    if len(hit) == 0:
        return -1
    return int(hit[np.argmin(np.linalg.norm(points[hit] - apex, axis=1))])


def _back_probe(pos: list, par: list, geo: list, p_pos: np.ndarray, tangent: np.ndarray, half_angle: float,
                gap: float, width: float) -> int:
    """Backward probe from P: the nearest point Q of the skeleton (``pos``, ``par``, ``geo`` lists; on an edge or a
    node) inside the cone from ``p_pos`` along ``tangent``, as a node: an edge's end within a quarter bin ``width``
    of Q, else a node inserted on the edge (appended to the lists). Returns Q's node, -1 when the cone holds none."""
    nodes = np.asarray(pos)
    parr = np.asarray(par)
    child = np.flatnonzero(parr >= 0)
    a, b = nodes[parr[child]], nodes[child]
    ab = b - a
    t = np.clip(np.sum((p_pos - a) * ab, 1) / np.maximum(np.sum(ab * ab, 1), 1e-300), 0, 1)
    q = np.concatenate([a + t[:, None] * ab, nodes])
    ok = _cone_hits(p_pos, tangent, q, half_angle, gap)
    if not ok.any():
        return -1
    cand = np.flatnonzero(ok)
    best = cand[np.argmin(np.linalg.norm(q[cand] - p_pos, axis=1))]
    if best >= len(child):
        return int(best - len(child))
    c = int(child[best])
    tb = t[best]
    seg = np.linalg.norm(ab[best])
    if tb * seg < 0.25 * width:
        return int(parr[c])
    if (1 - tb) * seg < 0.25 * width:
        return c
    pos.append(q[best])  # Q on the edge parent(c) -> c
    par.append(int(parr[c]))
    geo.append(geo[parr[c]] + tb * (geo[c] - geo[parr[c]]))
    par[c] = len(pos) - 1
    return len(pos) - 1


def _append(pos: list, par: list, geo: list, point_node: np.ndarray, sub: BinSkeleton, q_node: int,
            base_geo: float) -> range:
    """Append the subgraph's skeleton ``sub`` to the lists, its root hanging from ``q_node``, geodesic distances
    continuing from ``base_geo`` (P's); its points' nodes are renumbered in ``point_node``. Returns the new nodes."""
    off = len(pos)
    for i in range(len(sub.positions)):
        pos.append(sub.positions[i])
        par.append(off + int(sub.parents[i]) if sub.parents[i] >= 0 else q_node)
        geo.append(base_geo + float(sub.geodesic[i]))
    sel = sub.point_node >= 0
    point_node[sel] = off + sub.point_node[sel]
    return range(off, len(pos))


def _step_through(points, tree, attached, members, q_node: int, p_pos, base_geo: float, pos: list, par: list,
                  geo: list, point_node) -> int:
    """The segment PQ steps through the free points in the gap (:func:`bridge_waypoints`), each appended as a node
    below the last; geodesic distances still run along PQ, so the detour does not end the probing any earlier.
    Updates the lists and masks in place; returns the node the subgraph hangs from."""
    free = ~attached
    free[members] = False
    for w in bridge_waypoints(points, tree, free, pos[q_node], p_pos):
        geo.append(base_geo - float(np.linalg.norm(p_pos - points[w])))
        pos.append(points[w])
        par.append(q_node)
        q_node = len(pos) - 1
        point_node[w] = q_node
        attached[w] = True
    return q_node


def _hang(points, tree, attached, members, sub: BinSkeleton, q_node: int, p_idx: int, pos: list, par: list,
          geo: list, point_node, waypoints: bool) -> range:
    """Join subgraph ``members`` (its skeleton ``sub``, rooted at its point ``p_idx``) below node ``q_node``: the
    segment PQ, through the free returns in the gap with ``waypoints`` (:func:`_step_through`), then ``sub``
    (:func:`_append`); its points become attached. Updates the lists and masks in place; returns the new nodes of
    ``sub``."""
    p_pos = points[p_idx]
    base_geo = geo[q_node] + float(np.linalg.norm(p_pos - pos[q_node]))
    if waypoints:
        q_node = _step_through(points, tree, attached, members, q_node, p_pos, base_geo, pos, par, geo, point_node)
    attached[members] = True
    return _append(pos, par, geo, point_node, sub, q_node, base_geo)


def probe_extend(points: np.ndarray, graph: sp.csr_matrix, labels: np.ndarray, main: BinSkeleton,
                 attached: np.ndarray, *, width: float, cone_deg: float, gap: float, max_geodesic: float,
                 min_nodes: int = 2, tangent_nodes: int = 3, persistent: bool = False, large_share: float = 0.1,
                 waypoints: bool = False) -> tuple[BinSkeleton, np.ndarray, int]:
    """Section 4.2: breadth-first over the skeleton; at each node with geodesic distance below ``max_geodesic`` a
    cone (half-angle ``cone_deg``, along parent -> node) looks for the nearest point of an unattached subgraph G
    within ``gap``; G's own bin skeleton is built from that point P; a cone from P along the tangent T (from G's
    first ``tangent_nodes`` nodes back through P) must hit the main skeleton (a node or an edge) at Q within ``gap``;
    then G joins with the segment PQ (Q inserted on the edge if new) and its nodes go to the back of the queue.

    labels : (n,) connected-component label of every point; attached : (n,) bool, points already in the skeleton.
    Subgraphs whose skeleton has fewer than ``min_nodes`` nodes are not joined (our guard: no tangent exists).

    ``persistent`` (our fallback for a stem whose scan has a gap, :func:`reference_impl.xu.pipeline`): a node whose
    nearest subgraph cannot join (too small, or failing the backward probe) probes again past it, since on a sparse
    scan the nearest fragment across a gap is often a point or two; and a subgraph holding at least ``large_share`` of
    the points joins at the probing node even when the backward probe misses: the backward probe guards against
    joining noise, and a crown that a gap in the stem cut off is not noise, but its tangent at P follows whichever
    branch P lies on.
    ``waypoints``: the segment PQ passes through the free points (in no joined subgraph) between Q and P, in order
    (:func:`reference_impl.common.graph.bridge_waypoints`): the scattered returns of a branch that occlusion left in
    pieces too small to join on their own [S].
    Each node probes once, so the loop is bounded by the final node count. Returns the extended skeleton, the
    updated ``attached`` mask and the number of subgraphs joined.
    """
    pos = [p for p in main.positions]
    par = list(main.parents)
    geo = list(main.geodesic)
    point_node = main.point_node.copy()
    attached = attached.copy()
    tree = cKDTree(points)
    half = np.radians(cone_deg)
    queue = deque(range(len(pos)))
    rejected = np.zeros(labels.max() + 1, bool)
    joined = 0
    while queue:
        v = queue.popleft()
        if geo[v] >= max_geodesic:
            continue
        axis = unit(pos[v] - pos[par[v]]) if par[v] >= 0 else np.array([0.0, 0.0, 1.0])
        skip = rejected.copy()  # subgraphs this node has tried
        q_node = -1
        while q_node < 0:  # the nearest subgraph in the cone first; past it when it cannot join
            p_idx = _probe(tree, points, labels, attached, skip, pos[v], axis, half, gap)
            if p_idx < 0:
                break
            skip[labels[p_idx]] = True
            members = np.flatnonzero(labels == labels[p_idx])
            sub = bin_skeleton(points, graph, members, np.array([p_idx]), width)
            if len(sub.positions) < min_nodes:
                rejected[labels[p_idx]] = True
                if not persistent:
                    break
                continue
            # tangent at P: from the centroid of G's first nodes (by geodesic distance) back through P
            first = np.argsort(sub.geodesic, kind="stable")[:tangent_nodes]
            p_pos = points[p_idx]
            tangent = unit(p_pos - sub.positions[first[1:]].mean(0)) if len(first) > 1 else -axis
            q_node = _back_probe(pos, par, geo, p_pos, tangent, half, gap, width)
            if q_node < 0 and persistent and len(members) >= large_share * len(points):
                q_node = v  # a large part of the cloud straight ahead of the skeleton: joined at the probing node
            if q_node < 0 and not persistent:
                break
        if q_node < 0:
            continue
        queue.extend(_hang(points, tree, attached, members, sub, q_node, p_idx, pos, par, geo, point_node,
                           waypoints))
        joined += 1
    out = BinSkeleton(np.asarray(pos), np.asarray(par, np.int64), np.asarray(geo), point_node)
    return out, attached, joined


def join_fragments(points: np.ndarray, graph: sp.csr_matrix, labels: np.ndarray, skel: BinSkeleton,
                   attached: np.ndarray, *, width: float, gap: float, min_points: int = 3,
                   waypoints: bool = False) -> tuple[BinSkeleton, np.ndarray, int]:
    """After probing: every subgraph of at least ``min_points`` points still unattached whose nearest point lies
    within ``gap`` of an attached point joins there, the nearest first, in rounds until none is left within reach
    (each subgraph's skeleton hangs from the node of its nearest attached point, from the point P of the subgraph
    nearest to it). Returns the extended skeleton, ``attached`` and the number joined [S: docs/tuning/xu.md]."""
    pos = [p for p in skel.positions]
    par = list(skel.parents)
    geo = list(skel.geodesic)
    point_node = skel.point_node.copy()
    attached = attached.copy()
    tree = cKDTree(points)
    by_label = np.argsort(labels, kind="stable")  # each subgraph's points, found once
    bounds = np.searchsorted(labels[by_label], np.arange(labels.max() + 2))
    sizes = np.diff(bounds)
    joined = 0
    while True:  # a round joins every subgraph within reach of what was attached when it began
        att = np.flatnonzero(attached & (point_node >= 0))
        free = np.flatnonzero(~attached & (sizes[labels] >= min_points))
        if len(att) == 0 or len(free) == 0:
            break
        d, j = cKDTree(points[att]).query(points[free], distance_upper_bound=gap)
        ok = np.isfinite(d)
        if not ok.any():
            break
        free, d, j = free[ok], d[ok], j[ok]
        for k in np.lexsort((free, d)):  # nearest first; a subgraph's farther points find it attached
            p_idx = int(free[k])
            if attached[p_idx]:
                continue
            lab = labels[p_idx]
            members = by_label[bounds[lab]:bounds[lab + 1]]
            sub = bin_skeleton(points, graph, members, np.array([p_idx]), width)
            _hang(points, tree, attached, members, sub, int(point_node[att[j[k]]]), p_idx, pos, par, geo,
                  point_node, waypoints)
            joined += 1
    out = BinSkeleton(np.asarray(pos), np.asarray(par, np.int64), np.asarray(geo), point_node)
    return out, attached, joined
