"""The ``mvs`` method: a view capture in, the plant's point cloud (points.ply) out.

Pipeline (Guo et al. 2018, section 4): known poses (or pycolmap SfM) -> neighbours -> per-view depth + normal
(plane sweep + PatchMatch, :mod:`.patchmatch`) -> multi-view geometric consistency and free-space check
(:mod:`.filtering`) -> guided filter -> fusion and voxel downsampling (:mod:`.fusion`) -> ground removal
(:mod:`.ground`). The oracle mode replaces the depth estimation with noisy ground-truth depth (:mod:`.oracle`).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from plantbench.backend import thread_map
from plantbench.cameras import Camera, read_cameras
from plantbench.errors import InputError
from plantbench.io.atomic import atomic_write, write_json
from plantbench.io.ply import write_points
from plantbench.schemas import jsonable as _jsonable
from plantbench.seeding import rng as seeded_rng

from .filtering import consistency_counts, masked_guided_filter, nearest_views
from .fusion import fuse_views, voxel_downsample
from .ground import plant_mask
from .neighbours import depth_range, scene_centre, scene_scale, select_neighbours
from .params import FusionParams, MVSParams
from .patchmatch import DepthMap, estimate_depth, refine_geometric, to_gray

__all__ = ["MVS", "load_views", "depth_maps", "filter_depth_maps", "reconstruct_points"]


def load_views(capture_dir: str | Path) -> tuple[list[np.ndarray], list[Camera], list[str]]:
    """Images (RGB uint8), cameras and image names of a capture's ``views/``.

    Raises InputError on a missing cameras.json, fewer than 2 views, an unreadable or missing image, or an image
    whose size differs from its camera's.
    """
    views = Path(capture_dir) / "views"
    cam_path = views / "cameras.json"
    if not cam_path.is_file():
        raise InputError("no views/cameras.json: not a view capture", path=cam_path)
    cameras, names = read_cameras(cam_path)
    if len(cameras) < 2:
        raise InputError(f"multi-view stereo needs at least 2 views, the capture has {len(cameras)}", path=cam_path)
    images = load_images(views, names, cameras)
    return images, cameras, names


def load_images(views: Path, names: list[str], cameras: list[Camera]) -> list[np.ndarray]:
    """RGB uint8 images ``views/images/NAME`` in camera order; InputError naming the file when one is missing,
    unreadable, or not the size its camera says."""
    from PIL import Image, UnidentifiedImageError

    images = []
    for name, cam in zip(names, cameras, strict=True):
        path = Path(views) / "images" / name
        try:
            with Image.open(path) as im:
                img = np.asarray(im.convert("RGB"))
        except (FileNotFoundError, IsADirectoryError):
            raise InputError("image listed in cameras.json is missing", path=path) from None
        except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
            raise InputError(f"unreadable image ({exc})", path=path) from None
        if img.shape[:2] != (cam.height, cam.width):
            raise InputError(f"image is {img.shape[1]}x{img.shape[0]}, its camera says {cam.width}x{cam.height}",
                             path=path)
        images.append(img)
    return images


def depth_maps(
    images: list[np.ndarray], cameras: list[Camera], params: MVSParams | None = None, *, seed: int,
    neighbours: list[list[int]] | None = None,
) -> tuple[list[DepthMap], list[list[int]], list[float]]:
    """Raw per-view depth and normal maps (before the multi-view filter).

    Returns
    -------
    maps : one DepthMap per view
    neighbours : the source views used for each view
    seconds : time per view
    """
    p = params or MVSParams()
    nb = neighbours if neighbours is not None else select_neighbours(cameras, p.neighbours, p.depth_params.depth_margin)
    centre = scene_centre(cameras)
    ranges = [depth_range(cam, centre, p.depth_params.depth_margin) for cam in cameras]

    def one(i: int) -> tuple[DepthMap, float]:
        t0 = time.perf_counter()
        depth = estimate_depth(images[i], [images[j] for j in nb[i]], cameras[i], [cameras[j] for j in nb[i]],
                               ranges[i], p.depth_params, rng=seeded_rng(seed, "mvs", "patchmatch", i))
        if p.depth_params.geometric_iterations == 0:  # the raw planes serve only the geometric pass (16 B a pixel)
            depth = dataclasses.replace(depth, planes=None)
        return depth, time.perf_counter() - t0

    # one view at a time: Dr.Jit already runs each view's kernels on all of the job's threads, and two views at once
    # took longer (4 views of 1024 px on 2 cores: 12.3 s against 11.3 s one at a time; 21.7 against 18.8 s with
    # adaptive propagation, whose many gathers are traced in Python under the GIL)
    results = [one(i) for i in range(len(cameras))]
    maps, seconds = [r[0] for r in results], [r[1] for r in results]
    if p.depth_params.geometric_iterations > 0:
        def geometric(i: int) -> tuple[DepthMap, float]:
            t0 = time.perf_counter()
            depth = refine_geometric(images[i], [images[j] for j in nb[i]], cameras[i], [cameras[j] for j in nb[i]],
                                     maps[i], [maps[j].planes[0] for j in nb[i]], ranges[i], p.depth_params,
                                     rng=seeded_rng(seed, "mvs", "geometric", i))
            return depth, time.perf_counter() - t0

        # every view reads the photometric maps of its sources: the pass starts once all of them exist
        results = [geometric(i) for i in range(len(cameras))]
        maps = [dataclasses.replace(r[0], planes=None) for r in results]
        seconds = [s + r[1] for s, r in zip(seconds, results, strict=True)]
    return maps, nb, seconds


def filter_depth_maps(
    maps: list[DepthMap], images: list[np.ndarray], cameras: list[Camera], params: MVSParams | None = None,
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Multi-view consistency (>= ``min_consistent`` agreeing views, at most ``max_violations`` free-space
    violations; depths agree within ``filter.depth_px`` pixel footprints of the reference view), then the masked
    guided filter (a change larger than that tolerance is not applied: the filter must not move a depth across a
    discontinuity).

    Returns
    -------
    depths : list of (h, w) float32, NaN where rejected
    keep : list of (h, w) bool
    """
    p = params or MVSParams()
    f = p.filter
    raw = [m.depth for m in maps]
    # a pixel that saw the background past the scene sees through whatever lies in front of it: +inf for the
    # free-space test (no depth for the agreement test)
    seen = [d if m.background is None else np.where(m.background, np.inf, d).astype(np.float32)
            for d, m in zip(raw, maps, strict=True)]
    rel = [f.rel_depth(cam.K[0, 0]) for cam in cameras]  # depth_px pixel footprints of each view
    support, violations = consistency_counts(
        seen, cameras, views=nearest_views(cameras, f.consistency_views), reproj_px=f.reproj_px, rel_depth=rel,
        search_radius=f.search_radius,
    )

    def one(i: int) -> tuple[np.ndarray, np.ndarray]:
        keep = np.isfinite(raw[i]) & (support[i] >= f.min_consistent) & (violations[i] <= p.fusion.max_violations)
        out = np.where(keep, raw[i], np.nan).astype(np.float32)
        if f.guided and keep.any():
            g = masked_guided_filter(to_gray(images[i]), out, keep, f.guided_radius, f.guided_eps)
            ok = keep & np.isfinite(g) & (np.abs(g - out) < rel[i] * out)
            out = np.where(ok, g, out).astype(np.float32)
        return out, keep

    # the views are independent: on the job's threads, with the same result
    results = thread_map(one, range(len(raw)))
    return [r[0] for r in results], [r[1] for r in results]


def downscale_views(images: list[np.ndarray], cameras: list[Camera], max_size: int
                    ) -> tuple[list[np.ndarray], list[Camera], float]:
    """The views with their longer side at most ``max_size`` pixels: images area-averaged, cameras scaled (pixel
    centres at integers: u' + 0.5 = s (u + 0.5)); views already small enough are returned as they are. Returns the
    images, the cameras and the scale s of the largest view (1.0 when none was larger)."""
    import cv2

    out_i, out_c, smallest = [], [], 1.0
    for img, cam in zip(images, cameras, strict=True):
        s = max_size / max(cam.width, cam.height)
        if s >= 1.0:
            out_i.append(img)
            out_c.append(cam)
            continue
        w, h = max(1, round(cam.width * s)), max(1, round(cam.height * s))
        sx, sy = w / cam.width, h / cam.height
        S = np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])
        out_i.append(cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA))
        out_c.append(Camera(S @ cam.K, cam.R, cam.t, w, h))
        smallest = min(smallest, s)
    return out_i, out_c, smallest


def _to_size(depth: np.ndarray, cam: Camera) -> np.ndarray:
    """A working-size depth map at the camera's own size (nearest neighbour: no depth blended across an edge)."""
    import cv2

    if depth.shape == (cam.height, cam.width):
        return depth
    return cv2.resize(depth, (cam.width, cam.height), interpolation=cv2.INTER_NEAREST)


def _fields(normals: np.ndarray, colours: np.ndarray) -> dict[str, np.ndarray]:
    n = normals.astype(np.float32)
    c = colours.astype(np.uint8)
    return {"nx": n[:, 0], "ny": n[:, 1], "nz": n[:, 2], "red": c[:, 0], "green": c[:, 1], "blue": c[:, 2]}


def reconstruct_points(capture_dir: str | Path, out_dir: str | Path, params: MVSParams, *, seed: int) -> dict:
    """Run the whole stage; writes ``out_dir/points.ply`` and ``out_dir/mvs.json`` and returns the stats."""
    t_all = time.perf_counter()
    out = Path(out_dir)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    images, cameras, names = load_views(capture_dir)
    timings["load"] = time.perf_counter() - t0
    stats: dict = {"views": len(cameras), "poses": params.poses, "depth": params.depth}
    used = list(range(len(cameras)))
    if params.poses == "sfm":
        from .sfm import run_sfm

        t0 = time.perf_counter()
        res = run_sfm(Path(capture_dir) / "views" / "images", names, intrinsics=params.intrinsics,
                      reference=cameras, seed=seed, params=params.sfm)
        timings["sfm"] = time.perf_counter() - t0
        stats["sfm"] = {
            "intrinsics": params.intrinsics, "registered": len(res.registered),
            "unregistered": [names[i] for i in res.unregistered], "models": res.models,
            "sparse_points": res.points, "reprojection_error_px": res.reprojection_error,
            "sim3_scale": res.sim3[0], "centre_rmse": res.centre_rmse, "timings": res.timings,
            "focal_estimated": [float(res.cameras[i].K[0, 0]) for i in res.registered[:1]],
        }
        used = res.registered
        cameras = [res.cameras[i] for i in used]
        images = [images[i] for i in used]
    stats["views_used"] = len(used)
    native = cameras
    if params.max_size and params.depth != "oracle":
        images, cameras, stats["working_scale"] = downscale_views(images, cameras, params.max_size)
    scale = scene_scale(cameras)
    if params.depth == "oracle":
        from .oracle import oracle_depths

        t0 = time.perf_counter()
        depths, normals, keep, sigma = oracle_depths(capture_dir, [names[i] for i in used], cameras, params.noise,
                                                     seeded_rng(seed, "mvs", "oracle"))
        timings["depth"] = time.perf_counter() - t0
        stats["oracle"] = {"noise": params.noise, "sigma_m": sigma}
        neighbours, maps = None, None
    else:
        t0 = time.perf_counter()
        maps, neighbours, secs = depth_maps(images, cameras, params, seed=seed)
        timings["depth"] = time.perf_counter() - t0
        timings["depth_per_view_median"] = float(np.median(secs))
        t0 = time.perf_counter()
        depths, keep = filter_depth_maps(maps, images, cameras, params)
        normals = [m.normal for m in maps]
        timings["filter"] = time.perf_counter() - t0
        stats["pixels_matched"] = int(sum(np.isfinite(m.depth).sum() for m in maps))
        stats["pixels_kept"] = int(sum(k.sum() for k in keep))
    if params.poses == "known" or params.write_depth:
        written = depths if cameras is native else [_to_size(d, c) for d, c in zip(depths, native, strict=True)]
        _write_depth(out / "depth", [names[i] for i in used], written, maps if params.write_depth else None)
    t0 = time.perf_counter()
    pts, nrm, col, _ = fuse_views(depths, normals, images, cameras, keep)
    stats["points_fused"] = len(pts)
    timings["fusion"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    remove_ground = params.depth != "oracle" and params.ground.enabled
    pts, nrm, col, voxel, plane, n_down = plant_points(pts, nrm, col, scale=scale, params=params,
                                                       remove_ground=remove_ground, seed=seed)
    stats["points_downsampled"] = n_down
    if remove_ground:
        stats["ground_plane"] = None if plane is None else {"normal": plane.normal.tolist(), "offset": plane.offset}
    timings["ground"] = time.perf_counter() - t0
    stats["voxel"] = voxel
    stats["points"] = len(pts)
    if len(pts) == 0:
        raise InputError("the multi-view stage produced no points (views without texture or overlap?)",
                         path=Path(capture_dir) / "views")
    out.mkdir(parents=True, exist_ok=True)
    write_points(out / "points.ply", pts, _fields(nrm, col))
    timings["total"] = time.perf_counter() - t_all
    stats["timings"] = timings
    stats["neighbours"] = neighbours
    write_json(out / "mvs.json", _jsonable(stats))
    return stats


def plant_points(pts, nrm, col, *, scale: float, params: MVSParams, remove_ground: bool, seed: int):
    """The fused cloud to the written one: voxel-downsampled, the ground and floaters removed, downsampled again.

    The ground covers most of the views: it is removed before the final downsampling so that the point budget goes
    to the plant (downsampling first to the budget left the plant a few voxels per leaf). Returns the points,
    normals, colours, the last voxel size (0 when no downsampling was needed), the ground plane (None when not
    removed or not found) and the number of points after the first downsampling.
    """
    budget = params.fusion.points * (params.fusion.pre_ground_factor if remove_ground else 1)
    pts, nrm, col, voxel = voxel_downsample(pts, budget, normals=nrm, colours=col)
    n_down, plane = len(pts), None
    if remove_ground and len(pts):
        # the floater test's neighbourhood: 1 % of the scene scale, or 3 voxels when the voxels are coarser (why:
        # docs/tuning/mvs.md)
        radius = max(3.0 * voxel, 0.01 * scale)
        mask, plane = plant_mask(pts, col, scale=scale, params=params.ground, rng=seeded_rng(seed, "mvs", "ground"),
                                 component_radius=radius)
        pts, nrm, col = pts[mask], nrm[mask], col[mask]
        if len(pts):
            pts, nrm, col, voxel = voxel_downsample(pts, params.fusion.points, normals=nrm, colours=col)
    return pts, nrm, col, voxel, plane, n_down


def _write_depth(folder: Path, names: list[str], depths: list[np.ndarray], maps: list[DepthMap] | None) -> None:
    """Per view ``folder/STEM.npz``: the filtered z-depth (float32, NaN where rejected; ~0.1 MB a 512 px view), and
    with ``maps`` the raw depth, normal and cost maps too (oracle depth has none). Each file is written atomically."""
    for i, (name, d) in enumerate(zip(names, depths, strict=True)):
        extra = {} if maps is None else {"raw_depth": maps[i].depth, "normal": maps[i].normal, "cost": maps[i].cost}
        with atomic_write(folder / f"{Path(name).stem}.npz") as fh:
            np.savez_compressed(fh, depth=np.asarray(d, np.float32), **extra)


class MVS:
    """Multi-view point cloud (Guo et al. 2018, section 4): the first stage of guo, livny and xu on image captures.

    Options (a suite's ``[method_options.mvs]``): ``poses`` ('known' | 'sfm'), ``intrinsics`` ('known' |
    'unknown', SfM only), ``depth`` ('estimated' | 'oracle'), ``noise`` (oracle: sigma as a fraction of plant
    height), ``points`` (target cloud size), ``write_depth`` and any nested parameter as ``GROUP__FIELD`` (see
    :class:`reference_impl.mvs.params.MVSParams`). Writes ``points.ply`` (x y z nx ny nz red green blue, plant only)
    and ``mvs.json`` (stats).
    """

    name = "mvs"
    inputs = "views"
    options_model = MVSParams
    """What ``check_options`` validates and ``plantbench methods mvs`` lists (nested groups as ``GROUP__FIELD``)."""
    extra_options = {"points": (FusionParams().points, "Target cloud size: the same as fusion__points.")}
    oracle_when = {"depth": "oracle"}
    """``depth="oracle"`` reads the exact depth and instance maps and plant.json: an oracle run."""

    def check_options(self, options: dict) -> None:
        """Raise InputError on an unknown or invalid option (the planner calls it before any job runs)."""
        MVSParams.from_options(options)

    def reconstruct(
        self, capture_dir: Path, out_dir: Path, *, seed: int, species: str | None = None, **options
    ) -> None:
        params = MVSParams.from_options(options)
        reconstruct_points(capture_dir, out_dir, params, seed=seed)
