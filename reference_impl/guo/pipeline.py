"""The Guo et al. pipeline (Guo et al. 2018, section 5; Guo et al. 2017) as pure functions over a point cloud.

1. ground removal (reference_impl.common.ground; a scan has ground hits, the mvs cloud has none) and removal of
   isolated points (distance to the 8th neighbour above 4 times the median) [S];
2. Eq. 8 weights: PCA main direction per point (its eps_D ball), count of neighbours within eps_D whose
   direction agrees above eps_A (reference_impl.guo.weights);
3. roots: ground-plane density clusters of the lowest slab, the top k for a k-stem species (Fig. 9); trunk radius
   from a cross-section circle fit (reference_impl.guo.roots);
4. markers: the points merged per half-internode voxel with summed weights; for an occluded crown, Poisson-disk
   samples of the crown's convex hull (Fig. 8, reference_impl.guo.hull);
5. growth: L-system 1 with space colonisation, logistic influence distance (Eq. 6-7; 4 l with the default clamp),
   growth direction Eq. 9, Eq. 5 radii and shedding on the fly (reference_impl.guo.growth);
6. leaves at the nodes of thin branches near the tips, placed with the species hint's leaf configuration
   (reference_impl.guo.leaves: arrangement, mean length, phi as the divergence; generic Bezier blade) before the
   skeleton is simplified, then turned about
   their bases into the cloud around them (the leaf configuration of [40] "considering ... the normal direction";
   :func:`orient_leaves`); only the leaves whose blades lie on the cloud are kept, one per observed leaf
   (:func:`select_leaves`) [S: procedural leaves off the cloud contradict the data; docs/tuning/guo.md];
7. branch collapse and Hermite smoothing at 20 deg (reference_impl.guo.refine), Eq. 5 radii on the final skeleton;
8. generalised-cylinder branches (reference_impl.common.geometry.branch_mesh, plantbench.geometry.tubes).

:func:`prepare` does steps 1-4 once (they depend on the cloud and the internode length only), :func:`model` steps
5-8 for one parameter set, so analysis-by-synthesis (reference_impl.guo.abs) grows many candidates from one
preparation.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from plantbench.geometry import vectors
from plantbench.plant import Leaf, Skeleton, TriMesh
from reference_impl.common.geometry import branch_mesh
from reference_impl.common.graph import edge_lengths, median_spacing, voxel_downsample
from reference_impl.common.ground import Ground
from reference_impl.common.inputs import plant_height, split_ground
from reference_impl.common.roots import breast_height_scale, recentre_stems, refuse_implausible_radii
from reference_impl.common.skeleton_ops import branch_orders, remove_nodes, simplify, trim_unsupported_tips
from reference_impl.guo.growth import allometric_radii, grow
from reference_impl.guo.hull import crown_mask, poisson_disk_in_hull, shell_ratio
from reference_impl.guo.leaves import LeafConfig, PlacedLeaves, place_leaves
from reference_impl.guo.params import GENERIC_PRIOR, GuoParams, SpeciesPrior
from reference_impl.guo.refine import collapse, smooth
from reference_impl.guo.roots import density_roots, root_axes_and_radii
from reference_impl.guo.weights import eq8_weights

__all__ = ["Prepared", "GuoResult", "prepare", "model", "reconstruct_guo", "generic_leaves", "orient_leaves",
           "select_leaves", "merge_leaves"]

GENERIC_LEAF_LENGTH = 0.06
"""Blade length of the generic leaf (no species prior), metres [S: a mid-sized broadleaf]."""


@dataclass(frozen=True)
class Prepared:
    """Everything computed once from the cloud."""

    plant: np.ndarray
    """(n, 3) plant points (ground removed)."""
    ground: Ground
    height: float
    """Plant height above the ground, metres."""
    extent: float
    """Largest bounding-box side, metres."""
    markers: np.ndarray
    """(m, 3) growth markers (merged points, then hull samples)."""
    weights: np.ndarray
    """(m,) Eq. 8 weight of each marker (summed over its points; 1 for a hull sample)."""
    hull_samples: int
    """How many of the markers are hull samples (the last ones)."""
    roots: np.ndarray
    """(k, 3) root positions on the ground."""
    axes: np.ndarray
    """(k, 3) stem axes at the roots."""
    root_radii: np.ndarray
    """(k,) trunk radii from the cross-section fit."""
    info: dict
    spacing: float
    """Median nearest-neighbour spacing of the plant points, metres."""


@dataclass(frozen=True)
class GuoResult:
    skeleton: Skeleton
    mesh: TriMesh
    leaves: list[Leaf]
    info: dict


def generic_leaves() -> LeafConfig:
    """The leaf configuration without a species hint: a :data:`GENERIC_LEAF_LENGTH` blade, spiral arrangement."""
    return LeafConfig(length=GENERIC_LEAF_LENGTH)


def prepare(points: np.ndarray, rng: np.random.Generator, params: GuoParams = GuoParams(),
            prior: SpeciesPrior = GENERIC_PRIOR) -> Prepared:
    """Steps 1-4. points : (n, 3) float (metres, Z up). Raises InputError on too few or degenerate points."""
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    pts, ground, plant = split_ground(points, rng)
    plant = _drop_isolated(plant, params)
    hgt, height = plant_height(plant, ground)
    extent = float(np.ptp(plant, axis=0).max())
    ell = prior.internode_length
    timings["ground"] = time.perf_counter() - t0

    # Eq. 8
    t0 = time.perf_counter()
    tree = cKDTree(plant)
    spacing = median_spacing(plant)
    eps_d = max(params.eps_d * extent / 10.0, params.eps_d_min_spacing * spacing)
    _, w = eq8_weights(plant, eps_d, params.eps_a, max_neighbours=params.weight_neighbours,
                       min_neighbours=params.pca_min_neighbours, tree=tree)
    timings["weights"] = time.perf_counter() - t0

    # roots and trunk radii
    t0 = time.perf_counter()
    slab = hgt < params.root_slab * height
    if prior.roots == 1:  # a single stem stands at the crown's centre
        offset = np.hypot(*(plant[:, :2] - np.median(plant[:, :2], axis=0)).T)
        central = slab & (offset <= params.root_central * np.percentile(offset, 90))
        if central.sum() >= 3:
            slab = central
    if slab.sum() < 3:
        slab = hgt <= np.partition(hgt, min(2, len(hgt) - 1))[min(2, len(hgt) - 1)]
    clusters = density_roots(plant[slab, :2], params.root_cell * ell, k=prior.roots,
                             min_density=params.root_min_density)
    gz = ground.coef[0] * clusters.centroids[:, 0] + ground.coef[1] * clusters.centroids[:, 1] + ground.coef[2]
    roots, axes, radii = root_axes_and_radii(plant, hgt, clusters.centroids, gz, height=height,
                                             fit_height=params.trunk_fit_height, fallback=max(ell / 2, 2 * spacing))
    radii = np.maximum(radii, prior.tip_radius)
    timings["roots"] = time.perf_counter() - t0

    # markers
    t0 = time.perf_counter()
    markers, labels, _ = voxel_downsample(plant, params.marker_voxel * ell)
    mw = np.bincount(labels, weights=w, minlength=len(markers))
    crown = plant[crown_mask(plant, hgt)]
    samples = np.zeros((0, 3))
    ratio = 1.0
    used = False
    if params.hull_fill != "off" and len(crown) >= 4:
        ratio = shell_ratio(crown, rng)
        used = params.hull_fill == "on" or ratio < params.hull_shell_ratio
        if used:
            samples, _ = poisson_disk_in_hull(crown, params.hull_spacing * ell, rng,
                                              max_samples=params.hull_max_samples)
    if len(samples):
        markers = np.concatenate([markers, samples])
        mw = np.concatenate([mw, np.ones(len(samples))])
    timings["markers"] = time.perf_counter() - t0
    info = {
        "points": len(pts), "plant_points": len(plant), "ground_found": bool(ground.found), "height": height,
        "eps_d": eps_d, "weight_mean": float(w.mean()), "weight_max": float(w.max()), "roots": len(roots),
        "root_radii": radii.tolist(), "root_density": clusters.density.tolist(), "markers": len(markers),
        "hull_samples": len(samples), "hull_shell_ratio": ratio, "hull_fill": used, "timings": timings,
    }
    return Prepared(plant, ground, height, extent, markers, mw, len(samples), roots, axes, radii, info, spacing)


def _drop_isolated(plant: np.ndarray, params: GuoParams) -> np.ndarray:
    """``plant`` without its isolated points: those whose distance to their ``outlier_neighbours``-th neighbour
    exceeds ``outlier_factor`` times the median of that distance (multi-view stereo floaters would attract branches
    across empty space)."""
    if len(plant) <= params.outlier_neighbours + 1:
        return plant
    d, _ = cKDTree(plant).query(plant, k=params.outlier_neighbours + 1, workers=-1)
    dk = d[:, -1]
    return plant[dk <= params.outlier_factor * np.median(dk)]


def _leaves(pos, parents, radii, lateral, config: LeafConfig, rng, tip_internodes: int) -> PlacedLeaves:
    """Leaves (:func:`reference_impl.guo.leaves.place_leaves`) on the thin nodes at most ``tip_internodes``
    internodes below a tip ("distributed at the tip nodes along branch directions", section 5.3; 0: every thin
    node)."""
    from plantbench.geometry.tubes import node_frames

    main = (parents >= 0) & ~lateral
    tangent, normal, _, _ = node_frames(pos, parents, main)
    levels = vectors.levels(parents)
    eligible = np.ones(len(parents), bool)
    if tip_internodes > 0:
        above = np.zeros(len(parents), np.int64)       # internodes from a node up to its farthest tip
        for idx in reversed(levels):
            c = idx[parents[idx] >= 0]
            np.maximum.at(above, parents[c], above[c] + 1)
        eligible = above < tip_internodes
    return place_leaves(pos, parents, radii, main, tangent, normal, levels, eligible, config, rng)


def _blades(verts: np.ndarray, m: int) -> tuple[int, np.ndarray]:
    """Vertices per blade and the (m, q, 3) blade view of a foliage mesh's vertices: m blades of q vertices each,
    then m 6-vertex petioles (the layout of :func:`reference_impl.guo.leaves.place_leaves`)."""
    q = (len(verts) - 6 * m) // m
    return q, verts[: m * q].reshape(m, q, 3)


def orient_leaves(foliage, cloud_tree: cKDTree, cloud: np.ndarray, *, min_points: int = 5):
    """Data-driven leaf configuration: a leaf with cloud points near it moves onto the leaf the cloud saw.

    For each leaf, the cloud point nearest its blade centre (within one leaf length) becomes the new blade centre;
    the cloud within half a leaf length of that point gives the blade's plane (normal = smallest principal
    direction) and axis (largest principal direction, pointing away from the twig). The petiole stretches from the
    twig to the moved blade base. Leaves with no cloud point within one leaf length, or fewer than ``min_points``
    points around it (occluded parts), keep the species' procedural placement.

    Returns ``(mesh, leaves, moved)``: the new foliage mesh and leaves, and how many leaves moved.
    """
    leaves = foliage.leaves
    m = len(leaves)
    if m == 0:
        return foliage.mesh, leaves, 0
    verts = foliage.mesh.vertices.copy()
    q, blade = _blades(verts, m)
    base = np.array([lf.transform[:3, 3] for lf in leaves])
    rot = np.array([lf.transform[:3, :3] for lf in leaves])
    length = np.array([lf.length for lf in leaves])
    centre = blade.mean(axis=1)
    dist, near = cloud_tree.query(centre, k=1, workers=-1)
    snap = cloud[np.minimum(near, len(cloud) - 1)]
    lists = cloud_tree.query_ball_point(snap, 0.5 * length, workers=-1)
    cnt = np.fromiter((len(x) for x in lists), np.int64, m)
    ok = (dist <= length) & (cnt >= min_points)
    if not ok.any():
        return foliage.mesh, leaves, 0
    flat = np.concatenate([np.asarray(x, np.int64) for x, good in zip(lists, ok) if good])
    owner = np.repeat(np.flatnonzero(ok), cnt[ok])
    mean = np.zeros((m, 3))
    np.add.at(mean, owner, cloud[flat])
    mean[ok] /= cnt[ok, None]
    d = cloud[flat] - mean[owner]
    cov = np.zeros((m, 3, 3))
    np.add.at(cov, owner, d[:, :, None] * d[:, None, :])
    idx = np.flatnonzero(ok)
    _, vec = np.linalg.eigh(cov[idx] + 1e-12 * np.eye(3))
    nz, x = vec[:, :, 0], vec[:, :, 2]
    nz = np.where(np.sum(nz * rot[idx, :, 2], 1, keepdims=True) < 0, -nz, nz)
    x = np.where(np.sum(x * (snap[idx] - base[idx]), 1, keepdims=True) < 0, -x, x)
    new_rot = np.stack([x, np.cross(nz, x), nz], axis=2)
    # blade vertices in the old leaf frame about the blade centre, re-posed about the snapped point
    local = np.einsum("kji,kqj->kqi", rot[idx], blade[idx] - centre[idx, None, :])
    blade[idx] = np.einsum("kij,kqj->kqi", new_rot, local) + snap[idx, None, :]
    new_base = snap[idx] + np.einsum("kij,kj->ki", new_rot, np.einsum("kji,kj->ki", rot[idx], base[idx] - centre[idx]))
    verts[: m * q] = blade.reshape(-1, 3)
    pet = verts[m * q:].reshape(m, 6, 3)
    pet[idx, 3:] += (new_base - base[idx])[:, None, :]
    verts[m * q:] = pet.reshape(-1, 3)
    out = list(leaves)
    for j, i in enumerate(idx):
        t = leaves[i].transform.copy()
        t[:3, :3] = new_rot[j]
        t[:3, 3] = new_base[j]
        out[i] = replace(leaves[i], transform=t)
    return TriMesh(verts, foliage.mesh.faces), out, int(len(idx))


LEAF_SUPPORT_LENGTH = 0.1
"""Floor of the leaf-support scale, as a fraction of the leaf's length (a procedural blade differs from the observed
one by about this much) [S]."""


def select_leaves(mesh: TriMesh, leaves: list[Leaf], cloud_tree: cKDTree, spacing: float, *, support: float,
                  dedup: bool) -> tuple[TriMesh, list[Leaf], dict]:
    """Keep the leaves the cloud supports, one per observed leaf.

    ``mesh`` holds the leaves' blades first (the same number of vertices per leaf) then their 6-vertex petioles,
    as :func:`reference_impl.guo.leaves.place_leaves` and :func:`orient_leaves` write it. A leaf's support
    residual is the mean distance of its blade vertices to the cloud; leaves with a residual above ``support`` x
    max(``spacing``, :data:`LEAF_SUPPORT_LENGTH` x the leaf's length) are dropped (``support`` 0 keeps all): on a
    dense clean cloud the spacing alone would demand more than a procedural blade's shape can match
    (docs/tuning/guo.md). With ``dedup``, leaves are then taken in increasing residual and one whose blade centre
    is within half a leaf length of a kept leaf's is dropped.

    Returns the kept leaves' mesh, the kept leaves and counts ``{"unsupported": .., "duplicates": ..}``.
    """
    m = len(leaves)
    counts = {"unsupported": 0, "duplicates": 0}
    if m == 0:
        return mesh, leaves, counts
    verts = mesh.vertices
    q, blade = _blades(verts, m)
    length = np.array([lf.length for lf in leaves])
    resid, supported = leaf_support(blade, length, cloud_tree, spacing, support)
    keep = supported
    counts["unsupported"] = int(m - keep.sum())
    if dedup and keep.any():
        centre = blade.mean(axis=1)
        cand = np.flatnonzero(keep)
        cand = cand[np.argsort(resid[cand], kind="stable")]
        tree = cKDTree(centre[cand])
        taken = np.zeros(len(cand), bool)
        gone = np.zeros(len(cand), bool)
        for k in range(len(cand)):
            if gone[k]:
                continue
            taken[k] = True
            near = tree.query_ball_point(centre[cand[k]], 0.5 * length[cand[k]])
            gone[near] = True
        keep[:] = False
        keep[cand[taken]] = True
        counts["duplicates"] = int(len(cand) - taken.sum())
    if keep.all():
        return mesh, leaves, counts
    new_mesh, kept = _subset_foliage(mesh, leaves, keep)
    return new_mesh, kept, counts


def leaf_support(blade: np.ndarray, length: np.ndarray, cloud_tree: cKDTree, spacing: float, support: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Support residual of each blade (mean distance of its (m, q, 3) vertices to the cloud) and whether it is at most
    ``support`` x max(``spacing``, :data:`LEAF_SUPPORT_LENGTH` x the leaf's length) (``support`` 0: all kept)."""
    m, q = blade.shape[:2]
    resid = cloud_tree.query(blade.reshape(-1, 3), k=1, workers=-1)[0].reshape(m, q).mean(axis=1)
    if support <= 0:
        return resid, np.ones(m, bool)
    return resid, resid <= support * np.maximum(spacing, LEAF_SUPPORT_LENGTH * length)


def supported_fitted(fitted: tuple[TriMesh, list[Leaf]], cloud_tree: cKDTree, spacing: float, support: float
                     ) -> tuple[tuple[TriMesh, list[Leaf]], int]:
    """The image-fitted leaves (mesh of equal blade blocks, as reference_impl.leaves.fitted_mesh writes it) that
    the plant cloud supports (:func:`leaf_support`): a leaf fitted to ground or background depth that the
    multi-view fusion rejected lies off the cloud. Returns them and how many were dropped."""
    mesh, leaves = fitted
    m = len(leaves)
    if m == 0:
        return fitted, 0
    q = len(mesh.vertices) // m
    _, keep = leaf_support(mesh.vertices.reshape(m, q, 3), np.array([lf.length for lf in leaves]), cloud_tree,
                           spacing, support)
    if keep.all():
        return fitted, 0
    return _subset_leaves(mesh, leaves, keep, np.repeat(np.arange(m), q)), int(m - keep.sum())


def _subset_foliage(mesh: TriMesh, leaves: list[Leaf], keep: np.ndarray) -> tuple[TriMesh, list[Leaf]]:
    """The leaves with ``keep`` True (renumbered) and their part of a place_leaves-layout foliage mesh."""
    m = len(leaves)
    q, _ = _blades(mesh.vertices, m)
    owner = np.concatenate([np.repeat(np.arange(m), q), np.repeat(np.arange(m), 6)])  # blades, then petioles
    return _subset_leaves(mesh, leaves, keep, owner)


def _subset_leaves(mesh: TriMesh, leaves: list[Leaf], keep: np.ndarray, owner: np.ndarray
                   ) -> tuple[TriMesh, list[Leaf]]:
    """The kept leaves (renumbered) and the part of ``mesh`` whose vertices they own (``owner``: leaf per vertex)."""
    vkeep = keep[owner]
    remap = np.cumsum(vkeep) - 1
    faces = mesh.faces[vkeep[mesh.faces].all(axis=1)]
    kept = [replace(leaves[i], id=j) for j, i in enumerate(np.flatnonzero(keep))]
    return TriMesh(mesh.vertices[vkeep], remap[faces]), kept


def merge_leaves(mesh: TriMesh, leaves: list[Leaf], fitted: tuple[TriMesh, list[Leaf]]
                 ) -> tuple[TriMesh, list[Leaf], int]:
    """Image-fitted leaves (``fitted``: mesh and leaves) plus the procedural leaves that none of them covers (blade
    centre farther than half the procedural leaf's length from every fitted leaf's): what the cameras resolved as a
    leaf is taken from the images, the rest of the crown keeps the species' leaves. Returns the mesh (fitted blades
    first), the leaves (renumbered) and how many procedural leaves were replaced."""
    fit_mesh, fit_leaves = fitted
    if not leaves or not fit_leaves:
        keep = np.ones(len(leaves), bool)
    else:
        _, blade = _blades(mesh.vertices, len(leaves))
        d, _ = cKDTree(np.array([lf.centroid for lf in fit_leaves])).query(blade.mean(axis=1), k=1)
        keep = d > 0.5 * np.array([lf.length for lf in leaves])
    proc_mesh, proc = _subset_foliage(mesh, leaves, keep) if len(leaves) else (mesh, leaves)
    out = [replace(lf, id=i) for i, lf in enumerate(list(fit_leaves) + proc)]
    return TriMesh.concatenate([fit_mesh, proc_mesh]), out, int(len(leaves) - keep.sum())


def model(prep: Prepared, prior: SpeciesPrior, params: GuoParams, rng: np.random.Generator,
          fitted: tuple[TriMesh, list[Leaf]] | None = None, merge: bool = False) -> GuoResult:
    """Steps 5-8 for one parameter set. ``fitted``: leaves segmented and fitted from the images
    (:func:`reference_impl.leaves.segment_and_fit`, their mesh and Leaf instances) replace step 6's procedural
    leaves, or with ``merge`` replace those they cover (:func:`merge_leaves`)."""
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    ell = prior.internode_length
    g = grow(prep.markers, prep.weights, prep.roots, prep.axes, prep.root_radii, prep.height, prior, params)
    timings["growth"] = time.perf_counter() - t0

    gpos, gpar, grad, glat = g.positions, g.parents, g.radii, g.lateral
    if params.prune_tips > 0 or params.merge_forks > 0:  # the crown grown, its spurious forks and twigs shed
        gpos, gpar, grad, kept = simplify(gpos, gpar, grad,
                                          prune_tips=min(params.prune_tips * ell, params.prune_cap * prep.height),
                                          merge_forks=params.merge_forks * ell)
        glat = glat[kept]
    cloud_tree = cKDTree(prep.plant)
    trimmed = 0.0
    if params.trim_tips > 0:  # shoots that grew on past the data, trimmed back to it
        data = cloud_tree if prep.hull_samples == 0 else cKDTree(np.r_[prep.plant, prep.markers[-prep.hull_samples:]])
        keep = trim_unsupported_tips(gpar, data.query(gpos)[0], params.trim_tips * ell)
        trimmed = float(edge_lengths(gpos, gpar)[~keep].sum())
        gpar, _ = remove_nodes(gpar, keep)
        gpos, grad, glat = gpos[keep], grad[keep], glat[keep]
    t0 = time.perf_counter()
    placed, turned, dropped, replaced_, off_cloud = 0, 0, {"unsupported": 0, "duplicates": 0}, 0, 0
    if fitted is not None:
        fitted, off_cloud = supported_fitted(fitted, cloud_tree, prep.spacing, params.leaf_support)
    if fitted is None or merge:
        foliage = _leaves(gpos, gpar, grad, glat, prior.leaves or generic_leaves(), rng,
                          params.leaf_tip_internodes)
        placed = len(foliage.leaves)
        leaf_mesh, leaves = foliage.mesh, foliage.leaves
        if params.leaf_fit:
            leaf_mesh, leaves, turned = orient_leaves(foliage, cloud_tree, prep.plant)
        leaf_mesh, leaves, dropped = select_leaves(leaf_mesh, leaves, cloud_tree, prep.spacing,
                                                   support=params.leaf_support, dedup=params.leaf_dedup)
        if fitted is not None:
            leaf_mesh, leaves, replaced_ = merge_leaves(leaf_mesh, leaves, fitted)
    else:
        leaf_mesh, leaves = fitted
    timings["leaves"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    keep, par = collapse(gpos, gpar, grad, max_angle_deg=params.collapse_angle,
                         max_radius_change=params.collapse_radius)
    pos, par, _ = smooth(gpos[keep], par, angle_deg=params.smooth_angle, min_spacing=0.25 * ell)
    rad = allometric_radii(pos, par, prep.root_radii, prior.diameter_coefficient, levels=vectors.levels(par))
    rad = np.maximum(rad, 0.5 * prior.tip_radius)
    if params.stem_sections:
        pos, par, rad, _ = recentre_stems(prep.plant, pos, par, rad, height=prep.height)
    if params.breast_height_fit:
        rad = rad * breast_height_scale(prep.plant, pos, par, rad)
    refuse_implausible_radii(rad, prep.height, "guo")
    skeleton = Skeleton(pos, rad, par, branch_orders(par, rad))
    timings["refine"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    if leaves:
        base = np.array([lf.transform[:3, 3] for lf in leaves])
        _, near = cKDTree(pos).query(base, k=1)
        leaves = [replace(lf, node=int(j)) for lf, j in zip(leaves, near)]
    wood = branch_mesh(skeleton, edge_length=0.5 * ell)
    mesh = TriMesh.concatenate([wood, leaf_mesh])
    timings["mesh"] = time.perf_counter() - t0
    info = {
        "iterations": g.iterations, "growth_nodes": len(g.positions), "shed_nodes": g.shed_nodes,
        "markers_left": g.markers_left, "trimmed_length_m": trimmed, "nodes": len(pos), "leaves": len(leaves),
        "leaves_fitted": turned,
        "leaves_placed": placed, "leaves_from_images": 0 if fitted is None else len(fitted[1]),
        "leaves_replaced": replaced_, "leaves_from_images_off_cloud": off_cloud, "leaves_unsupported": dropped["unsupported"],
        "leaves_duplicate": dropped["duplicates"],
        "internode_length": ell, "roll_angle": prior.roll_angle, "branching_angle": prior.branching_angle,
        "diameter_coefficient": prior.diameter_coefficient, "timings": timings,
        "history": g.history,
    }
    return GuoResult(skeleton, mesh, leaves, info)


def reconstruct_guo(points: np.ndarray, rng: np.random.Generator, params: GuoParams = GuoParams(),
                    prior: SpeciesPrior = GENERIC_PRIOR, fitted: tuple[TriMesh, list[Leaf]] | None = None,
                    merge: bool = False) -> GuoResult:
    """One reconstruction (no analysis-by-synthesis): :func:`prepare` then :func:`model` (``fitted``: see there)."""
    prep = prepare(points, rng, params, prior)
    res = model(prep, prior, params, rng, fitted, merge)
    return GuoResult(res.skeleton, res.mesh, res.leaves, {"prepare": prep.info} | res.info)

