"""Roots of a plant cloud and stem anchoring.

- :func:`plant_groups`: separate plants in one cloud (connected occupied voxels).
- :func:`find_roots`: the lowest vertex of each central connected cluster of the lowest slab (AdTree uses the bottom
  2 % of the height; Livny allows several roots, which covers multi-stem shrubs): one root per stem base.
- :func:`stem_radius`: the trunk radius of a stem from a cylinder fit (reference_impl.common.radii.fit_trunk_radius)
  around the first part of the skeleton from that root; :func:`stem_radii` for every stem, along one axis or the
  best of several (:func:`candidate_axes`).
- :func:`anchor_roots`: add a node on the ground plane under each root, so skeletons start on the ground like the
  ground truth does (ground removal trimmed the stem's lowest centimetres).
- :func:`fit_stems` and :func:`finish_stems`: the steps livny and xu share, the stems' base radii fitted along
  the candidate axes, then the ground nodes, the breast-height scale and the plausibility check.
- :func:`recentre_stems`: each stem's lowest stretch moved onto the axis of circles fitted to the cloud's stem
  sections (a skeleton grown from a thick trunk's bark runs along the bark).
- :func:`breast_height_scale`: the factor that brings a skeleton's stem radius at breast height to the radius the
  cloud shows there (DBH measured, not extrapolated from the base).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from plantbench.errors import PlantbenchError
from plantbench.geometry.vectors import perpendicular, unit
from plantbench.plant import Skeleton
from plantbench.skeletons import stem_at_height
from reference_impl.common.graph import children_csr
from reference_impl.common.radii import fit_trunk_radius
from reference_impl.common.skeleton_ops import remove_nodes

__all__ = ["StemFitParams", "plant_groups", "find_roots", "stem_radius", "stem_radii", "candidate_axes", "trunk_axes",
           "half_gaps", "anchor_roots", "breast_height_scale", "refuse_implausible_radii", "fit_stems",
           "finish_stems", "recentre_stems"]


@dataclass(frozen=True)
class StemFitParams:
    """The stem-fit parameters livny and xu share (their parameter dataclasses extend it)."""

    breast_height_fit: bool = True
    """Scale every radius so the stem's radius 1.3 m above the base matches a circle fitted to the cloud there, on
    plants taller than 3 m whose stem shows bark at breast height (:func:`reference_impl.common.roots.
    breast_height_scale`): the base fit takes in the root flare and the allometric taper overshoots the DBH [S]."""
    min_radius_fraction: float = 0.0005
    """Smallest radius, fraction of the plant height (0.5 mm on a 1 m plant) [S]."""
    trunk_fit_fraction: float = 0.05
    """Base radius fitted to the cloud over this fraction of the height above the root (Xu et al. section 5.2: from
    the scan) [S]."""
    stem_sections: bool = True
    """Move each stem's lowest 30 % onto the axis of circles fitted to the cloud's stem sections where they are one
    stem's bark ring (:func:`reference_impl.common.roots.recentre_stems`): a skeleton grown from the bark of a thick
    trunk runs along its bark [S: docs/tuning/xu.md]. False: the stems stay where the skeleton put them."""
    trunk_axis_candidates: bool = True
    """The trunk cylinder is fitted along the method's own axis at the root (livny: the orientation field; xu: the
    root's first edge), along the stem's first ``trunk_fit_fraction`` of the height (the heaviest-child chain) and
    along the vertical, and the circle the most points lie on is kept (:func:`stem_radii`): along a skewed axis, a
    fit about a root on the bark closes a small circle on a patch of the bark, and which axis is skewed flips with a
    few centimetres of the root's position (AdTree's tree7: 2 or 12 cm; the multiview wp_oak: 5 or 32 cm; the patch
    circle holds 4 points, the bark 700-1000) [S: docs/tuning/xu.md]. False: the method's own axis alone."""


def plant_groups(positions: np.ndarray, cell: float) -> np.ndarray:
    """(n,) label of each point's plant: connected groups of occupied ``cell``-sized voxels (26-neighbourhood)."""
    from scipy import ndimage

    key = np.floor((positions - positions.min(0)) / cell).astype(np.int64)
    shape = key.max(0) + 1
    if np.prod(shape) > 50_000_000:  # absurdly fine cells for the extent: everything is one plant
        return np.zeros(len(positions), np.int64)
    grid = np.zeros(shape, bool)
    grid[tuple(key.T)] = True
    lab, _ = ndimage.label(grid, structure=np.ones((3, 3, 3), bool))
    return lab[tuple(key.T)].astype(np.int64) - 1


def find_roots(positions: np.ndarray, heights: np.ndarray, graph: sp.csr_matrix, *, slab: float,
               group_cell: float, min_fraction: float = 0.2, min_group_fraction: float = 0.05,
               max_roots: int = 16, central_fraction: float = 0.4) -> np.ndarray:
    """Root vertices, one per stem base.

    The cloud is first split into plants (:func:`plant_groups` with ``group_cell``; groups holding at least
    ``min_group_fraction`` of the vertices count). In each plant, the lowest slab (``heights < min + slab``) is split
    into the connected components of ``graph``; components holding at least ``min_fraction`` of the largest one's
    vertices and lying within ``central_fraction`` of the plant's crown radius (90th percentile of the horizontal
    distances from its median x, y) of its centre are stem bases (at most ``max_roots``), each rooted at its lowest
    vertex. Leaves hanging down to the ground at the crown's rim are thus not taken for stems [S: in Xu et al. 2007 the
    user picks the root; a leafy shrub scanned from one side may show low leaves and no stem base]. When no slab
    component is central, the root is the plant's lowest vertex within that central radius (the occluded stem's
    lowest visible part), else its lowest vertex.
    """
    groups = _join_stem_bases(positions, heights, plant_groups(positions, group_cell), min_group_fraction,
                              central_fraction)
    sizes = np.bincount(groups)
    roots: list[int] = []
    for gid in np.flatnonzero(sizes >= min_group_fraction * len(positions)):
        members = np.flatnonzero(groups == gid)
        roots.extend(int(members[r]) for r in _roots_of_plant(positions[members], heights[members],
                                                               graph[members][:, members], slab, min_fraction,
                                                               central_fraction))
    if not roots:
        roots = [int(np.argmin(heights))]
    return np.asarray(sorted(roots)[:max_roots], np.int64)


def _join_stem_bases(positions: np.ndarray, heights: np.ndarray, groups: np.ndarray, min_group_fraction: float,
                     central_fraction: float) -> np.ndarray:
    """``groups`` with each small group (under ``min_group_fraction`` of the vertices) that lies lower than a plant
    group and within ``central_fraction`` of its crown radius of its centre joined to that plant: a stem base cut off
    from its crown by a gap in the scan (an occluded or unscanned stretch of the trunk) [S: AdTree's tree13 has no
    points between about 1 and 2 m, and its crown alone would be rooted at 2 m]."""
    sizes = np.bincount(groups)
    small = np.flatnonzero(sizes < min_group_fraction * len(positions))
    out = groups.copy()
    for gid in np.flatnonzero(sizes >= min_group_fraction * len(positions)):
        members = groups == gid
        centre, central, _ = _crown_centre(positions[members], central_fraction)
        low = float(heights[members].min())
        for sid in small:
            sm = groups == sid
            if (heights[sm].min() < low and heights[sm].max() <= low
                    and np.hypot(*(positions[sm, :2].mean(0) - centre)) <= central):
                out[sm] = gid
    return out


def _crown_centre(positions: np.ndarray, central_fraction: float) -> tuple[np.ndarray, float, np.ndarray]:
    """A plant's centre (median x, y), the central radius (``central_fraction`` of the crown radius, the 90th
    percentile of the horizontal distances from the centre) and those distances."""
    centre = np.median(positions[:, :2], axis=0)
    hdist = np.hypot(*(positions[:, :2] - centre).T)
    return centre, central_fraction * max(float(np.percentile(hdist, 90)), 1e-12), hdist


def _roots_of_plant(positions, heights, graph, slab, min_fraction, central_fraction) -> list[int]:
    centre, central, hdist = _crown_centre(positions, central_fraction)
    low = float(np.min(heights))
    in_slab = np.flatnonzero(heights <= low + slab)
    if len(in_slab) > 1:
        sub = graph[in_slab][:, in_slab]
        ncomp, lab = csgraph.connected_components(sub, directed=False)
        sizes = np.bincount(lab, minlength=ncomp)
        cen = np.zeros((ncomp, 2))
        np.add.at(cen, lab, positions[in_slab, :2])
        cen /= sizes[:, None]
        ok = np.hypot(*(cen - centre).T) <= central
        if ok.any():
            good = np.flatnonzero(ok & (sizes >= min_fraction * sizes[ok].max()))
            good = good[np.argsort(-sizes[good], kind="stable")]
            return [int(in_slab[lab == c][np.argmin(heights[in_slab[lab == c]])]) for c in good]
    near = np.flatnonzero(hdist <= central)
    if len(near):
        return [int(near[np.argmin(heights[near])])]
    return [int(np.argmin(heights))]


def stem_radius(points: np.ndarray, base: np.ndarray, direction: np.ndarray, *, length: float, max_radius: float,
                fallback: float | None, windows: int = 5, on_bark: bool = False,
                in_stem: bool = False) -> tuple[float, np.ndarray] | None:
    """Trunk radius at a stem base from the cloud (cylinder fit along ``direction``). Returns ``(radius, axis point at
    the base)``; where no circle fits, ``(fallback, base)``, or None when ``fallback`` is None.

    The fit is repeated in windows around the axis doubling from ``max_radius / 2^(windows - 1)`` to ``max_radius``;
    the answer is the smallest window whose circle lies well inside it (|centre offset| + r <= 0.8 window) and agrees
    within 25 % with the next window's (a plateau: a window that cuts the stem gives too small a circle, one that
    takes in neighbouring stems of a shrub or low foliage too large a one); without a plateau, the smallest window
    holding its circle [S; AdTree refits within 3.5 r of a first estimate].

    With ``on_bark`` (``base`` is a point of the cloud, the lowest of a stem's base: on its bark, a radius off the
    axis, where on a stem thicker than the smallest windows they fit arcs of its bark), the windows are tried again
    about the centre of the largest window's circle, and that answer wins when its circle is the larger, ``base``
    lies on it (within a quarter of its radius) and :func:`_bark_ring` finds the points near it to be one stem's
    hollow bark ring, not a circle through two stems or a ring of thin stems [S: docs/tuning/xu.md].
    With ``in_stem`` (``base`` lies inside the stem's cross-section, e.g. the centroid of a density cluster of its
    base), the same, but the answer needs ``base`` within its circle (a quarter of the radius of slack) instead of
    on it: on a trunk much wider than the smallest window, whose projection is a ring with a gap where the capture
    saw little, the centroid lies off the axis and the windows about it fit an arc of the bark (guo on
    wp_weeping_willow-2: 8.1 cm where the bark ring has 26 cm) [S].
    """
    fit = _nested_fit(points, base, direction, length, max_radius, windows)
    if on_bark or in_stem:
        ring = _ring_fit(points, base, direction, length, max_radius, windows, inside=in_stem)
        if ring is not None and (fit is None or ring[0] > fit[0]):
            fit = ring
    if fit is None and fallback is not None:
        return float(fallback), np.asarray(base, float)
    return fit


def _ring_fit(points: np.ndarray, base: np.ndarray, direction: np.ndarray, length: float, max_radius: float,
              windows: int, inside: bool = False) -> tuple[float, np.ndarray] | None:
    """:func:`stem_radius`'s windows about the centre of the largest window's circle, where ``base`` lies on the
    circle they find (``inside``: within it) and :func:`_bark_ring` takes the points around it for one stem's bark;
    else None."""
    r_all, c_all = fit_trunk_radius(points, base, direction, length=length, max_radius=max_radius, strict=True)
    if not (np.isfinite(r_all) and r_all > 0):
        return None
    fit = _nested_fit(points, c_all, direction, length, max_radius, windows)
    if fit is None:
        return None
    r, centre = fit
    off = float(np.linalg.norm(_perp(base - centre, direction)))
    on_it = off <= 1.25 * r if inside else abs(off - r) <= 0.25 * r
    return fit if on_it and _bark_ring(*_on_circle(points, centre, direction, r, length)) else None


def _cylinder_coords(points: np.ndarray, centre: np.ndarray, direction: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each point's position along the axis through ``centre`` (``direction``, normalised here), its offset across
    the axis and that offset's length: ``(t (n,), perp (n, 3), d (n,))``."""
    axis = np.asarray(direction, float) / max(np.linalg.norm(direction), 1e-12)
    rel = points - centre
    t = rel @ axis
    perp = rel - t[:, None] * axis
    return t, perp, np.linalg.norm(perp, axis=1)


def _on_circle(points: np.ndarray, centre: np.ndarray, direction: np.ndarray, r: float, length: float
               ) -> tuple[float, float, float]:
    """Of the points within ``length`` above ``centre`` along ``direction`` and 1.5 ``r`` of the axis: the share
    within 0.2 ``r`` of the circle (near 1 for one stem's bark, low for a circle spanning two stems), and the share
    of 36 sectors about the axis those points reach (most of them for a bark ring, a few for a ring of thin stems),
    and the share inside 0.6 ``r`` (none in a hollow bark ring)."""
    t, perp, d = _cylinder_coords(points, centre, direction)
    axis = np.asarray(direction, float) / max(np.linalg.norm(direction), 1e-12)
    sel = (t >= 0) & (t <= length) & (d <= 1.5 * r)
    if not sel.any():
        return 0.0, 0.0, 1.0
    on = sel & (np.abs(d - r) <= 0.2 * r)
    u = perpendicular(axis[None, :])[0]
    v = np.cross(axis, u)
    sector = np.floor((np.arctan2(perp[on] @ v, perp[on] @ u) + np.pi) / (2 * np.pi) * 36).astype(np.int64) % 36
    return float(on.sum() / sel.sum()), len(np.unique(sector)) / 36.0, float(np.mean(d[sel] < 0.6 * r))


def _bark_ring(on: float, sectors: float, inside: float) -> bool:
    """Whether :func:`_on_circle`'s shares describe one stem's bark: 60 % of the points on it, reaching three
    quarters of the sectors, at most a tenth inside [S: docs/tuning/xu.md]."""
    return on >= 0.6 and sectors >= 0.75 and inside <= 0.1


def _nested_fit(points: np.ndarray, base: np.ndarray, direction: np.ndarray, length: float, max_radius: float,
                windows: int) -> tuple[float, np.ndarray] | None:
    """:func:`stem_radius`'s nested windows about ``base``: (radius, axis point), or None when no circle fits."""
    fits = []
    for k in range(windows - 1, -1, -1):
        window = max_radius / 2**k
        r, centre = fit_trunk_radius(points, base, direction, length=length, max_radius=window, strict=True)
        inside = bool(np.isfinite(r) and r > 0
                      and np.linalg.norm(_perp(centre - base, direction)) + r <= 0.8 * window)
        fits.append((r, centre, inside))
    for (r, centre, inside), (r2, _, _) in zip(fits[:-1], fits[1:]):
        if inside and np.isfinite(r2) and abs(r2 - r) <= 0.25 * r:
            return float(r), centre
    for r, centre, inside in fits:
        if inside:
            return float(r), centre
    return None


def stem_radii(points: np.ndarray, roots: np.ndarray, axes: np.ndarray, *, offset: float, length: float,
               max_radius: float, fallback: float, min_radius: float) -> np.ndarray:
    """(k,) trunk radius of each stem, at least ``min_radius``: :func:`stem_radius` fitted from ``offset`` below
    the root along its stem axis, within ``max_radius`` and half the distance to the nearest other root (a stem is
    not wider than the gap to its neighbour); ``fallback`` where no circle fits. roots : (k, 3) root positions; axes :
    (k, 3) unit stem axes, or (c, k, 3) candidates (:func:`candidate_axes`), of whose circles each stem keeps the one
    the most points lie on (within a fifth of its radius, over the fitted length): the stem's bark, rather than a
    small circle closed on a patch of it along a skewed axis."""
    roots = np.asarray(roots, float)
    axes = np.asarray(axes, float).reshape(-1, len(roots), 3)
    reach = np.minimum(float(max_radius), half_gaps(roots[:, :2]))
    out = []
    for i, (root, r_max) in enumerate(zip(roots, reach, strict=True)):
        best, best_on = float(fallback), -1
        for axis in axes[:, i]:
            fit = stem_radius(points, root - axis * offset, axis, length=length, max_radius=r_max, fallback=None,
                              on_bark=True)
            if fit is not None and (on := _points_on_circle(points, fit[1], axis, fit[0], length)) > best_on:
                best, best_on = fit[0], on
        out.append(max(best, min_radius))
    return np.asarray(out)


def candidate_axes(own: np.ndarray, positions: np.ndarray, parents: np.ndarray, weights: np.ndarray,
                   roots: np.ndarray, length: float) -> np.ndarray:
    """(3, k, 3) candidate stem axes for :func:`stem_radii`: a method's own axis at each root (k, 3), the axis of the
    stem's first ``length`` (:func:`trunk_axes`, heaviest child by ``weights``) and the vertical."""
    up = np.tile([0.0, 0.0, 1.0], (len(roots), 1))
    return np.stack([np.asarray(own, float).reshape(-1, 3), trunk_axes(positions, parents, weights, roots, length),
                     up])


def trunk_axes(pos: np.ndarray, parents: np.ndarray, w: np.ndarray, roots: np.ndarray, length: float
               ) -> np.ndarray:
    """(k, 3) unit axis of each root's stem: from the root to where its heaviest-child chain (by ``w``, e.g. the
    supported length) has run ``length`` (the stretch the trunk cylinder is fitted over), up for a root without
    children."""
    ptr, kids = children_csr(parents)
    out = np.tile([0.0, 0.0, 1.0], (len(roots), 1))
    for i, r in enumerate(roots):
        node, run = int(r), 0.0
        while run < length and ptr[node + 1] > ptr[node]:
            ch = kids[ptr[node]:ptr[node + 1]]
            nxt = int(ch[np.argmax(w[ch])])
            run += float(np.linalg.norm(pos[nxt] - pos[node]))
            node = nxt
        if node != r:
            out[i] = unit(pos[node] - pos[r])
    return out


def _points_on_circle(points: np.ndarray, centre: np.ndarray, direction: np.ndarray, r: float, length: float) -> int:
    """How many of ``points`` lie within 0.2 ``r`` of the circle of radius ``r`` about the axis through ``centre``,
    within ``length`` above it."""
    t, _, d = _cylinder_coords(points, centre, direction)
    return int(np.sum((t >= 0) & (t <= length) & (np.abs(d - r) <= 0.2 * r)))


def half_gaps(xy: np.ndarray) -> np.ndarray:
    """(k,) half the distance from each of ``xy`` (k, 2) to the nearest other one (inf for a single point): how wide
    a stem at each root may be."""
    xy = np.asarray(xy, float)
    if len(xy) < 2:
        return np.full(len(xy), np.inf)
    gap, _ = cKDTree(xy).query(xy, k=2)
    return 0.5 * gap[:, 1]


def _perp(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The component of ``v`` perpendicular to ``axis`` (its projection on the plane across the axis)."""
    a = np.asarray(axis, float) / max(np.linalg.norm(axis), 1e-12)
    return v - (v @ a) * a


def anchor_roots(positions: np.ndarray, parents: np.ndarray, radii: np.ndarray, ground_z: np.ndarray, *,
                 min_gap: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Prepend a ground node under each root that is more than ``min_gap`` above the ground.

    ground_z : (n,) ground height under every node (only the roots' entries are used). The new node takes its
    root's radius. Returns ``positions``, ``parents``, ``radii`` (the new nodes come first) and ``index`` (old node
    -> new node).
    """
    roots = np.flatnonzero(parents < 0)
    lift = roots[positions[roots, 2] - ground_z[roots] > min_gap]
    k = len(lift)
    if k == 0:
        return positions, parents, radii, np.arange(len(parents))
    new_pos = positions[lift].copy()
    new_pos[:, 2] = ground_z[lift]
    index = np.arange(len(parents)) + k
    par = np.where(parents >= 0, parents + k, -1)
    par[lift] = np.arange(k)
    return (np.concatenate([new_pos, positions]), np.concatenate([np.full(k, -1), par]).astype(np.int64),
            np.concatenate([radii[lift], radii]), index)


def breast_height_scale(points: np.ndarray, positions: np.ndarray, parents: np.ndarray, radii: np.ndarray, *,
                        breast_height: float = 1.3, slab: float = 0.3, band: float = 0.45, step: float = 0.15,
                        min_height: float = 3.0, min_sectors: float = 0.4) -> float:
    """The factor for every radius of a skeleton whose allometric radii were anchored at its base: the stem's radius
    about ``breast_height`` above the skeleton's lowest node fitted to the cloud, over the skeleton's radius there. A
    base fit takes in the root flare, and the allometric models (pipe model, WBE, Eq. 5) taper too slowly from it to
    give the stem's diameter at breast height, the trait a forester reads first (rtwig's coffeetree: xu's DBH 9.4 cm
    against the reference QSMs' 7.3-7.9).

    The stem is fitted section by section over the band ``breast_height`` +- ``band``, the way TreeQSM and 3DFin fit
    a stem's cylinders: a section every ``step``, each a ``slab`` along the skeleton's stem fitted with
    :func:`stem_radius`'s nested circles; the factor is the median, over the sections whose circle is one stem's
    bark (most points within 0.2 r of the circle, reaching ``min_sectors`` of the directions around it: a
    one-station scan sees half a stem; few inside it), of the fitted radius over the skeleton's radius there. One
    section alone is at the mercy of its few points: on the multiview weeping willow's mvs cloud the breast-height
    section's circle had 59.7 % of its points on it, against 60 % required, and livny's DBH fell back to the
    allometric 41.7 cm (truth 27.9); the band's median reads 29.9 [S: docs/tuning/xu.md].

    1 (no change) when the plant is shorter than ``min_height`` (breast height lies in a shrub's crown), the stem
    does not reach breast height, no section's circle is a bark ring, or the factor would be outside [1/4, 4] (a fit
    of something else)."""
    z0 = float(positions[:, 2].min())
    if float(positions[:, 2].max()) - z0 < min_height:
        return 1.0
    skeleton = Skeleton(positions, radii, parents)
    if stem_at_height(skeleton, z0 + breast_height) is None:
        return 1.0
    ratios = []
    for dz in np.arange(-band, band + 0.5 * step, step):
        at = stem_at_height(skeleton, z0 + breast_height + dz)
        if at is None:
            continue
        centre, direction, r_model = at
        fit = _nested_fit(points, centre - 0.5 * slab * direction, direction, slab, max(3.0 * r_model, 0.05), 4)
        if fit is None:
            continue
        r, axis_point = fit
        on, sectors, inside = _on_circle(points, axis_point, direction, r, slab)
        if on >= 0.6 and sectors >= min_sectors and inside <= 0.1:
            ratios.append(r / r_model)
    if not ratios:
        return 1.0
    scale = float(np.median(ratios))
    return scale if 0.25 <= scale <= 4.0 else 1.0


def refuse_implausible_radii(radii: np.ndarray, height: float, method: str) -> None:
    """Raise when a radius is one no tree has: above half the plant's height (a trunk as wide as the tree is tall
    means the radius model ran away), naming the method and the radius."""
    r = float(np.max(radii)) if len(radii) else 0.0
    if not np.isfinite(r) or r > 0.5 * height:
        raise PlantbenchError(f"{method}: a branch radius of {r:.3g} m on a plant {height:.3g} m tall; no tree has a "
                              "radius above half its height: the reconstruction is refused")


def fit_stems(points: np.ndarray, positions: np.ndarray, parents: np.ndarray, own_axes: np.ndarray,
              weights: np.ndarray, params: StemFitParams, *, height: float, offset: float, fallback: float
              ) -> np.ndarray:
    """(k,) base radius of each stem of a skeleton (its roots: ``parents < 0``): :func:`stem_radii` over
    ``params.trunk_fit_fraction`` of the height, along the method's ``own_axes`` (k, 3) or, with
    ``params.trunk_axis_candidates``, the best of :func:`candidate_axes` (the heaviest chain by ``weights``)."""
    roots = np.flatnonzero(parents < 0)
    length = params.trunk_fit_fraction * height
    axes = own_axes
    if params.trunk_axis_candidates:
        axes = candidate_axes(own_axes, positions, parents, weights, roots, length)
    return stem_radii(points, positions[roots], axes, offset=offset, length=length, max_radius=0.1 * height,
                      fallback=fallback, min_radius=params.min_radius_fraction * height)


def finish_stems(points: np.ndarray, positions: np.ndarray, parents: np.ndarray, radii: np.ndarray, ground_coef,
                 params: StemFitParams, *, height: float, min_gap: float, method: str
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A skeleton's last steps: the stems moved onto their sections' axis (:func:`recentre_stems`, with
    ``params.stem_sections``), a ground node under each root (:func:`anchor_roots`, the ground plane
    ``z = a x + b y + c`` of ``ground_coef``), every radius scaled to the breast-height fit
    (:func:`breast_height_scale`, with ``params.breast_height_fit``), and the radii checked
    (:func:`refuse_implausible_radii`). Returns ``positions``, ``parents``, ``radii``."""
    if params.stem_sections:
        positions, parents, radii, _ = recentre_stems(points, positions, parents, radii, height=height)
    gz = positions[:, 0] * ground_coef[0] + positions[:, 1] * ground_coef[1] + ground_coef[2]
    positions, parents, radii, _ = anchor_roots(positions, parents, radii, gz, min_gap=min_gap)
    if params.breast_height_fit:
        radii = radii * breast_height_scale(points, positions, parents, radii)
    refuse_implausible_radii(radii, height, method)
    return positions, parents, radii


def recentre_stems(points: np.ndarray, positions: np.ndarray, parents: np.ndarray, radii: np.ndarray, *,
                   height: float, reach: float = 0.3) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Every stem's lowest stretch moved onto the axis of the cloud's stem sections, the way TreeQSM and 3DFin fit a
    stem's cylinders section by section.

    The chain from each root along the thickest child, up to ``reach`` of the plant's height, is first divided so
    that no edge is longer than two radii (nodes added in the middle of its edges, appended after the existing
    ones, radii interpolated; those that do not move are removed again, so a stem no section fits keeps its nodes).
    Each chain node's section, a slab two radii thick across the chain's local direction, is fitted with
    :func:`stem_radius`'s nested circles (``in_stem``, windows up to three radii); where the circle is one stem's bark
    ring (:func:`_bark_ring`: 60 % of the points near it on it, reaching three quarters of the
    directions around it, at most a tenth inside it) with a radius within 0.5-2x the node's, the node moves across
    the axis to the circle's centre. Elsewhere (a one-sided arc, too few points, a fork, a circle through the
    stems of a shrub's base) it stays.

    Why: a skeleton grown from points on a thick stem's bark runs along the bark; its root is a point of the bark.
    On the multiview trees' mvs clouds (1024 px) the stem 2 % of the height up lay about one trunk radius from the
    true axis (livny and xu 14-44 cm on the four Weber-Penn trees, whose trunks have 24-40 cm there), the wood a
    volume-weighted score weighs most [S: docs/tuning/xu.md].

    Returns ``positions``, ``parents``, ``radii`` (with the added nodes) and how many nodes moved."""
    pos, par, rad, chains = _divided_stem_chains(positions, parents, radii, reach * height)
    n0 = len(positions)
    out = pos.copy()
    shifted = np.zeros(len(pos), bool)
    for chain in chains:
        for k, i in enumerate(chain):
            lo, hi = chain[max(k - 1, 0)], chain[min(k + 1, len(chain) - 1)]
            d = pos[hi] - pos[lo]
            if not np.linalg.norm(d) > 0:
                continue
            d = d / np.linalg.norm(d)
            r = float(rad[i])
            slab = 2.0 * r
            fit = stem_radius(points, pos[i] - 0.5 * slab * d, d, length=slab, max_radius=3.0 * r, fallback=None,
                              in_stem=True)
            if fit is None:
                continue
            rf, centre = fit
            on, sectors, inside = _on_circle(points, centre, d, rf, slab)
            if _bark_ring(on, sectors, inside) and 0.5 * r <= rf <= 2.0 * r:
                out[i] = pos[i] + _perp(centre - pos[i], d)
                shifted[i] = True
    keep = shifted | (np.arange(len(pos)) < n0)  # an added node that did not move is only a point of its edge
    if not keep.all():
        par, _ = remove_nodes(par, keep)
        out, rad = out[keep], rad[keep]
    return out, par, rad, int(shifted.sum())


def _divided_stem_chains(positions: np.ndarray, parents: np.ndarray, radii: np.ndarray,
                         reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[list[int]]]:
    """Each root's chain along its thickest child, up to ``reach`` above the root, with its edges divided so that no
    edge is longer than two radii (at most 50 nodes per edge, appended after the existing nodes, radii interpolated).

    Returns the new ``positions``, ``parents``, ``radii`` and the chains as node lists from the root up."""
    pos = np.asarray(positions, float)
    par = np.asarray(parents, np.int64).copy()
    rad = np.asarray(radii, float)
    add_pos, add_par, add_rad = [], [], []
    n = len(pos)
    chains = []
    ptr, kids = children_csr(par)
    for root in np.flatnonzero(par < 0):
        chain, node = [int(root)], int(root)
        while ptr[node + 1] > ptr[node] and pos[node, 2] - pos[root, 2] < reach:
            ch = kids[ptr[node]:ptr[node + 1]]
            node = int(ch[np.argmax(rad[ch])])
            chain.append(node)
        if len(chain) < 2:
            continue
        full = [chain[0]]
        for a, b in zip(chain[:-1], chain[1:]):
            step = 2.0 * max(min(rad[a], rad[b]), 1e-9)
            k = min(int(np.ceil(np.linalg.norm(pos[b] - pos[a]) / step)) - 1, 50)
            prev = a
            for j in range(1, k + 1):
                f = j / (k + 1)
                add_pos.append(pos[a] + f * (pos[b] - pos[a]))
                add_rad.append(rad[a] + f * (rad[b] - rad[a]))
                add_par.append(prev)
                prev = n
                full.append(n)
                n += 1
            par[b] = prev
            full.append(b)
        chains.append(full)
    if add_pos:
        pos = np.concatenate([pos, np.array(add_pos)])
        par = np.concatenate([par, np.array(add_par, np.int64)])
        rad = np.concatenate([rad, np.array(add_rad)])
    return pos, par, rad, chains
