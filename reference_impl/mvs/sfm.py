"""Structure from motion with pycolmap on the CPU (poses withheld), and the Sim(3) alignment used for evaluation.

pycolmap 4.2.1: SIFT extraction (DSP-SIFT, affine shape) and exhaustive guided matching with ``Device.cpu``, then
incremental mapping with relaxed inlier thresholds (:class:`~reference_impl.mvs.params.SfMParams`); the largest
model is kept. Intrinsics are either fixed to the capture's (``known``: one PINHOLE camera whose parameters are
not refined) or estimated (``unknown``: one SIMPLE_RADIAL camera initialised by COLMAP's focal-length prior and
refined by bundle adjustment; the radial term is then ignored for the dense stage, the images being distortion free).

The reconstruction lives in an arbitrary similarity frame. For evaluation only, it is mapped onto the ground-truth
frame by the Umeyama Sim(3) that best aligns the registered camera centres with those of ``views/cameras.json``;
the dense stage then runs with the aligned poses, so the cloud is scored in the world frame. Views that fail to
register are reported (names and count), never silently dropped.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from plantbench.cameras import Camera
from plantbench.errors import InputError, PlantbenchError
from plantbench.geometry.vectors import similarity_transform

from .params import SfMParams

__all__ = ["SfMResult", "run_sfm", "umeyama", "SfMFailed"]


class SfMFailed(PlantbenchError):
    """Structure from motion registered too few views to go on."""


@dataclass
class SfMResult:
    """Registered views and their cameras (already aligned to the reference frame when one was given).

    cameras : dict view index -> Camera (OpenCV convention)
    registered, unregistered : view indices
    sim3 : (scale, R (3, 3), t (3,)) mapping SfM coordinates into the reference frame (x' = s R x + t)
    centre_rmse : RMS camera-centre error after alignment (reference frame units), NaN without a reference
    points : number of sparse 3-D points
    reprojection_error : mean reprojection error, pixels
    """

    cameras: dict[int, Camera]
    registered: list[int]
    unregistered: list[int]
    sim3: tuple[float, np.ndarray, np.ndarray]
    centre_rmse: float
    points: int
    reprojection_error: float
    models: int = 1
    timings: dict[str, float] = field(default_factory=dict)


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity (Umeyama 1991) with dst ~ s R src + t: the checks of the evaluation's alignment
    around :func:`plantbench.geometry.vectors.similarity_transform`.

    Parameters
    ----------
    src, dst : (n, 3) float, n >= 3 corresponding points, not collinear

    Returns
    -------
    s : float, R : (3, 3) rotation, t : (3,)
    """
    src = np.asarray(src, float)
    dst = np.asarray(dst, float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise InputError(f"umeyama needs two (n >= 3, 3) arrays, got {src.shape} and {dst.shape}")
    if ((src - src.mean(0)) ** 2).sum() <= 0:
        raise InputError("umeyama: the source points coincide")
    return similarity_transform(src, dst)


def run_sfm(
    image_dir: Path, names: list[str], *, intrinsics: str, reference: list[Camera] | None, seed: int,
    work_dir: Path | None = None, threads: int = 2, params: SfMParams | None = None,
) -> SfMResult:
    """SIFT + exhaustive matching + incremental mapping on the CPU, the largest model's cameras, and their Sim(3)
    alignment to ``reference``.

    Parameters
    ----------
    image_dir : folder of the images
    names : image file names, in view order
    intrinsics : 'known' (fixed to ``reference``'s K, which must then be given) or 'unknown'
    reference : the capture's cameras: the Sim(3) target (evaluation frame) and the known intrinsics
    seed : random seed of the mapper
    work_dir : where to keep the database and model (a temporary folder when None)
    params : extraction, matching and mapper settings (:class:`~reference_impl.mvs.params.SfMParams`)
    """
    import importlib

    importlib.import_module("PIL.Image")  # PIL before pycolmap: zlib clash (docs/design.md, Platform notes)
    pycolmap = importlib.import_module("pycolmap")

    if intrinsics not in ("known", "unknown"):
        raise InputError(f"intrinsics must be 'known' or 'unknown', got {intrinsics!r}")
    if intrinsics == "known" and not reference:
        raise InputError("intrinsics='known' needs the reference cameras")
    sp = params or SfMParams()
    timings: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="sfm.") as tmp:
        work = Path(work_dir) if work_dir is not None else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        db = work / "database.db"
        if db.exists():
            db.unlink()
        reader = _reader_options(pycolmap, intrinsics, reference)
        models = _sparse_models(pycolmap, db, image_dir, names, work / "sparse", reader=reader,
                                mapper=_mapper_options(pycolmap, sp, intrinsics, seed, threads), params=sp,
                                threads=threads, timings=timings)
        if not models:
            raise SfMFailed(f"structure from motion registered no model from {len(names)} views")
        rec = max(models.values(), key=lambda r: r.num_reg_images())
        cams = _registered_cameras(rec, names)
        registered = sorted(cams)
        unregistered = [i for i in range(len(names)) if i not in cams]
        if len(registered) < 2:
            raise SfMFailed(f"structure from motion registered {len(registered)} of {len(names)} views")
        sim3, rmse = (1.0, np.eye(3), np.zeros(3)), float("nan")
        if reference is not None:
            sim3, rmse = _align_to_reference(cams, registered, reference)
        return SfMResult(
            cams, registered, unregistered, sim3, rmse, int(rec.num_points3D()),
            float(rec.compute_mean_reprojection_error()), len(models), timings,
        )


def _reader_options(pycolmap, intrinsics: str, reference: list[Camera] | None):
    """The image reader's camera: one PINHOLE camera fixed to the reference's K ('known') or one SIMPLE_RADIAL
    camera from COLMAP's focal-length prior ('unknown')."""
    reader = pycolmap.ImageReaderOptions()
    if intrinsics == "known":
        k = reference[0].K
        if any(not np.allclose(c.K, k) for c in reference):
            raise InputError("intrinsics='known' in SfM mode supports one shared camera (all K equal)")
        reader.camera_model = "PINHOLE"
        # COLMAP puts pixel centres at +0.5
        reader.camera_params = f"{k[0, 0]},{k[1, 1]},{k[0, 2] + 0.5},{k[1, 2] + 0.5}"
    else:
        reader.camera_model = "SIMPLE_RADIAL"
    return reader


def _mapper_options(pycolmap, sp: SfMParams, intrinsics: str, seed: int, threads: int):
    """Incremental mapping with ``sp``'s inlier thresholds; known intrinsics are not refined."""
    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = threads
    opts.random_seed = int(seed) % (2**31)
    opts.min_num_matches = sp.min_num_matches
    opts.mapper.init_min_num_inliers = sp.init_min_num_inliers
    opts.mapper.abs_pose_min_num_inliers = sp.abs_pose_min_num_inliers
    if intrinsics == "known":
        opts.ba_refine_focal_length = False
        opts.ba_refine_principal_point = False
        opts.ba_refine_extra_params = False
    return opts


def _sparse_models(pycolmap, db: Path, image_dir: Path, names: list[str], sparse_dir: Path, *, reader, mapper,
                   params: SfMParams, threads: int, timings: dict[str, float]) -> dict:
    """SIFT extraction, exhaustive matching and incremental mapping on the CPU (``timings`` gets each step's
    seconds); returns pycolmap's models by id."""
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = threads
    extraction.sift.peak_threshold = params.peak_threshold
    extraction.sift.octave_resolution = params.octave_resolution
    extraction.sift.domain_size_pooling = params.domain_size_pooling
    extraction.sift.estimate_affine_shape = params.estimate_affine_shape
    extraction.sift.max_num_features = params.max_num_features
    t0 = time.perf_counter()
    pycolmap.extract_features(
        db, image_dir, image_names=list(names), camera_mode=pycolmap.CameraMode.SINGLE,
        reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu,
    )
    timings["extract"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = threads
    matching.guided_matching = params.guided_matching
    pycolmap.match_exhaustive(db, matching_options=matching, device=pycolmap.Device.cpu)
    timings["match"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    models = pycolmap.incremental_mapping(db, image_dir, sparse_dir, options=mapper)
    timings["map"] = time.perf_counter() - t0
    return models


def _registered_cameras(rec, names: list[str]) -> dict[int, Camera]:
    """View index -> Camera (OpenCV convention: pixel centres at integers) of the model's posed images."""
    index_of = {n: i for i, n in enumerate(names)}
    cams: dict[int, Camera] = {}
    for img in rec.images.values():
        if not img.has_pose:
            continue
        cam = img.camera
        params = np.asarray(cam.params, float)
        model = str(cam.model_name) if hasattr(cam, "model_name") else str(cam.model)
        if "PINHOLE" in model and "SIMPLE" not in model:
            fx, fy, cx, cy = params[:4]
        else:  # SIMPLE_PINHOLE / SIMPLE_RADIAL: f, cx, cy[, k]
            fx = fy = params[0]
            cx, cy = params[1], params[2]
        kmat = np.array([[fx, 0, cx - 0.5], [0, fy, cy - 0.5], [0, 0, 1.0]])
        pose = img.cam_from_world() if callable(img.cam_from_world) else img.cam_from_world
        mat = np.asarray(pose.matrix())
        cams[index_of[img.name]] = Camera(kmat, mat[:, :3], mat[:, 3], int(cam.width), int(cam.height))
    return cams


def _align_to_reference(cams: dict[int, Camera], registered: list[int], reference: list[Camera]
                        ) -> tuple[tuple[float, np.ndarray, np.ndarray], float]:
    """The Umeyama Sim(3) of the registered camera centres onto the reference's and the RMS centre error after it;
    ``cams`` are moved into the reference frame in place."""
    if len(registered) < 3:
        raise SfMFailed("Sim(3) alignment needs at least 3 registered views")
    src = np.array([cams[i].center for i in registered])
    dst = np.array([reference[i].center for i in registered])
    s, r, t = umeyama(src, dst)
    rmse = float(np.sqrt(np.mean(np.sum((s * src @ r.T + t - dst) ** 2, axis=1))))
    for i in registered:
        c = cams[i]
        # x_cam = R_c x + t_c, x = (x' - t) / s R^T  ->  x_cam = R_c R^T x' + (t_c - R_c R^T t / s) ... scaled
        r_new = c.R @ r.T
        t_new = s * c.t - r_new @ t
        cams[i] = Camera(c.K, r_new, t_new, c.width, c.height)
    return (s, r, t), rmse
