"""Point graphs and rooted trees over them.

- :func:`voxel_downsample`: one centroid per occupied voxel (and each point's voxel).
- :func:`knn_graph`, :func:`radius_graph`: symmetric sparse graphs weighted by Euclidean edge length.
- :func:`bridge_components`: join every connected component to the rest with its shortest inter-component edge
  (Boruvka rounds, so at most ceil(log2 k) rounds for k components).
- :func:`bridge_waypoints`: the points a bridge across a gap steps through (the cheapest path by squared step length).
- :func:`shortest_path_tree`: multi-source Dijkstra (scipy.sparse.csgraph), the nearest root claims each vertex.
- :func:`empty_segments`: which straight segments cross empty space (a point along them farther than a tolerance
  from every point of the cloud): the test behind issue 25's "no edge through empty space".
- :func:`subtree_sums`, :func:`subtree_lengths`, :func:`edge_lengths`, :func:`children_csr`: vectorised passes over a
  parent array (depths and depth levels: :mod:`plantbench.geometry.vectors`).

A "tree" here is a parent array (``-1`` for roots), as in :class:`plantbench.plant.Skeleton`.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from plantbench.errors import InputError
from plantbench.geometry import vectors

__all__ = [
    "voxel_downsample",
    "knn_graph",
    "radius_graph",
    "median_spacing",
    "components",
    "bridge_components",
    "bridge_waypoints",
    "shortest_path_tree",
    "subtree_sums",
    "subtree_lengths",
    "edge_lengths",
    "children_csr",
    "empty_segments",
]


def voxel_downsample(points: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Average the points of each occupied voxel.

    points : (n, 3) float; voxel : edge length, metres (> 0)
    Returns ``centroids (m, 3)``, ``labels (n,)`` (each point's voxel, index into centroids) and ``counts (m,)``.
    Voxels are ordered lexicographically by integer cell, so the result does not depend on the point order.
    """
    if not voxel > 0:
        raise InputError(f"voxel size must be > 0, got {voxel}")
    points = np.asarray(points, np.float64)
    if len(points) == 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    cell = np.floor((points - points.min(0)) / voxel).astype(np.int64)
    _, labels, counts = np.unique(cell, axis=0, return_inverse=True, return_counts=True)
    labels = labels.ravel()
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, labels, points)
    return sums / counts[:, None], labels, counts


def _symmetric(i: np.ndarray, j: np.ndarray, w: np.ndarray, n: int) -> sp.csr_matrix:
    keep = i != j
    i, j, w = i[keep], j[keep], w[keep]
    # zero-length edges (duplicate points) would vanish from a sparse matrix: give them a tiny positive length
    w = np.maximum(w, 1e-12)
    g = sp.coo_matrix((np.concatenate([w, w]), (np.concatenate([i, j]), np.concatenate([j, i]))), shape=(n, n))
    g = g.tocsr()
    g.sum_duplicates()
    # duplicates were summed: take the single length back (each undirected pair appears 1 or 2 times per side)
    cnt = sp.coo_matrix((np.ones(2 * len(i)), (np.concatenate([i, j]), np.concatenate([j, i]))), shape=(n, n)).tocsr()
    cnt.sum_duplicates()
    g.data = g.data / cnt.data
    return g


def knn_graph(points: np.ndarray, k: int, max_edge: float | None = None) -> sp.csr_matrix:
    """Symmetrised k-nearest-neighbour graph, edge weight = Euclidean length.

    points : (n, 3) float; k : neighbours per point; max_edge : drop longer edges (None keeps all)
    Returns an (n, n) CSR matrix (symmetric, zero diagonal).
    """
    n = len(points)
    if n < 2:
        return sp.csr_matrix((n, n))
    k = int(min(k, n - 1))
    dist, idx = cKDTree(points).query(points, k=k + 1, workers=-1)
    i = np.repeat(np.arange(n), k)
    j = idx[:, 1:].ravel()
    d = dist[:, 1:].ravel()
    keep = np.isfinite(d) & (j < n)
    if max_edge is not None:
        keep &= d <= max_edge
    return _symmetric(i[keep], j[keep], d[keep], n)


def radius_graph(points: np.ndarray, radius: float) -> sp.csr_matrix:
    """Every pair closer than ``radius`` joined, edge weight = Euclidean length (Xu 2007 section 4.1)."""
    n = len(points)
    if n < 2:
        return sp.csr_matrix((n, n))
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return sp.csr_matrix((n, n))
    d = np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)
    return _symmetric(pairs[:, 0], pairs[:, 1], d, n)


def median_spacing(points: np.ndarray) -> float:
    """Median distance from a point to its nearest other point (0 for fewer than 2 points)."""
    if len(points) < 2:
        return 0.0
    d, _ = cKDTree(points).query(points, k=2, workers=-1)
    return float(np.median(d[:, 1]))


def components(graph: sp.spmatrix) -> tuple[int, np.ndarray]:
    """Connected components of an undirected graph: ``(count, labels (n,))``."""
    return csgraph.connected_components(graph, directed=False)


def bridge_components(points: np.ndarray, graph: sp.csr_matrix, *, max_rounds: int | None = None
                      ) -> tuple[sp.csr_matrix, int]:
    """Join all components with their shortest inter-component edges (Boruvka's rule on the Euclidean complete graph).

    Each round every component gets its shortest edge (approximately: the shortest among each point's 32 nearest) to
    a point of another component (found with kNN queries of growing k, and for a component whose neighbours are all
    its own, a KD-tree over the other points); the rounds at least halve the component count, so at most ``ceil(log2
    k) + 1`` rounds run.
    Returns the augmented graph and the number of bridge edges added.
    """
    n = len(points)
    ncomp, labels = components(graph)
    if ncomp <= 1:
        return graph, 0
    tree = cKDTree(points)
    rounds = max_rounds or int(np.ceil(np.log2(ncomp))) + 2
    add_i: list[np.ndarray] = []
    add_j: list[np.ndarray] = []
    for _ in range(rounds):
        if ncomp <= 1:
            break
        best_d = np.full(ncomp, np.inf)
        best_i = np.full(ncomp, -1)
        best_j = np.full(ncomp, -1)
        for k in (8, 32):
            kk = min(k + 1, n)
            dist, idx = tree.query(points, k=kk, workers=-1)
            other = labels[idx] != labels[:, None]
            dist = np.where(other, dist, np.inf)
            col = np.argmin(dist, axis=1)
            dmin = dist[np.arange(n), col]
            jmin = idx[np.arange(n), col]
            ok = np.isfinite(dmin)
            order = np.lexsort((dmin[ok], labels[ok]))
            src = np.flatnonzero(ok)[order]
            first = np.ones(len(src), bool)
            first[1:] = labels[src][1:] != labels[src][:-1]
            s = src[first]
            better = dmin[s] < best_d[labels[s]]
            c = labels[s][better]
            best_d[c], best_i[c], best_j[c] = dmin[s][better], s[better], jmin[s][better]
            if np.all(np.isfinite(best_d)):
                break
        for c in np.flatnonzero(~np.isfinite(best_d)):  # all kNN of this component are its own: exact search
            inside = labels == c
            out_idx = np.flatnonzero(~inside)
            d, j = cKDTree(points[out_idx]).query(points[inside], k=1)
            a = int(np.argmin(d))
            best_d[c], best_i[c], best_j[c] = d[a], np.flatnonzero(inside)[a], out_idx[j[a]]
        add_i.append(best_i)
        add_j.append(best_j)
        bridges = _bridges(add_i, add_j, n)
        ncomp, labels = csgraph.connected_components(graph + bridges + bridges.T, directed=False)
    ii, jj = np.concatenate(add_i), np.concatenate(add_j)
    pair = np.unique(np.sort(np.stack([ii, jj], 1), axis=1), axis=0)
    d = np.linalg.norm(points[pair[:, 0]] - points[pair[:, 1]], axis=1)
    bridges = _symmetric(pair[:, 0], pair[:, 1], d, n)
    out = graph.maximum(bridges) if graph.nnz else bridges
    return out.tocsr(), len(pair)


def _bridges(add_i: list[np.ndarray], add_j: list[np.ndarray], n: int) -> sp.coo_matrix:
    i, j = np.concatenate(add_i), np.concatenate(add_j)
    return sp.coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n))


def shortest_path_tree(graph: sp.csr_matrix, roots: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Multi-source Dijkstra: every vertex joins the tree of its geodesically nearest root.

    Returns ``dist (n,)`` (inf where unreachable), ``parents (n,)`` (-1 at roots and unreachable vertices) and
    ``source (n,)`` (the root claiming each vertex, -1 where unreachable).
    """
    roots = np.atleast_1d(np.asarray(roots, np.int64))
    dist, pred, source = csgraph.dijkstra(graph, directed=False, indices=roots, return_predecessors=True,
                                          min_only=True)
    parents = np.where(pred < 0, -1, pred).astype(np.int64)
    parents[roots] = -1
    return dist, parents, source.astype(np.int64)


def subtree_sums(values: np.ndarray, parents: np.ndarray, levels: list[np.ndarray] | None = None) -> np.ndarray:
    """(n,) sum of ``values`` over each node's subtree (the node included): one pass from the deepest level up."""
    total = np.asarray(values, np.float64).copy()
    for idx in reversed(levels if levels is not None else vectors.levels(parents)):
        c = idx[parents[idx] >= 0]
        np.add.at(total, parents[c], total[c])
    return total


def edge_lengths(positions: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """(n,) length of the edge from each node's parent (0 at roots)."""
    out = np.zeros(len(parents))
    has = parents >= 0
    out[has] = np.linalg.norm(positions[has] - positions[parents[has]], axis=1)
    return out


def subtree_lengths(positions: np.ndarray, parents: np.ndarray, *, include_incoming: bool = True) -> np.ndarray:
    """(n,) total edge length a node supports (Livny's vertex weight, Xu's supported branch length).

    ``include_incoming``: count the edge from the node's parent too (so a tip's weight is its own twig length).
    """
    inc = edge_lengths(positions, parents)
    total = subtree_sums(inc, parents)
    return total if include_incoming else total - inc


def children_csr(parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Children of every node as CSR: node v's children are ``kids[ptr[v]:ptr[v + 1]]`` (increasing index)."""
    parents = np.asarray(parents, np.int64)
    n = len(parents)
    child = np.flatnonzero(parents >= 0)
    order = child[np.argsort(parents[child], kind="stable")]
    ptr = np.zeros(n + 1, np.int64)
    ptr[1:] = np.cumsum(np.bincount(parents[child], minlength=n))
    return ptr, order


def empty_segments(a: np.ndarray, b: np.ndarray, tree: cKDTree, tolerance: float) -> np.ndarray:
    """(m,) bool: segment ``a[i] -> b[i]`` crosses empty space, i.e. some point along it lies farther than
    ``tolerance`` from every point of the cloud held by ``tree`` (a cKDTree). The segments are sampled at most
    ``tolerance`` apart (ends included), so a point between two samples is within ``tolerance / 2`` of one: a
    segment reported full has every point within 1.5 ``tolerance`` of the cloud, one reported empty has a point
    farther than ``tolerance``."""
    a = np.asarray(a, float).reshape(-1, 3)
    b = np.asarray(b, float).reshape(-1, 3)
    if len(a) == 0:
        return np.zeros(0, bool)
    if not tolerance > 0:
        raise InputError(f"empty_segments: tolerance must be > 0, got {tolerance}")
    k = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / tolerance).astype(np.int64), 1) + 1
    seg = np.repeat(np.arange(len(a)), k)
    t = (np.arange(k.sum()) - np.repeat(np.cumsum(k) - k, k)) / np.repeat(k - 1, k)
    samples = a[seg] + t[:, None] * (b[seg] - a[seg])
    d, _ = tree.query(samples, k=1, distance_upper_bound=tolerance * (1 + 1e-9), workers=-1)
    far = ~np.isfinite(d)
    out = np.zeros(len(a), bool)
    np.logical_or.at(out, seg, far)
    return out


def bridge_waypoints(points: np.ndarray, tree: cKDTree, free: np.ndarray, a: np.ndarray, b: np.ndarray
                     ) -> np.ndarray:
    """Indices of the points a bridge from ``a`` to ``b`` passes through, in order from a: the cheapest path from a to
    b over the complete graph of a, b and the ``free`` points inside the ball with diameter ab, an edge costing its
    squared length (so the path steps from point to point across a gap rather than jumping it). The ball bounds the
    detour: a single waypoint beats the straight jump exactly when it lies inside it. Empty when the jump is
    cheapest [S]."""
    half = 0.5 * float(np.linalg.norm(b - a))
    if half <= 0:
        return np.zeros(0, np.int64)
    cand = np.asarray(tree.query_ball_point(0.5 * (a + b), half), np.int64)
    cand = np.sort(cand[free[cand]])
    if len(cand) == 0:
        return cand
    xyz = np.concatenate([a[None], points[cand], b[None]])
    cost = np.sum((xyz[:, None, :] - xyz[None, :, :]) ** 2, axis=2)
    _, pred = csgraph.dijkstra(cost, directed=False, indices=0, return_predecessors=True)
    path = []
    v = pred[len(xyz) - 1]
    while v > 0:
        path.append(int(v))
        v = pred[v]
    return cand[np.asarray(path[::-1], np.int64) - 1]
