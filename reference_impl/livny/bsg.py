"""The Livny et al. 2010 pipeline (docs/design.md, Shipped methods) as pure functions.

Steps and where each parameter comes from ([L] Livny 2010 (docs/design.md, Shipped methods), [G] the Groot
re-implementation, [A] AdTree, [S] our choice; every length is scaled by the plant's size):

1. ground removal (reference_impl.common.ground) [S]; voxel downsampling at 0.5 % of the plant height [S, within
   0.5-1 % of the height; docs/tuning/guo.md], at least 0.6 median point spacings [S], coarsened only when more than
   150k voxels remain (speed) [S];
2. symmetrised 10-NN graph without edges longer than 3 x the median 1-NN spacing; components under 20 voxels
   dropped, the others bridged by their shortest edges [S];
3. roots: the lowest vertex of each central cluster of the bottom 2 % of the height, per separate plant [A, L:
   several roots allowed; S: the central and per-plant rules, reference_impl.common.roots.find_roots];
4. shortest-path tree by multi-source Dijkstra [L]; a subtree hung by a bridge longer than its own length dropped,
   the other bridges re-drawn through the dropped scraps between their ends [S];
5. five outer iterations [G] of: vertex weights = supported subtree length [L, G, A]; the orientation field
   minimising sum w_pc^2 |o_p - o_c|^2 + w_c^2 |o_c - e_c|^2 (Groot's energy) solved as one sparse linear least
   squares and normalised [S: the cheap equivalent of Groot's sphere-constrained solve]; re-embedding of the
   positions by sparse least squares, edges aligned with the field plus a data term [G], no vertex farther from
   the cloud than its radius plus half a voxel [S]; resampling by merging the
   vertices sharing a one-voxel cell and rebuilding the shortest-path tree [S];
6. simplification until stable: subtree-ratio pruning 0.02 [A: 0.019] plus twigs under 3 voxels and twigs whose
   tip lies within 3 radii of another branch's axis (bark ridges) [S],
   sibling merging below 25 deg with length ratio in [1/2, 2] [A], removal of degree-2 vertices within the local
   radius of their neighbours' line [A];
7. pipe-model radii r = r_root (w / w_root)^(1/2) [L, standard], r_root from a trunk cylinder fit [A] at the scale
   of a 0.75 % voxel [S];
8. leaves in the lobes around terminal subtrees: crown points the branches do not explain, one Bezier leaf per
   leaf-sized cell, hanging from the nearest node of a terminal subtree (one supporting at most 5 % of the plant's
   branch length) [L: lobes; S: the cell rule and the 5 %].

Two choices differ from Groot and are ours [S]: the field term of the re-embedding keeps each edge's length along
the field (((p_c - p_p) . o) o) instead of its full length, so zig-zag shortest paths over a branch surface are
straightened without being stretched; and the data term anchors each vertex to the centroid of the cloud within
1.5 local radii of it (its axial offset removed), which pulls skeletons from the scanned surface to the branch axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve
from scipy.spatial import cKDTree

from plantbench.errors import InputError
from plantbench.geometry.vectors import levels, unit
from plantbench.plant import Leaf, Skeleton, TriMesh
from plantbench.skeletons import branch_chains
from reference_impl.common.geometry import bezier_leaves, branch_mesh, leaf_frames
from reference_impl.common.graph import (
    bridge_components,
    bridge_waypoints,
    components,
    edge_lengths,
    knn_graph,
    median_spacing,
    shortest_path_tree,
    subtree_lengths,
    subtree_sums,
    voxel_downsample,
)
from reference_impl.common.ground import Ground
from reference_impl.common.inputs import plant_height, split_ground
from reference_impl.common.leaves import foliage_cells, sample_edges, skeleton_distance
from reference_impl.common.radii import pipe_model_radii
from reference_impl.common.roots import StemFitParams, find_roots, finish_stems, fit_stems
from reference_impl.common.skeleton_ops import (
    branch_orders,
    merge_close_forks,
    merge_siblings,
    prune_by_ratio,
    prune_short_tips,
    remove_degree2,
    remove_nodes,
    spatial_merge,
)

__all__ = ["LivnyParams", "LivnyResult", "reconstruct_livny", "orientation_field", "reembed"]


@dataclass(frozen=True)
class LivnyParams(StemFitParams):
    """Parameters of the Livny-style baseline (source in brackets, see the module docstring)."""

    voxel_fraction: float = 0.005
    """Voxel edge as a fraction of the plant's height (Livny et al. work on the points themselves) [S, within
    0.5-1 % of the height; docs/tuning/guo.md, livny voxel: 0.75 % until the 1024 px clouds]."""
    min_voxel_spacings: float = 0.6
    """The voxel is at least this many median point spacings of the cloud: below the spacing a voxel holds one point
    and merges nothing, and the lengths counted in voxels (twigs, forks, offsets) fall under what the cloud can show
    (the 5 cm scans of the small plants, 1.0-1.3 % of the height apart; the mvs clouds are 0.09-0.43 %) [S:
    docs/tuning/guo.md, livny voxel]. 0: the height rule alone."""
    stem_voxel_fraction: float = 0.0075
    """The stem fit's scale (its section offset, and twice it the fallback radius) is the larger of the voxel and
    this fraction of the height: a finer voxel for the crown need not shrink the stem's fit on a sparse scan (tree33
    of the real suite: DBH 37.9 cm at the 0.75 % voxel, 20.3 at 0.5 %, 38.1 at 0.5 % with this at 0.0075) [S:
    docs/tuning/guo.md, livny voxel]. 0: the voxel."""
    max_vertices: int = 150_000
    """When more voxels than this remain, the voxel grows (by the square root of the excess: scans sample surfaces)
    until they fit [S: keeps a 300k-point plant under the 60 s target of issue 7]."""
    k: int = 10
    """Neighbours per vertex in the kNN graph [S]."""
    max_edge_factor: float = 3.0
    """Drop kNN edges longer than this times the median 1-NN spacing, then bridge components [S]."""
    min_component_voxels: int = 20
    """Components of the kNN graph with fewer voxels than this are dropped before they are bridged: a scrap of a sparse
    scan (a few returns from a twig, a leaf, a stray) that bridging would hang from the tree by a straight edge
    through the air [S: measured on the real suite and the multiview mvs clouds, docs/tuning/xu.md]. 0: none."""
    bridge_scraps: bool = False
    """The scraps (components under ``min_component_voxels``) are bridged to the tree after the large components are
    joined, instead of dropped: on a sparse scan they are returns from twigs and thinly scanned limbs, while the
    large components' own bridges stay those of the scraps' absence (a trunk crosses a gap in the scan straight, not
    along a low limb's scraps). For scans; off for clouds from photographs, whose scraps are stereo outliers as often as
    wood [S: docs/tuning/xu.md, "livny on scans: the scraps bridged in"]."""
    bridge_support: float = 1.0
    """A subtree hung from the shortest-path tree by a bridge (an edge the kNN graph does not have) is dropped when the
    bridge is longer than this times the subtree's own length: a fragment smaller than the gap it would be drawn
    across [S: docs/tuning/xu.md]. 0: none."""
    bridge_waypoints: bool = True
    """A bridge left in the tree steps through the dropped scraps' voxels between its ends (the cheapest path by squared
    step length, :func:`reference_impl.common.graph.bridge_waypoints`) instead of jumping the gap straight: the scraps
    of an occluded branch are too small to stand as branches, but they say where it runs [S: docs/tuning/xu.md]."""
    max_offset_voxels: float = 0.5
    """After each re-embedding, a vertex farther from the cloud than its pipe radius plus this many voxels is pulled
    back to that distance: the contraction moves vertices onto a branch's axis, never out of the data (on a sparse
    scan the field term otherwise straightens chains across the gaps between branches) [S: docs/tuning/xu.md].
    0: none."""
    root_slab_fraction: float = 0.02
    """Roots are searched in the lowest 2 % of the height [A]."""
    plant_gap_fraction: float = 0.05
    """Clouds separated by more than about this fraction of the height are separate plants, each rooted on its own
    (several blobs in one capture); never below twice the longest kNN edge [S]."""
    outer_iterations: int = 5
    """Weights / orientation / re-embedding / resampling passes [G: max_iterations = 5]."""
    data_weight: float = 0.5
    """Weight of the data (anchor) term against the field term in the re-embedding [S]."""
    anchor_radius_factor: float = 1.5
    """Anchor = centroid of the cloud within this many local (pipe-model) radii of a vertex [S]."""
    merge_factor: float = 1.0
    """Resampling between passes merges vertices in cells of this many voxels [S: delta = 1 voxel]."""
    prune_ratio: float = 0.02
    """Keep a child subtree if (w(child) + |edge|) / w(parent) >= this [A: 0.019; issue: ~0.02]."""
    min_twig_voxels: float = 3.0
    """Terminal twigs shorter than this many voxels hanging from a junction are noise: pruned with the ratio rule
    [S: below the cloud's resolution, the 0.02 ratio alone keeps such stubs near the tips]."""
    min_twig_radii: float = 3.0
    """A terminal twig whose tip lies within this many radii of another branch's axis is a ridge of that branch's
    bark, not a branch: a voxel fine enough for a twig's cloud leaves a thick one-sided stem's surface as stubs
    along it (the one-sided test tree: 40 tips for the truth's 17 at the 0.5 % voxel, 17 with the rule) [S:
    docs/tuning/guo.md, livny voxel]. 0: none."""
    merge_fork_voxels: float = 2.0
    """Forks joined by a chain shorter than this many voxels become one fork, in each simplification round (a noisy
    cloud splits one fork into several) [S: measured, docs/tuning/xu.md]. 0: none."""
    sibling_angle_deg: float = 25.0
    """Merge siblings whose directions differ by less than this [A: cos > 0.9]."""
    sibling_length_ratio: float = 2.0
    """... and whose edge lengths differ by at most this factor [A: ratio in [0.5, 2]]."""
    radius_exponent: float = 0.5
    """Pipe model: r proportional to supported length^exponent [L, standard pipe model]."""
    leaf_length_fraction: float = 0.025
    """Leaf blade length, fraction of the plant height [S; AdTree uses 0.05 of the bounding distance]."""
    lobe_fraction: float = 0.05
    """Terminal subtrees (lobes) are those supporting at most this fraction of the plant's branch length; leaves
    hang from their nodes [L: lobes around terminal subtrees; S: the value]."""
    foliage_margin: float = 2.0
    """A point is foliage when it lies more than local radius + this many voxels from the skeleton [S]."""
    simplify_rounds: int = 10
    """Upper bound on prune / merge / degree-2 rounds (they stop earlier when nothing changes) [S]."""


@dataclass(frozen=True)
class LivnyResult:
    skeleton: Skeleton
    mesh: TriMesh
    leaves: list[Leaf]
    info: dict


def orientation_field(positions: np.ndarray, parents: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(n, 3) unit orientation per vertex minimising Groot's energy without the unit constraint, then normalised.

    E(O) = sum_(p,c) wbar_pc^2 |o_p - o_c|^2 + sum_c w_c^2 |o_c - e_c|^2, wbar = (w_p + w_c) / 2, e_c the unit
    direction parent -> child. weights : (n,) positive (normalised internally). Roots take their children's field.
    """
    n = len(parents)
    c = np.flatnonzero(parents >= 0)
    p = parents[c]
    w = weights / weights.max()
    e = unit(positions[c] - positions[p])
    a = ((w[p] + w[c]) / 2) ** 2
    d = np.zeros(n)
    d[c] = w[c] ** 2
    rhs = np.zeros((n, 3))
    rhs[c] = d[c, None] * e
    lap = sp.coo_matrix((np.concatenate([-a, -a]), (np.concatenate([p, c]), np.concatenate([c, p]))), shape=(n, n))
    deg = np.zeros(n)
    np.add.at(deg, p, a)
    np.add.at(deg, c, a)
    mat = (lap + sp.diags(deg + d + 1e-12 * (deg + d).max() + 1e-300)).tocsc()
    o = spsolve(mat, rhs)
    o = np.asarray(o).reshape(n, 3)
    bad = np.linalg.norm(o, axis=1) < 1e-12
    o[bad] = np.array([0.0, 0.0, 1.0])
    return unit(o)


def reembed(positions: np.ndarray, parents: np.ndarray, weights: np.ndarray, field: np.ndarray,
            anchors: np.ndarray, data_weight: float) -> np.ndarray:
    """(n, 3) positions minimising sum wbar^2 |(p_c - p_p) - ((p_c - p_p)^0 . o) o|^2 + lambda w^2 |p - anchor|^2.

    o = unit(o_p + o_c) is the field on the edge, ``(p_c - p_p)^0`` the current edge. One sparse SPD solve for the
    three coordinates.
    """
    n = len(parents)
    c = np.flatnonzero(parents >= 0)
    p = parents[c]
    w = weights / weights.max()
    o = unit(field[p] + field[c])
    cur = positions[c] - positions[p]
    target = np.sum(cur * o, 1, keepdims=True) * o
    a = ((w[p] + w[c]) / 2) ** 2
    g = data_weight * w**2
    # normal equations of: sqrt(a) (x_c - x_p - t), sqrt(g) (x - anchor)
    lap = sp.coo_matrix((np.concatenate([-a, -a]), (np.concatenate([p, c]), np.concatenate([c, p]))), shape=(n, n))
    deg = np.zeros(n)
    np.add.at(deg, p, a)
    np.add.at(deg, c, a)
    mat = (lap + sp.diags(deg + g)).tocsc()
    rhs = g[:, None] * anchors
    np.add.at(rhs, c, a[:, None] * target)
    np.add.at(rhs, p, -a[:, None] * target)
    out = np.asarray(spsolve(mat, rhs)).reshape(n, 3)
    if not np.all(np.isfinite(out)):
        return positions
    return out


def _anchors(tree: cKDTree, cloud: np.ndarray, mass: np.ndarray, positions: np.ndarray, field: np.ndarray,
             radius: np.ndarray) -> np.ndarray:
    """Mass-weighted centroid of the cloud within ``radius`` of each vertex, with its offset along the field removed."""
    lists = tree.query_ball_point(positions, radius, workers=-1)
    lens = np.fromiter((len(x) for x in lists), np.int64, len(lists))
    out = positions.copy()
    ok = lens > 0
    if ok.any():
        flat = np.concatenate([np.asarray(x, np.int64) for x, good in zip(lists, ok) if good])
        owner = np.repeat(np.flatnonzero(ok), lens[ok])
        wsum = np.zeros(len(positions))
        np.add.at(wsum, owner, mass[flat])
        acc = np.zeros((len(positions), 3))
        np.add.at(acc, owner, cloud[flat] * mass[flat, None])
        cen = acc[ok] / wsum[ok, None]
        off = cen - positions[ok]
        off -= np.sum(off * field[ok], 1, keepdims=True) * field[ok]
        out[ok] = positions[ok] + off
    return out


def _stay_near(tree: cKDTree, cloud: np.ndarray, positions: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """Positions farther than ``limit`` from the cloud pulled back along the line to their nearest cloud vertex until
    they are ``limit`` from it."""
    dist, idx = tree.query(positions, workers=-1)
    far = dist > limit
    if far.any():
        near = cloud[idx[far]]
        positions = positions.copy()
        positions[far] = near + (positions[far] - near) * (limit[far] / dist[far])[:, None]
    return positions


def _voxel_cloud(plant: np.ndarray, height: float, params: LivnyParams) -> tuple[np.ndarray, np.ndarray, float]:
    """Step 1's downsampling: the voxel centroids, their point counts (as float masses) and the voxel edge, grown
    until at most ``max_vertices`` voxels remain."""
    voxel = params.voxel_fraction * height
    if params.min_voxel_spacings > 0:
        voxel = max(voxel, params.min_voxel_spacings * median_spacing(plant))
    cloud, _, mass = voxel_downsample(plant, voxel)
    for _ in range(8):  # bounded: each pass grows the voxel by at least 10 %
        if len(cloud) <= params.max_vertices:
            break
        voxel *= max(1.1, float(np.sqrt(len(cloud) / params.max_vertices)))
        cloud, _, mass = voxel_downsample(plant, voxel)
    return cloud, mass.astype(float), voxel


def _shortest_path_forest(cloud: np.ndarray, ground: Ground, height: float, voxel: float, params: LivnyParams
                          ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Steps 2-4: the kNN graph, the roots (found on the whole cloud), the scraps dropped (components under
    ``min_component_voxels`` other than the roots'; with ``bridge_scraps`` bridged in after the rest is joined), the
    rest bridged, the shortest-path tree from the roots and the
    subtrees hung by long bridges dropped (:func:`_unbridged`). Returns ``keep`` (n,) (the cloud's vertices in the
    tree), the parents over ``cloud[keep]`` and statistics."""
    n = len(cloud)
    spacing = max(median_spacing(cloud), 1e-9)
    max_edge = params.max_edge_factor * spacing
    knn = knn_graph(cloud, params.k, max_edge=max_edge)
    graph, nbridges = bridge_components(cloud, knn)
    roots = find_roots(cloud, ground.height(cloud), graph, slab=params.root_slab_fraction * height + voxel,
                       group_cell=max(params.plant_gap_fraction * height, 2 * max_edge))
    keep = np.ones(n, bool)
    if params.min_component_voxels > 1:
        _, lab = components(knn)
        keep = (np.bincount(lab)[lab] >= params.min_component_voxels) | np.isin(lab, lab[roots])
        if not keep.all():
            graph, nbridges = bridge_components(cloud[keep], knn[keep][:, keep].tocsr())
            if params.bridge_scraps:
                graph, extra = _bridge_scraps_in(cloud, knn, graph, keep)
                nbridges += extra
                keep[:] = True
            else:
                roots = (np.cumsum(keep) - 1)[roots]
    kept = np.flatnonzero(keep)
    _, parents, _ = shortest_path_tree(graph, roots)
    if params.bridge_support > 0:
        tree_keep = _unbridged(cloud[kept], parents, max_edge, params.bridge_support)
        parents, _ = remove_nodes(parents, tree_keep)
        keep[kept[~tree_keep]] = False
    stats = {"bridges": nbridges, "roots": len(roots), "scraps_and_unbridged": int(n - keep.sum())}
    if params.bridge_waypoints:
        keep, parents, stats["bridge_waypoints"] = _route_bridges(cloud, keep, parents, max_edge)
    return keep, parents, stats


def _bridge_scraps_in(cloud: np.ndarray, knn: sp.csr_matrix, joined: sp.csr_matrix, large: np.ndarray
                      ) -> tuple[sp.csr_matrix, int]:
    """The whole cloud's graph: the kNN graph, the bridges ``joined`` already holds between the ``large`` vertices
    (its indices are those of ``cloud[large]``), and the scraps bridged to them (:func:`bridge_components`). Returns
    the graph and the number of bridges added to it."""
    index = np.flatnonzero(large)
    g = joined.tocoo()
    big = sp.csr_matrix((g.data, (index[g.row], index[g.col])), shape=knn.shape)
    return bridge_components(cloud, knn.maximum(big).tocsr())


def _route_bridges(cloud: np.ndarray, keep: np.ndarray, parents: np.ndarray, max_edge: float
                   ) -> tuple[np.ndarray, np.ndarray, int]:
    """Every bridge of the tree (an edge longer than ``max_edge``; ``parents`` over ``cloud[keep]``) re-drawn through
    the dropped vertices between its ends (:func:`reference_impl.common.graph.bridge_waypoints`), which join the
    tree as a chain. Returns the new ``keep``, the parents over ``cloud[keep]`` and the number of vertices added."""
    kept = np.flatnonzero(keep)
    up = np.full(len(cloud), -1, np.int64)  # parents as cloud indices
    up[kept] = np.where(parents >= 0, kept[np.maximum(parents, 0)], -1)
    free = ~keep
    tree = cKDTree(cloud)
    added = 0
    for c in kept[edge_lengths(cloud[kept], parents) > max_edge * (1 + 1e-9)]:
        prev = up[c]
        for w in bridge_waypoints(cloud, tree, free, cloud[prev], cloud[c]):
            up[w], free[w], prev = prev, False, w
            added += 1
        up[c] = prev
    if added == 0:
        return keep, parents, 0
    return ~free, remove_nodes(up, ~free)[0], added


def _unbridged(cloud: np.ndarray, parents: np.ndarray, max_edge: float, support: float) -> np.ndarray:
    """(n,) False for the vertices of every subtree hung from the tree by a bridge (an edge longer than ``max_edge``,
    which only :func:`bridge_components` adds) longer than ``support`` times the subtree's own length (its edges that
    are not bridges): a fragment of the scan smaller than the gap it would be drawn across [S]."""
    inc = edge_lengths(cloud, parents)
    bridge = inc > max_edge * (1 + 1e-9)
    lv = levels(parents)
    own = subtree_sums(np.where(bridge, 0.0, inc), parents, lv)
    drop = bridge & (inc > support * own)
    for idx in lv:  # a dropped vertex drops its subtree
        c = idx[parents[idx] >= 0]
        drop[c] |= drop[parents[c]]
    return ~drop


def _pipe_radii(pos: np.ndarray, parents: np.ndarray, plant: np.ndarray, *, voxel: float, height: float,
                params: LivnyParams) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vertex weights (supported length plus one voxel), the orientation field, the trunk radius of each root
    (cylinder fit along the field [A]) and the pipe-model radii anchored on them: ``(w, field, trunk, radii)``."""
    w = subtree_lengths(pos, parents) + voxel
    field = orientation_field(pos, parents, w)
    min_r = params.min_radius_fraction * height
    stem = max(voxel, params.stem_voxel_fraction * height)
    trunk = fit_stems(plant, pos, parents, field[parents < 0], w, params, height=height, offset=stem,
                      fallback=2 * stem)
    radii = pipe_model_radii(w, parents, trunk, exponent=params.radius_exponent, min_radius=min_r)
    return w, field, trunk, radii


def _contract(cloud: np.ndarray, mass: np.ndarray, parents: np.ndarray, plant: np.ndarray, *, voxel: float,
              height: float, params: LivnyParams) -> tuple[np.ndarray, np.ndarray]:
    """Step 5, the BSG passes: weights, orientation field, re-embedding towards the cloud's anchors (``mass``: each
    cloud vertex's point count), resampling. Returns positions and parents."""
    pos = cloud.copy()
    vmass = mass.copy()
    tree = cKDTree(cloud)
    for _ in range(params.outer_iterations):
        w, field, _, radii = _pipe_radii(pos, parents, plant, voxel=voxel, height=height, params=params)
        rho = np.clip(params.anchor_radius_factor * radii, voxel, 0.1 * height)
        anchors = _anchors(tree, cloud, mass, pos, field, rho)
        pos = reembed(pos, parents, w, field, anchors, params.data_weight)
        if params.max_offset_voxels > 0:
            pos = _stay_near(tree, cloud, pos, radii + params.max_offset_voxels * voxel)
        pos, parents, vmass, _ = spatial_merge(pos, parents, vmass, params.merge_factor * voxel)
    return pos, parents


def _simplify(pos: np.ndarray, parents: np.ndarray, plant: np.ndarray, *, voxel: float, height: float,
              params: LivnyParams) -> tuple[np.ndarray, np.ndarray]:
    """Step 6 until stable: subtree-ratio pruning with short twigs, sibling merging, degree-2 removal."""
    ridges = params.min_twig_radii > 0  # (the radii of each round's skeleton, from the round before)
    radii = _pipe_radii(pos, parents, plant, voxel=voxel, height=height, params=params)[3] if ridges else None
    for _ in range(params.simplify_rounds):
        n_before = len(pos)
        keep = prune_by_ratio(pos, parents, params.prune_ratio)
        keep &= prune_short_tips(pos, parents, params.min_twig_voxels * voxel, rounds=1)
        if ridges:
            keep &= _prune_ridges(pos, parents, radii, params.min_twig_radii, 0.5 * voxel)
        if params.merge_fork_voxels > 0:
            keep &= merge_close_forks(pos, parents, params.merge_fork_voxels * voxel, rounds=1)
        parents, _ = remove_nodes(parents, keep)
        pos = pos[keep]
        w = subtree_lengths(pos, parents) + voxel
        pos, parents, _ = merge_siblings(pos, parents, w, max_angle_deg=params.sibling_angle_deg,
                                         length_ratio=params.sibling_length_ratio)
        _, _, _, radii = _pipe_radii(pos, parents, plant, voxel=voxel, height=height, params=params)
        alive, parents = remove_degree2(pos, parents, radii)
        pos, radii = pos[alive], radii[alive]
        if len(pos) == n_before:
            break
    return pos, parents


def _prune_ridges(pos: np.ndarray, parents: np.ndarray, radii: np.ndarray, factor: float, step: float
                  ) -> np.ndarray:
    """(n,) keep mask without the terminal chains (tip up to the first junction, exclusive) whose tip lies within
    ``factor`` radii of another chain's axis: a ridge of that branch's bark, not a branch of its own. ``step``:
    the spacing of the axis samples. A lone stem (a root's chain ending in a tip) stays."""
    skeleton = Skeleton(pos, radii, parents)
    children = skeleton.children_counts()
    twigs = [c[1:] for c in branch_chains(skeleton) if children[c[-1]] == 0 and children[c[0]] >= 2]
    keep = np.ones(len(pos), bool)
    if not twigs:
        return keep
    chain_of = np.full(len(pos), -1)
    for i, twig in enumerate(twigs):
        chain_of[twig] = i
    samples, owner, rad = sample_edges(pos, parents, radii, step)
    k = min(64, len(samples))
    d, j = cKDTree(samples).query(pos[[twig[-1] for twig in twigs]], k=k)
    d, j = d.reshape(len(twigs), k), j.reshape(len(twigs), k)
    other = chain_of[owner[j]] != np.arange(len(twigs))[:, None]  # samples of another chain's axis
    rows, first = np.arange(len(twigs)), np.argmax(other, axis=1)
    ridge = other[rows, first] & (d[rows, first] < factor * rad[j[rows, first]])
    for i in np.flatnonzero(ridge):
        keep[twigs[i]] = False
    return keep


def _lobe_leaves(plant: np.ndarray, skeleton: Skeleton, *, voxel: float, height: float, params: LivnyParams
                 ) -> tuple[TriMesh, list[Leaf]]:
    """Step 8: leaves in the lobes. The crown points the tubes do not explain, one leaf per leaf-sized cell, each
    hanging from the nearest node of a terminal subtree (supported length <= ``lobe_fraction`` of its root's)."""
    pos, parents = skeleton.positions, skeleton.parents
    leaf_len = params.leaf_length_fraction * height
    dist, _, rad = skeleton_distance(plant, pos, parents, skeleton.radii, step=0.5 * voxel)
    fol = dist > rad + params.foliage_margin * voxel
    w = subtree_lengths(pos, parents)
    lobe = w <= params.lobe_fraction * w[parents < 0].max()
    lobe &= parents >= 0
    if lobe.any() and fol.any():
        s_pts, s_node, _ = sample_edges(pos, np.where(lobe, parents, -1), skeleton.radii, 0.5 * voxel)
        in_lobe = lobe[s_node]
        _, j = cKDTree(s_pts[in_lobe]).query(plant[fol], k=1, workers=-1)
        lnode_pt = s_node[in_lobe][j]
    else:
        lnode_pt = np.zeros(int(fol.sum()), np.int64)
    cen, normal, lnode, _ = foliage_cells(plant[fol], lnode_pt, leaf_len)
    axis = unit(cen - pos[lnode])
    frames = leaf_frames(cen - 0.5 * leaf_len * axis, axis, normal)
    return bezier_leaves(frames, np.full(len(cen), leaf_len), lnode)


def reconstruct_livny(points: np.ndarray, rng: np.random.Generator, params: LivnyParams = LivnyParams()
                      ) -> LivnyResult:
    """Skeleton, branch + leaf mesh and leaves from a cloud (metres, Z up, ground near z = 0).

    points : (n, 3) float. Raises InputError for fewer than MIN_POINTS valid points (after ground removal) or
    non-finite coordinates. The steps are those of the module docstring.
    """
    pts, ground, plant = split_ground(points, rng)
    _, height = plant_height(plant, ground)
    cloud, mass, voxel = _voxel_cloud(plant, height, params)
    info: dict = {"points": len(pts), "plant_points": len(plant), "voxel": voxel, "vertices": len(cloud)}
    if len(cloud) < 3:
        raise InputError(f"the cloud collapses to {len(cloud)} voxels of {voxel:.4g} m; too small to skeletonise")
    keep, parents, stats = _shortest_path_forest(cloud, ground, height, voxel, params)
    info.update(stats)
    cloud, mass = cloud[keep], mass[keep]
    pos, parents = _contract(cloud, mass, parents, plant, voxel=voxel, height=height, params=params)
    info["bsg_vertices"] = len(pos)
    pos, parents = _simplify(pos, parents, plant, voxel=voxel, height=height, params=params)

    # step 7: radii, anchored on the trunk fit; then the ground node under each root
    _, _, rr, radii = _pipe_radii(pos, parents, plant, voxel=voxel, height=height, params=params)
    pos, parents, radii = finish_stems(plant, pos, parents, radii, ground.coef, params, height=height,
                                       min_gap=0.25 * voxel, method="livny")
    skeleton = Skeleton(pos, np.maximum(radii, params.min_radius_fraction * height), parents,
                        branch_orders(parents, radii))

    leaf_mesh, leaves = _lobe_leaves(plant, skeleton, voxel=voxel, height=height, params=params)
    wood = branch_mesh(skeleton, edge_length=max(voxel, 2 * np.pi * float(rr.max()) / 12))
    info.update(nodes=len(pos), leaves=len(leaves), height=height, root_radii=rr.tolist())
    return LivnyResult(skeleton, TriMesh.concatenate([wood, leaf_mesh]), leaves, info)
