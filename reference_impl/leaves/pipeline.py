"""From a view capture (colour + per-view depth) to fitted Bezier leaves: Chaurasia and Beardsley 2017,
sections 4.1, 4.2 and 5.

:func:`segment_and_fit` is the entry point; :func:`write_leaves` writes its result as a method output
(``leaves.json`` and the leaves' points as ``points.ply``).

Depth comes from the caller (``depth_maps``), from a folder of per-view maps (``depth_dir``: the mvs stage's
``out/depth/NNNN.npz`` with key ``depth``, NaN where rejected, or ``NNNN.npy``), or, as an explicitly named oracle for
development and upper bounds, from the capture's exact ``views/depth`` (``oracle_depth=True``). The default path
never reads ground truth.

Documented skips (counted in :attr:`LeafFitResult.skipped`):

- ``view_without_depth``: a view with no depth map or no finite depth;
- (not a skip, counted in ``stats["speckle_pixels"]``) depth speckles: connected pieces of a depth map smaller than
  ``speckle_fraction`` of a leaf's projected square, the isolated wrong depths of textureless or out-of-range
  background that pass the mvs consistency check, lose their depth before segmentation;
- ``superpixel_few_points`` / ``superpixel_no_plane``: superpixels dropped before the graph (section 4.1);
- ``candidate_few_points``: a candidate leaf with fewer than ``min_candidate_points`` points;
- ``degenerate_ellipse``: a candidate or extracted leaf whose points are collinear (no enclosing ellipse);
- ``duplicate``: a candidate already claimed by a leaf extracted from another view (section 4.2), a fitted blade
  whose points lie on a larger fitted blade (:func:`_drop_overlapping`), or a piece of a larger blade's leaf: in
  its plane and touching it (:func:`_drop_fragments`, with ``fragment_fraction``);
- ``few_points_after_icp``: too few unclaimed points near the ICP-placed template, or [S] a fitted blade with fewer
  than ``min_point_fraction`` of the typical blade's points (:func:`_typical_points`);
- ``not_leaf_shaped`` [S]: a fitted blade narrower than ``min_width_fraction`` of the template's width-to-length
  ratio (a twig or a sliver: the paper ignores branches and twigs, section 1, but a stem seen from the side is
  planar within delta_plane too, and the template ICP lays the ellipse along it), or longer than
  ``max_length_factor`` x the leaf length (conjoined leaves and background).
- ``few_views`` [S]: a leaf whose points come from fewer than ``min_views`` views (a surface that one or two views'
  wrong depths agree on; a leaf the capture resolves is seen by many).
- ``fit_failed``: the Bezier fit raised (too few mapped points).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from plantbench.backend import thread_map
from plantbench.cameras import Camera, read_cameras
from plantbench.errors import InputError
from plantbench.geometry.leaf import BezierLeaf
from plantbench.plant import Leaf, TriMesh
from plantbench.schemas import jsonable as _jsonable
from plantbench.seeding import rng as seeded_rng

from .fit import LeafFit, fit_leaves
from .params import LeafParams
from .refine import refine_candidates
from .segment import Candidate, ViewSegments, backproject, candidate_confidence, segment_view

__all__ = ["LeafFitResult", "segment_and_fit", "write_leaves", "load_depth_dir", "views_folder", "fitted_mesh"]

SKIP_REASONS = ("view_without_depth", "superpixel_few_points", "superpixel_no_plane", "candidate_few_points",
                "degenerate_ellipse", "duplicate", "few_points_after_icp", "not_leaf_shaped", "few_views", "fit_failed")


@dataclass
class LeafFitResult:
    """Fitted leaves of one capture.

    leaves : plantbench Leaf instances (node -1, ids 0..k-1), transform leaf frame -> world
    fits : the :class:`reference_impl.leaves.fit.LeafFit` of each leaf (same order)
    points : (k_i, 3) float, the segmented points of each leaf (same order)
    skipped : count per reason (:data:`SKIP_REASONS`)
    stats : views, candidates, delta_plane, leaf length used, template ratio, timings (seconds)
    candidate_maps : per view (image name -> (h, w) uint16), the section 4.1 candidate leaf of each pixel (0: none,
        k + 1: the view's candidate k), before the section 4.2 refinement across views
    """

    leaves: list[Leaf]
    fits: list[LeafFit]
    points: list[np.ndarray]
    skipped: dict[str, int] = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    candidate_maps: dict[str, np.ndarray] = field(default_factory=dict)


def views_folder(path: str | os.PathLike) -> Path:
    """The ``views/`` folder: ``path`` itself when it holds cameras.json, else ``path/views``."""
    p = Path(path)
    if (p / "cameras.json").is_file():
        return p
    if (p / "views" / "cameras.json").is_file():
        return p / "views"
    raise InputError("no cameras.json: not a view capture (expected views/cameras.json)", path=p)


def load_depth_dir(depth_dir: str | os.PathLike, names: list[str]) -> list[np.ndarray | None]:
    """Per-view depth maps from a folder: ``STEM.npz`` (key ``depth``, the mvs stage's output) or ``STEM.npy``;
    None for a view with neither."""
    d = Path(depth_dir)
    if not d.is_dir():
        raise InputError("depth folder not found", path=d)
    out: list[np.ndarray | None] = []
    for name in names:
        stem = Path(name).stem
        if (d / f"{stem}.npz").is_file():
            with np.load(d / f"{stem}.npz") as z:
                if "depth" not in z:
                    raise InputError("depth archive has no 'depth' array", path=d / f"{stem}.npz")
                out.append(np.asarray(z["depth"], np.float64))
        elif (d / f"{stem}.npy").is_file():
            out.append(np.asarray(np.load(d / f"{stem}.npy"), np.float64))
        else:
            out.append(None)
    return out


def _ground_masks(depths: list[np.ndarray | None], cameras: list[Camera], delta: float, rng: np.random.Generator
                  ) -> list[np.ndarray | None]:
    """Per view, the pixels within delta of the ground plane (RANSAC among near-horizontal planes, the mvs stage's
    :func:`reference_impl.mvs.ground.fit_ground_plane`); None where no ground was found."""
    from reference_impl.mvs.ground import fit_ground_plane

    clouds = []
    for d, cam in zip(depths, cameras, strict=True):
        if d is not None:
            p, _ = backproject(d, cam)
            if len(p) > 20_000:
                p = p[rng.choice(len(p), 20_000, replace=False)]
            clouds.append(p)
    if not clouds or sum(len(c) for c in clouds) < 3:
        return [None] * len(depths)
    try:
        plane, inl = fit_ground_plane(np.concatenate(clouds), inlier_dist=0.5 * delta, rng=rng)
    except InputError:
        return [None] * len(depths)
    if inl.mean() < 0.05:  # no dominant horizontal plane: no ground in view
        return [None] * len(depths)
    masks: list[np.ndarray | None] = []
    for d, cam in zip(depths, cameras, strict=True):
        if d is None:
            masks.append(None)
            continue
        p, flat = backproject(d, cam)
        m = np.zeros(d.size, bool)
        m[flat[plane.height(p) < delta]] = True
        masks.append(m.reshape(d.shape))
    return masks


def _segment_all(images, depths, cameras, *, delta, leaf_length, params, seed, grounds
                 ) -> tuple[list[ViewSegments], dict]:
    def one(i: int) -> ViewSegments | None:
        if depths[i] is None:
            return None
        return segment_view(images[i], depths[i], cameras[i], delta=delta, leaf_length=leaf_length, params=params,
                            rng=seeded_rng(seed, "leaves", "view", i), exclude=grounds[i])

    # each view has its own random stream: the views run on the job's threads with the same result (SLIC and the
    # plane fits release the GIL for most of their time)
    segs = thread_map(one, range(len(images)))
    skipped = {"superpixel_few_points": 0, "superpixel_no_plane": 0}
    for s in segs:
        for k, v in ({} if s is None else s.skipped).items():
            skipped[k] += v
    return segs, skipped


def _candidates(segs: list[ViewSegments | None], params: LeafParams
                ) -> tuple[np.ndarray, list[Candidate], dict]:
    """Scene points (all views) and the candidates with their confidence."""
    pts, groups, areas, views = [], [], [], []
    skipped = {"candidate_few_points": 0, "degenerate_ellipse": 0}
    offset = 0
    for v, s in enumerate(segs):
        if s is None or not len(s.points):
            continue
        pts.append(s.points)
        c = s.candidate
        sel = np.flatnonzero(c >= 0)
        order = sel[np.argsort(c[sel], kind="stable")]
        ids, starts, counts = np.unique(c[order], return_index=True, return_counts=True)
        area = np.bincount(c[sel], s.area[sel], int(c.max()) + 1 if len(sel) else 0)
        for cid, st, n in zip(ids, starts, counts, strict=True):
            if n < params.min_candidate_points:
                skipped["candidate_few_points"] += 1
                continue
            groups.append(order[st: st + n] + offset)
            areas.append(area[cid])
            views.append(v)
        offset += len(s.points)
    points = np.concatenate(pts) if pts else np.zeros((0, 3))
    cands = candidate_confidence(points, groups, np.asarray(areas), views)
    skipped["degenerate_ellipse"] = sum(c is None for c in cands)
    return points, [c for c in cands if c is not None], skipped


def segment_and_fit(views_dir: str | os.PathLike, depth_maps: list[np.ndarray | None] | None = None, *,
                    depth_dir: str | os.PathLike | None = None, oracle_depth: bool = False,
                    leaf_length_hint: float | None = None, seed: int, params: LeafParams = LeafParams(),
                    up=(0.0, 0.0, 1.0)) -> LeafFitResult:
    """Segment leaves in a view capture and fit the Bezier leaf to each (Chaurasia and Beardsley 2017).

    Parameters
    ----------
    views_dir : a capture's ``views/`` folder (or the case folder holding it): ``images/`` and ``cameras.json``
    depth_maps : one (h, w) float z-depth map per camera (inf/NaN: no depth; None: view without depth)
    depth_dir : or a folder of per-view maps (:func:`load_depth_dir`)
    oracle_depth : or the capture's exact ``views/depth`` (ground truth: an explicit oracle, never the default)
    leaf_length_hint : expected leaf length, metres (the species' ``leaves.length``); scales delta_plane and the
        superpixel size. None: estimated from the data (a first pass at a pixel-footprint guess, then the median
        major axis of the most confident candidates).
    seed : root seed of every random draw (RANSAC samples, fit subsamples)
    params : :class:`LeafParams`
    up : world up direction (the fitted leaves' upper side faces it)
    """
    t_all = time.perf_counter()
    views = views_folder(views_dir)
    cameras, names = read_cameras(views / "cameras.json")
    skipped = dict.fromkeys(SKIP_REASONS, 0)
    depths = _read_depths(views, cameras, names, depth_maps=depth_maps, depth_dir=depth_dir,
                          oracle_depth=oracle_depth, skipped=skipped)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    from reference_impl.mvs.method import load_images

    images = load_images(views, names, cameras)
    timings["load"] = time.perf_counter() - t0
    stats: dict = {"views": len(cameras), "views_with_depth": sum(d is not None for d in depths)}
    if stats["views_with_depth"] == 0:
        stats["timings"] = timings
        return LeafFitResult([], [], [], skipped, stats)

    length = _first_leaf_length(depths, cameras, leaf_length_hint)
    if params.speckle_fraction > 0:
        depths, stats["speckle_pixels"] = _remove_speckles(depths, cameras, length, params.speckle_fraction)
    t0 = time.perf_counter()
    grounds = (_ground_masks(depths, cameras, params.scaled_delta(length), seeded_rng(seed, "leaves", "ground"))
               if params.ground else [None] * len(depths))
    timings["ground"] = time.perf_counter() - t0
    points, cands, length, delta, segs = _segment_candidates(
        images, depths, cameras, length=length, estimate=leaf_length_hint is None, params=params, seed=seed,
        grounds=grounds, skipped=skipped, timings=timings)
    stats.update({"leaf_length": length, "delta_plane": delta, "candidates": len(cands),
                  "superpixels": int(sum(s.superpixels for s in segs if s is not None)), "scene_points": len(points)})

    t0 = time.perf_counter()
    groups, sk_ref, ratio = refine_candidates(points, cands, delta=delta, params=params,
                                              leaf_length=length if leaf_length_hint is not None else 0.0)
    timings["refine"] = time.perf_counter() - t0
    skipped.update(sk_ref)
    stats["template_ratio"] = ratio

    if params.min_views > 1:
        groups = _seen_by_views(groups, segs, params.min_views, skipped)
    t0 = time.perf_counter()
    leaves, fits, leaf_pts = _fit(points, groups, params=params, rng=seeded_rng(seed, "leaves", "fit"), up=up,
                                  skipped=skipped, min_width_ratio=params.min_width_fraction / ratio,
                                  max_length=params.max_length_factor * length)
    leaves, fits, leaf_pts = _drop_overlapping(leaves, fits, leaf_pts, radius=params.capture_distance * delta,
                                               fraction=params.overlap_fraction, skipped=skipped)
    if params.fragment_fraction > 0:
        leaves, fits, leaf_pts = _drop_fragments(leaves, fits, leaf_pts, delta=delta, leaf_length=length,
                                                 fraction=params.fragment_fraction, skipped=skipped)
    if params.min_point_fraction > 0 and leaves:
        least = params.min_point_fraction * _typical_points([len(q) for q in leaf_pts])
        kept = [k for k, p in enumerate(leaf_pts) if len(p) >= least]
        skipped["few_points_after_icp"] += len(leaf_pts) - len(kept)
        leaves, fits, leaf_pts = _select(leaves, fits, leaf_pts, kept)
    timings["fit"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - t_all
    stats["timings"] = timings
    stats["fit_iterations_median"] = float(np.median([f.iterations for f in fits])) if fits else 0.0
    stats["fits_reset"] = int(sum(f.reset for f in fits))
    return LeafFitResult(leaves, fits, leaf_pts, skipped, stats, _candidate_maps(segs, cameras, names))


def _candidate_maps(segs: list[ViewSegments | None], cameras: list[Camera], names: list[str]) -> dict[str, np.ndarray]:
    """Per view with segments, the candidate label image (0: none, k + 1: candidate k of the view)."""
    maps = {}
    for s, cam, name in zip(segs, cameras, names, strict=True):
        if s is None:
            continue
        label = np.zeros(cam.height * cam.width, np.uint16)
        sel = s.candidate >= 0
        label[s.pixel[sel]] = (s.candidate[sel] + 1).astype(np.uint16)
        maps[name] = label.reshape(cam.height, cam.width)
    return maps


def _read_depths(views: Path, cameras: list[Camera], names: list[str], *, depth_maps, depth_dir, oracle_depth: bool,
                 skipped: dict[str, int]) -> list[np.ndarray | None]:
    """One float64 depth map per camera from the one depth source given, None for a view without depth (counted in
    ``skipped``); InputError for no or several sources, a wrong number of maps or a map of the wrong size."""
    sources = sum(x is not None and x is not False for x in (depth_maps, depth_dir, oracle_depth or None))
    if sources != 1:
        raise InputError("segment_and_fit needs exactly one depth source: depth_maps, depth_dir or oracle_depth=True")
    if depth_maps is not None:
        if len(depth_maps) != len(cameras):
            raise InputError(f"{len(depth_maps)} depth maps for {len(cameras)} cameras")
        depths = [None if d is None else np.asarray(d, np.float64) for d in depth_maps]
    else:
        depths = load_depth_dir(views / "depth" if oracle_depth else depth_dir, names)
    for i, (d, cam) in enumerate(zip(depths, cameras, strict=True)):
        if d is not None and d.shape != (cam.height, cam.width):
            raise InputError(f"depth map {i} is {d.shape[1]}x{d.shape[0]}, its camera says {cam.width}x{cam.height}")
        if d is None or not np.any(np.isfinite(d) & (d > 0)):
            depths[i] = None
            skipped["view_without_depth"] += 1
    return depths


def _remove_speckles(depths: list[np.ndarray | None], cameras: list[Camera], length: float, fraction: float
                     ) -> tuple[list[np.ndarray | None], int]:
    """Depth speckles out: per view, the 8-connected components of pixels with a depth smaller than ``fraction`` x
    the square of the leaf length in pixels (at the view's median depth) lose their depth. Returns the maps and the
    number of pixels cleared."""
    from scipy import ndimage

    out, cleared = [], 0
    for d, cam in zip(depths, cameras, strict=True):
        valid = None if d is None else np.isfinite(d) & (d > 0)
        if valid is None or not valid.any():
            out.append(d)
            continue
        min_px = fraction * (length * cam.K[0, 0] / float(np.median(d[valid]))) ** 2
        label, _ = ndimage.label(valid, structure=np.ones((3, 3), bool))
        small = np.bincount(label.ravel()) < min_px
        small[0] = False
        drop = small[label]
        cleared += int(drop.sum())
        out.append(np.where(drop, np.nan, d))
    return out, cleared


def _first_leaf_length(depths: list[np.ndarray | None], cameras: list[Camera], hint: float | None) -> float:
    """The hint, else a leaf ~40 pixels long at the median depth: a first guess, refined by
    :func:`_segment_candidates`."""
    if hint is not None:
        if not hint > 0:
            raise InputError(f"leaf_length_hint must be positive, got {hint!r}")
        return float(hint)
    foot = [np.median(d[np.isfinite(d) & (d > 0)]) / cam.K[0, 0] for d, cam in zip(depths, cameras, strict=True)
            if d is not None]
    return 40.0 * float(np.median(foot))


def _segment_candidates(images, depths, cameras, *, length: float, estimate: bool, params: LeafParams, seed: int,
                        grounds, skipped: dict[str, int], timings: dict[str, float]
                        ) -> tuple[np.ndarray, list[Candidate], float, float, list[ViewSegments | None]]:
    """Per-view segmentation and the candidates at leaf ``length``; with ``estimate``, run again once at the median
    major axis of the ``template_leaves`` most confident candidates when it is more than 25 % off.

    Returns the scene points, the candidates, the leaf length and delta_plane used, and the views' segments;
    ``skipped`` and ``timings`` (segment, candidates) are updated.
    """
    for attempt in range(2):
        delta = params.scaled_delta(length)
        t0 = time.perf_counter()
        segs, sk_seg = _segment_all(images, depths, cameras, delta=delta, leaf_length=length, params=params,
                                    seed=seed, grounds=grounds)
        timings["segment"] = timings.get("segment", 0.0) + time.perf_counter() - t0
        t0 = time.perf_counter()
        points, cands, sk_cand = _candidates(segs, params)
        timings["candidates"] = timings.get("candidates", 0.0) + time.perf_counter() - t0
        if not estimate or attempt == 1 or not cands:
            break
        conf = np.array([c.confidence for c in cands])
        top = np.argsort(-conf, kind="stable")[: params.template_leaves]
        est = float(np.median([2 * cands[i].semi_axes[0] for i in top]))
        if abs(est / length - 1.0) <= 0.25:
            break
        length = est
    skipped.update(sk_seg)
    skipped.update(sk_cand)
    return points, cands, length, delta, segs


def _seen_by_views(groups: list[np.ndarray], segs: list[ViewSegments | None], min_views: int,
                   skipped: dict[str, int]) -> list[np.ndarray]:
    """The groups (indices into the scene points, which :func:`_candidates` concatenates view by view) whose points
    come from at least ``min_views`` views; the others are counted as ``few_views``."""
    view_of_point = np.concatenate([np.full(len(s.points), v) for v, s in enumerate(segs)
                                    if s is not None and len(s.points)] or [np.zeros(0, int)])
    kept = [g for g in groups if len(np.unique(view_of_point[g])) >= min_views]
    skipped["few_views"] += len(groups) - len(kept)
    return kept


def _fit(points: np.ndarray, groups: list[np.ndarray], *, params: LeafParams, rng: np.random.Generator, up,
         skipped: dict[str, int], min_width_ratio: float = 0.0, max_length: float = np.inf
         ) -> tuple[list[Leaf], list[LeafFit], list[np.ndarray]]:
    """The Bezier leaf fitted to each group of ``points``: the Leaf instances (ids in order), their fits and points;
    the groups whose fit failed are counted in ``skipped``, the blades narrower than ``min_width_ratio`` x their
    length or longer than ``max_length`` as ``not_leaf_shaped``."""
    fits_or_skips = fit_leaves([points[g] for g in groups], params=params, rng=rng, up=up)
    leaves, fits, leaf_pts = [], [], []
    for g, f in zip(groups, fits_or_skips, strict=True):
        if isinstance(f, str):
            skipped["candidate_few_points" if f == "few_points" else f] += 1
            continue
        if f.width < min_width_ratio * f.length or f.length > max_length:
            skipped["not_leaf_shaped"] += 1
            continue
        leaves.append(Leaf(len(leaves), -1, f.transform, BezierLeaf.from_vector(f.omega).to_dict(), f.length, f.width))
        fits.append(f)
        leaf_pts.append(points[g])
    return leaves, fits, leaf_pts


def _drop_overlapping(leaves: list[Leaf], fits: list[LeafFit], leaf_pts: list[np.ndarray], *, radius: float,
                      fraction: float, skipped: dict[str, int]) -> tuple[list[Leaf], list[LeafFit], list[np.ndarray]]:
    """De-duplication of the fitted blades [S]: largest blade (length x width) first, a leaf whose points lie within
    ``radius`` of an already kept blade's fitted surface in at least ``fraction`` of cases is a fragment of that leaf
    (section 4.2's de-duplication compares the candidates' own points; a fragment whose points the template ICP did
    not reach is caught by the fitted, whole blade) and is dropped as ``duplicate``. Ids are renumbered in order."""
    from scipy.spatial import cKDTree

    def ball(points: np.ndarray) -> tuple[np.ndarray, float]:
        centre = points.mean(axis=0)
        return centre, float(np.sqrt(((points - centre) ** 2).sum(axis=1).max()))

    order = np.argsort([-f.length * f.width for f in fits], kind="stable")
    kept: list[int] = []
    surfaces: list[np.ndarray] = []
    balls: list[tuple[np.ndarray, float]] = []
    for k in order:
        # only the kept blades whose bounding balls come within radius of this leaf's can hold a point near it
        c, r = ball(leaf_pts[k])
        close = [j for j, (cj, rj) in enumerate(balls) if np.linalg.norm(cj - c) <= r + rj + radius]
        if close:
            tree = cKDTree(np.concatenate([surfaces[j] for j in close]))
            near = tree.query(leaf_pts[k], distance_upper_bound=radius)[0] <= radius
            if near.mean() >= fraction:
                skipped["duplicate"] += 1
                continue
        kept.append(int(k))
        surfaces.append(fits[k].surface(17, 33))
        balls.append(ball(surfaces[-1]))
    return _select(leaves, fits, leaf_pts, sorted(kept))


def _typical_points(counts: list[int]) -> float:
    """The point count of the blade that holds the median point (the point-weighted median of the blades' counts):
    the size of the blades that carry the foliage's surface, whatever the number of tiny false blades beside them
    (a plain median falls to their size once they are the majority)."""
    c = np.sort(np.asarray(counts, np.float64))
    return float(c[np.searchsorted(np.cumsum(c), 0.5 * c.sum())])


def _select(leaves: list[Leaf], fits: list[LeafFit], leaf_pts: list[np.ndarray], kept: list[int]
            ) -> tuple[list[Leaf], list[LeafFit], list[np.ndarray]]:
    """The leaves, fits and points at the indices ``kept`` (ascending), the leaves renumbered 0, 1, ..."""
    out = [Leaf(i, -1, leaves[k].transform, leaves[k].params, leaves[k].length, leaves[k].width)
           for i, k in enumerate(kept)]
    return out, [fits[k] for k in kept], [leaf_pts[k] for k in kept]


def _drop_fragments(leaves: list[Leaf], fits: list[LeafFit], leaf_pts: list[np.ndarray], *, delta: float,
                    leaf_length: float, fraction: float, skipped: dict[str, int]
                    ) -> tuple[list[Leaf], list[LeafFit], list[np.ndarray]]:
    """Pieces of one leaf fitted as two blades [S]: largest blade (point count) first, a blade is a fragment of a
    kept one, and dropped as ``duplicate``, when their centroids are less than ``leaf_length`` apart, at least
    ``fraction`` of its points lie within delta / 2 of the kept blade's plane (the least-squares plane of its
    points) and the two point sets touch (some pair closer than delta / 2). A blade beside a coplanar neighbour
    that does not touch it stays. Ids are renumbered in order."""
    from scipy.spatial import cKDTree

    order = np.argsort([-len(p) for p in leaf_pts], kind="stable")
    kept: list[int] = []
    planes: list[tuple[np.ndarray, np.ndarray]] = []
    trees: list = []
    for k in order:
        pts = leaf_pts[k]
        centre = pts.mean(axis=0)
        fragment = False
        for (c, n), tree in zip(planes, trees, strict=True):
            if np.linalg.norm(c - centre) >= leaf_length or np.mean(np.abs((pts - c) @ n) < 0.5 * delta) < fraction:
                continue
            if np.isfinite(tree.query(pts, distance_upper_bound=0.5 * delta)[0]).any():
                fragment = True
                break
        if fragment:
            skipped["duplicate"] += 1
            continue
        kept.append(int(k))
        planes.append((centre, np.linalg.svd(pts - centre, full_matrices=False)[2][2]))
        trees.append(cKDTree(pts))
    return _select(leaves, fits, leaf_pts, sorted(kept))


def fitted_mesh(result: LeafFitResult, resolution: tuple[int, int] = (4, 8)) -> TriMesh:
    """The fitted leaves as one triangle mesh in world coordinates (the generator's tessellation at each leaf's
    transform), blades in leaf order, the same number of vertices each."""
    from plantbench.geometry.leaf import tessellate_placed

    if not result.fits:
        return TriMesh.empty()
    tr = np.stack([f.transform for f in result.fits])
    verts, faces = tessellate_placed(np.stack([f.omega for f in result.fits]),
                                     np.array([f.length for f in result.fits]), tr[:, :3, :3], tr[:, :3, 3],
                                     resolution)
    return TriMesh(verts.reshape(-1, 3), faces)


def write_leaves(out_dir: str | os.PathLike, result: LeafFitResult, *, samples_per_leaf: int = 153) -> None:
    """Write ``leaves.json`` and ``points.ply`` (points on each fitted surface, with a ``leaf_id`` field),
    ``leaves_stats.json`` (skips and stats) and ``candidates/STEM.png`` (each view's candidate map, uint16) into
    ``out_dir``."""
    from PIL import Image

    from plantbench.io.atomic import write_json
    from plantbench.io.plantio import write_reconstruction

    nv = max(3, int(round(np.sqrt(samples_per_leaf * 2))))
    nu = max(3, samples_per_leaf // nv)
    surf = [f.surface(nu, nv) for f in result.fits]
    pts = np.concatenate(surf) if surf else np.zeros((0, 3))
    ids = np.repeat(np.arange(len(surf), dtype=np.int32), [len(s) for s in surf]) if surf else np.zeros(0, np.int32)
    write_reconstruction(out_dir, None, leaves=result.leaves, points=pts, point_fields={"leaf_id": ids})
    write_json(Path(out_dir) / "leaves_stats.json", {"format": "plantbench.leaves-stats/1", "count": len(result.leaves),
                                                     "skipped": result.skipped, "stats": _jsonable(result.stats)})
    if result.candidate_maps:
        (Path(out_dir) / "candidates").mkdir(exist_ok=True)
        for name, label in result.candidate_maps.items():
            Image.fromarray(label).save(Path(out_dir) / "candidates" / f"{Path(name).stem}.png")
