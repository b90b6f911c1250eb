"""Analysis-by-synthesis option (Guenard et al. 2014, Eq. 3-4) for guo.

Grow k candidates from one preparation of the cloud, with varied Table 1 parameters (l, phi, psi drawn around the
prior with relative standard deviation ``candidate_jitter``; candidate 0 is the prior itself) and their own random
streams, render each candidate's silhouette in every input view, and keep

    M_i0 = argmax_i p(M_i) p(I | M_i),   p(I | M_i) = 1 - error_i  (Eq. 4),

with error_i the mean over views of #(rendered XOR reference) / #(reference) (Eq. 3) and p(M_i) the species prior:
a product of Gaussians of each parameter's relative deviation from the species value, sigma = the jitter.

The reference masks are estimated from the input views, not read from ground truth (``views/instance``): colour
segmentation against the background (ground, sky) inside the region the cloud projects to (:func:`estimate_masks`).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from plantbench.cameras import Camera
from plantbench.errors import InputError
from reference_impl.guo.params import GuoParams, SpeciesPrior
from reference_impl.guo.pipeline import GuoResult, model, prepare

__all__ = ["load_input_views", "estimate_masks", "candidate_priors", "prior_probability", "analysis_by_synthesis"]


def load_input_views(capture_dir: str | Path) -> tuple[list[Camera], list[np.ndarray]]:
    """The input views of a points capture: ``capture_dir/views/cameras.json`` and the RGB images (uint8)."""
    from PIL import Image

    from plantbench.cameras import read_cameras

    views = Path(capture_dir) / "views"
    path = views / "cameras.json"
    if not path.is_file():
        raise InputError("analysis-by-synthesis (candidates > 1) needs the input views (views/cameras.json); a scan "
                         "capture has none", path=path)
    cameras, names = read_cameras(path)
    images = []
    for cam, name in zip(cameras, names):
        p = views / "images" / Path(name).name
        if not p.is_file():
            raise InputError("image missing for a camera", path=p)
        img = np.asarray(Image.open(p).convert("RGB"))
        if img.shape[:2] != (cam.height, cam.width):
            raise InputError(f"image is {img.shape[:2]}, camera is {(cam.height, cam.width)}", path=p)
        images.append(img)
    return cameras, images


def _splat(points: np.ndarray, cam: Camera) -> np.ndarray:
    uv, z = cam.project(points)
    ok = (z > 0) & np.all(np.isfinite(uv), axis=1)
    u = np.round(uv[ok, 0]).astype(np.int64)
    v = np.round(uv[ok, 1]).astype(np.int64)
    inside = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    mask = np.zeros((cam.height, cam.width), bool)
    mask[v[inside], u[inside]] = True
    return mask


def estimate_masks(points: np.ndarray, cameras: list[Camera], images: list[np.ndarray], *, dilation: int = 2,
                   margin: int = 8, clusters: int = 3, threshold: float = 3.5, seed: int = 0) -> list[np.ndarray]:
    """Plant masks of the input views, estimated from the images and the cloud (no ground truth).

    Per view: the cloud's splat S (the images' own 3D estimate, projected); the plant's image region, the convex hull
    of S grown by ``margin`` pixels; a background colour model from the pixels outside that region (``clusters``
    k-means clusters of RGB, each with its own covariance: ground, sky, shadow); the mask is every pixel of the
    region farther than ``threshold`` (Mahalanobis) from all background clusters, plus S closed with a disk of
    ``dilation`` pixels.
    """
    from scipy import ndimage
    from scipy.cluster.vq import kmeans2
    from skimage.morphology import convex_hull_image

    out = []
    disk = np.hypot(*np.mgrid[-dilation:dilation + 1, -dilation:dilation + 1]) <= dilation
    for v, (cam, img) in enumerate(zip(cameras, images)):
        s = _splat(points, cam)
        mask = ndimage.binary_closing(ndimage.binary_dilation(s, disk), disk)
        if s.sum() >= 3:
            region = ndimage.binary_dilation(convex_hull_image(s), iterations=margin)
            col = img.reshape(-1, 3).astype(np.float64)
            bg = col[~region.ravel()]
            if len(bg) > 50 * clusters:
                rs = np.random.default_rng([seed, v])
                sub = bg[rs.choice(len(bg), min(len(bg), 20000), replace=False)]
                k = int(min(clusters, len(np.unique(sub, axis=0))))
                with warnings.catch_warnings():   # a flat background has fewer distinct colours than clusters
                    warnings.simplefilter("ignore")
                    _, lab = kmeans2(sub, k, minit="++", seed=rs)
                inside = np.flatnonzero(region.ravel())
                best = np.full(len(inside), np.inf)
                for c in range(k):
                    mem = sub[lab == c]
                    if len(mem) < 10:
                        continue
                    icov = np.linalg.inv(np.cov(mem.T) + np.eye(3))
                    diff = col[inside] - mem.mean(0)
                    best = np.minimum(best, np.sqrt(np.einsum("ij,jk,ik->i", diff, icov, diff)))
                flat = mask.ravel()
                flat[inside[best > threshold]] = True
                mask = flat.reshape(s.shape)
        out.append(mask)
    return out


def candidate_priors(prior: SpeciesPrior, k: int, jitter: float, rng: np.random.Generator) -> list[SpeciesPrior]:
    """k parameter sets: the prior, then k - 1 draws with l, phi, psi scaled by exp(N(0, jitter))."""
    out = [prior]
    for _ in range(k - 1):
        f = np.exp(rng.normal(0.0, jitter, 3))
        out.append(replace(prior, internode_length=float(prior.internode_length * f[0]),
                           roll_angle=float(prior.roll_angle * f[1]),
                           branching_angle=float(np.clip(prior.branching_angle * f[2], 5.0, 90.0))))
    return out


def prior_probability(candidate: SpeciesPrior, prior: SpeciesPrior, jitter: float) -> float:
    """p(M): product of Gaussians of the log-ratios of l, phi, psi to the species values (sigma = jitter)."""
    r = np.log([candidate.internode_length / prior.internode_length, candidate.roll_angle / prior.roll_angle,
                candidate.branching_angle / prior.branching_angle])
    return float(np.exp(-0.5 * np.sum((r / jitter) ** 2)))


def analysis_by_synthesis(points: np.ndarray, cameras: list[Camera], images: list[np.ndarray],
                          rng: np.random.Generator, params: GuoParams, prior: SpeciesPrior,
                          fitted=None, merge: bool = False) -> GuoResult:
    """Grow ``params.candidates`` candidates and keep the one maximising p(M) (1 - reprojection error).
    ``fitted``: image-fitted leaves (mesh, Leaf list) that replace the procedural ones, as in :func:`model`."""
    from plantbench.metrics.reprojection import render_silhouettes, reprojection_error

    if len(cameras) == 0:
        raise InputError("analysis-by-synthesis: no input views")
    t0 = time.perf_counter()
    prep = prepare(points, rng, params, prior)
    masks = estimate_masks(prep.plant, cameras, images, dilation=params.mask_dilation)
    t_masks = time.perf_counter() - t0
    cands = candidate_priors(prior, params.candidates, params.candidate_jitter, rng)
    scores, errors, priors = [], [], []
    best, best_score = None, -np.inf
    for i, cand in enumerate(cands):
        res = model(prep, cand, params, np.random.default_rng(rng.integers(2**63)), fitted, merge)
        err = reprojection_error(masks, render_silhouettes(res.mesh, cameras)).error
        err = 1.0 if err is None else float(err)
        pm = prior_probability(cand, prior, params.candidate_jitter)
        score = pm * max(0.0, 1.0 - err)
        scores.append(score)
        errors.append(err)
        priors.append(pm)
        if score > best_score or best is None:
            best, best_score = (i, res), score
    i, res = best
    info = {"prepare": prep.info} | res.info | {
        "abs": {"candidates": len(cands), "chosen": i, "scores": scores, "errors": errors, "priors": priors,
                "params": [[c.internode_length, c.roll_angle, c.branching_angle] for c in cands],
                "mask_seconds": t_masks, "seconds": time.perf_counter() - t0}}
    return GuoResult(res.skeleton, res.mesh, res.leaves, info)
