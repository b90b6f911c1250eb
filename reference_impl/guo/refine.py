"""Skeleton refinement after growth (Guo et al. 2018, section 5.3).

"(1) branch collapse. We traverse each node in the skeletal graph; if the degree of this node is 2 and its adjacent
edges share similar orientations and radii, then we collapse this node to its parent node; (2) branch smooth. For a
node v with parent node u and child w, if the angle between uv and vw is larger than a threshold (20 deg), then we
subdivide the sharp section between these two edges using a Hermite curve [8]."

Collapse removes nodes in rounds of non-adjacent candidates (alternating depth parity,
:func:`reference_impl.common.skeleton_ops.remove_chain_nodes`), so that a straight chain does not vanish at once and
each removal is judged against its current neighbours. Smoothing applies to nodes with one child, as the rule reads
("a node v with parent node u and child w"): the shared Xu et al. implementation
(reference_impl.common.skeleton_ops.hermite_smooth) also rounds junctions, which would start every child along its
parent and erase the branching angle psi; here it runs on the skeleton with each junction's children detached, and
the junctions are put back afterwards.
"""

from __future__ import annotations

import numpy as np

from plantbench.geometry.vectors import unit
from reference_impl.common.skeleton_ops import hermite_smooth, remove_chain_nodes

__all__ = ["collapse", "smooth"]


def collapse(positions: np.ndarray, parents: np.ndarray, radii: np.ndarray, *, max_angle_deg: float,
             max_radius_change: float, max_rounds: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Collapse degree-2 nodes (one parent, one child) whose incoming and outgoing edges turn by less than
    ``max_angle_deg`` and whose parent and child radii differ by less than ``max_radius_change`` (relative).

    Roots and junctions are never removed. Returns ``keep (n,)`` and the new parents over the kept nodes.
    """
    cos_min = np.cos(np.radians(max_angle_deg))

    def straight_and_even(v: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        e_in = unit(positions[v] - positions[a])
        e_out = unit(positions[b] - positions[v])
        straight = np.sum(e_in * e_out, 1) > cos_min
        rp, rc = radii[a], radii[b]
        return straight & (np.abs(rp - rc) <= max_radius_change * np.maximum(np.maximum(rp, rc), 1e-15))

    return remove_chain_nodes(parents, straight_and_even, max_rounds=max_rounds)


def smooth(positions: np.ndarray, parents: np.ndarray, *, angle_deg: float, min_spacing: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hermite smoothing of every chain node (one child) turning by more than ``angle_deg``.

    Returns positions, parents and origin (the input node of each output node, -1 for inserted samples).
    """
    par = np.asarray(parents, np.int64)
    n = len(par)
    nk = np.bincount(par[par >= 0], minlength=n)
    # detach the children of junctions: each becomes a root of its own piece, so hermite_smooth sees only chains
    cut = (par >= 0) & (nk[np.maximum(par, 0)] >= 2)
    pos, new_par, origin = hermite_smooth(positions, np.where(cut, -1, par), min_angle_deg=angle_deg,
                                          min_spacing=min_spacing)
    # reattach: a detached child's parent is the (kept) output node of its old parent
    out_of = np.full(n, -1, np.int64)
    kept = origin >= 0
    out_of[origin[kept]] = np.flatnonzero(kept)
    det = np.flatnonzero(kept & (new_par < 0))
    old = origin[det]
    back = cut[old]
    new_par[det[back]] = out_of[par[old[back]]]
    return pos, new_par, origin
