"""Skeleton simplification and refinement over parent arrays.

- :func:`remove_nodes`: drop nodes, reattaching children to the nearest kept ancestor.
- :func:`prune_by_ratio`: keep a child subtree only if (w(child) + |edge|) / w(parent) >= ratio (AdTree's
  ``keep_main_skeleton``, 0.019; Livny's subtree-ratio simplification).
- :func:`spatial_merge`: merge vertices sharing a grid cell of size ``delta`` and rebuild the shortest-path tree
  (resampling between Livny passes).
- :func:`merge_siblings`: merge sibling children closer than ``max_angle`` in direction with edge-length ratio in
  [1/2, 2] (AdTree's sibling merge, 25 deg), the new node at the weight-averaged position.
- :func:`remove_chain_nodes`: drop single-child nodes that a rule accepts, in rounds of non-adjacent nodes.
- :func:`remove_degree2`: drop single-child nodes lying within ``tol`` of the segment joining their parent and child.
- :func:`prune_short_tips`: drop terminal chains shorter than a length (spur removal).
- :func:`merge_close_forks`: merge two forks joined by a chain shorter than a length into one fork.
- :func:`simplify`: both, until nothing changes.
- :func:`hermite_smooth`: Xu et al. 2007 section 4.4: a sharp transition A -> O -> B is replaced by a cubic Hermite
  curve from A to B with tangents along AO and OB, sampled more densely for sharper turns.

All functions return new arrays; a ``keep``/``index`` map says where old nodes went where relevant.
"""

from __future__ import annotations

import numpy as np

from plantbench.geometry.vectors import depths, levels, unit
from reference_impl.common.graph import children_csr, edge_lengths, subtree_lengths

__all__ = ["remove_nodes", "prune_by_ratio", "spatial_merge", "merge_siblings", "remove_chain_nodes",
           "remove_degree2", "prune_short_tips", "trim_unsupported_tips", "merge_close_forks", "simplify",
           "hermite_smooth", "turn_angles", "branch_orders"]


def remove_nodes(parents: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Remove the nodes where ``keep`` is False; a kept node's new parent is its nearest kept ancestor.

    Returns ``new_parents (m,)`` over the kept nodes (in their original order) and ``index (n,)``: each old node's
    new index, -1 for removed ones.
    """
    parents = np.asarray(parents, np.int64)
    keep = np.asarray(keep, bool)
    n = len(parents)
    # up[v]: v itself if kept, else its parent (sentinel n for "none"), then pointer doubling
    sentinel = n
    par = np.where(parents < 0, sentinel, parents)
    up = np.append(np.where(keep, np.arange(n), par), sentinel)
    kept_ext = np.append(keep, True)
    for _ in range(int(np.ceil(np.log2(max(n, 2)))) + 2):
        nxt = up[up]
        if np.array_equal(nxt, up):
            break
        up = np.where(kept_ext[up], up, nxt)
    anc = up[np.append(par, sentinel)][:n]  # nearest kept ancestor strictly above each node
    index = np.full(n, -1, np.int64)
    index[keep] = np.arange(int(keep.sum()))
    new_par = np.where(anc[keep] == sentinel, -1, index[np.minimum(anc[keep], n - 1)])
    return new_par.astype(np.int64), index


def prune_by_ratio(positions: np.ndarray, parents: np.ndarray, ratio: float) -> np.ndarray:
    """(n,) bool keep mask: a child survives if (w(child) + |edge|) / w(parent) >= ratio and its parent survives.

    w is the subtree edge length below a node (its incoming edge excluded), as in AdTree.
    """
    inc = edge_lengths(positions, parents)
    w = subtree_lengths(positions, parents, include_incoming=False)
    ok = np.ones(len(parents), bool)
    has = parents >= 0
    wp = w[parents[has]]
    ok[has] = (w[has] + inc[has]) >= ratio * np.maximum(wp, 1e-15)
    keep = ok.copy()
    for idx in levels(parents):
        c = idx[parents[idx] >= 0]
        keep[c] &= keep[parents[c]]
    return keep


def spatial_merge(positions: np.ndarray, parents: np.ndarray, mass: np.ndarray, delta: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Merge the vertices sharing a ``delta`` grid cell (whatever their place in the tree), then rebuild the tree.

    The merged vertices are joined wherever an old tree edge joined two of their members; a shortest-path tree from
    the cells of the old roots over that graph is the new tree (Livny's resampling: merge vertices closer
    than delta, rebuild the shortest-path tree). Parallel paths that the re-embedding moved onto the same axis
    become one. mass : (n,) positive weights for averaging.
    Returns ``positions (m, 3)``, ``parents (m,)``, ``mass (m,)`` and ``index (n,)`` (old vertex -> merged vertex).
    """
    from reference_impl.common.graph import shortest_path_tree

    key = np.floor((positions - positions.min(0)) / delta).astype(np.int64)
    _, index = np.unique(key, axis=0, return_inverse=True)
    index = index.ravel()
    m = int(index.max()) + 1
    w = np.zeros(m)
    np.add.at(w, index, mass)
    pos = np.zeros((m, 3))
    np.add.at(pos, index, positions * mass[:, None])
    pos /= np.maximum(w, 1e-300)[:, None]
    c = np.flatnonzero(parents >= 0)
    a, b = index[parents[c]], index[c]
    diff = a != b
    a, b = a[diff], b[diff]
    ln = np.maximum(np.linalg.norm(pos[a] - pos[b], axis=1), 1e-12)
    import scipy.sparse as sp

    g = sp.coo_matrix((np.concatenate([ln, ln]), (np.concatenate([a, b]), np.concatenate([b, a]))), shape=(m, m))
    g = g.tocsr()
    g.data[:] = np.maximum(g.data, 1e-12)  # duplicate entries were summed; any positive length keeps the edge
    roots = np.unique(index[np.flatnonzero(parents < 0)])
    dist, par, _ = shortest_path_tree(g, roots)
    par[~np.isfinite(dist)] = -1
    return pos, par, w, index


def merge_siblings(positions: np.ndarray, parents: np.ndarray, weights: np.ndarray, *, max_angle_deg: float = 25.0,
                   length_ratio: float = 2.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge pairs of siblings whose directions from the parent differ by less than ``max_angle_deg`` and whose edge
    lengths are within a factor ``length_ratio``; repeated at each junction until no pair qualifies.

    weights : (n,) positive (supported lengths); the merged node sits at the weight-averaged position and carries
    the summed weight. Returns ``positions``, ``parents`` and ``index`` (old -> new node) after removal.
    """
    pos = np.array(positions, float, copy=True)
    par = np.array(parents, np.int64, copy=True)
    w = np.array(weights, float, copy=True)
    n = len(par)
    target = np.arange(n)  # where each node was merged to
    cos_max = np.cos(np.radians(max_angle_deg))
    ptr, kids = children_csr(par)
    for p in np.flatnonzero(np.diff(ptr) >= 2):
        live = list(kids[ptr[p]:ptr[p + 1]])
        for _ in range(len(live)):
            if len(live) < 2:
                break
            c = np.asarray(live)
            d = pos[c] - pos[p]
            ln = np.linalg.norm(d, axis=1)
            u = unit(d)
            cos = u @ u.T
            ratio = np.maximum(ln[:, None], ln[None, :]) / np.maximum(np.minimum(ln[:, None], ln[None, :]), 1e-15)
            ok = (cos > cos_max) & (ratio <= length_ratio)
            np.fill_diagonal(ok, False)
            if not ok.any():
                break
            a, b = np.unravel_index(np.argmax(np.where(ok, cos, -2.0)), cos.shape)
            a, b = int(c[a]), int(c[b])
            if w[b] > w[a]:
                a, b = b, a
            pos[a] = (w[a] * pos[a] + w[b] * pos[b]) / (w[a] + w[b])
            w[a] += w[b]
            target[b] = a
            live.remove(b)
    merged = target != np.arange(n)
    # children of merged nodes move to the survivor (targets are never merged themselves at that junction later)
    final = target.copy()
    for _ in range(int(np.ceil(np.log2(max(n, 2)))) + 2):
        nxt = final[final]
        if np.array_equal(nxt, final):
            break
        final = nxt
    has = par >= 0
    par[has] = final[par[has]]
    new_par, index = remove_nodes(par, ~merged)
    index = index[final]
    return pos[~merged], new_par, index


def remove_chain_nodes(parents: np.ndarray, removable, *, max_rounds: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Drop single-child nodes that ``removable`` accepts, each child reattached to the node's parent.

    ``removable(node, parent, child)`` takes (k,) index arrays of candidates, their parents and their single children
    and returns a (k,) bool mask. Rounds alternate depth parity, so that neighbours are never removed together and a
    straight chain does not vanish at once; they stop when no node has a single child, after two rounds without a
    removal, or after ``max_rounds``. Returns ``keep (n,)`` and the new parents over the kept nodes.
    """
    par = np.array(parents, np.int64, copy=True)
    n = len(par)
    alive = np.ones(n, bool)
    quiet = 0
    for rnd in range(max_rounds):
        nk = np.bincount(par[alive & (par >= 0)], minlength=n)
        cand = np.flatnonzero(alive & (par >= 0) & (nk == 1))
        if len(cand) == 0:
            break
        child_of = np.full(n, -1)
        ch = np.flatnonzero(alive & (par >= 0))
        child_of[par[ch]] = ch
        dep = depths(np.where(alive, par, -1))
        rem = cand[removable(cand, par[cand], child_of[cand]) & (dep[cand] % 2 == rnd % 2)]
        if len(rem) == 0:
            quiet += 1
            if quiet >= 2:
                break
            continue
        quiet = 0
        par[child_of[rem]] = par[rem]
        alive[rem] = False
    new_par, _ = remove_nodes(np.where(alive, par, -1), alive)
    return alive, new_par


def remove_degree2(positions: np.ndarray, parents: np.ndarray, tol: np.ndarray, *, max_rounds: int = 64
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Drop single-child nodes closer than ``tol`` (per node) to the segment parent-child, in rounds of
    non-adjacent nodes (:func:`remove_chain_nodes`). Returns ``keep (n,)`` and new parents.
    """
    tol = np.broadcast_to(np.asarray(tol, float), (len(parents),))

    def near_segment(v: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        pa, pb = positions[a], positions[b]
        ab = pb - pa
        t = np.clip(np.sum((positions[v] - pa) * ab, 1) / np.maximum(np.sum(ab * ab, 1), 1e-300), 0, 1)
        return np.linalg.norm(positions[v] - (pa + t[:, None] * ab), axis=1) < tol[v]

    return remove_chain_nodes(parents, near_segment, max_rounds=max_rounds)


def prune_short_tips(positions: np.ndarray, parents: np.ndarray, min_length: float, *, rounds: int = 2
                     ) -> np.ndarray:
    """(n,) keep mask after removing terminal chains (tip up to the first junction, exclusive) shorter than
    ``min_length`` that hang from a junction (so a lone stem is never removed); ``rounds`` passes."""
    par = np.asarray(parents, np.int64)
    n = len(par)
    keep = np.ones(n, bool)
    for _ in range(rounds):
        live_par = np.where(keep, par, -1)
        nk = np.bincount(live_par[keep & (live_par >= 0)], minlength=n)
        inc = edge_lengths(positions, live_par)
        # length from each node down to its tip along single-child chains, computed bottom-up by levels
        single_len = np.where(keep, inc, 0.0)
        tip_chain = keep & (nk == 0)
        chain_len = np.where(tip_chain, inc, 0.0)
        for idx in reversed(levels(live_par)):
            idx = idx[tip_chain[idx] & (live_par[idx] >= 0)]
            p = live_par[idx]
            ext = nk[p] == 1
            tip_chain[p[ext]] = True
            chain_len[p[ext]] = chain_len[idx[ext]] + single_len[p[ext]]
        # a chain top: tip-chain node whose parent is a junction (>= 2 children)
        top = np.flatnonzero(tip_chain & (live_par >= 0))
        top = top[nk[live_par[top]] >= 2]
        short = top[chain_len[top] < min_length]
        if len(short) == 0:
            break
        drop = np.zeros(n, bool)
        drop[short] = True
        for idx in levels(live_par):
            c = idx[live_par[idx] >= 0]
            drop[c] |= drop[live_par[c]]
        keep &= ~drop
    return keep


def merge_close_forks(positions: np.ndarray, parents: np.ndarray, min_length: float, *, rounds: int = 8
                      ) -> np.ndarray:
    """(n,) keep mask after merging forks joined by a short chain: where a chain runs from a fork J1 to a fork J2
    (two or more children) and is shorter than ``min_length``, its nodes after J1 (J2 included) go and J2's children
    hang from J1 (:func:`remove_nodes`): one fork where two stood a chain's length apart (a noisy cloud splits one
    fork into several, and every short chain between them is a branch of its own). A chain from a root is kept (the
    stem's base stays). Up to ``rounds`` passes; in a pass no chain is merged whose J1 is another merged chain's J2,
    so a run of close forks collapses in steps."""
    pos = np.asarray(positions, float)
    par = np.asarray(parents, np.int64)
    alive = np.arange(len(par))  # original index of each current node
    for _ in range(rounds):
        n = len(par)
        nk = np.bincount(par[par >= 0], minlength=n)
        inc = edge_lengths(pos, par)
        chains = []
        for j2 in np.flatnonzero(nk >= 2).tolist():
            nodes, total, v = [j2], inc[j2], par[j2]
            while v >= 0 and nk[v] == 1 and par[v] >= 0:
                nodes.append(v)
                total += inc[v]
                v = par[v]
            if v >= 0 and nk[v] >= 2 and total < min_length:
                chains.append((total, v, nodes))
        drop = np.zeros(n, bool)
        j1_used = np.zeros(n, bool)
        for _, j1, nodes in sorted(chains, key=lambda c: c[0]):
            if drop[j1] or j1_used[nodes[0]]:
                continue
            drop[nodes] = True
            j1_used[j1] = True
        if not drop.any():
            break
        par, _ = remove_nodes(par, ~drop)
        pos, alive = pos[~drop], alive[~drop]
    keep = np.zeros(len(parents), bool)
    keep[alive] = True
    return keep


def trim_unsupported_tips(parents: np.ndarray, distance: np.ndarray, max_distance: float) -> np.ndarray:
    """(n,) keep mask without the unsupported ends of the branches: from each tip, the nodes farther than
    ``max_distance`` from the data (``distance``: (n,) each node's distance to it) are removed back along the tip's
    chain, up to the first node within it; a junction stays while another branch hangs from it, and a root always
    stays. A branch with no supported node at all goes back to its junction."""
    par = np.asarray(parents, np.int64)
    n = len(par)
    nchild = np.bincount(par[par >= 0], minlength=n)
    far = np.asarray(distance, float) > max_distance
    keep = np.ones(n, bool)
    for tip in np.flatnonzero(nchild == 0):
        v = int(tip)
        while par[v] >= 0 and far[v] and nchild[v] == 0:
            keep[v] = False
            v = int(par[v])
            nchild[v] -= 1
    return keep


def simplify(positions: np.ndarray, parents: np.ndarray, radii: np.ndarray | None = None, *, prune_tips: float = 0.0,
             merge_forks: float = 0.0, rounds: int = 8) -> tuple[np.ndarray, np.ndarray, np.ndarray | None,
                                                                  np.ndarray]:
    """A skeleton's structure simplified: forks joined by a chain shorter than ``merge_forks`` merged
    (:func:`merge_close_forks`), then terminal chains shorter than ``prune_tips`` removed (:func:`prune_short_tips`),
    both until nothing changes (at most ``rounds`` passes: a pruned spur can leave two forks a short chain apart).
    Returns positions, parents and radii (None when not given) of the kept nodes, and their indices in the input."""
    pos = np.asarray(positions, float)
    par = np.asarray(parents, np.int64)
    rad = None if radii is None else np.asarray(radii, float)
    alive = np.arange(len(par))
    for _ in range(rounds):
        keep = np.ones(len(par), bool)
        if merge_forks > 0:
            keep &= merge_close_forks(pos, par, merge_forks)
        if prune_tips > 0:
            sub_par, _ = remove_nodes(par, keep)
            sub_keep = prune_short_tips(pos[keep], sub_par, prune_tips, rounds=rounds)
            keep[np.flatnonzero(keep)[~sub_keep]] = False
        if keep.all():
            break
        par, _ = remove_nodes(par, keep)
        pos, alive = pos[keep], alive[keep]
        rad = None if rad is None else rad[keep]
    return pos, par, rad, alive


def turn_angles(positions: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """(n,) angle (radians) between a node's incoming edge and its parent's incoming edge (0 where undefined)."""
    has = parents >= 0
    e = np.zeros((len(parents), 3))
    e[has] = unit(positions[has] - positions[parents[has]])
    gp = np.where(has, parents, 0)
    ok = has & (parents[gp] >= 0)
    cos = np.sum(e * e[gp], 1)
    return np.where(ok, np.arccos(np.clip(cos, -1, 1)), 0.0)


def hermite_smooth(positions: np.ndarray, parents: np.ndarray, *, min_angle_deg: float = 30.0,
                   deg_per_sample: float = 10.0, max_samples: int = 8, min_samples: int = 2,
                   min_spacing: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Xu et al. 2007 section 4.4: smooth sharp transitions with Hermite curves.

    For every node O with parent A and a child B where the turn between AO and OB exceeds ``min_angle_deg``, the
    path A -> O -> B is replaced by a cubic Hermite curve from A to B with tangents |AB| * unit(AO) at A and |AB| *
    unit(OB) at B, sampled with clip(angle / deg_per_sample, min_samples, max_samples) interior points (the paper's
    Fig. 7 uses 8 points for a sharp turn and 6 for a milder one), and at most |AB| / ``min_spacing`` of them (no
    curve where |AB| < 2 min_spacing: finer than the skeleton's resolution) [S]. At a junction each sharp child gets
    its own curve from A; O is kept while it still has a child. Nodes are processed parent-first, so each curve
    starts at an already-smoothed position. Returns ``positions``, ``parents`` and ``origin`` (for each output node,
    the input node it came from, or -1 for inserted samples).
    """
    pos = [p for p in np.asarray(positions, float)]
    par = list(np.asarray(parents, np.int64))
    origin = list(range(len(par)))
    n0 = len(par)
    ptr, kids = children_csr(np.asarray(parents, np.int64))
    children = [list(kids[ptr[v]:ptr[v + 1]]) for v in range(n0)]
    removed = np.zeros(n0, bool)
    cos_min = np.cos(np.radians(min_angle_deg))
    order = np.concatenate(levels(np.asarray(parents, np.int64))) if n0 else np.zeros(0, np.int64)
    for o in order:
        a = par[o]
        if a < 0 or not children[o]:
            continue
        ao = pos[o] - pos[a]
        lao = np.linalg.norm(ao)
        if lao < 1e-12:
            continue
        t_a = ao / lao
        for b in list(children[o]):
            ob = pos[b] - pos[o]
            lob = np.linalg.norm(ob)
            if lob < 1e-12:
                continue
            t_b = ob / lob
            cos = float(t_a @ t_b)
            if cos >= cos_min:
                continue
            angle = np.degrees(np.arccos(np.clip(cos, -1, 1)))
            k = int(np.clip(round(angle / deg_per_sample), min_samples, max_samples))
            pa, pb = pos[a], pos[b]
            scale = np.linalg.norm(pb - pa)
            if min_spacing > 0:
                k = min(k, int(scale / min_spacing) - 1)
                if k < 1:
                    continue
            s = np.arange(1, k + 1) / (k + 1)
            h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
            h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
            curve = h00[:, None] * pa + h10[:, None] * scale * t_a + h01[:, None] * pb + h11[:, None] * scale * t_b
            prev = a
            for q in curve:
                pos.append(q)
                par.append(prev)
                origin.append(-1)
                prev = len(par) - 1
            par[b] = prev
            children[o].remove(b)
        if not children[o]:
            removed[o] = True
    keep = np.ones(len(par), bool)
    keep[:n0] = ~removed
    new_par, _ = remove_nodes(np.asarray(par, np.int64), keep)
    return np.asarray(pos)[keep], new_par, np.asarray(origin, np.int64)[keep]


def branch_orders(parents: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """(n,) branch order: 0 on the stems, +1 at every child that is not its parent's thickest child."""
    from plantbench.geometry.tubes import main_child_mask

    main = main_child_mask(parents, radii)
    order = np.zeros(len(parents), np.int64)
    for idx in levels(parents):
        c = idx[parents[idx] >= 0]
        order[c] = order[parents[c]] + (~main[c]).astype(np.int64)
    return order
