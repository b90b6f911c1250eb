"""Structural views of a :class:`~plantbench.plant.Skeleton` shared by the generator, metrics and methods."""

from __future__ import annotations

import numpy as np

from plantbench.plant import Skeleton

__all__ = ["children_lists", "branch_chains", "chain_lengths", "topological_order", "stem_at_height",
           "stem_edge_at_height"]


def children_lists(skeleton: Skeleton) -> list[np.ndarray]:
    """Children of each node, in increasing index order."""
    n = len(skeleton)
    par = skeleton.parents
    idx = np.flatnonzero(par >= 0)
    order = idx[np.argsort(par[idx], kind="stable")]
    counts = np.bincount(par[idx], minlength=n)
    return np.split(order, np.cumsum(counts)[:-1]) if n else []


def stem_edge_at_height(skeleton: Skeleton, z: float) -> tuple[int, int] | None:
    """The stem's edge (parent, child) that crosses height ``z``, or None when the stem does not reach ``z``. The
    stem starts at the thickest root and follows the thickest child."""
    if len(skeleton) == 0:
        return None
    pos, rad = skeleton.positions, skeleton.radii
    kids = children_lists(skeleton)
    roots = skeleton.roots
    node = int(roots[np.argmax(rad[roots])])
    while len(kids[node]):
        nxt = int(kids[node][np.argmax(rad[kids[node]])])
        a, b = pos[node], pos[nxt]
        if (a[2] - z) * (b[2] - z) <= 0 and a[2] != b[2]:
            return node, nxt
        node = nxt
    return None


def stem_at_height(skeleton: Skeleton, z: float) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Where the stem crosses height ``z``: (point, unit direction of that edge, radius interpolated there), or None
    when it does not reach ``z`` (:func:`stem_edge_at_height`)."""
    edge = stem_edge_at_height(skeleton, z)
    if edge is None:
        return None
    node, nxt = edge
    pos, rad = skeleton.positions, skeleton.radii
    a, b = pos[node], pos[nxt]
    f = (z - a[2]) / (b[2] - a[2])
    d = b - a
    return a + f * d, d / np.linalg.norm(d), float(rad[node] + f * (rad[nxt] - rad[node]))


def topological_order(skeleton: Skeleton) -> np.ndarray:
    """Node indices ordered so that every parent precedes its children (breadth-first from the roots)."""
    kids = children_lists(skeleton)
    out = list(skeleton.roots)
    i = 0
    while i < len(out):
        out.extend(kids[out[i]].tolist())
        i += 1
    return np.asarray(out, np.int64)


def branch_chains(skeleton: Skeleton) -> list[np.ndarray]:
    """Branches in Stava's sense: maximal unbranched chains of nodes.

    Each chain starts at a root or at a junction (a node with two or more children) and follows single-child links
    until a tip or the next junction, which it includes. Chains with a single node (a root that is itself a
    junction, or an isolated node) have no length and are omitted. Chains are returned parent-first in
    breadth-first order, so a chain's parent chain always comes earlier.
    """
    kids = children_lists(skeleton)
    chains: list[np.ndarray] = []
    starts: list[tuple[int, int]] = [(int(r), -1) for r in skeleton.roots]  # (first node, junction it hangs from)
    i = 0
    while i < len(starts):
        node, junction = starts[i]
        i += 1
        chain = [junction] if junction >= 0 else []
        chain.append(node)
        while len(kids[node]) == 1:
            node = int(kids[node][0])
            chain.append(node)
        if len(chain) > 1:
            chains.append(np.asarray(chain, np.int64))
        for c in kids[node]:
            starts.append((int(c), node))
    return chains


def chain_lengths(skeleton: Skeleton, chains: list[np.ndarray]) -> np.ndarray:
    """Polyline length of each chain, metres."""
    p = skeleton.positions
    return np.array([np.linalg.norm(np.diff(p[c], axis=0), axis=1).sum() for c in chains])
