"""Which views to match, and over which depths: neighbour selection and per-view depth ranges from cameras alone.

No sparse points are needed. The scene centre is the point closest (least squares) to all optical axes; each
view's depth range is a sphere around it whose radius is ``margin x distance x tan(half field of view)`` (the
largest object that fits in the view, with a margin). Neighbours are ranked by the triangulation angle at the scene
centre (preferring ``best_angle_deg``) weighted by the fraction of the reference frustum they see.
"""

from __future__ import annotations

import numpy as np

from plantbench.cameras import Camera
from plantbench.errors import InputError

from .params import NeighbourParams

__all__ = ["scene_centre", "depth_range", "frustum_overlap", "select_neighbours", "scene_scale"]


def scene_centre(cameras: list[Camera]) -> np.ndarray:
    """(3,) least-squares intersection of the cameras' optical axes."""
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in cameras:
        d = cam.R[2]  # optical axis in world coordinates
        p = np.eye(3) - np.outer(d, d)
        a += p
        b += p @ cam.center
    if np.linalg.cond(a) > 1e8:
        raise InputError("the cameras' optical axes are parallel: no common scene centre (views without overlap?)")
    return np.linalg.solve(a, b)


def scene_scale(cameras: list[Camera]) -> float:
    """Median distance from the cameras to the scene centre: the length scale of the capture."""
    c = scene_centre(cameras)
    return float(np.median([np.linalg.norm(cam.center - c) for cam in cameras]))


def depth_range(cam: Camera, centre: np.ndarray, margin: float) -> tuple[float, float]:
    """(near, far) z-depths of the sphere around ``centre`` that fits the view (radius ``margin`` x distance x
    tan(half the smaller field of view))."""
    zc = float((cam.R @ centre + cam.t)[2])
    if zc <= 0:
        raise InputError("the scene centre is behind a camera (views without overlap?)")
    half = min(np.arctan(0.5 * cam.width / cam.K[0, 0]), np.arctan(0.5 * cam.height / cam.K[1, 1]))
    r = margin * float(np.linalg.norm(cam.center - centre)) * np.tan(half)
    return max(zc - r, 0.05 * zc), zc + r


def frustum_overlap(ref: Camera, src: Camera, near: float, far: float, samples: int = 8) -> float:
    """Fraction of the reference frustum between ``near`` and ``far`` (a samples^2 pixel grid x 5 depths) that
    projects inside ``src`` in front of it."""
    u = np.linspace(0, ref.width - 1, samples)
    v = np.linspace(0, ref.height - 1, samples)
    uu, vv = np.meshgrid(u, v)
    rays = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], 1) @ np.linalg.inv(ref.K).T
    pts = []
    for z in np.linspace(near, far, 5):
        xc = rays * z
        pts.append((xc - ref.t) @ ref.R)  # camera -> world: R^T (xc - t)
    uv, zs = src.project(np.concatenate(pts))
    ok = (zs > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= src.width - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= src.height - 1)
    return float(ok.mean())


def select_neighbours(cameras: list[Camera], params: NeighbourParams | None = None, margin: float = 1.25) -> list[list[int]]:
    """Source views of every reference view, best first.

    Returns
    -------
    list (one per view) of lists of view indices, at most ``params.count`` each.

    Raises
    ------
    InputError when fewer than 2 views are given, or when a view has no usable neighbour (no overlap, or every
    other view is outside the triangulation-angle bounds).
    """
    p = params or NeighbourParams()
    n = len(cameras)
    if n < 2:
        raise InputError(f"multi-view stereo needs at least 2 views, got {n}")
    centre = scene_centre(cameras)
    dirs = np.array([c.center - centre for c in cameras])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    angles = np.degrees(np.arccos(np.clip(dirs @ dirs.T, -1.0, 1.0)))
    out, lonely = [], []
    for i, ref in enumerate(cameras):
        near, far = depth_range(ref, centre, margin)
        scored = []
        for j, src in enumerate(cameras):
            a = angles[i, j]
            if j == i or not p.min_angle_deg <= a <= p.max_angle_deg:
                continue
            ov = frustum_overlap(ref, src, near, far)
            if ov < p.min_overlap:
                continue
            scored.append((ov * np.exp(-((a - p.best_angle_deg) ** 2) / (2 * 10.0**2)), j))
        scored.sort(key=lambda s: -s[0])
        if not scored:
            lonely.append(i)
        out.append([j for _, j in scored[: p.count]])
    if lonely:
        raise InputError(
            f"views without overlap: view(s) {lonely} share no usable field of view with any other view "
            f"(triangulation angle {p.min_angle_deg}-{p.max_angle_deg} deg and frustum overlap >= {p.min_overlap})"
        )
    return out
