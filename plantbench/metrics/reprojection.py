"""Reprojection error (Guenard et al. 2014, Eq. 3) and silhouette IoU.

Per view i: error_i = #(rendered XOR reference) / #(reference), the reference being the ground-truth plant mask
(instance map > 0) and the rendered mask the reconstruction's silhouette seen by the same camera; reported as the
mean over views, beside IoU_i = #(rendered AND reference) / #(rendered OR reference) because the XOR ratio is
unbounded above (a render that overshoots can exceed 1).

Views larger than :data:`MAX_PX` are scored on a regular subset of their pixels (:func:`strided`): every s-th
pixel centre along each axis, s = ceil(longer side / MAX_PX), the reference mask read at the same pixels and the
silhouette cast through them (the same pixels' rays, exactly: a 1024 px view scores 512 x 512 of its own pixels).
The counts of a uniform quarter of a megapixel estimate the ratios of the whole view; the silhouette's ray casting,
which grew with the pixel count (a third of a 512 px multiview cell's metrics), stays at its 512 px cost.

Degenerate input: a view whose reference mask is empty has no error_i (it is left out of the mean; error is None
when every view is empty); its IoU is 1 when the render is empty too, else 0. Different view counts or image
sizes raise InputError.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from plantbench.cameras import Camera
from plantbench.errors import InputError
from plantbench.plant import TriMesh

__all__ = ["MAX_PX", "ReprojectionResult", "reprojection_error", "render_silhouettes", "strided"]

MAX_PX = 512
"""Longest side, in scored pixels, of a view (see the module docstring)."""


def strided(camera: Camera, max_px: int = MAX_PX) -> tuple[Camera, int]:
    """The camera whose pixel (u, v) is ``camera``'s pixel (s u, s v), s = ceil(longer side / ``max_px``) (1: the
    camera itself), and s: its intrinsics scaled by 1 / s (OpenCV pixel centres at integers, so that u = s u' exactly)
    and its image ceil(w / s) x ceil(h / s), the size of ``mask[::s, ::s]``."""
    s = max(1, -(-max(camera.width, camera.height) // max_px))
    if s == 1:
        return camera, 1
    k = np.diag([1.0 / s, 1.0 / s, 1.0]) @ camera.K
    return Camera(k, camera.R, camera.t, -(-camera.width // s), -(-camera.height // s)), s


@dataclass(frozen=True)
class ReprojectionResult:
    per_view_error: np.ndarray
    """(v,) float, NaN for a view with an empty reference mask"""
    per_view_iou: np.ndarray
    """(v,) float"""
    error: float | None
    """mean of the defined per-view errors"""
    iou: float
    """mean per-view IoU"""


def reprojection_error(gt_masks, pred_masks) -> ReprojectionResult:
    """Eq. 3 per view and its mean, plus IoU.

    Parameters
    ----------
    gt_masks, pred_masks : sequences of (h, w) bool (or anything whose nonzero pixels are the plant), one per view,
        same count and per-view shapes.
    """
    if len(gt_masks) != len(pred_masks):
        raise InputError(f"reprojection: {len(gt_masks)} reference masks but {len(pred_masks)} rendered masks")
    if len(gt_masks) == 0:
        raise InputError("reprojection: no views")
    err = np.full(len(gt_masks), np.nan)
    iou = np.zeros(len(gt_masks))
    for i, (g, p) in enumerate(zip(gt_masks, pred_masks)):
        g, p = np.asarray(g) != 0, np.asarray(p) != 0
        if g.shape != p.shape or g.ndim != 2:
            raise InputError(f"reprojection: view {i}: mask shapes differ or are not 2-D ({g.shape} vs {p.shape})")
        n_ref = int(np.count_nonzero(g))
        union = int(np.count_nonzero(g | p))
        if n_ref:
            err[i] = np.count_nonzero(g ^ p) / n_ref
        iou[i] = np.count_nonzero(g & p) / union if union else 1.0
    ok = np.isfinite(err)
    return ReprojectionResult(err, iou, float(err[ok].mean()) if ok.any() else None, float(iou.mean()))


def render_silhouettes(mesh: TriMesh, cameras: list[Camera], *, scene=None) -> list[np.ndarray]:
    """Binary silhouette of a mesh in each camera: exact ray casting through every pixel centre (Open3D).

    Returns one (height, width) bool array per camera; all False for a mesh without triangles.
    scene : :func:`plantbench.metrics.surface.raycasting_scene` of ``mesh`` when the caller has one.
    """
    if len(mesh.faces) == 0:
        return [np.zeros((c.height, c.width), bool) for c in cameras]
    import open3d as o3d

    from plantbench.backend import open3d_threads
    from plantbench.metrics.surface import raycasting_scene

    nthreads = open3d_threads()
    scene = raycasting_scene(mesh) if scene is None else scene
    out = []
    for cam in cameras:
        origin, dirs = cam.pixel_rays()
        rays = np.empty((len(dirs), 6), np.float32)
        rays[:, :3] = origin
        rays[:, 3:] = dirs
        hit = scene.test_occlusions(o3d.core.Tensor(rays), nthreads=nthreads).numpy()
        out.append(hit.reshape(cam.height, cam.width).astype(bool))
    return out
