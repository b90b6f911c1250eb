"""Branch geometry shared by every generator family: radii, node frames and generalised-cylinder tubes.

- :func:`supported_length_radii`: Eq. 5 of Guo et al. 2018, d_c = d_p (l_c / sum_j l_cj)^gamma, with l the branch length
  a node supports, applied at every node (so chains taper smoothly), anchored at a twig radius.
- :func:`node_frames`: a tangent and a parallel-transported normal per node (transport by projection, level by
  level from the roots), continuous along each axis.
- :func:`tube_mesh`: one ring per node (on its axis) plus one start ring per lateral at the parent node (inside
  the parent tube, since a child is never thicker), quads between successive rings, a cone cap on every tip.
  Ring sides follow the axis thickness. Normals point outwards (counter-clockwise seen from outside).

``unit`` and ``depths`` are :mod:`plantbench.geometry.vectors`'s, named here too for the modules that import them
from here.
"""

from __future__ import annotations

import numpy as np

from plantbench.geometry.vectors import depths, levels, perpendicular, unit
from plantbench.plant import TriMesh

__all__ = ["unit", "depths", "axis_positions", "main_child_mask", "supported_lengths", "supported_length_radii",
           "node_frames", "tube_mesh"]


def axis_positions(parents: np.ndarray, main: np.ndarray, levels: list[np.ndarray]) -> np.ndarray:
    """(n,) index of each node along its axis (0 where an axis starts; ``main`` marks the nodes that continue their
    parent's axis; ``levels`` the nodes by depth, roots first): the phyllotaxis counter."""
    k = np.zeros(len(parents), np.int64)
    for idx in levels:
        c = idx[(parents[idx] >= 0) & main[idx]]
        k[c] = k[parents[c]] + 1
    return k


def supported_lengths(positions: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """(n,) branch length each node supports: its incoming internode plus everything above it, metres."""
    n = len(parents)
    inc = np.zeros(n)
    has = parents >= 0
    inc[has] = np.linalg.norm(positions[has] - positions[parents[has]], axis=1)
    total = inc.copy()
    for idx in reversed(levels(parents)):
        c = idx[parents[idx] >= 0]
        np.add.at(total, parents[c], total[c])
    return total


def supported_length_radii(positions: np.ndarray, parents: np.ndarray, *, gamma: float, tip_radius: float,
                           internode_length: float) -> np.ndarray:
    """(n,) radii r = tip_radius (L / l)^gamma with L the supported length (Eq. 5 at every node).

    At a junction the children's radii relate as in Guo et al. 2018, Eq. 5; along a chain the radius shrinks with the
    length still supported. Radii are never larger than the parent's and never below ``tip_radius / 2``.
    """
    sup = supported_lengths(positions, parents)
    sup = np.where(sup > 0, sup, internode_length)
    r = tip_radius * (sup / internode_length) ** gamma
    return np.maximum(r, 0.5 * tip_radius)


def main_child_mask(parents: np.ndarray, radii: np.ndarray, lateral: np.ndarray | None = None) -> np.ndarray:
    """(n,) bool: node continues its parent's axis. Without ``lateral``, the thickest child (lowest index on ties)."""
    n = len(parents)
    if lateral is not None:
        return (parents >= 0) & ~np.asarray(lateral, bool)
    child = np.flatnonzero(parents >= 0)
    order = np.lexsort((child, -radii[child], parents[child]))
    c = child[order]
    first = np.ones(len(c), bool)
    first[1:] = parents[c][1:] != parents[c][:-1]
    mask = np.zeros(n, bool)
    mask[c[first]] = True
    return mask


def node_frames(positions: np.ndarray, parents: np.ndarray, main: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Tangents and transported normals.

    Returns ``tangent (n, 3)``, ``normal (n, 3)`` at each node's own ring (tangent = bisector of the incoming and the
    main outgoing internode), and ``start_tangent (n, 3)``, ``start_normal (n, 3)``: the frame of the start ring of a
    lateral node (at its parent), valid where ``parents >= 0 & ~main``.
    """
    n = len(parents)
    has = parents >= 0
    e_in = np.zeros((n, 3))
    e_in[has] = unit(positions[has] - positions[parents[has]])
    e_out = np.zeros((n, 3))
    mc = np.flatnonzero(main & has)
    e_out[parents[mc]] = e_in[mc]
    tangent = unit(e_in + e_out)
    deg = np.linalg.norm(tangent, axis=1) < 1e-9
    tangent[deg] = np.array([0.0, 0.0, 1.0])
    normal = np.zeros((n, 3))
    start_normal = np.zeros((n, 3))
    for idx in levels(parents):
        root = parents[idx] < 0
        r = idx[root]
        normal[r] = perpendicular(tangent[r])
        c = idx[~root]
        ref = normal[parents[c]]
        lat = ~main[c]
        # lateral: first through the start ring (tangent = first internode)
        lref = ref[lat] - np.sum(ref[lat] * e_in[c[lat]], 1, keepdims=True) * e_in[c[lat]]
        bad = np.linalg.norm(lref, axis=1) < 1e-9
        lref[bad] = perpendicular(e_in[c[lat]][bad])
        start_normal[c[lat]] = unit(lref)
        ref[lat] = start_normal[c[lat]]
        t = tangent[c]
        proj = ref - np.sum(ref * t, 1, keepdims=True) * t
        bad = np.linalg.norm(proj, axis=1) < 1e-9
        proj[bad] = perpendicular(t[bad])
        normal[c] = unit(proj)
    return tangent, normal, e_in, start_normal


def tube_mesh(positions: np.ndarray, parents: np.ndarray, radii: np.ndarray, main: np.ndarray, *,
              max_sides: int = 12, min_sides: int = 4, edge_length: float = 0.02) -> TriMesh:
    """Generalised cylinders along every axis of the skeleton.

    positions : (n, 3) float; parents : (n,) int; radii : (n,) float; main : (n,) bool (see :func:`main_child_mask`)
    edge_length : target ring edge length; an axis gets ceil(2 pi r_base / edge_length) sides, clipped.
    """
    n = len(parents)
    if n == 0:
        return TriMesh.empty()
    tangent, normal, start_t, start_n = node_frames(positions, parents, main)
    # axis id and its base radius (thickest ring on the axis: the first one)
    axis = np.arange(n)
    for idx in levels(parents):
        c = idx[(parents[idx] >= 0) & main[idx]]
        axis[c] = axis[parents[c]]
    base_r = radii[axis]
    sides = np.clip(np.ceil(2 * np.pi * base_r / edge_length).astype(np.int64), min_sides, max_sides)
    lateral = np.flatnonzero((parents >= 0) & ~main)
    # rings: 0..n-1 node rings, n.. start rings of laterals
    ring_centre = np.concatenate([positions, positions[parents[lateral]]])
    ring_r = np.concatenate([radii, radii[lateral]])
    ring_t = np.concatenate([tangent, start_t[lateral]])
    ring_n = np.concatenate([normal, start_n[lateral]])
    ring_s = np.concatenate([sides, sides[lateral]])
    ring_b = np.cross(ring_t, ring_n)
    nr = len(ring_centre)
    ring_off = np.zeros(nr + 1, np.int64)
    ring_off[1:] = np.cumsum(ring_s)
    start_ring = np.full(n, -1, np.int64)
    start_ring[lateral] = n + np.arange(len(lateral))
    verts = np.zeros((ring_off[-1], 3))
    for s in np.unique(ring_s):
        rg = np.flatnonzero(ring_s == s)
        th = 2 * np.pi * np.arange(s) / s
        ring = (np.cos(th)[None, :, None] * ring_n[rg, None, :] + np.sin(th)[None, :, None] * ring_b[rg, None, :])
        pts = ring_centre[rg, None, :] + ring_r[rg, None, None] * ring
        verts[(ring_off[rg][:, None] + np.arange(s)[None, :]).ravel()] = pts.reshape(-1, 3)
    faces = []
    child = np.flatnonzero(parents >= 0)
    a_ring = np.where(main[child], parents[child], start_ring[child])
    b_ring = child
    for s in np.unique(sides[child]):
        sel = sides[child] == s
        a0 = ring_off[a_ring[sel]][:, None]
        b0 = ring_off[b_ring[sel]][:, None]
        k = np.arange(s)[None, :]
        k1 = (k + 1) % s
        t1 = np.stack([a0 + k, a0 + k1, b0 + k1], -1)
        t2 = np.stack([a0 + k, b0 + k1, b0 + k], -1)
        faces.append(np.concatenate([t1, t2], 1).reshape(-1, 3))
    # cone caps on tips (nodes with no main child)
    has_main = np.zeros(n, bool)
    has_main[parents[child[main[child]]]] = True
    tips = np.flatnonzero(~has_main & (parents >= 0))
    apex = positions[tips] + tangent[tips] * radii[tips, None]
    apex_id = len(verts) + np.arange(len(tips))
    verts = np.concatenate([verts, apex])
    for s in np.unique(sides[tips]):
        sel = sides[tips] == s
        a0 = ring_off[tips[sel]][:, None]
        k = np.arange(s)[None, :]
        ap = np.broadcast_to(apex_id[sel][:, None], (sel.sum(), s))
        faces.append(np.stack([a0 + k, a0 + (k + 1) % s, ap], -1).reshape(-1, 3))
    return TriMesh(verts, np.concatenate(faces) if faces else np.zeros((0, 3), np.int64))
