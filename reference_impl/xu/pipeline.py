"""The Xu, Gossett, Chen 2007 pipeline end to end: :func:`reconstruct_xu`.

Parameters are the paper's Table I values for its 20 m elm, scaled by ``plant height / 20 m`` where they are
lengths (the paper: "all parameter values ... are based on trees of this size"; the issue: scale with plant size).
Where the paper gives no value, the choice is ours ([S]) and says why.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from plantbench.errors import InputError
from plantbench.geometry.vectors import levels, unit
from plantbench.plant import Leaf, Skeleton, TriMesh
from reference_impl.common.geometry import branch_mesh, leaf_frames, quad_leaves
from reference_impl.common.graph import children_csr, median_spacing, radius_graph, subtree_lengths, voxel_downsample
from reference_impl.common.ground import Ground
from reference_impl.common.inputs import plant_height, split_ground
from reference_impl.common.radii import murray_angle, wbe_murray_radii
from reference_impl.common.roots import StemFitParams, find_roots, finish_stems, fit_stems
from reference_impl.common.skeleton_ops import branch_orders, hermite_smooth, prune_short_tips, remove_nodes, simplify
from reference_impl.xu.skeleton import bin_skeleton, join_fragments, probe_extend
from reference_impl.xu.synthesis import (
    SynthesisResult,
    axil_angles,
    leaf_locations,
    node_directions,
    prune_bare_twigs,
    support,
    synthesize,
)

__all__ = ["XuParams", "XuResult", "reconstruct_xu", "adjust_branch_angles"]


@dataclass(frozen=True)
class XuParams(StemFitParams):
    """Parameters of the Xu-style baseline. Lengths marked "at 20 m" are scaled by height / reference_height."""

    reference_height: float = 20.0
    """Height of the paper's example elm, metres (section 3); lengths below are scaled from it."""
    neighbourhood: float = 0.2
    """Local neighbourhood of the radius graph at 20 m (Table I, section 4.1)."""
    min_spacing_factor: float = 2.5
    """... but at least this many median point spacings, so a sparse scan still links neighbours (the paper: the
    neighbourhood depends on the scanning resolution) [S]."""
    downsample_factor: float = 1.0 / 3.0
    """Voxel downsampling at this fraction of the neighbourhood before the graph, for speed; it keeps the radius
    graph's connectivity [S: the paper used all 115k points]."""
    bin_factor: float = 1.0
    """Geodesic bin width in neighbourhoods (the paper gives no value; one neighbourhood makes each bin one graph
    hop deep, like Brostow et al.'s level sets) [S]."""
    spur_bins: float = 2.0
    """Main-skeleton terminal chains shorter than this many bins that hang from a junction, and extra root trees
    shorter than that in all, are bin noise; their points become leaf points [S]."""
    root_slab_fraction: float = 0.02
    """Stem bases searched in the lowest 2 % of the height; one root per stem (the paper's user picks the root; a
    multi-stem shrub has one per stem) [S]."""
    plant_gap_fraction: float = 0.05
    """Clouds separated by more than about this fraction of the height (and two neighbourhoods) are separate plants,
    each with its own root [S]."""
    cone_angle_deg: float = 45.0
    """Bi-directional probing cone, half-angle (Table I, section 4.2: slightly above the mean axil angle)."""
    max_gap: float = 2.0
    """Largest gap bridged by probing at 20 m (Table I, section 4.2)."""
    bridge_waypoints: bool = True
    """A probed join (segment PQ) steps through the scan's free points between Q and P (the cheapest path by squared
    step length, :func:`reference_impl.xu.skeleton.bridge_waypoints`) instead of jumping the gap straight: on a
    sparse scan an occluded branch leaves scattered returns too small to join as subgraphs [S: docs/tuning/xu.md]."""
    probe_height_fraction: float = 2.0 / 3.0
    """Only nodes with shortest path below this fraction of the height probe (section 4.2)."""
    prune_tip_bins: float = 3.0
    """After smoothing, terminal branches (a fork to a tip) shorter than this many geodesic bins are removed, until
    none is left (the paper removes twigs that support no leaf location, section 4.4; a twig this short is a split of
    the bin clustering, not a branch) [S: measured, docs/tuning/xu.md]. 0: none."""
    merge_fork_bins: float = 1.0
    """After smoothing, forks joined by a chain shorter than this many bins become one fork [S]. 0: none."""
    stem_gap_share: float = 0.5
    """When the root subgraph (the radius-graph components of the stem bases) spans less than this share of the
    height, a gap in the stem's scan would stop the skeleton there: the probing is persistent
    (:func:`reference_impl.xu.skeleton.probe_extend`) [S: docs/tuning/xu.md]."""
    join_fragments: bool = False
    """After probing, every radius-graph subgraph still unattached and within the probing gap of the skeleton joins at
    its nearest attached point, the nearest first, in rounds (:func:`reference_impl.xu.skeleton.join_fragments`): on
    a sparse scan the crown falls apart into hundreds of subgraphs (AdTree's tree13: 1243 for 7k points) and the
    cones along the branches reach few of them; the rest were leaf points, which synthesis reaches only within the
    density range. The scan suites set it (scan-sparse: coverage +0.12 / +0.11 and vF1 +0.011 / +0.006 at 2 / 5 cm,
    intervals above 0); off by default: on an mvs cloud the fragments are stereo outliers as often as wood (the quick
    suite's mvs cells: support@1% 0.165 -> 0.076) [S: docs/tuning/xu.md]."""
    fragment_min_points: int = 3
    """Subgraphs of fewer points stay leaf points (:attr:`join_fragments`) [S]."""
    support_distance: float = 0.1
    """d0: largest distance from a supported leaf location to its feasible node at 20 m (Table I, section 4.3)."""
    density_range: float = 0.5
    """Leaf density range at 20 m (Table I, section 4.3)."""
    leaf_group: float = 0.1
    """Leaf-location grouping cell at 20 m: the paper's "sphere based on leaf size"; we take d0 (Table I's twig
    length), which matches the ~32k leaf quads of Table II for 115k points [S]."""
    leaf_size: float | None = None
    """The species' leaf size in metres, unscaled, when known: the leaf-location cell (the paper: "a sphere of a
    certain radius based on leaf or leaf cluster size for the tree species in question") and d0 = leaf_size x
    support_distance / leaf_group (Table I's 0.1 m twig length is a leaf-scale length too, the elm's leaf, not a
    twentieth of its height). The method sets it from the species hint's leaf length. None: both scaled by height
    (on a small plant d0 then falls below a leaf's length and synthesis over-branches) [S: measured,
    docs/tuning/xu.md]."""
    synthesis_iterations: int = 3
    """Maximal skeleton synthesis iterations (Table I, section 4.3)."""
    bare_twig_keep: float = 0.25
    """Fraction of unnecessary twigs kept (Table I, section 4.4)."""
    default_axil_deg: tuple[float, float] = (34.1, 7.4)
    """Mean and standard deviation of axil angles used when the skeleton has fewer than 3 splits (Fig. 6) [S]."""
    hermite_min_angle_deg: float = 30.0
    """A transition is sharp (section 4.4) above this turn [S: the paper gives no threshold]."""
    wbe_exponent: float = 1.5
    """Eq. 4 exponent (WBE, section 5.2)."""
    murray_exponent: float = 2.49
    """Eq. 5 exponent (Murray, section 5.2)."""
    angle_tolerance_deg: float = 10.0
    """Branching angles further than this from Eq. 3's prediction are adjusted (section 5.2) [S]."""
    angle_shift_limit: float = 0.5
    """The split point moves at most this fraction of the adjacent parent edges [S: "closer to", not onto]."""
    leaf_bins: int = 4
    """Density bins for leaf clusters of 1..leaf_bins leaves per quad (section 6, Fig. 8) [S: Fig. 8 shows 4]."""
    leaf_jitter_deg: float = 10.0
    """Random perturbation of the quad normals (section 6: "slightly") [S]."""
    empty_tolerance_fraction: float = 0.025
    """An edge crosses empty space where a point along it lies farther than this fraction of the height from every
    point of the (downsampled) cloud; synthesis refuses a copy or twig with such an edge [S: no edge through empty
    space, while synthesis may still bridge the gaps occlusion leaves inside the crown, up to the density range;
    a tolerance as tight as the support check's refuses most copies: docs/tuning/xu.md]. 0: no test."""
    association_reach: float = 0.5
    """An unsupported leaf location (no feasible node within d0) is associated with its nearest feasible node only
    within d0 plus this distance at 20 m (the density range), so synthesis never hangs a copy from a node across the
    crown [S; the paper associates every location with its nearest feasible node, at any distance]."""
    max_nodes: int = 20000
    """Synthesis stops beyond this many skeleton nodes [S: bounds time and memory; Table II reaches 14,653 nodes
    for a 20 m elm]."""


@dataclass(frozen=True)
class XuResult:
    skeleton: Skeleton
    mesh: TriMesh
    leaves: list[Leaf]
    info: dict


def adjust_branch_angles(positions: np.ndarray, parents: np.ndarray, radii: np.ndarray, *, tolerance_deg: float,
                         shift_limit: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Section 5.2: at each split, a lateral child (not the thickest) whose angle to the parent direction differs
    from Eq. 3's prediction by more than ``tolerance_deg`` gets a new split point S on the parent axis, moved along
    the axis (at most ``shift_limit`` of the neighbouring edge) towards the point where the angle equals the
    prediction. S is inserted as a node; the child hangs from it. Returns positions, parents, radii and the number
    of adjusted branches.

    Two splits can insert points on the same edge (a split's S on the edge down to its main child, that child's own
    S on the edge up to its parent): each S goes into the edge's chain in order along the edge, and a child is
    re-hung together with the points already inserted above it, so every inserted point stays on the axis it was
    made for (re-hanging the child alone would leave an inserted point with the axis radius carrying only a twig)."""
    pos = [p for p in positions]
    par = list(parents)
    rad = list(radii)
    edge_of: dict[int, tuple[int, int]] = {}  # inserted node -> the original edge (upper, lower) it lies on

    def chain_node(upper: int, lower: int, at: np.ndarray | None = None) -> int:
        """The node of the edge (upper, lower)'s chain (``lower`` and the points inserted above it) just below
        ``at``, or the chain's top when ``at`` is None."""
        d = positions[lower] - positions[upper]
        u = -np.inf if at is None else float((at - positions[upper]) @ d)
        node = lower
        while edge_of.get(par[node]) == (upper, lower) and float((pos[par[node]] - positions[upper]) @ d) > u:
            node = par[node]
        return node

    def insert(upper: int, lower: int, at: np.ndarray, r: float) -> int:
        """Insert a node at ``at`` (on the edge from ``upper`` down to ``lower``) into that edge's chain, in order
        along the edge; returns its index."""
        below = chain_node(upper, lower, at)
        pos.append(at)
        par.append(int(par[below]))
        rad.append(r)
        s = len(pos) - 1
        par[below] = s
        edge_of[s] = (upper, lower)
        return s

    ptr, kids = children_csr(parents)
    adjusted = 0
    for j in np.flatnonzero((np.diff(ptr) >= 2) & (parents >= 0)):
        c_all = kids[ptr[j]:ptr[j + 1]]
        main = c_all[np.argmax(radii[c_all])]
        d = unit(positions[j] - positions[parents[j]])
        up_len = float(np.linalg.norm(positions[j] - positions[parents[j]]))
        down_len = float(np.linalg.norm(positions[main] - positions[j]))
        for c in c_all:
            if c == main:
                continue
            rel = positions[c] - positions[j]
            a = float(rel @ d)
            h = float(np.linalg.norm(rel - a * d))
            if h < 1e-12:
                continue
            actual = np.arctan2(h, a)
            pred = float(murray_angle(radii[j], radii[c]))
            if abs(np.degrees(actual - pred)) <= tolerance_deg:
                continue
            t = a - h / np.tan(np.clip(pred, 1e-3, np.pi - 1e-3))
            t = float(np.clip(t, -shift_limit * up_len, shift_limit * down_len))
            if abs(t) < 1e-9:
                continue
            if t < 0:  # on the parent edge: S between parent(j) and j
                s = insert(int(parents[j]), int(j), positions[j] + t * d, float(radii[j]))
            else:  # on the main child's edge
                s = insert(int(j), int(main), positions[j] + t * unit(positions[main] - positions[j]),
                           float(radii[main]))
            par[chain_node(int(j), int(c))] = s  # the lateral moves to S with the points inserted on its edge
            adjusted += 1
            break  # one adjustment per split keeps the main axis intact
    return np.asarray(pos), np.asarray(par, np.int64), np.asarray(rad), adjusted


def _stub_root_trees(positions: np.ndarray, parents: np.ndarray, min_length: float) -> np.ndarray:
    """(n,) keep mask without the trees (root and descendants) of total edge length below ``min_length``; the
    longest tree is always kept [S]."""
    w = subtree_lengths(positions, parents)
    roots = np.flatnonzero(parents < 0)
    keep = np.ones(len(parents), bool)
    if len(roots) < 2:
        return keep
    drop = np.zeros(len(parents), bool)
    stub = roots[(w[roots] < min_length) & (roots != roots[np.argmax(w[roots])])]
    drop[stub] = True
    for idx in levels(parents):
        c = idx[parents[idx] >= 0]
        drop[c] |= drop[parents[c]]
    return keep & ~drop


def _main_components(labels: np.ndarray, roots: np.ndarray) -> np.ndarray:
    return np.isin(labels, np.unique(labels[roots]))


def _scanned_skeleton(cloud: np.ndarray, cloud_height: np.ndarray, height: float, radius: float, width: float,
                      gap: float, params: XuParams) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Sections 4.1-4.2: the main skeleton from the root subgraph(s) of the radius graph, extended by bi-directional
    probing across gaps up to ``gap``, then cleaned of bin noise [S]. Returns its positions and parents, the leaf
    points (the cloud's points no node explains) and statistics."""
    graph = radius_graph(cloud, radius)
    ncomp, labels = csgraph.connected_components(graph, directed=False)
    roots = find_roots(cloud, cloud_height, graph, slab=params.root_slab_fraction * height + radius,
                       group_cell=max(params.plant_gap_fraction * height, 2 * radius))
    in_main = _main_components(labels, roots)
    main = bin_skeleton(cloud, graph, np.flatnonzero(in_main), roots, width)
    stats = {"subgraphs": int(ncomp), "roots": len(roots), "main_nodes": len(main.positions)}
    probe = dict(width=width, cone_deg=params.cone_angle_deg, gap=gap,
                 max_geodesic=params.probe_height_fraction * height, waypoints=params.bridge_waypoints)
    # a gap in the stem's scan: the root subgraph stops low. Read on the root subgraph, not on the probed skeleton:
    # which fragments a probe joins turns on a few points (on the quick maple's mvs cloud 6 points of 21k moved the
    # probed span from 0.54 to 0.48 of the height, across the threshold; docs/tuning/xu.md)
    z = cloud_height[in_main] if in_main.any() else np.zeros(1)
    persistent = bool(z.max() - z.min() < params.stem_gap_share * height)
    ext, attached, joined = probe_extend(cloud, graph, labels, main, in_main, persistent=persistent, **probe)
    if params.join_fragments:
        ext, attached, more = join_fragments(cloud, graph, labels, ext, attached, width=width, gap=gap,
                                             min_points=params.fragment_min_points, waypoints=params.bridge_waypoints)
        stats["fragments_joined"] = more
    if persistent:
        stats["persistent_probing"] = True
    stats["joined_subgraphs"] = joined
    # bin-noise spurs go; their points count as leaf points with the unattached ones
    keep = prune_short_tips(ext.positions, ext.parents, params.spur_bins * width)
    # ... and so do whole trees shorter than the spur length hanging from extra roots: a stem base scanned from
    # several sides splits into radius-graph components, each found as a stem base (the longest tree always stays)
    keep &= _stub_root_trees(ext.positions, ext.parents, params.spur_bins * width)
    par, index = remove_nodes(ext.parents, keep)
    pos = ext.positions[keep]
    pnode = np.where(ext.point_node >= 0, index[np.maximum(ext.point_node, 0)], -1)
    stats["scanned_nodes"] = len(pos)
    return pos, par, cloud[(~attached) | (attached & (pnode < 0))], stats


def _synthesis(pos: np.ndarray, par: np.ndarray, leaf_pts: np.ndarray, *, d0: float, density_range: float,
               group: float, cloud: cKDTree, tolerance: float | None, reach: float, params: XuParams
               ) -> tuple[SynthesisResult, np.ndarray, np.ndarray, tuple, dict]:
    """Section 4.3: leaf locations from the leaf points, the skeleton's axil-angle statistics and the skeleton
    synthesis towards the leaf locations. Returns the synthesis, the leaf locations and their densities, the
    two-sigma axil interval (for the support tests that follow) and statistics."""
    locs, density = leaf_locations(leaf_pts, group, density_range)
    axil = axil_angles(pos, par)
    mu, sd = (float(axil.mean()), float(axil.std())) if len(axil) >= 3 else params.default_axil_deg
    sd = max(sd, 1.0)
    i1, i2 = (mu - sd, mu + sd), (mu - 2 * sd, mu + 2 * sd)
    syn = synthesize(pos, par, locs, density, d0=d0, interval=i1, group=group,
                     iterations=params.synthesis_iterations, max_nodes=params.max_nodes, cloud=cloud,
                     tolerance=tolerance, max_reach=reach)
    stats = {"leaf_locations": len(locs), "axil_mean": mu, "axil_std": sd, "synthesis_iterations": syn.iterations,
             "synthesized_branches": syn.branches, "synthesis_refused": syn.refused}
    return syn, locs, density, i2, stats


def _prune_and_smooth(syn: SynthesisResult, locs: np.ndarray, *, d0: float, interval: tuple, width: float,
                      params: XuParams, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Section 4.4: synthesised twigs that support no leaf location are pruned (``bare_twig_keep`` of them kept),
    then sharp transitions are smoothed with Hermite curves. Returns positions, parents and the kept bare twigs'
    tips."""
    pos, par = syn.positions, syn.parents
    snode, _, sup = support(locs, pos, par, d0=d0, interval=interval)
    supporting = np.zeros(len(pos), bool)
    supporting[snode[sup]] = True
    keep, bare_tips = prune_bare_twigs(pos, par, syn.synthetic, supporting, params.bare_twig_keep, rng)
    par, index = remove_nodes(par, keep)
    pos = pos[keep]
    bare_tips = index[bare_tips]
    bare_pos = pos[bare_tips[bare_tips >= 0]]
    pos, par, _ = hermite_smooth(pos, par, min_angle_deg=params.hermite_min_angle_deg, min_spacing=width)
    if params.prune_tip_bins > 0 or params.merge_fork_bins > 0:
        pos, par, _, _ = simplify(pos, par, prune_tips=params.prune_tip_bins * width,
                                  merge_forks=params.merge_fork_bins * width)
    return pos, par, bare_pos


def _stem_axes(pos: np.ndarray, par: np.ndarray) -> np.ndarray:
    """(k, 3) unit direction from each root to its first child (up for a root without children)."""
    axes = []
    for r in np.flatnonzero(par < 0):
        kids = np.flatnonzero(par == r)
        axes.append(unit(pos[kids[0]] - pos[r]) if len(kids) else np.array([0.0, 0.0, 1.0]))
    return np.asarray(axes, float).reshape(-1, 3)


def _radii_and_angles(pos: np.ndarray, par: np.ndarray, plant: np.ndarray, ground: Ground, height: float,
                      radius: float, params: XuParams) -> tuple[Skeleton, np.ndarray, int]:
    """Section 5.2: radii by Eq. 4-5 anchored on the base radius fitted to the scan, branching angles adjusted
    towards Eq. 3, then a ground node under each root. Returns the skeleton, the base radii and the number of
    adjusted branches."""
    min_r = params.min_radius_fraction * height
    rr = fit_stems(plant, pos, par, _stem_axes(pos, par), subtree_lengths(pos, par), params, height=height,
                   offset=radius, fallback=radius)
    radii = wbe_murray_radii(pos, par, rr, wbe_exponent=params.wbe_exponent,
                             murray_exponent=params.murray_exponent, min_radius=min_r)
    pos, par, radii, nadj = adjust_branch_angles(pos, par, radii, tolerance_deg=params.angle_tolerance_deg,
                                                 shift_limit=params.angle_shift_limit)
    pos, par, radii = finish_stems(plant, pos, par, radii, ground.coef, params, height=height,
                                   min_gap=0.25 * radius, method="xu")
    return Skeleton(pos, np.maximum(radii, min_r), par, branch_orders(par, radii)), rr, nadj


def reconstruct_xu(points: np.ndarray, rng: np.random.Generator, params: XuParams = XuParams()) -> XuResult:
    """Skeleton, branch mesh + leaf quads, and leaves from a cloud (metres, Z up, ground near z = 0).

    points : (n, 3) float. Raises InputError for too few valid points or non-finite coordinates.

    The steps: ground removal and the paper's lengths scaled to the plant; the scanned skeleton (sections 4.1-4.2,
    :func:`_scanned_skeleton`); leaf locations and skeleton synthesis (4.3, :func:`_synthesis`); pruning of bare
    synthesised twigs and Hermite smoothing (4.4, :func:`_prune_and_smooth`); radii and branching angles (5.2,
    :func:`_radii_and_angles`); leaf quads (6, :func:`_leaf_quads`) and the branch mesh.
    """
    pts, ground, plant = split_ground(points, rng)
    _, height = plant_height(plant, ground)
    s = height / params.reference_height
    spacing = median_spacing(plant)
    radius = max(params.neighbourhood * s, params.min_spacing_factor * spacing)
    cloud, _, _ = voxel_downsample(plant, params.downsample_factor * radius)
    if len(cloud) < 3:
        raise InputError(f"the cloud collapses to {len(cloud)} cells; too small to skeletonise")
    width = params.bin_factor * radius
    dens_r = params.density_range * s
    if params.leaf_size is not None:  # leaf-scale lengths: the species' leaf, not the plant's height
        d0 = params.leaf_size * params.support_distance / params.leaf_group
        group = params.leaf_size
    else:
        d0, group = params.support_distance * s, params.leaf_group * s
    info: dict = {"points": len(pts), "plant_points": len(plant), "neighbourhood": radius, "vertices": len(cloud)}

    pos, par, leaf_pts, stats = _scanned_skeleton(cloud, ground.height(cloud), height, radius, width,
                                                  params.max_gap * s, params)
    info.update(stats)
    tol = params.empty_tolerance_fraction * height if params.empty_tolerance_fraction > 0 else None
    syn, locs, density, i2, stats = _synthesis(pos, par, leaf_pts, d0=d0, density_range=dens_r, group=group,
                                               cloud=cKDTree(cloud), tolerance=tol,
                                               reach=d0 + params.association_reach * s, params=params)
    info.update(stats)
    pos, par, bare_pos = _prune_and_smooth(syn, locs, d0=d0, interval=i2, width=width, params=params, rng=rng)
    skeleton, rr, adjusted = _radii_and_angles(pos, par, plant, ground, height, radius, params)
    info["angles_adjusted"] = adjusted
    pos, par = skeleton.positions, skeleton.parents

    # 6 leaves: a quad per supported location on its nearest feasible node, plus clusters on kept bare twigs
    snode, _, sup = support(locs, pos, par, d0=d0, interval=i2)
    leaf_mesh, leaves = _leaf_quads(locs[sup], density[sup], snode[sup], pos, par, bare_pos, group, params, rng)
    wood = branch_mesh(skeleton, edge_length=max(0.5 * radius, 2 * np.pi * float(rr.max()) / 12))
    info.update(nodes=len(pos), leaves=len(leaves), height=height, root_radii=rr.tolist())
    return XuResult(skeleton, TriMesh.concatenate([wood, leaf_mesh]), leaves, info)


def _leaf_quads(locs, density, snode, pos, par, bare_pos, size, params: XuParams, rng):
    """Section 6: normal (SL x d) x SL, slightly perturbed; density bins -> 1..leaf_bins leaves per quad (side
    proportional to sqrt(count): area proportional to the number of leaves); bare twigs get random clusters."""
    d = node_directions(pos, par)
    k = len(locs)
    count = np.ones(k, np.int64)
    if k:
        order = np.argsort(-density, kind="stable")
        count[order] = 1 + (np.arange(k) * params.leaf_bins) // k
    sl = unit(locs - pos[snode]) if k else np.zeros((0, 3))
    normal = np.cross(np.cross(sl, d[snode]), sl) if k else np.zeros((0, 3))
    # extra leaves at the tips of the kept bare twigs (random cluster size)
    if len(bare_pos):
        tree_nodes = cKDTree(pos).query(bare_pos, k=1)[1]
        extra_dir = d[tree_nodes]
        locs = np.concatenate([locs, bare_pos + 0.5 * size * extra_dir])
        snode = np.concatenate([snode, tree_nodes])
        sl = np.concatenate([sl, extra_dir])
        normal = np.concatenate([normal, np.cross(np.cross(extra_dir, [0.0, 0.0, 1.0]), extra_dir)])
        count = np.concatenate([count, rng.integers(1, params.leaf_bins + 1, len(bare_pos))])
    if len(locs) == 0:
        return TriMesh.empty(), []
    jitter = rng.normal(0.0, np.radians(params.leaf_jitter_deg), (len(locs), 3))
    normal = unit(unit(normal) + jitter)
    length = size * np.sqrt(count)
    frames = leaf_frames(locs - 0.5 * length[:, None] * sl, sl, normal)
    extra = [{"model": "quad", "leaves": int(c)} for c in count]
    return quad_leaves(frames, length, 0.5 * length, snode, extra)
